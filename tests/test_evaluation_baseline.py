"""FMU baseline and time-offset window on data the FMU itself generated (errors known exactly)."""

import json

import numpy as np
import pandas as pd
import pytest

from hybridfmu.evaluation.baseline import run_baseline
from hybridfmu.evaluation.offset import run_time_offset
from hybridfmu.fmu import load_fmu, simulate_open_loop

STEP_S = 1e-4
POLE_PAIRS = 4


def rotating_field_inputs(n: int) -> np.ndarray:
    """(n, 5) inputs: a voltage vector rotating at a rising electrical speed, stepped up at 0.05 s."""
    t = np.arange(n) * STEP_S
    phase = 2 * np.pi * (20.0 * t + 400.0 * t ** 2)
    amplitude = np.where(t < 0.05, 0.05, 0.15)
    duties = [0.5 + amplitude * np.cos(phase - k * 2 * np.pi / 3) for k in range(3)]
    return np.column_stack([*duties, np.full(n, 12.0), np.zeros(n)])


def measured_frame(time_s, u, states) -> pd.DataFrame:
    """An ingested frame of the FMU's own simulation; phase currents by inverse Park/Clarke."""
    i_d, i_q, theta, omega = states.T
    theta_e = POLE_PAIRS * theta
    alpha = i_d * np.cos(theta_e) - i_q * np.sin(theta_e)
    beta = i_d * np.sin(theta_e) + i_q * np.cos(theta_e)
    return pd.DataFrame({
        "time_s": time_s, "duty_a": u[:, 0], "duty_b": u[:, 1], "duty_c": u[:, 2], "u_dc_v": u[:, 3],
        "tau_load_nm": u[:, 4], "theta_rad": theta, "omega_rad_s": omega, "i_a_a": alpha,
        "i_b_a": -0.5 * alpha + np.sqrt(3) / 2 * beta, "i_c_a": -0.5 * alpha - np.sqrt(3) / 2 * beta})


@pytest.fixture()
def generated(ipbmotor_fmu, tmp_path):
    """Data of the FMU driven by the true inputs; the logged duties are stamped 3 samples late."""
    n, shift = 1500, 3
    time_s = np.arange(n) * STEP_S
    u_true = rotating_field_inputs(n)
    with load_fmu(ipbmotor_fmu) as model:
        states = simulate_open_loop(model, time_s, u_true, np.array([0.0, 0.0, 5.0, 0.0])).states
    u_logged = np.concatenate([np.repeat(u_true[:1], shift, axis=0), u_true[:-shift]])
    exact, shifted = tmp_path / "exact.parquet", tmp_path / "shifted.parquet"
    measured_frame(time_s, u_true, states).to_parquet(exact)
    measured_frame(time_s, u_logged, states).to_parquet(shifted)
    return exact, shifted, shift * STEP_S, states


def test_baseline_reproduces_the_fmu_and_writes_the_contract(ipbmotor_fmu, generated, tmp_path):
    exact, _, _, states = generated
    metrics = run_baseline(ipbmotor_fmu, exact, tmp_path / "b.parquet", tmp_path / "b.metrics.json", {}, None,
                           "train")
    frame = pd.read_parquet(tmp_path / "b.parquet")
    assert list(frame.columns) == ["time_s", "i_d", "i_q", "theta", "omega"]
    np.testing.assert_allclose(frame[["i_d", "i_q", "theta", "omega"]].to_numpy(), states, atol=1e-9)
    assert metrics["fmu"]["angle_mae"] < 1e-9 and metrics["fmu"]["speed_mse"] < 1e-12
    assert json.loads((tmp_path / "b.metrics.json").read_text())["x0"]["theta"] == pytest.approx(5.0)
    assert np.ptp(states[:, 3]) > 10.0   # the rotor really moved


def test_baseline_with_changed_parameter_differs(ipbmotor_fmu, generated, tmp_path):
    exact, _, _, _ = generated
    metrics = run_baseline(ipbmotor_fmu, exact, tmp_path / "b.parquet", tmp_path / "b.json", {"J": 4e-4}, None, "m")
    assert metrics["fmu"]["speed_mae"] > 1.0


def test_time_offset_found_on_shifted_logs(ipbmotor_fmu, generated, tmp_path):
    _, shifted, delay_s, _ = generated
    summary = run_time_offset(ipbmotor_fmu, shifted, tmp_path / "w.parquet", tmp_path / "w.json",
                              {"length_s": 0.01, "t_start_s": None, "max_lag_s": 1e-3}, {}, None, "train")
    # u_true(t) = u_logged(t + delay): the FMU driven by the logged inputs lags the data by the delay
    assert summary["input_delay_s"] == pytest.approx(delay_s, abs=1e-9)
    assert summary["speed_mse_with_delay"] < 1e-12 < summary["speed_mse_without_delay"]
    window = pd.read_parquet(tmp_path / "w.parquet")
    assert window["time_s"].iloc[0] == pytest.approx(summary["t_start_s"])
    assert len(window) == 101


def test_missing_column_is_named(ipbmotor_fmu, generated, tmp_path):
    exact, _, _, _ = generated
    frame = pd.read_parquet(exact).drop(columns=["tau_load_nm"])
    frame.to_parquet(tmp_path / "bad.parquet")
    with pytest.raises(ValueError, match=r"bad\.parquet.*tau_load_nm"):
        run_baseline(ipbmotor_fmu, tmp_path / "bad.parquet", tmp_path / "o.parquet", tmp_path / "o.json", {}, None,
                     "m")
    assert not (tmp_path / "o.parquet").exists()
