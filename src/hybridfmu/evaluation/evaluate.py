"""Evaluation of the best neural FMU (rule ``evaluate``).

The best model of the hyperparameter search and the FMU are simulated open loop over the WHOLE
validation and test maneuvers, from their first sample (measured initial state, recorded inputs,
no controller, no windows). The FMU trajectories are the baseline's (same FMU, inputs and initial
state). Writes per role ``metrics/<role>.json`` (whole trajectories and zoomed intervals), the
trajectories for plotting, and the evaluation's MLflow run.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.evaluation.baseline import mechanical_states, read_maneuver
from hybridfmu.evaluation.best import best_trial_summary
from hybridfmu.evaluation.comparison import ManeuverRun, role_metrics
from hybridfmu.evaluation.tracking import log_evaluation_run, resolve_tracking
from hybridfmu.io import read_json, write_json_atomic, write_parquet_atomic
from hybridfmu.progress import Progress

LOG = logging.getLogger(__name__)


def read_baseline(path: str | Path, state_names: list[str], time_s: np.ndarray) -> np.ndarray:
    """FMU states (T, n_x) of a baseline trajectory, checked against the data's time grid ``time_s`` (T,)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: baseline trajectory does not exist (rule simulate_baseline)")
    frame = pd.read_parquet(path)
    missing = [name for name in ["time_s", *state_names] if name not in frame.columns]
    if missing:
        raise ValueError(f"{path}: column(s) {missing} missing; expected time_s and the FMU states {state_names}")
    if len(frame) != time_s.size or not np.allclose(frame["time_s"].to_numpy(), time_s, rtol=0, atol=1e-9):
        raise ValueError(f"{path}: time_s does not match the ingested maneuver's grid ({len(frame)} vs "
                         f"{time_s.size} samples); rerun simulate_baseline")
    return frame[state_names].to_numpy(dtype=float)


def simulate_best(model: Any, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray, maneuver: str) -> np.ndarray:
    """Neural FMU open loop from ``x0``: time_s (T,) s, u (T, n_u), x0 (n_x,) -> states (T, n_x)."""
    from hybridfmu.training.inference import simulate_neural_fmu

    states = np.asarray(simulate_neural_fmu(model, time_s, u, x0), dtype=float)
    if states.shape != (time_s.size, x0.size):
        raise ValueError(f"{maneuver}: neural FMU returned states of shape {states.shape}, "
                         f"expected ({time_s.size}, {x0.size})")
    if not np.all(np.isfinite(states)):
        bad = int(np.argmax(~np.all(np.isfinite(states), axis=1)))
        raise FloatingPointError(f"{maneuver}: neural FMU open-loop simulation diverged at t = {time_s[bad]:.6g} s")
    return states


def run_evaluation(best_path: str | Path, fmu_path: str | Path, data_paths: list[str], baseline_paths: list[str],
                   maneuver_roles: dict[str, str], metrics_paths: list[str], trajectory_paths: list[str],
                   run_path: str | Path, zoom_settings: dict[str, Any], signals_config: dict[str, Any] | None,
                   mlflow_config: dict[str, Any] | None, results_dir: str | Path, case: str) -> dict[str, dict]:
    """Evaluate the best neural FMU against the FMU on every validation and test maneuver.

    Args:
        best_path: ``hpo/best.json`` of the hyperparameter search.
        fmu_path: the FMU.
        data_paths, baseline_paths, trajectory_paths: per maneuver, in the order of ``maneuver_roles``:
            the ingested data, the FMU baseline trajectory, and where the trajectories go.
        maneuver_roles: maneuver name -> role ("validation" / "test").
        metrics_paths: ``metrics/<role>.json``, one per role; the role is the file's stem.
        run_path: JSON record of the MLflow run.
        zoom_settings: config ``evaluation.zoom``.
        signals_config, mlflow_config: config sections ``signals`` and ``mlflow``.
        results_dir, case: where the default MLflow store lies, and the default experiment name.

    Returns:
        Metrics per role.
    """
    from hybridfmu.fmu import load_fmu
    from hybridfmu.training.inference import load_trained_neural_fmu

    maneuvers = list(maneuver_roles)
    if not (len(maneuvers) == len(data_paths) == len(baseline_paths) == len(trajectory_paths)):
        raise ValueError(f"evaluate: {len(maneuvers)} maneuvers but {len(data_paths)} data, {len(baseline_paths)} "
                         f"baseline and {len(trajectory_paths)} trajectory paths")
    unknown = sorted(set((zoom_settings or {}).get("intervals", {}) or {}) - set(maneuvers))
    if unknown:
        raise ValueError(f"config.evaluation.zoom.intervals: maneuver(s) {unknown} are not evaluated; "
                         f"expected some of {maneuvers} (the validation and test maneuvers)")
    best = read_json(best_path)
    summary = best_trial_summary(best, best_path)
    with load_fmu(fmu_path) as fmu:
        state_names, input_names = list(fmu.state_names), list(fmu.input_names)
    angle_state, speed_state = mechanical_states(signals_config)
    angle_i, speed_i = state_names.index(angle_state), state_names.index(speed_state)
    model = load_trained_neural_fmu(best_path, fmu_path)
    learned = learned_quantities(model)
    LOG.info("best trial %s: dt = %.4g s, gates %s", summary.get("trial_id"), learned["dt_s"], learned["gates"])

    runs_by_role: dict[str, list[ManeuverRun]] = {}
    total_s = 0.0
    arrays = []
    for name, data_path, baseline_path in zip(maneuvers, data_paths, baseline_paths):
        time_s, u, x_measured = read_maneuver(data_path, state_names, input_names, signals_config)
        arrays.append((name, data_path, baseline_path, time_s, u, x_measured))
        total_s += float(time_s[-1] - time_s[0])
    progress = Progress(total_s, "neural FMU open loop", unit="simulated s", logger=LOG, interval_s=0.0)
    for (name, data_path, baseline_path, time_s, u, x_measured), out in zip(arrays, trajectory_paths):
        fmu_states = read_baseline(baseline_path, state_names, time_s)
        start = time.perf_counter()
        neural_states = simulate_best(model, time_s, u, x_measured[0], name)
        LOG.info("%s: %.3f s simulated in %.1f s wall time", name, time_s[-1] - time_s[0], time.perf_counter() - start)
        progress.update(float(time_s[-1] - time_s[0]))
        run = ManeuverRun(name, time_s, x_measured[:, angle_i], x_measured[:, speed_i], state_names, fmu_states,
                          neural_states, angle_i, speed_i)
        write_parquet_atomic(out, run.frame())
        runs_by_role.setdefault(maneuver_roles[name], []).append(run)
    progress.finish()

    metrics_by_role: dict[str, dict] = {}
    extra = {**learned, "best_trial": summary}
    for path in metrics_paths:
        role = Path(path).stem
        metrics_by_role[role] = role_metrics(role, runs_by_role.get(role, []), zoom_settings, extra)
        write_json_atomic(path, metrics_by_role[role])
        improvement = metrics_by_role[role]["improvement"]
        LOG.info("%s: improvement angle MAE x%s, MSE x%s; speed MAE x%s, MSE x%s", role,
                 *(_fmt(improvement[k]) for k in ("angle_mae", "angle_mse", "speed_mae", "speed_mse")))

    uri, experiment = resolve_tracking(mlflow_config, results_dir, case)
    params = {"dt_s": learned["dt_s"], "best_trial_id": summary.get("trial_id"),
              **{f"hp.{k}": v for k, v in summary.get("hyperparameters", {}).items()}}
    params.update({f"gate.{state}.{gate}": value for state, gates in (learned["gates"] or {}).items()
                   for gate, value in gates.items()})
    log_evaluation_run(run_path, uri, experiment, metrics_by_role, metrics_paths, params,
                       summary.get("mlflow_run_id"), case)
    return metrics_by_role


def learned_quantities(model: Any) -> dict[str, Any]:
    """The learned input delay ``dt_s`` (s) and the gates ``{state: {"g_F", "g_A"}}`` of a neural FMU."""
    return {"dt_s": float(model.delay_s()), "gates": model.gate_values()}


def _fmt(value: float | None) -> str:
    return "unbounded" if value is None else f"{value:.3g}"
