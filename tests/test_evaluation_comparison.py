"""Role metrics over whole maneuvers and zoomed intervals, against hand-computed values."""

import numpy as np
import pytest

from hybridfmu.evaluation.comparison import ManeuverRun, pooled_errors, role_metrics

SIGNALS = ["angle", "speed"]
ZOOM = {"length_s": {"angle": 0.3, "speed": 0.2}, "criterion": {"angle": "growth", "speed": "mse"}, "intervals": {}}


def _run(name, n=11, fmu_angle_offset=0.2, neural_angle_offset=0.05):
    t = np.linspace(0.0, 1.0, n)
    data = np.column_stack([np.linspace(0, 2, n), np.full(n, 2.0)])
    fmu = data + np.column_stack([fmu_angle_offset * 10 * t ** 2,   # error grows 0 .. 10*offset, fastest at the end
                                  np.full(n, 1.0)])                 # speed error 1
    neural = data + np.column_stack([np.full(n, neural_angle_offset), np.full(n, -0.5)])
    return ManeuverRun(name, t, SIGNALS, data, fmu, neural)


def test_role_metrics_by_hand():
    run = _run("validation")
    metrics = role_metrics("validation", [run], ZOOM, {"dt_s": -2e-5})
    # FMU angle error = 2 t^2, t = 0, 0.1, ..., 1 -> mean |e| = 2 * 3.85 / 11 = 0.7; mean e^2 = 4 * mean(t^4)
    assert metrics["fmu"]["angle_mae"] == pytest.approx(0.7)
    assert metrics["fmu"]["angle_mse"] == pytest.approx(4 * np.mean(np.linspace(0, 1, 11) ** 4))
    assert metrics["fmu"]["speed_mae"] == pytest.approx(1.0)
    assert metrics["neural_fmu"]["angle_mae"] == pytest.approx(0.05)
    assert metrics["neural_fmu"]["speed_mse"] == pytest.approx(0.25)
    assert metrics["improvement"]["angle_mae"] == pytest.approx(14.0)
    assert metrics["improvement"]["speed_mse"] == pytest.approx(4.0)
    assert metrics["fmu"]["speed_rmse"] == pytest.approx(1.0) and metrics["neural_fmu"]["speed_rmse"] == 0.5
    assert metrics["improvement"]["speed_rmse"] == pytest.approx(2.0)
    assert list(metrics["fmu"]) == [f"{s}_{m}" for s in SIGNALS for m in ("mae", "mse", "rmse")]
    assert metrics["signals"] == SIGNALS
    assert metrics["dt_s"] == -2e-5 and metrics["samples"] == 11 and metrics["duration_s"] == pytest.approx(1.0)
    angle_zoom, speed_zoom = metrics["zooms"]
    assert angle_zoom["signal"] == "angle" and angle_zoom["source"] == "auto" and angle_zoom["criterion"] == "growth"
    # the error grows fastest at the end: window [0.7, 1.0] s
    assert (angle_zoom["t_start_s"], angle_zoom["t_end_s"]) == pytest.approx((0.7, 1.0))
    # there: FMU angle errors 0.98, 1.28, 1.62, 2.0 -> MAE 1.47; neural 0.05 -> x29.4
    assert angle_zoom["fmu"]["angle_mae"] == pytest.approx(1.47)
    assert angle_zoom["improvement"]["angle_mae"] == pytest.approx(29.4)
    assert speed_zoom["signal"] == "speed" and speed_zoom["criterion"] == "mse"


def test_one_target_signal_and_one_length_for_all():
    """Any number of target signals: one signal, one zoom length and the default criterion."""
    t = np.linspace(0.0, 1.0, 101)
    run = ManeuverRun("m", t, ["level"], np.zeros(101), np.sin(t), np.zeros(101) + 0.01)
    metrics = role_metrics("test", [run], {"length_s": 0.25}, {})
    assert set(metrics["fmu"]) == {"level_mae", "level_mse", "level_rmse"}
    (zoom,) = metrics["zooms"]
    assert zoom["signal"] == "level" and zoom["t_end_s"] - zoom["t_start_s"] == pytest.approx(0.25)
    with pytest.raises(ValueError, match=r"zoom\.length_s: signal\(s\) \['speed'\]"):
        role_metrics("test", [run], {"length_s": {"speed": 1.0}}, {})


def test_pooled_over_maneuvers_and_configured_zoom():
    a, b = _run("test_a"), _run("test_b", n=21, fmu_angle_offset=0.0)
    pooled = pooled_errors([a, b], "fmu")
    errors = np.concatenate([2 * np.linspace(0, 1, 11) ** 2, np.zeros(21)])
    assert pooled["angle_mae"] == pytest.approx(errors.mean())
    metrics = role_metrics("test", [a, b], {"intervals": {"test_b": [{"t_start_s": 0.5, "t_end_s": 0.6,
                                                                       "signal": "speed"}]}}, {})
    assert metrics["maneuvers"] == ["test_a", "test_b"] and set(metrics["per_maneuver"]) == {"test_a", "test_b"}
    configured = [z for z in metrics["zooms"] if z["source"] == "config"]
    assert len(configured) == 1 and configured[0]["maneuver"] == "test_b"
    assert len(metrics["zooms"]) == 4


def test_shape_mismatch_named():
    t = np.linspace(0, 1, 5)
    two = np.column_stack([t, t])
    with pytest.raises(ValueError, match=r"neural_fmu has shape \(4, 2\), expected \(5, 2\)"):
        ManeuverRun("m", t, SIGNALS, two, two, two[:4])
    with pytest.raises(ValueError, match=r"x\.parquet: column\(s\) \['neural_fmu_speed'\] missing"):
        import pandas as pd
        ManeuverRun.from_frame(pd.DataFrame({c: t for c in ("time_s", "data_angle", "data_speed", "fmu_angle",
                                                            "fmu_speed", "neural_fmu_angle")}), "m", SIGNALS,
                               "x.parquet")
    with pytest.raises(ValueError, match="no maneuver with role"):
        role_metrics("test", [], {}, {})


def test_further_models_are_compared_with_the_fmu_and_tabled():
    """FMU + effects and the hybrid beside the neural FMU: their errors, factors against the FMU, the report's
    table of all models; a model only some maneuvers have is left out; an unknown model is refused."""
    import pandas as pd

    from hybridfmu.evaluation.report import models_table
    from hybridfmu.evaluation.tracking import flat_metrics

    first, second = _run("a"), _run("b")
    for run, offset in ((first, 0.1), (second, 0.3)):
        run.further = {"fmu_effects": run.data + offset, "hybrid": run.data + offset / 2}
    metrics = role_metrics("test", [first, second], ZOOM, {})
    assert metrics["fmu_effects"]["speed_mae"] == pytest.approx(0.2)
    assert metrics["hybrid"]["angle_mse"] == pytest.approx((0.05 ** 2 + 0.15 ** 2) / 2)
    assert metrics["improvement_hybrid"]["speed_mae"] == pytest.approx(1.0 / 0.1)
    assert metrics["per_maneuver"]["a"]["improvement_fmu_effects"]["speed_mae"] == pytest.approx(10.0)
    table = models_table({"test": metrics}, {"angle": "rad", "speed": "rad/s"})
    assert table[0] == "| data | signal | measure | FMU | FMU + diagnosed effects | neural FMU | hybrid (FMU + effects + ANN) |"
    assert "| test | speed | MAE | 1 rad/s | 0.2 rad/s (×5) | 0.5 rad/s (×2) | 0.1 rad/s (×10) |" in table
    assert {"test/hybrid/speed_mae", "test/improvement_fmu_effects/angle_mae"} <= set(flat_metrics({"test": metrics}))
    second.further = {"fmu_effects": second.data}
    partial = role_metrics("test", [first, second], ZOOM, {})
    assert "hybrid" not in partial and "fmu_effects" in partial
    assert models_table({"test": role_metrics("test", [_run("c")], ZOOM, {})}) == []
    frame = pd.DataFrame({"time_s": first.time_s, **{f"{kind}_{s}": getattr(first, kind)[:, k]
                                                     for kind in ("data", "fmu", "neural_fmu")
                                                     for k, s in enumerate(SIGNALS)},
                          **{f"hybrid_{s}": first.further["hybrid"][:, k] for k, s in enumerate(SIGNALS)}})
    loaded = ManeuverRun.from_frame(frame, "a", SIGNALS)
    assert loaded.models == ["fmu", "neural_fmu", "hybrid"]
    with pytest.raises(ValueError, match=r"unknown model\(s\) \['ann'\]"):
        ManeuverRun("x", first.time_s, SIGNALS, first.data, first.fmu, first.neural_fmu, further={"ann": first.data})


def test_trained_coefficients_are_tabled_with_their_change():
    """The report lists a hybrid's trained effect coefficients beside the diagnosed ones (relative change; none
    for a zero start; a '|' of an effect name escaped so the table keeps its columns); none when they were
    fixed."""
    from hybridfmu.evaluation.report import coefficient_lines

    lines = coefficient_lines({"coulomb(w)*|tau|[0]": {"diagnosed": 400.0, "trained": 410.0},
                               "periodic(x)[1]": {"diagnosed": 0.0, "trained": 0.25}})
    assert "| `coulomb(w)*\\|tau\\|[0]` | 400 | 410 | +2.5 % |" in lines
    assert "| `periodic(x)[1]` | 0 | 0.25 | – |" in lines
    assert all(line.count("|") - line.count("\\|") in (0, 5) for line in lines)
    assert coefficient_lines({}) == [] and coefficient_lines(None) == []


def test_in_tolerance_metrics_distributions_and_warnings_by_hand():
    """In step: share of time within the tolerance, exits, errors while within; median and range over the
    maneuvers; a model worse than its own physics is named."""
    from hybridfmu.evaluation.comparison import tolerance_settings
    from hybridfmu.evaluation.report import distribution_table, warning_lines

    t = np.linspace(0.0, 1.0, 11)
    data = np.column_stack([np.linspace(0, 2, 11), np.full(11, 2.0)])
    slip = np.where(np.arange(11) >= 6, 1.0, 0.05)  # in step for 6 samples, then 1 rad off
    fmu = data + np.column_stack([np.full(11, 2.0), np.full(11, 1.0)])
    runs = []
    for name, hybrid_offset in (("a", 0.02), ("b", 0.5), ("c", 0.1)):
        neural = data + np.column_stack([slip, np.full(11, 0.5)])
        effects = data + np.column_stack([np.full(11, 0.1), np.full(11, 0.2)])
        hybrid = data + np.column_stack([np.full(11, hybrid_offset), np.full(11, 0.1)])
        runs.append(ManeuverRun(name, t, SIGNALS, data, fmu, neural,
                                further={"fmu_effects": effects, "hybrid": hybrid, "ceiling": data + 0.001}))
    tolerance = tolerance_settings({"signals": {"angle": 0.3}}, SIGNALS, runs[:1])
    assert tolerance == {"signals": {"angle": 0.3}, "source": "config"}
    metrics = role_metrics("test", runs, ZOOM, {}, tolerance)
    neural = metrics["per_maneuver"]["a"]["in_tolerance"]["neural_fmu"]
    assert neural["in_tolerance_share"] == pytest.approx(6 / 11) and neural["tolerance_exits"] == 1
    assert neural["angle_mae_in_tolerance"] == pytest.approx(0.05)
    assert neural["speed_mae_in_tolerance"] == pytest.approx(0.5)
    fmu = metrics["per_maneuver"]["a"]["in_tolerance"]["fmu"]
    assert fmu["in_tolerance_share"] == 0.0 and fmu["angle_mae_in_tolerance"] is None
    hybrid = metrics["distribution"]["hybrid"]["angle_mae_factor"]  # FMU 2.0 over 0.02, 0.5, 0.1
    assert (hybrid["median"], hybrid["min"], hybrid["max"], hybrid["n"]) == pytest.approx((20.0, 4.0, 100.0, 3))
    assert metrics["distribution"]["ceiling"]["angle_mae"]["median"] == pytest.approx(0.001)
    assert metrics["models"] == ["fmu", "fmu_effects", "neural_fmu", "hybrid", "ceiling"]
    # the hybrid (0.5) is worse than its physical layer, the FMU + effects (0.1), on maneuver b only
    (warning,) = metrics["warnings"]
    assert warning.startswith("b: hybrid is worse than fmu_effects, its own physics, in angle MAE (0.5 against 0.1")
    assert warning_lines({"test": metrics}) == [f"- **WARNING** test: {warning}"]
    table = "\n".join(distribution_table({"test": metrics}))
    assert "| test | 3 | hybrid (FMU + effects + ANN) | ×20 [×4 – ×100] |" in table
    assert "| test | 3 | ceiling (true plant) |" in table
    # defaults chosen from the validation maneuvers' data: 5 % of each signal's 1st..99th percentile range
    angle_only = [ManeuverRun("v", t, ["angle"], data[:, 0], data[:, 0] + 2.0, data[:, 0])]
    chosen = tolerance_settings({}, ["angle"], angle_only)
    assert chosen["signals"]["angle"] == pytest.approx(0.05 * (np.percentile(data[:, 0], 99)
                                                                - np.percentile(data[:, 0], 1)))
    assert chosen["source"].startswith("chosen from the data")
    with pytest.raises(ValueError, match="speed does not vary"):  # speed is constant: its tolerance must be named
        tolerance_settings({"fraction_of_range": 0.05}, ["speed"], [ManeuverRun("v", t, ["speed"], data[:, 1],
                                                                                 data[:, 1], data[:, 1])])
    with pytest.raises(ValueError, match=r"config.evaluation.tolerance.signals: \['torque'\]"):
        tolerance_settings({"signals": {"torque": 1.0}}, SIGNALS, runs)


def test_closed_loop_errors_factors_and_warnings_by_hand(tmp_path):
    """Closed-loop trajectories: errors per model, factors against the FMU's closed loop, median over the maneuvers,
    a model worse than its own physics in closed loop is named; read back from the saved frames."""
    import pandas as pd

    from hybridfmu.evaluation.evaluate import read_closed_loop
    from hybridfmu.evaluation.report import distribution_table

    t = np.linspace(0.0, 1.0, 11)
    data = np.column_stack([np.linspace(0, 2, 11), np.full(11, 2.0)])
    runs = []
    for name, hybrid_error in (("a", 0.01), ("b", 0.2), ("c", 0.04)):
        closed = {"fmu": data + 0.1, "neural_fmu": data + 0.05, "fmu_effects": data + 0.02,
                  "hybrid": data + hybrid_error}
        runs.append(ManeuverRun(name, t, SIGNALS, data, data + 1.0, data + 0.5, closed_loop=closed,
                                further={"fmu_effects": data + 0.3, "hybrid": data + 0.3}))
    metrics = role_metrics("test", runs, ZOOM, {})
    assert metrics["per_maneuver"]["a"]["closed_loop"]["hybrid"]["angle_mae"] == pytest.approx(0.01)
    factor = metrics["distribution"]["hybrid"]["angle_mae_closed_loop_factor"]  # 0.1 over 0.01, 0.2, 0.04
    assert (factor["median"], factor["min"], factor["max"]) == pytest.approx((2.5, 0.5, 10.0))
    assert metrics["distribution"]["neural_fmu"]["speed_mae_closed_loop_factor"]["median"] == pytest.approx(2.0)
    closed_warnings = [w for w in metrics["warnings"] if "closed-loop" in w]
    assert closed_warnings == metrics["warnings"] and len(closed_warnings) == 4  # b and c: 0.2, 0.04 > 0.02
    assert closed_warnings[0].startswith("b: hybrid is worse than fmu_effects, its own physics, in closed-loop angle "
                                         "MAE (0.2 against 0.02")
    assert "closed-loop MAE vs FMU" in distribution_table({"test": metrics})[0]
    assert "closed-loop" not in distribution_table({"test": role_metrics("test", [
        ManeuverRun("a", t, SIGNALS, data, data + 1.0, data + 0.5)], ZOOM, {})})[0]
    # the rule's files: one per model, checked against the maneuver's grid
    paths = []
    for kind in ("fmu", "hybrid"):
        path = tmp_path / f"{kind}.parquet"
        pd.DataFrame({"time_s": t, **{f"closed_loop_{kind}_{s}": runs[0].closed_loop[kind][:, k]
                                      for k, s in enumerate(SIGNALS)}}).to_parquet(path)
        paths.append(path)
    columns = read_closed_loop(paths, ["fmu", "hybrid"], SIGNALS, t)
    np.testing.assert_array_equal(columns["closed_loop_hybrid_angle"], data[:, 0] + 0.01)
    with pytest.raises(ValueError, match=r"fmu.parquet: time_s does not match the maneuver.s grid"):
        read_closed_loop(paths, ["fmu", "hybrid"], SIGNALS, t[:-1])
    with pytest.raises(ValueError, match=r"fmu.parquet: column\(s\) \['closed_loop_neural_fmu_angle'"):
        read_closed_loop(paths[:1], ["neural_fmu"], SIGNALS, t)
