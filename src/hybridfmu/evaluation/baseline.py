"""The FMU alone, open loop over a whole maneuver (rule ``simulate_baseline``).

The FMU starts from the measured state at the maneuver's first sample (currents via Park with the
measured angle) and is driven by the recorded inputs, without the controller. The result is the
baseline every hybrid model is compared with.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.data.signals import input_array, state_array, time_array
from hybridfmu.data.settings import section_settings
from hybridfmu.evaluation.metrics import trajectory_errors
from hybridfmu.io import write_json_atomic, write_parquet_atomic

LOG = logging.getLogger(__name__)


def read_maneuver(data_path: str | Path, state_names: list[str], input_names: list[str],
                  signals_config: dict[str, Any] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time, inputs and measured states of an ingested maneuver, in the FMU's orders.

    Returns:
        time_s (T,) s, u (T, n_u) in ``input_names`` order, x_measured (T, n_x) in ``state_names`` order.

    Raises:
        FileNotFoundError / DataError naming the file and the missing column or signal.
    """
    data_path = Path(data_path)
    if not data_path.is_file():
        raise FileNotFoundError(f"{data_path}: ingested maneuver does not exist")
    frame = pd.read_parquet(data_path)
    try:
        time_s = time_array(frame)
        u = input_array(frame, signals_config, input_names)
        x_measured = state_array(frame, signals_config, state_names)
    except ValueError as err:
        raise type(err)(f"{data_path}: {err}") from None
    if time_s.size < 2:
        raise ValueError(f"{data_path}: column 'time_s' holds {time_s.size} sample(s), at least 2 are needed")
    return time_s, u, x_measured


def mechanical_states(signals_config: dict[str, Any] | None) -> tuple[str, str]:
    """FMU names of the angle and the speed state (config ``signals.angle_state`` / ``speed_state``)."""
    settings = section_settings(signals_config, "signals")
    return settings["angle_state"], settings["speed_state"]


def simulate_fmu_open_loop(model: Any, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
                           label: str = "") -> tuple[np.ndarray, list]:
    """FMU open loop on the input grid from ``x0``.

    Args:
        model: a loaded FMU (``hybridfmu.fmu.load_fmu``).
        time_s: time grid (T,), s; u: inputs (T, n_u), held between samples; x0: initial state (n_x,).
        label: what is simulated, for the error message.

    Returns:
        states (T, n_x) and the list of state events ``(time_s, description)``.

    Raises:
        FloatingPointError: the simulation produced a non-finite state (names the time).
    """
    from hybridfmu.fmu import simulate_open_loop

    result = simulate_open_loop(model, time_s, u, x0)
    states = np.asarray(result.states, dtype=float)
    if not np.all(np.isfinite(states)):
        bad = int(np.argmax(~np.all(np.isfinite(states), axis=1)))
        raise FloatingPointError(f"{label}: FMU open-loop simulation diverged (non-finite state) "
                                 f"at t = {time_s[bad]:.6g} s")
    return states, list(result.events)


def run_baseline(fmu_path: str | Path, data_path: str | Path, trajectory_path: str | Path,
                 metrics_path: str | Path, fmu_parameters: dict[str, float] | None,
                 signals_config: dict[str, Any] | None, maneuver: str) -> dict[str, Any]:
    """Simulate the FMU open loop over the whole maneuver and write the trajectory and its errors.

    Writes ``trajectory_path`` (Parquet: ``time_s`` + one column per FMU state, SI units) and
    ``metrics_path`` (JSON: ``{"maneuver", "samples", "duration_s", "x0", "events", "fmu": {angle_mae,
    angle_mse, speed_mae, speed_mse}}``). Returns the metrics.
    """
    from hybridfmu.fmu import load_fmu

    with load_fmu(fmu_path, parameters=dict(fmu_parameters or {})) as model:
        state_names, input_names = list(model.state_names), list(model.input_names)
        time_s, u, x_measured = read_maneuver(data_path, state_names, input_names, signals_config)
        x0 = x_measured[0]
        LOG.info("%s: FMU open loop over %.3f s (%d samples) from x0 = %s", maneuver, time_s[-1] - time_s[0],
                 time_s.size, dict(zip(state_names, np.round(x0, 6).tolist())))
        states, events = simulate_fmu_open_loop(model, time_s, u, x0, label=maneuver)
    angle_state, speed_state = mechanical_states(signals_config)
    angle_i, speed_i = state_names.index(angle_state), state_names.index(speed_state)
    errors = trajectory_errors(states[:, angle_i], states[:, speed_i], x_measured[:, angle_i], x_measured[:, speed_i])
    frame = pd.DataFrame({"time_s": time_s, **{name: states[:, i] for i, name in enumerate(state_names)}})
    write_parquet_atomic(trajectory_path, frame)
    metrics = {"maneuver": maneuver, "samples": int(time_s.size), "duration_s": float(time_s[-1] - time_s[0]),
               "x0": dict(zip(state_names, x0.tolist())), "events": len(events), "fmu": errors}
    write_json_atomic(metrics_path, metrics)
    LOG.info("%s: FMU angle MAE %.4g rad, speed MAE %.4g rad/s, %d state events", maneuver, errors["angle_mae"],
             errors["speed_mae"], len(events))
    return metrics
