"""FMU baseline and time-offset window on data the FMU itself generated (errors known exactly)."""

import json

import numpy as np
import pandas as pd
import pytest

from hybridfmu.calibration.result import Calibration
from hybridfmu.data.roles import case_roles
from hybridfmu.evaluation.baseline import run_baseline
from hybridfmu.evaluation.offset import run_time_offset
from hybridfmu.fmu import load_fmu, simulate_open_loop

STEP_S = 1e-4
#: Signals of the test frames, each in the FMU's unit (the ingested frame's model units).
SIGNALS = {"duty_a": "1", "duty_b": "1", "duty_c": "1", "u_dc": "V", "load_torque": "N*m", "angle": "rad",
           "speed": "rad/s", "current_d": "A", "current_q": "A"}
MANEUVERS = {name: {"role": role, "raw": f"{name}.mf4"} for name, role in
             (("train", "train"), ("val", "validation"), ("tst", "test"), ("m", "test"))}


def motor_config(measured_currents: bool = True, targets: dict | None = None) -> dict:
    """A case config (sections fmu, maneuvers, signals, roles) of the IPBMotor FMU for the test frames."""
    states = {"theta": "angle", "omega": "speed"}
    if measured_currents:
        states = {"i_d": "current_d", "i_q": "current_q", **states}
    return {"fmu": {"source": "build", "model_name": "IPBMotor", "path": "", "parameters": {}},
            "maneuvers": MANEUVERS,
            "signals": {name: {"channel": name.upper(), "unit": unit} for name, unit in SIGNALS.items()},
            "transforms": [],
            "roles": {"inputs": {"d_a": "duty_a", "d_b": "duty_b", "d_c": "duty_c", "u_dc": "u_dc",
                                 "tau_load": "load_torque"},
                      "states": states, "targets": targets or {"theta": 0.5, "omega": 0.5}}}


def motor_roles(measured_currents: bool = True, targets: dict | None = None):
    return case_roles(motor_config(measured_currents, targets))


def write_calibration(path, parameters=None, initial_states=None):
    """A calibration result as the rule calibrate writes it."""
    return Calibration(parameters=dict(parameters or {}), initial_states=dict(initial_states or {})).save(path)


def rotating_field_inputs(n: int) -> np.ndarray:
    """(n, 5) inputs: a voltage vector rotating at a rising electrical speed, stepped up at 0.05 s."""
    t = np.arange(n) * STEP_S
    phase = 2 * np.pi * (20.0 * t + 400.0 * t ** 2)
    amplitude = np.where(t < 0.05, 0.05, 0.15)
    duties = [0.5 + amplitude * np.cos(phase - k * 2 * np.pi / 3) for k in range(3)]
    return np.column_stack([*duties, np.full(n, 12.0), np.zeros(n)])


def measured_frame(time_s, u, states) -> pd.DataFrame:
    """An ingested frame (time_s + one column per signal, model units) of an FMU simulation."""
    columns = {"time_s": time_s}
    columns.update(zip(["duty_a", "duty_b", "duty_c", "u_dc", "load_torque"], u.T))
    columns.update(zip(["current_d", "current_q", "angle", "speed"], states.T))
    return pd.DataFrame(columns)


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
    calibration = write_calibration(tmp_path / "calibration.json")
    metrics = run_baseline(ipbmotor_fmu, calibration, exact, tmp_path / "b.parquet", tmp_path / "b.metrics.json",
                           motor_roles(), MANEUVERS, "train")
    frame = pd.read_parquet(tmp_path / "b.parquet")
    assert list(frame.columns) == ["time_s", "i_d", "i_q", "theta", "omega"]
    np.testing.assert_allclose(frame[["i_d", "i_q", "theta", "omega"]].to_numpy(), states, atol=1e-9)
    assert set(metrics["fmu"]) == {f"{s}_{m}" for s in ("angle", "speed") for m in ("mae", "mse", "rmse")}
    assert metrics["fmu"]["angle_mae"] < 1e-9 and metrics["fmu"]["speed_mse"] < 1e-12
    assert metrics["signals"] == ["angle", "speed"]
    assert json.loads((tmp_path / "b.metrics.json").read_text())["x0"]["theta"] == pytest.approx(5.0)
    assert np.ptp(states[:, 3]) > 10.0   # the rotor really moved


def test_baseline_uses_the_calibration(ipbmotor_fmu, generated, tmp_path):
    """Calibrated parameters change the FMU; unmeasured states start from the calibrated values."""
    exact, _, _, states = generated
    changed = write_calibration(tmp_path / "changed.json", {"J": 4e-4})
    metrics = run_baseline(ipbmotor_fmu, changed, exact, tmp_path / "b.parquet", tmp_path / "b.json", motor_roles(),
                           MANEUVERS, "m")
    assert metrics["fmu"]["speed_mae"] > 1.0
    # currents unmeasured: started from the calibration (the true 0 A) the FMU reproduces its data ...
    roles = motor_roles(measured_currents=False, targets={"omega": 1.0})
    exact_start = write_calibration(tmp_path / "start.json", initial_states={"m": {"i_d": 0.0, "i_q": 0.0}})
    metrics = run_baseline(ipbmotor_fmu, exact_start, exact, tmp_path / "c.parquet", tmp_path / "c.json", roles,
                           MANEUVERS, "m")
    assert metrics["signals"] == ["speed"] and metrics["fmu"]["speed_mae"] < 1e-9
    assert metrics["x0"]["i_q"] == 0.0
    # ... started from a wrong calibrated current it does not
    wrong_start = write_calibration(tmp_path / "wrong.json", initial_states={"m": {"i_d": 0.0, "i_q": 30.0}})
    metrics = run_baseline(ipbmotor_fmu, wrong_start, exact, tmp_path / "d.parquet", tmp_path / "d.json", roles,
                           MANEUVERS, "m")
    assert metrics["x0"]["i_q"] == 30.0 and metrics["fmu"]["speed_mae"] > 1.0


def test_time_offset_found_on_shifted_logs(ipbmotor_fmu, generated, tmp_path):
    _, shifted, delay_s, _ = generated
    calibration = write_calibration(tmp_path / "calibration.json")
    summary = run_time_offset(ipbmotor_fmu, calibration, shifted, tmp_path / "w.parquet", tmp_path / "w.json",
                              {"length_s": 0.01, "t_start_s": None, "max_lag_s": 1e-3}, motor_roles(), MANEUVERS,
                              "train")
    # u_true(t) = u_logged(t + delay): the FMU driven by the logged inputs lags the data by the delay
    assert summary["input_delay_s"] == pytest.approx(delay_s, abs=1e-9)
    assert summary["signals"] == ["angle", "speed"]
    assert summary["mse_with_delay"]["speed"] < 1e-12 < summary["mse_without_delay"]["speed"]
    assert summary["cost_with_delay"] < summary["cost_without_delay"]
    window = pd.read_parquet(tmp_path / "w.parquet")
    assert window["time_s"].iloc[0] == pytest.approx(summary["t_start_s"])
    assert {"data_angle", "fmu_speed", "fmu_delayed_speed"} <= set(window.columns)
    assert len(window) == 101


def test_missing_column_is_named(ipbmotor_fmu, generated, tmp_path):
    exact, _, _, _ = generated
    frame = pd.read_parquet(exact).drop(columns=["load_torque"])
    frame.to_parquet(tmp_path / "bad.parquet")
    with pytest.raises(ValueError, match=r"bad\.parquet.*load_torque"):
        run_baseline(ipbmotor_fmu, None, tmp_path / "bad.parquet", tmp_path / "o.parquet", tmp_path / "o.json",
                     motor_roles(), MANEUVERS, "m")
    assert not (tmp_path / "o.parquet").exists()
