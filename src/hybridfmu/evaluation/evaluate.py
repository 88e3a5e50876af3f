"""Evaluation of the best neural FMU (rules ``simulate_best`` and ``evaluate``).

``simulate_best``: the best model of the hyperparameter search is simulated open loop over the WHOLE
maneuver, from its first sample (measured initial states, unmeasured ones from the calibration,
recorded inputs, no windows), one job per validation/test maneuver. The FMU trajectory is the
baseline's (same calibrated FMU, inputs and initial state). Data, FMU and neural FMU are saved
together for plotting.

``evaluate``: errors of both models over the whole trajectories and the zoomed intervals, per role
``metrics/<role>.json``, and the evaluation's MLflow run.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.evaluation.best import best_trial_summary
from hybridfmu.evaluation.comparison import ManeuverRun, role_metrics, tolerance_settings
from hybridfmu.evaluation.tracking import log_evaluation_run, resolve_tracking
from hybridfmu.io import read_json, write_json_atomic, write_parquet_atomic
from hybridfmu.model.delay import describe_delays
from hybridfmu.tracking.mlflow_store import mlflow_key
from hybridfmu.training.multiple_shooting import describe_windows, window_samples, windowed_trajectory

LOG = logging.getLogger(__name__)


def read_ceiling(path: str | Path, signals: list[str], time_s: np.ndarray) -> dict[str, np.ndarray]:
    """The ``ceiling_*``, ``windowed_ceiling_*`` and ``closed_loop_ceiling_*`` columns (each (T,)) of a ceiling
    trajectory, checked against the target ``signals`` and the data's grid ``time_s`` (T,)."""
    path = Path(path)
    frame = pd.read_parquet(path)
    missing = [name for name in ["time_s", *(f"ceiling_{signal}" for signal in signals)] if name not in frame.columns]
    if missing:
        raise ValueError(f"{path}: column(s) {missing} missing; expected time_s and ceiling_<signal> per target "
                         f"signal {signals}")
    if len(frame) != time_s.size or not np.allclose(frame["time_s"].to_numpy(), time_s, rtol=0, atol=1e-9):
        raise ValueError(f"{path}: time_s does not match the ingested maneuver's grid ({len(frame)} vs "
                         f"{time_s.size} samples); rerun simulate_ceiling")
    return {name: frame[name].to_numpy(dtype=float) for name in frame.columns
            if name.startswith(("ceiling_", "windowed_ceiling_", "closed_loop_ceiling_"))}


def read_closed_loop(paths: list[str | Path], model_kinds: list[str], signals: list[str],
                     time_s: np.ndarray) -> dict[str, np.ndarray]:
    """The ``closed_loop_<model>_<signal>`` columns (each (T,)) of one maneuver's closed-loop trajectories, one file
    per model of ``model_kinds`` (rule ``simulate_closed_loop``), checked against the data's grid ``time_s`` (T,)."""
    columns: dict[str, np.ndarray] = {}
    for path, kind in zip(paths, model_kinds):
        frame = pd.read_parquet(path)
        wanted = [f"closed_loop_{kind}_{signal}" for signal in signals]
        missing = [name for name in ["time_s", *wanted] if name not in frame.columns]
        if missing:
            raise ValueError(f"{path}: column(s) {missing} missing; expected the closed-loop trajectory of {kind} "
                             "(rule simulate_closed_loop)")
        if len(frame) != time_s.size or not np.allclose(frame["time_s"].to_numpy(), time_s, rtol=0, atol=1e-9):
            raise ValueError(f"{path}: time_s does not match the maneuver's grid ({len(frame)} vs {time_s.size} "
                             "samples); rerun simulate_closed_loop")
        columns.update({name: frame[name].to_numpy(dtype=float) for name in wanted})
    return columns


def learned_quantities(model: Any) -> dict[str, Any]:
    """The learned input delays ``dt_s`` ({group: s}) and the gates ``{state: {"g_F", "g_A"}}`` of a neural FMU;
    ``delay_bounds_s`` ({group: [low, high]} s) where some groups learned within narrower bounds; for a hybrid
    whose effect coefficients trained, also ``coefficients`` ({name: {"diagnosed", "trained"}})."""
    learned = {"dt_s": model.delay_s(), "gates": model.gate_values()}
    if model.spec.delay_bounds_s:
        learned["delay_bounds_s"] = {name: list(bounds) for name, bounds in model.spec.delay_bounds_s.items()}
    coefficients = model.physics_coefficients()
    if coefficients:
        learned["coefficients"] = coefficients
    return learned


def checked_states(states: np.ndarray, time_s: np.ndarray, n_states: int, maneuver: str, label: str) -> np.ndarray:
    """``states`` (T, n_x) of an open-loop simulation over ``time_s`` (T,), checked for shape and finiteness.

    Raises:
        ValueError: another shape. FloatingPointError: a non-finite state (the time it first appears).
    """
    if states.shape != (time_s.size, n_states):
        raise ValueError(f"{maneuver}: {label} returned states of shape {states.shape}, expected "
                         f"({time_s.size}, {n_states})")
    if not np.all(np.isfinite(states)):
        bad = int(np.argmax(~np.all(np.isfinite(states), axis=1)))
        raise FloatingPointError(f"{maneuver}: {label} open-loop simulation diverged at t = {time_s[bad]:.6g} s")
    return states


def simulate_diagnosed(diagnosed_path: str | Path, fmu_path: str | Path, fmu_parameters: dict[str, float],
                       time_s: np.ndarray, u: np.ndarray, x0: np.ndarray, maneuver: str,
                       window_steps: int | None = None, x_measured: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray | None]:
    """States (T, n_x) of the FMU plus the diagnosed effects open loop from ``x0`` (n_x,; its unmeasured states
    recalibrated with the effects where the diagnosis did so) with the logged inputs ``u`` (T, n_u)
    (:meth:`hybridfmu.diagnosis.export.DiagnosedModel.simulate`); with ``window_steps`` also its windowed
    trajectory (T, n_x) from the measured states ``x_measured`` (T, n_x; NaN columns: unmeasured, taken from its
    own open loop), else None."""
    from hybridfmu.diagnosis.export import load_diagnosed
    from hybridfmu.fmu import load_fmu

    diagnosed = load_diagnosed(diagnosed_path)
    x0 = diagnosed.initial_state(x0, maneuver)
    start = time.perf_counter()
    windowed = None
    with load_fmu(fmu_path, parameters=dict(fmu_parameters) or None) as fmu, \
            load_fmu(fmu_path, parameters=dict(fmu_parameters) or None) as helper:
        with diagnosed.open_loop(fmu, helper) as open_loop:  # the record and its windows share one set-up
            states = checked_states(np.asarray(open_loop(time_s, u, x0), dtype=float), np.asarray(time_s), len(x0),
                                    maneuver, "FMU + effects")
            if window_steps is not None:
                windowed = windowed_trajectory(open_loop, time_s, u, start_states(x_measured, states), window_steps)
    LOG.info("%s: FMU + %d diagnosed effect(s) (%s) open loop in %.1f s", maneuver, len(diagnosed.terms),
             ", ".join(diagnosed.effects) or "parameters only", time.perf_counter() - start)
    return states, windowed


def start_states(x_measured: np.ndarray, own: np.ndarray) -> np.ndarray:
    """(T, n_x) states windows start from: the measured ones, and a model's ``own`` open-loop states (T, n_x) where
    a state is not measured (NaN columns of ``x_measured``)."""
    x_measured = np.asarray(x_measured, dtype=float)
    return np.where(np.isnan(x_measured), np.asarray(own, dtype=float), x_measured)


def simulate_best(best_path: str | Path, fmu_path: str | Path, calibration_path: str | Path | None,
                  data_path: str | Path, baseline_path: str | Path, trajectory_path: str | Path,
                  learned_path: str | Path, roles: Any, maneuvers: dict[str, Any] | None,
                  maneuver: str, diagnosed_path: str | Path | None = None,
                  hybrid_best_path: str | Path | None = None,
                  ceiling_path: str | Path | None = None,
                  window_length_s: float | None = None) -> dict[str, Any]:
    """Simulate the best neural FMU open loop over the whole maneuver; save it beside data and FMU.

    Args:
        best_path: ``hpo/best.json``; fmu_path, calibration_path: the FMU and its calibration (None: as
            configured); data_path, baseline_path: the ingested maneuver and the FMU's baseline of it.
        trajectory_path, learned_path: outputs.
        roles: :class:`hybridfmu.data.roles.CaseRoles`; maneuvers: config ``maneuvers``; maneuver: its name.
        diagnosed_path: ``diagnosis/diagnosed_model.pkl``: the FMU plus the diagnosed effects is simulated too
            (model ``fmu_effects``), or None.
        hybrid_best_path: ``hybrid/best.json`` of the hybrid's search (model ``hybrid``, around the diagnosed
            model), or None.
        ceiling_path: the best any model could reach on this maneuver (model ``ceiling``: Parquet with
            ``time_s``, ``ceiling_<signal>`` per target signal and ``ceiling_state_<state>``; for an emulated
            case, the bench's true plant open loop), or None.
        window_length_s: the windows of the multiple-shooting trajectories (s; config
            ``evaluation.windows.length_s``); None: the record in
            :data:`hybridfmu.training.multiple_shooting.DEFAULT_WINDOWS_PER_RECORD` windows.

    Writes ``trajectory_path`` (Parquet: ``time_s``; per target signal ``data_<signal>``, ``fmu_<signal>``,
    ``neural_fmu_<signal>`` and ``<model>_<signal>`` of the further models, and ``windowed_<model>_<signal>``
    of every model over windows restarted from the measured state
    (:mod:`hybridfmu.training.multiple_shooting`); per FMU state ``fmu_state_<state>``,
    ``neural_fmu_state_<state>``, ``<model>_state_<state>``; model units) and ``learned_path`` (JSON:
    ``{"maneuver", "trial_id", "signals", "dt_s", "gates", "x0", "wall_time_s"}``, and ``hybrid``: the
    hybrid's ``{"trial_id", "dt_s", "gates", "effects"}``). Returns the latter.
    """
    from hybridfmu.evaluation.baseline import simulate_fmu_open_loop
    from hybridfmu.training.inference import (load_trained_neural_fmu, physical_layer, simulate_neural_fmu,
                                              simulate_neural_fmu_windows)
    from hybridfmu.training.measured import initial_state, load_calibration, read_baseline, read_measured

    best = read_json(best_path)
    summary = best_trial_summary(best, best_path)
    calibration = load_calibration(calibration_path)
    model = load_trained_neural_fmu(best_path, fmu_path, dict(calibration.parameters) or None)
    state_names = list(model.spec.state_names)
    if state_names != list(roles.state_names) or list(model.spec.input_names) != list(roles.input_names):
        raise ValueError(f"{best_path}: the trained model's states {state_names} / inputs {model.spec.input_names} "
                         f"differ from the case roles' {roles.state_names} / {roles.input_names}")
    measured = read_measured(data_path, roles)
    time_s = measured.time_s
    fmu_states = read_baseline(baseline_path, state_names, time_s)
    x0 = initial_state(model.fmu.rhs.model, measured.x[0], roles, calibration, maneuver, maneuvers)
    target_index = [state_names.index(name) for name in measured.target_states]
    learned = learned_quantities(model)
    duration_s = float(time_s[-1] - time_s[0])
    LOG.info("%s: neural FMU (trial %s, delays %s, gates %s) open loop over %.3f s (%d samples) ...", maneuver,
             summary["trial_id"], describe_delays(learned["dt_s"]), learned["gates"], duration_s, time_s.size)
    start = time.perf_counter()
    states = np.asarray(simulate_neural_fmu(model, time_s, measured.u, x0), dtype=float)
    wall_s = time.perf_counter() - start
    states = checked_states(states, time_s, len(state_names), maneuver, "neural FMU")
    LOG.info("%s: %.3f s simulated in %.1f s wall time (%.3g s per simulated second)", maneuver, duration_s, wall_s,
             wall_s / max(duration_s, 1e-12))
    steps = window_samples(window_length_s, model.spec.sample_period_s, duration_s)
    LOG.info("%s: multiple shooting over %s from the measured state", maneuver,
             describe_windows(steps, model.spec.sample_period_s, time_s.size))
    x_fmu = start_states(measured.x, fmu_states)
    windowed = {
        "fmu": windowed_trajectory(lambda t, v, x: simulate_fmu_open_loop(model.fmu.rhs.model, t, v, x)[0],
                                   time_s, measured.u, x_fmu, steps),
        "neural_fmu": simulate_neural_fmu_windows(model, time_s, measured.u, start_states(measured.x, states),
                                                  steps)}
    columns: dict[str, np.ndarray] = {"time_s": time_s}
    for k, signal in enumerate(measured.target_signals):
        columns[f"data_{signal}"] = measured.targets[:, k]
        columns[f"fmu_{signal}"] = fmu_states[:, target_index[k]]
        columns[f"neural_fmu_{signal}"] = states[:, target_index[k]]
    for i, name in enumerate(state_names):
        columns[f"fmu_state_{name}"] = fmu_states[:, i]
        columns[f"neural_fmu_state_{name}"] = states[:, i]
    record = {"maneuver": maneuver, "trial_id": summary["trial_id"], "signals": list(measured.target_signals),
              **learned, "x0": dict(zip(state_names, x0.tolist())), "wall_time_s": wall_s}
    further: dict[str, np.ndarray] = {}
    if diagnosed_path is not None:
        further["fmu_effects"], windowed["fmu_effects"] = simulate_diagnosed(
            diagnosed_path, fmu_path, calibration.parameters, time_s, measured.u, x0, maneuver, steps, measured.x)
    if hybrid_best_path is not None:
        hybrid = load_trained_neural_fmu(hybrid_best_path, fmu_path, dict(calibration.parameters) or None,
                                         diagnosed_path)
        hybrid_summary = best_trial_summary(read_json(hybrid_best_path), hybrid_best_path)
        record["hybrid"] = {"trial_id": hybrid_summary["trial_id"], **learned_quantities(hybrid),
                            "effects": list(hybrid.spec.physics_effects or [])}
        LOG.info("%s: hybrid (trial %s, delays %s) open loop ...", maneuver, hybrid_summary["trial_id"],
                 describe_delays(record["hybrid"]["dt_s"]))
        x0_hybrid = physical_layer(hybrid).diagnosed.initial_state(x0, maneuver)  # its physical layer's start
        further["hybrid"] = checked_states(
            np.asarray(simulate_neural_fmu(hybrid, time_s, measured.u, x0_hybrid), dtype=float), time_s,
            len(state_names), maneuver, "hybrid")
        windowed["hybrid"] = simulate_neural_fmu_windows(hybrid, time_s, measured.u,
                                                         start_states(measured.x, further["hybrid"]), steps)
    for model_name, model_states in further.items():
        for k, signal in enumerate(measured.target_signals):
            columns[f"{model_name}_{signal}"] = model_states[:, target_index[k]]
        for i, name in enumerate(state_names):
            columns[f"{model_name}_state_{name}"] = model_states[:, i]
    for model_name, model_states in windowed.items():
        for k, signal in enumerate(measured.target_signals):
            columns[f"windowed_{model_name}_{signal}"] = model_states[:, target_index[k]]
    record["window_steps"] = steps
    if ceiling_path is not None:
        columns.update(read_ceiling(ceiling_path, measured.target_signals, time_s))
    write_parquet_atomic(trajectory_path, pd.DataFrame(columns))
    write_json_atomic(learned_path, record)
    return record


def run_evaluation(best_path: str | Path, trajectory_paths: list[str], learned_paths: list[str],
                   maneuver_roles: dict[str, str], metrics_paths: list[str], run_path: str | Path,
                   zoom_settings: dict[str, Any], mlflow_config: dict[str, Any] | None, results_dir: str | Path,
                   case: str, tolerance: dict[str, Any] | None = None,
                   closed_loop_paths: list[str] | None = None,
                   closed_loop_models: list[str] | None = None) -> dict[str, dict]:
    """Errors of the FMU and the best neural FMU on every validation and test maneuver, and the MLflow run.

    Args:
        best_path: ``hpo/best.json`` of the search (the best trial, for the record and the MLflow link).
        trajectory_paths, learned_paths: per maneuver, in the order of ``maneuver_roles``: the saved
            trajectories and the learned quantities written by :func:`simulate_best`.
        maneuver_roles: maneuver name -> role ("validation" / "test").
        metrics_paths: ``metrics/<role>.json``, one per role; the role is the file's stem.
        run_path: JSON record of the MLflow run.
        zoom_settings: config ``evaluation.zoom``.
        mlflow_config, results_dir, case: config ``mlflow``; where the default store lies; default experiment.
        tolerance: config ``evaluation.tolerance`` (the in-tolerance metrics; defaults chosen from the validation
            maneuvers' data).
        closed_loop_paths, closed_loop_models: the closed-loop trajectories (rule ``simulate_closed_loop``), model by
            model and within a model maneuver by maneuver in the order of ``maneuver_roles``; None: open loop only.

    Returns:
        Metrics per role.
    """
    maneuvers = list(maneuver_roles)
    if not (len(maneuvers) == len(trajectory_paths) == len(learned_paths)):
        raise ValueError(f"evaluate: {len(maneuvers)} maneuvers but {len(trajectory_paths)} trajectory and "
                         f"{len(learned_paths)} learned-quantity files")
    unknown = sorted(set((zoom_settings or {}).get("intervals", {}) or {}) - set(maneuvers))
    if unknown:
        raise ValueError(f"config.evaluation.zoom.intervals: maneuver(s) {unknown} are not evaluated; "
                         f"expected some of {maneuvers} (the validation and test maneuvers)")
    summary = best_trial_summary(read_json(best_path), best_path)
    learned = [read_json(path) for path in learned_paths]
    for path, record in zip(learned_paths, learned):
        if record.get("trial_id") != summary["trial_id"] or record.get("dt_s") != learned[0].get("dt_s"):
            raise ValueError(f"{path}: simulated with trial {record.get('trial_id')} (dt {record.get('dt_s')}), but "
                             f"best.json names {summary['trial_id']}; rerun simulate_best")
    signals = list(learned[0].get("signals") or [])
    for path, record in zip(learned_paths, learned):
        if list(record.get("signals") or []) != signals or not signals:
            raise ValueError(f"{path}: target signals {record.get('signals')} differ from {signals} (or none); "
                             "rerun simulate_best")
    runs_by_role: dict[str, list[ManeuverRun]] = {}
    kinds = list(closed_loop_models or [])
    closed_paths = list(closed_loop_paths or [])
    if len(closed_paths) != len(kinds) * len(maneuvers):
        raise ValueError(f"evaluate: {len(closed_paths)} closed-loop trajectories for {len(kinds)} model(s) and "
                         f"{len(maneuvers)} maneuvers")
    for index, (name, path) in enumerate(zip(maneuvers, trajectory_paths)):
        frame = pd.read_parquet(path)
        if kinds:
            frame = frame.assign(**read_closed_loop(closed_paths[index::len(maneuvers)], kinds, signals,
                                                    frame["time_s"].to_numpy(dtype=float)))
        run = ManeuverRun.from_frame(frame, name, signals, str(path))
        runs_by_role.setdefault(maneuver_roles[name], []).append(run)
    extra = {"dt_s": learned[0]["dt_s"], "gates": learned[0]["gates"], "best_trial": summary}
    if learned[0].get("delay_bounds_s"):
        extra["delay_bounds_s"] = learned[0]["delay_bounds_s"]
    if learned[0].get("hybrid"):
        extra["hybrid_learned"] = learned[0]["hybrid"]
    tolerance_used = tolerance_settings(tolerance, signals, runs_by_role.get("validation", []))
    LOG.info("in-tolerance metrics: %s (%s)", ", ".join(f"{k} within {v:.4g}" for k, v in
                                                         tolerance_used["signals"].items()), tolerance_used["source"])
    metrics_by_role: dict[str, dict] = {}
    for path in metrics_paths:
        role = Path(path).stem
        metrics_by_role[role] = role_metrics(role, runs_by_role.get(role, []), zoom_settings or {}, extra,
                                             tolerance_used)
        write_json_atomic(path, metrics_by_role[role])
        for warning in metrics_by_role[role]["warnings"]:
            LOG.warning("%s: %s", role, warning)
        for key, label in (("improvement", "neural FMU"), ("improvement_fmu_effects", "FMU + effects"),
                           ("improvement_hybrid", "hybrid")):
            improvement = metrics_by_role[role].get(key)
            if improvement:
                LOG.info("%s: %s against the FMU: %s", role, label, "; ".join(
                    f"{signal} MAE x{_fmt(improvement[f'{signal}_mae'])}, MSE x{_fmt(improvement[f'{signal}_mse'])}"
                    for signal in signals))
    uri, experiment = resolve_tracking(mlflow_config, results_dir, case)
    hybrid = extra.get("hybrid_learned") or {}
    params = {**{f"dt_s.{group}": value for group, value in extra["dt_s"].items()},
              **{f"hybrid.dt_s.{group}": value for group, value in (hybrid.get("dt_s") or {}).items()},
              **({"hybrid.trial_id": hybrid["trial_id"], "hybrid.effects": ", ".join(hybrid.get("effects") or [])}
                 if hybrid else {}),
              **{f"hybrid.coefficient.{mlflow_key(name)}": values["trained"]
                 for name, values in (hybrid.get("coefficients") or {}).items()},
              "best_trial_id": summary["trial_id"],
              **{f"hp.{k}": v for k, v in summary["hyperparameters"].items()},
              **{f"gate.{state}.{gate}": value for state, gates in (extra["gates"] or {}).items()
                 for gate, value in gates.items()}}
    log_evaluation_run(run_path, uri, experiment, metrics_by_role, metrics_paths, params,
                       summary.get("mlflow_run_id"), case)
    return metrics_by_role


def _fmt(value: float | None) -> str:
    return "unbounded" if value is None else f"{value:.3g}"
