"""The report puts this run's improvement factors beside a reference's (the paper's) and lists the figures;
labels and units come from the case's signals."""

import yaml

from hybridfmu.evaluation.metrics import improvement_factors
from hybridfmu.evaluation.report import ReportFigure, render_report
from test_evaluation_baseline import motor_roles

UNITS = {"angle": "rad", "speed": "rad/s"}


def _reference():
    """The paper's results as config/config.yaml declares them (section evaluation.reference)."""
    from pathlib import Path

    config = yaml.safe_load((Path(__file__).resolve().parents[1] / "config" / "config.yaml").read_text())
    return config["evaluation"]["reference"]


def _metrics(role, fmu, neural):
    zoom = {"maneuver": role, "signal": "angle", "source": "auto", "criterion": "growth", "t_start_s": 1.0,
            "t_end_s": 3.0, "fmu": fmu, "neural_fmu": neural, "improvement": improvement_factors(fmu, neural)}
    return {"signals": ["angle", "speed"], "fmu": fmu, "neural_fmu": neural,
            "improvement": improvement_factors(fmu, neural), "zooms": [zoom]}


def test_report_tables_and_verdicts():
    fmu = {"angle_mae": 10.0, "angle_mse": 200.0, "speed_mae": 6.0, "speed_mse": 90.0}
    good = {"angle_mae": 1.0, "angle_mse": 2.0, "speed_mae": 2.0, "speed_mse": 10.0}    # x10, x100, x3, x9
    weak = {"angle_mae": 5.0, "angle_mse": 100.0, "speed_mae": 6.0, "speed_mse": 90.0}  # x2, x2, x1, x1
    text = render_report(
        "tiny", {"validation": _metrics("validation", fmu, good), "test": _metrics("test", fmu, weak)},
        {"lr": 3e-6, "width": 8}, {"trial": "t007"}, dt_s={"inputs": -2.0e-5}, gates=[0.9, 0.3],
        true_dt_s={"inputs": -5.0e-5},
        truth_source="raw/test.truth.json", figures=[ReportFigure("figures/test_angle.png", "Test angle")],
        mlflow_run={"run_id": "abc", "experiment": "tiny", "tracking_uri": "sqlite:///x.db"}, units=UNITS,
        reference=_reference())
    assert "| validation | angle | MAE | 10 rad | 1 rad | ×10 | ×4.6 (Figs. 9-10) |" in text
    assert "| test | speed | MSE | 90 (rad/s)² | 90 (rad/s)² | ×1 | not reported |" in text
    assert "| validation | validation | 1.000 – 3.000 | angle | auto (growth) |" in text
    assert "| test | angle | MSE | 200 rad² | 100 rad² | ×2 | ×74 (Fig. 13) |" in text
    assert "validation angle MSE: ×100 against the paper's ×61 (Figs. 9-10) — reached." in text
    assert "test angle MAE: ×2 against the paper's ×5.4 (Fig. 13) — not reached." in text
    assert "| inputs | -20.00 µs | - | -50.00 µs | +30.00 µs |" in text
    assert "![Test angle](figures/test_angle.png)" in text
    assert "| lr | 3e-06 |" in text and "Evaluation run `abc`" in text


def test_report_without_truth():
    fmu = {"angle_mae": 1.0, "angle_mse": 1.0, "speed_mae": 1.0, "speed_mse": 1.0}
    text = render_report("user", {"test": _metrics("test", fmu, fmu)}, {}, {}, dt_s={"inputs": 1e-6}, gates=None,
                         true_dt_s=None, truth_source=None, figures=[], mlflow_run=None)
    assert "true time offsets are unknown" in text and "| validation |" not in text
    assert "paper" not in text  # no reference configured: nothing to compare with


def test_write_report_from_files(tmp_path):
    import json

    import pytest

    from hybridfmu.evaluation.report import true_input_delay, write_report

    fmu = {"angle_mae": 10.0, "angle_mse": 200.0, "speed_mae": 6.0, "speed_mse": 90.0}
    neural = {"angle_mae": 2.0, "angle_mse": 2.0, "speed_mae": 3.0, "speed_mse": 10.0}
    paths = []
    for role in ("validation", "test"):
        metrics = {**_metrics(role, fmu, neural), "maneuvers": [role],
                   "dt_s": {"duties": 2.5e-5, "rest": -1e-6},
                   "gates": {"omega": {"g_F": 1.0, "g_A": 0.3}}}
        path = tmp_path / "metrics" / f"{role}.json"
        path.parent.mkdir(exist_ok=True)
        path.write_text(json.dumps(metrics))
        paths.append(str(path))
    best = tmp_path / "best.json"
    best.write_text(json.dumps({"trial_id": "b2c1", "hyperparameters": {"lr": 3e-6, "depth": 4},
                                "checkpoint": "x.pt", "objective": 0.12, "mlflow_run_id": "r1",
                                "model_spec": {"delay_groups": {"duties": ["d_a", "d_b", "d_c"],
                                                                "rest": ["u_dc", "tau_load"]}}}))
    run = tmp_path / "run.json"
    run.write_text(json.dumps({"tracking_uri": "sqlite:///x", "experiment": "e", "run_id": "r2"}))
    offset = tmp_path / "offset.json"
    offset.write_text(json.dumps({"maneuver": "train", "t_start_s": 1.0, "t_end_s": 1.02, "input_delay_s": 3e-5,
                                  "signals": ["angle", "speed"], "mse_without_delay": {"angle": 0.1, "speed": 4.0},
                                  "mse_with_delay": {"angle": 0.05, "speed": 1.0},
                                  "groups": {"duties": {"delay_s": 3.1e-5, "windows": 100, "window_samples": 4},
                                             "rest": {"delay_s": 2e-6, "windows": 80, "window_samples": 4}}}))
    truth = tmp_path / "test.truth.json"
    truth.write_text(json.dumps({"time_offset": {"input_delay_s": 3e-5, "channels": ["DUTY_A", "DUTY_B",
                                                                   "DUTY_C"]}}))
    figures = {"validation_angle": str(tmp_path / "figures" / "validation_angle.png"),
               "time_offset": str(tmp_path / "figures" / "time_offset.png")}
    report = write_report(tmp_path / "report.md", "tiny", paths, best, run, offset, figures, [str(truth)],
                          roles=motor_roles(), reference=_reference(), log_to_mlflow=False)
    text = report.read_text()
    assert "| validation | angle | MAE | 10 rad | 2 rad | ×5 | ×4.6 (Figs. 9-10) |" in text
    # the truth applies to the logged channels it names; the other inputs are true to 0
    assert "| duties | 25.00 µs | 31.00 µs | 30.00 µs | -5.00 µs |" in text
    assert "| rest | -1.00 µs | 2.00 µs | 0.00 µs | -1.00 µs |" in text
    assert "duties 31.00 µs (100 windows of 4 steps)" in text
    assert "![Validation maneuver 'validation': angle, whole trajectory, open loop (cf. paper Fig. 9).]" \
           "(figures/validation_angle.png)" in text
    assert "speed MSE 4 → 1 (rad/s)²" in text
    assert "| depth | 4 |" in text and "trial_id: b2c1" in text and "estimated input delay 30.0 µs" in text
    assert "chosen by: the validation objective" in text
    chosen = json.loads(best.read_text())
    chosen["selection"] = {"by": "maneuvers", "maneuvers": ["train", "validation"], "score": 0.1211,
                           "objective_rank": 2, "finalists": [{"trial_id": "b2c0"}, {"trial_id": "b2c1"}]}
    best.write_text(json.dumps(chosen))
    text = write_report(tmp_path / "report.md", "tiny", paths, best, run, offset, figures, [str(truth)],
                        roles=motor_roles(), reference=_reference(), log_to_mlflow=False).read_text()
    assert ("chosen by: open loop over the whole train and validation maneuvers (error 0.121 of the FMU's; "
            "rank 2 by the objective among 2 finalists)") in text
    bad = tmp_path / "bad.truth.json"
    bad.write_text("{}")
    with pytest.raises(ValueError, match=r"bad\.truth\.json: field 'time_offset.input_delay_s' missing"):
        true_input_delay([str(bad)])
    assert true_input_delay([]) == (None, None)
    # a group mixing offset and plain channels has no single true offset; without channels all inputs are offset
    channels = {"d_a": "DUTY_A", "u_dc": "U_DC"}
    assert true_input_delay([str(truth)], {"all": ["d_a", "u_dc"]}, channels)[0] == {"all": None}
    plain = tmp_path / "plain.truth.json"
    plain.write_text(json.dumps({"time_offset": {"input_delay_s": 3e-5}}))
    assert true_input_delay([str(plain)], {"all": ["d_a", "u_dc"]}, channels)[0] == {"all": 3e-5}


def test_delay_table_shows_the_estimates_error_and_the_band_the_delay_learned_within():
    from hybridfmu.evaluation.report import delay_lines

    estimates = {"duties": {"delay_s": 2.845e-5, "standard_error_s": 6.1e-7, "identified": True},
                 "load": {"delay_s": 0.0, "standard_error_s": None, "identified": False}}
    lines = delay_lines({"duties": 2.7e-5, "load": 2e-6}, {"duties": 3e-5, "load": 0.0}, "truth.json", None,
                        estimates, {"duties": [2.66e-5, 3.03e-5]})
    assert lines[0] == "| input group | learned Δt | time-offset estimate | learned within | true offset | learned − true |"
    assert "| duties | 27.00 µs | 28.45 µs ± 0.61 µs | 26.60 µs … 30.30 µs | 30.00 µs | -3.00 µs |" in lines
    assert "| load | 2.00 µs | 0.00 µs | the config's range | 0.00 µs | +2.00 µs |" in lines
    # without bounds there is no such column; a plain number is an estimate without its error
    plain = delay_lines({"duties": 2.7e-5}, None, None, None, {"duties": 2.845e-5})
    assert plain[:3] == ["| input group | learned Δt | time-offset estimate |", "|---|---|---|",
                         "| duties | 27.00 µs | 28.45 µs |"]
    # a hybrid whose physical layer already shifts its inputs learns only the rest: no comparison with the truth
    from hybridfmu.evaluation.report import diagnosed_offsets_text

    on_top = diagnosed_offsets_text(["parameter(R)", "time_offset(d_a,d_b)"])
    assert on_top == "the physical layer's diagnosed time_offset(d_a,d_b)"
    assert diagnosed_offsets_text(["parameter(R)", "deadtime(d_a)"]) is None
    residual = delay_lines({"duties": 1.6e-5}, {"duties": 3e-5}, "truth.json", None, None, None, on_top)
    assert residual[0] == "| input group | learned Δt | time-offset estimate |"
    assert "| duties | 16.00 µs | - |" in residual
    assert not any("learned − true" in line or "-14.00 µs" in line for line in residual)
    assert residual[-1].startswith("These delays act on top of the physical layer's diagnosed time_offset(d_a,d_b)")
    from hybridfmu.evaluation.report import group_estimate_text

    assert group_estimate_text("duties", {**estimates["duties"], "windows": 100, "window_samples": 4}) == (
        "duties 28.45 µs ± 0.61 µs (100 windows of 4 steps)")
