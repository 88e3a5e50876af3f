"""The FMU alone, open loop over a whole maneuver (rule ``simulate_baseline``).

The FMU, with the calibrated parameters, starts from the measured states at the maneuver's first
sample (unmeasured states from the calibration) and is driven by the recorded inputs. The result is
the baseline every hybrid model is compared with.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.evaluation.metrics import trajectory_errors
from hybridfmu.io import write_json_atomic, write_parquet_atomic
from hybridfmu.training.measured import initial_state, load_calibrated_fmu, load_calibration, read_measured

LOG = logging.getLogger(__name__)


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


def run_baseline(fmu_path: str | Path, calibration_path: str | Path | None, data_path: str | Path,
                 trajectory_path: str | Path, metrics_path: str | Path, roles: Any,
                 maneuvers: dict[str, Any] | None, maneuver: str) -> dict[str, Any]:
    """Simulate the calibrated FMU open loop over the whole maneuver and write the trajectory and its errors.

    Args:
        fmu_path, calibration_path: the FMU and its calibration result (None: the FMU as configured).
        data_path: the ingested maneuver.
        trajectory_path, metrics_path: outputs.
        roles: :class:`hybridfmu.data.roles.CaseRoles`; maneuvers: config ``maneuvers``; maneuver: its name.

    Writes ``trajectory_path`` (Parquet: ``time_s`` + one column per FMU state, model units) and
    ``metrics_path`` (JSON: ``{"maneuver", "samples", "duration_s", "x0", "events", "signals",
    "fmu": {<signal>_mae, <signal>_mse, <signal>_rmse per target signal}}``). Returns the metrics.
    """
    calibration = load_calibration(calibration_path)
    with load_calibrated_fmu(fmu_path, calibration) as model:
        state_names = list(model.state_names)
        measured = read_measured(data_path, roles)
        time_s = measured.time_s
        x0 = initial_state(model, measured.x[0], roles, calibration, maneuver, maneuvers)
        LOG.info("%s: FMU open loop over %.3f s (%d samples) from x0 = %s", maneuver, time_s[-1] - time_s[0],
                 time_s.size, dict(zip(state_names, np.round(x0, 6).tolist())))
        states, events = simulate_fmu_open_loop(model, time_s, measured.u, x0, label=maneuver)
    target_index = [state_names.index(name) for name in measured.target_states]
    errors = trajectory_errors(states[:, target_index], measured.targets, measured.target_signals)
    frame = pd.DataFrame({"time_s": time_s, **{name: states[:, i] for i, name in enumerate(state_names)}})
    write_parquet_atomic(trajectory_path, frame)
    metrics = {"maneuver": maneuver, "samples": int(time_s.size), "duration_s": float(time_s[-1] - time_s[0]),
               "x0": dict(zip(state_names, x0.tolist())), "events": len(events),
               "signals": list(measured.target_signals), "fmu": errors}
    write_json_atomic(metrics_path, metrics)
    LOG.info("%s: FMU %s, %d state events", maneuver,
             ", ".join(f"{signal} MAE {errors[f'{signal}_mae']:.4g} {roles.signals[signal].unit}".rstrip()
                       for signal in measured.target_signals), len(events))
    return metrics
