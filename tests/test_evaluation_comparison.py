"""Role metrics over whole maneuvers and zoomed intervals, against hand-computed values."""

import numpy as np
import pytest

from hybridfmu.evaluation.comparison import ManeuverRun, pooled_errors, role_metrics

STATES = ["i_d", "i_q", "theta", "omega"]


def _run(name, n=11, fmu_angle_offset=0.2, neural_angle_offset=0.05):
    t = np.linspace(0.0, 1.0, n)
    angle = np.linspace(0, 2, n)
    speed = np.full(n, 2.0)
    fmu = np.zeros((n, 4))
    fmu[:, 2] = angle + fmu_angle_offset * 10 * t ** 2  # error grows 0 .. 10*offset, fastest at the end
    fmu[:, 3] = speed + 1.0                             # speed error 1
    neural = np.zeros((n, 4))
    neural[:, 2] = angle + neural_angle_offset           # constant angle error
    neural[:, 3] = speed - 0.5                           # speed error -0.5
    return ManeuverRun(name, t, angle, speed, fmu[:, 2], fmu[:, 3], neural[:, 2], neural[:, 3])


def test_role_metrics_by_hand():
    run = _run("validation")
    metrics = role_metrics("validation", [run], {"angle_length_s": 0.3, "speed_length_s": 0.2, "intervals": {}},
                           {"dt_s": -2e-5})
    # FMU angle error = 2 t^2, t = 0, 0.1, ..., 1 -> mean |e| = 2 * 3.85 / 11 = 0.7; mean e^2 = 4 * mean(t^4)
    assert metrics["fmu"]["angle_mae"] == pytest.approx(0.7)
    assert metrics["fmu"]["angle_mse"] == pytest.approx(4 * np.mean(np.linspace(0, 1, 11) ** 4))
    assert metrics["fmu"]["speed_mae"] == pytest.approx(1.0)
    assert metrics["neural_fmu"]["angle_mae"] == pytest.approx(0.05)
    assert metrics["neural_fmu"]["speed_mse"] == pytest.approx(0.25)
    assert metrics["improvement"]["angle_mae"] == pytest.approx(14.0)
    assert metrics["improvement"]["speed_mse"] == pytest.approx(4.0)
    assert metrics["dt_s"] == -2e-5 and metrics["samples"] == 11 and metrics["duration_s"] == pytest.approx(1.0)
    angle_zoom, speed_zoom = metrics["zooms"]
    assert angle_zoom["quantity"] == "angle" and angle_zoom["source"] == "auto"
    # the error grows fastest at the end: window [0.7, 1.0] s
    assert (angle_zoom["t_start_s"], angle_zoom["t_end_s"]) == pytest.approx((0.7, 1.0))
    # there: FMU angle errors 0.98, 1.28, 1.62, 2.0 -> MAE 1.47; neural 0.05 -> x29.4
    assert angle_zoom["fmu"]["angle_mae"] == pytest.approx(1.47)
    assert angle_zoom["improvement"]["angle_mae"] == pytest.approx(29.4)
    assert speed_zoom["quantity"] == "speed"


def test_pooled_over_maneuvers_and_configured_zoom():
    a, b = _run("test_a"), _run("test_b", n=21, fmu_angle_offset=0.0)
    pooled = pooled_errors([a, b], "fmu")
    errors = np.concatenate([2 * np.linspace(0, 1, 11) ** 2, np.zeros(21)])
    assert pooled["angle_mae"] == pytest.approx(errors.mean())
    metrics = role_metrics("test", [a, b], {"intervals": {"test_b": [{"t_start_s": 0.5, "t_end_s": 0.6,
                                                                       "quantity": "speed"}]}}, {})
    assert metrics["maneuvers"] == ["test_a", "test_b"] and set(metrics["per_maneuver"]) == {"test_a", "test_b"}
    configured = [z for z in metrics["zooms"] if z["source"] == "config"]
    assert len(configured) == 1 and configured[0]["maneuver"] == "test_b"
    assert len(metrics["zooms"]) == 4


def test_shape_mismatch_named():
    t = np.linspace(0, 1, 5)
    with pytest.raises(ValueError, match=r"speed_neural_rad_s has shape \(4,\), expected \(5,\)"):
        ManeuverRun("m", t, t, t, t, t, t, t[:4])
    with pytest.raises(ValueError, match=r"x\.parquet: column\(s\) \['neural_fmu_speed_rad_s'\] missing"):
        import pandas as pd
        ManeuverRun.from_frame(pd.DataFrame({c: t for c in ("time_s", "data_angle_rad", "data_speed_rad_s",
                                                            "fmu_angle_rad", "fmu_speed_rad_s",
                                                            "neural_fmu_angle_rad")}), "m", "x.parquet")
    with pytest.raises(ValueError, match="no maneuver with role"):
        role_metrics("test", [], {}, {})
