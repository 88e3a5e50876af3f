"""One Snakemake training job: a configuration trained through one Hyperband rung, resumed from the
previous rung's checkpoint, validated open loop, checkpointed and tracked.

A trial that diverges (too many skipped steps, a non-finite validation) or fails (an error while
training or validating) still writes its checkpoint and result, with ``status`` and ``reason``; the
selection ranks it last and the search goes on.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hybridfmu.io import atomic_path, file_sha256, read_json, write_json_atomic
from hybridfmu.model.delay import describe_delays
from hybridfmu.progress import Progress
from hybridfmu.training.build import build_neural_fmu, model_spec
from hybridfmu.training.checkpoint import CHECKPOINT_FORMAT, load_checkpoint
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.losses import objective_from_config
from hybridfmu.training.plan import plan_entry
from hybridfmu.training.trainer import Hyperparameters, Trainer, TrainerSettings, TrialDiverged
from hybridfmu.training.physical_layer_rollout import read_physical_layer_rollout, write_physical_layer_rollout
from hybridfmu.training.validation import score_states, validate, validation_batch

LOG = logging.getLogger(__name__)

#: When a rung reaches MLflow (config ``mlflow.rung_logging``): logged by its own job, or queued for select_best.
RUNG_LOGGING = ("each_job", "at_search_end")


def _finite_or_none(value: float) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _curve(history: list[list[float]], points: int) -> list[list[float]]:
    """At most ``points`` rows [resource_s, loss] (means over consecutive steps)."""
    rows = [(r, l) for r, l, *_ in history]
    if not rows:
        return []
    groups = np.array_split(np.arange(len(rows)), min(points, len(rows)))
    curve = []
    for group in groups:
        losses = [rows[i][1] for i in group if math.isfinite(rows[i][1])]
        curve.append([rows[group[-1]][0], float(np.mean(losses)) if losses else None])
    return curve


def _track_rung(plan: dict[str, Any], plan_path: str | Path, result: dict[str, Any], result_path: str | Path,
                history: list[list[float]], model: Any, spec: Any, run_id: str | None,
                options: dict[str, Any]) -> tuple[str | None, dict[str, str]]:
    """Log the rung to MLflow; on failure queue it for later. Returns (run id, tracking record)."""
    from hybridfmu.tracking import Tracker
    from hybridfmu.training.search_tracking import (drop_pending, end_stale_runs, log_trial_rung, record_pending,
                                           sync_pending, trial_lock)

    tracking = plan["tracking"]
    try:
        tracker = Tracker(tracking["uri"], create=False, **options)
        end_stale_runs(tracker, tracking["experiment_id"], plan["search_id"])
        with trial_lock(plan_path, result["trial_id"]):
            run_id = log_trial_rung(tracking, plan["search_id"], result, history, model, spec, run_id, tracker=tracker)
    except Exception as err:  # any store failure: the rung is kept and logged later
        error = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"[:500]
        entry = record_pending(plan_path, result, result_path, error)
        LOG.warning("trial %s rung %d: MLflow logging failed (%s); the rung is kept and queued in %s for later",
                    result["trial_id"], result["rung"], error, entry)
        return None, {"status": "deferred", "error": error}
    drop_pending(plan_path, result)
    try:  # the store answers: catch up on rungs whose logging failed before
        sync_pending(plan_path, tracker)
    except Exception as err:
        LOG.warning("MLflow: rungs queued for later logging stay queued (%s: %s)", type(err).__name__,
                    str(err).splitlines()[0] if str(err) else "")
    return run_id, {"status": "logged", "error": ""}


def hybrid_physics(model_config: dict[str, Any], fmu_path: str | Path, fmu_parameters: dict[str, float],
                   diagnosed_path: str | Path | None):
    """The physical layer of a hybrid (``model.physics_terms`` other than ``none``), else None.

    The physical layer is the FMU plus every chosen diagnosed effect, the diagnosed time offsets of inputs
    included, so a hybrid with its ANN at zero and its delays fixed at zero is the model "FMU + diagnosed effects"
    (and is simulated as that model: :func:`hybridfmu.training.inference.diagnosed_simulator`). A trainable input
    delay learns what time offset remains on top of it (started where ``input_delay.init_s`` says: rule
    ``hybrid_time_offset`` estimates it on this physical layer).

    Raises:
        ValueError: a hybrid without the diagnosed model's path.
    """
    from hybridfmu.model.settings import uses_physics

    if not uses_physics(model_config):
        return None
    from hybridfmu.model.physics import physics_effects, physics_model  # the diagnosis' modules: only for a hybrid

    if diagnosed_path is None:
        raise ValueError(f"config.model.physics_terms is {model_config['physics_terms']!r}: a hybrid needs the "
                         "diagnosed model (diagnosis/diagnosed_model.pkl, rule diagnose)")
    physics = physics_model(fmu_path, fmu_parameters, diagnosed_path, physics_effects(model_config["physics_terms"]))
    LOG.info("physical layer: %s (parameters %s)", ", ".join(physics.effects) or "no effects", physics.parameters)
    for note in physics.notes:
        LOG.warning("physical layer: %s", note)
    return physics


def hybrid_arrays(arrays: ManeuverArrays, physics: Any) -> ManeuverArrays:
    """The maneuver as the hybrid's physical layer sees it: its inputs through the diagnosed input changes, and
    the unmeasured states its windows start from taken along the physical layer's own open-loop simulation
    (from the maneuver's first sample, unmeasured initial states recalibrated with the effects where the
    diagnosis did so), not the calibrated FMU's."""
    unmeasured = [i for i, name in enumerate(arrays.state_names) if name not in arrays.measured_states]
    x_init = arrays.x_init
    if unmeasured:
        diagnosed = physics.diagnosed
        x0 = diagnosed.initial_state(arrays.x_init[0], arrays.name)
        states = diagnosed.simulate(physics.fmu, physics.helper, arrays.time_s, arrays.u, x0)
        if not np.all(np.isfinite(states[:, unmeasured])):
            raise FloatingPointError(f"maneuver {arrays.name}: the hybrid's physical layer diverged in its open-loop "
                                     "simulation (the unmeasured states its windows start from)")
        x_init = np.array(arrays.x_init, dtype=float)
        x_init[:, unmeasured] = states[:, unmeasured]
        LOG.info("maneuver %s: unmeasured state(s) %s from the physical layer's open loop", arrays.name,
                 [arrays.state_names[i] for i in unmeasured])
    return dataclasses.replace(arrays, u=physics.inputs(arrays.u, arrays.sample_period_s), x_init=x_init)


def trial_model(plan: dict[str, Any], entry: dict[str, Any], model_config: dict[str, Any],
                train_arrays_path: str | Path, validation_arrays_path: str | Path, statistics_path: str | Path,
                fmu_path: str | Path, calibration_path: str | Path | None, diagnosed_path: str | Path | None
                ) -> tuple[ManeuverArrays, ManeuverArrays, dict[str, Any], Any]:
    """A configuration's untrained model and its data: (train, validation, statistics, model).

    ``entry`` is the configuration's plan entry (``plan_entry``); for a hybrid (``model.physics_terms``) the
    maneuvers are as its physical layer sees them (:func:`hybrid_arrays`) and the model is built around it.
    """
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.training.measured import load_calibrated_fmu, load_calibration

    hyper = Hyperparameters.from_dict(entry["hyperparameters"])
    train = ManeuverArrays.load(train_arrays_path)
    valid = ManeuverArrays.load(validation_arrays_path)
    statistics = read_json(statistics_path)
    calibration = load_calibration(calibration_path)
    fmu_model = load_calibrated_fmu(fmu_path, calibration)
    physics = hybrid_physics(model_config, fmu_path, calibration.parameters, diagnosed_path)
    if physics is not None:
        train, valid = hybrid_arrays(train, physics), hybrid_arrays(valid, physics)
    spec = model_spec(model_config, fmu_model, train.sample_period_s, hyper.width, hyper.depth, hyper.gate_opening,
                      delay_init_s=plan.get("initial_delays_s"), delay_bounds_s=plan.get("delay_bounds_s"),
                      physics_effects=None if physics is None else physics.effects)
    model = build_neural_fmu(FmuRhs(fmu_model if physics is None else physics), spec, statistics, entry["seed"])
    return train, valid, statistics, model


def first_configuration(plan: dict[str, Any]) -> dict[str, Any]:
    """The plan entry of the search's first configuration at rung 0: untrained, a hybrid's is its physical layer
    (every configuration's is the same)."""
    return plan_entry(plan, plan["brackets"][0]["bracket"], 0, 0)


def physical_layer_sources(fmu_path: str | Path, calibration_path: str | Path | None,
                           diagnosed_path: str | Path | None) -> dict[str, str]:
    """{file role: SHA-256} of the files a hybrid's physical layer is made of (part of its rollout's key)."""
    return {role: file_sha256(path) if path else "" for role, path in
            (("fmu", fmu_path), ("calibration", calibration_path), ("diagnosed", diagnosed_path))}


def run_physical_layer_rollout(*, plan_path: str | Path, train_arrays_path: str | Path,
                               validation_arrays_path: str | Path, statistics_path: str | Path,
                               fmu_path: str | Path, calibration_path: str | Path | None,
                               model_config: dict[str, Any], diagnosed_path: str | Path,
                               rollout_path: str | Path) -> dict[str, Any]:
    """Rule ``physical_layer_rollout``: the untrained hybrid of the search's first configuration (every
    configuration's untrained hybrid is the same physical layer) simulated over the validation segments once,
    for all rung-0 trials of the search (:mod:`hybridfmu.training.physical_layer_rollout`).

    Raises:
        ValueError: the search's model is not a hybrid (``model.physics_terms`` is ``none``).
    """
    plan = read_json(plan_path)
    _, valid, _, model = trial_model(plan, first_configuration(plan), model_config, train_arrays_path,
                                     validation_arrays_path, statistics_path, fmu_path, calibration_path,
                                     diagnosed_path)
    if model.spec.physics_effects is None:
        raise ValueError("config.model.physics_terms is 'none': a neural FMU has no physical layer to roll out")
    started = time.perf_counter()
    content = write_physical_layer_rollout(rollout_path, model, valid,
                                           physical_layer_sources(fmu_path, calibration_path, diagnosed_path))
    LOG.info("physical layer rollout for the search's rung-0 trials: %.1f s", time.perf_counter() - started)
    return content


def validation_points(start_s: float, target_s: float, every_s: float | None) -> list[float]:
    """Resources (s of data) at which a rung from ``start_s`` to ``target_s`` validates: evenly spaced, at most
    ``every_s`` apart, the last at ``target_s`` (only there if ``every_s`` is None)."""
    if not every_s or target_s <= start_s:
        return [target_s]
    count = max(1, int(math.ceil((target_s - start_s) / every_s - 1e-9)))
    return [start_s + (target_s - start_s) * (k + 1) / count for k in range(count)]


def run_trial_rung(*, plan_path: str | Path, bracket: int, rung: int, config_index: int,
                   train_arrays_path: str | Path, validation_arrays_path: str | Path, statistics_path: str | Path,
                   fmu_path: str | Path, calibration_path: str | Path | None, roles: Any,
                   model_config: dict[str, Any], training_config: dict[str, Any],
                   previous_checkpoint: str | Path | None,
                   checkpoint_path: str | Path, result_path: str | Path, track: bool = True,
                   tracking_options: dict[str, Any] | None = None, rung_logging: str = "each_job",
                   diagnosed_path: str | Path | None = None,
                   physical_layer_rollout_path: str | Path | None = None) -> dict[str, Any]:
    """Train configuration ``config_index`` of ``bracket`` up to the resource of ``rung`` and validate it.

    Validation (open loop over the validation segments) runs at the rung's end and, with
    ``training.validation_every_s``, also in between; the trial reports the best validated state so far
    (checkpoint ``model``, result ``objective``), while training continues from the last state (checkpoint
    ``trainer``), so a resumed rung equals an uninterrupted run.

    Args:
        plan_path: the search plan (``hpo/plan.json``; also names the MLflow parent run).
        train_arrays_path, validation_arrays_path, statistics_path: outputs of ``prepare_training_data``.
        fmu_path, calibration_path: the FMU and the calibration result whose parameters it is loaded with
            (None: the FMU as configured, for tests).
        roles: :class:`hybridfmu.data.roles.CaseRoles` of the case (target weights: the trial's ``w_<state>``
            override the configured ones, as does the plan's objective).
        model_config, training_config: validated ``model`` and ``training`` sections.
        previous_checkpoint: the previous rung's checkpoint (None for rung 0).
        checkpoint_path, result_path: outputs (written atomically, also for a failed trial).
        track: log to MLflow (the plan's tracking store).
        tracking_options: :class:`hybridfmu.tracking.Tracker` options (``retry_budget_s``,
            ``request_timeout_s``, ``http_retries``; config section ``mlflow``).
        rung_logging: ``each_job`` logs the rung to MLflow now; ``at_search_end`` queues it beside the plan for
            select_best (config ``mlflow.rung_logging``; the job then never imports MLflow).
        diagnosed_path: the diagnosed model (``diagnosis/diagnosed_model.pkl``), for a hybrid
            (``model.physics_terms``): its physical layer is the FMU plus the diagnosed effects, and the data's
            inputs pass through the effects' input changes (:mod:`hybridfmu.model.physics`).
        physical_layer_rollout_path: the hybrid search's shared rollout of its untrained state (rule
            ``physical_layer_rollout``): a rung-0 hybrid scores it instead of simulating its untrained state,
            when it is its own (:mod:`hybridfmu.training.physical_layer_rollout`).

    The checkpoint and the result are written before anything is logged: a tracking store that is locked
    too long, lost or unreachable does not fail the job. The result's ``tracking`` records what happened
    (``{"status": "logged" | "queued" | "deferred" | "off", "error"}``: ``queued`` by ``rung_logging``, ``deferred``
    by a store that failed); a queued or deferred rung waits beside the plan and is
    logged later (:func:`hybridfmu.training.search_tracking.sync_pending`, run by the next job that reaches the store
    and by select_best).

    Returns:
        The result record (also written to ``result_path``).
    """
    if rung_logging not in RUNG_LOGGING:
        raise ValueError(f"config.mlflow.rung_logging is {rung_logging!r}; expected one of {list(RUNG_LOGGING)}")
    wall_start = time.perf_counter()
    plan = read_json(plan_path)
    entry = plan_entry(plan, bracket, rung, config_index)
    hyper = Hyperparameters.from_dict(entry["hyperparameters"])
    trial_id = f"b{bracket}c{config_index}"
    weights = roles.weights_with(hyper.target_weights)
    objective = objective_from_config(plan["objective"], roles)
    train, valid, statistics, model = trial_model(plan, entry, model_config, train_arrays_path,
                                                  validation_arrays_path, statistics_path, fmu_path,
                                                  calibration_path, diagnosed_path)
    spec = model.spec
    settings = TrainerSettings(max_skipped_steps=int(training_config["max_skipped_steps"]),
                               max_grad_norm=float(training_config["max_grad_norm"]),
                               gradients=str(training_config.get("gradients", "adjoint")))
    validations: list[dict[str, Any]] = []
    mlflow_run_id = None
    status, reason = "ok", ""
    trainer = None
    start_resource_s = 0.0
    best: dict[str, Any] = {}
    best_model = None
    if previous_checkpoint:
        previous = load_checkpoint(previous_checkpoint)
        if previous["config"] != config_index or previous["bracket"] != bracket or previous["rung"] != rung - 1:
            raise ValueError(f"{previous_checkpoint}: checkpoint of b{previous['bracket']} r{previous['rung']} "
                             f"c{previous['config']} (fields 'bracket', 'rung', 'config'), expected "
                             f"b{bracket} r{rung - 1} c{config_index}")
        if previous.get("hash") != entry["hash"]:
            raise ValueError(f"{previous_checkpoint}: field 'hash' is {previous.get('hash')!r}, expected "
                             f"{entry['hash']!r} (the configuration of {plan_path}); the checkpoint is of "
                             f"another search")
        validations = list(previous["validations"])
        best = dict(previous.get("best") or {})
        best_model = previous["model"]
        mlflow_run_id = previous.get("mlflow_run_id")
        if previous["status"] != "ok":
            status, reason = previous["status"], f"previous rung: {previous['reason']}"
    LOG.info("trial %s rung %d: %s, train to %.4g s of data", trial_id, rung, entry["hyperparameters"],
             entry["resource_s"])
    try:
        trainer = Trainer(model, train, hyper, statistics, settings, entry["seed"], weights)
        if previous_checkpoint:
            trainer.load_state_dict(previous["trainer"])
        start_resource_s = trainer.resource_used_s
        if status == "ok":
            progress = Progress(max(entry["resource_s"] - trainer.resource_used_s, 0.0), f"trial {trial_id} rung {rung}",
                                unit="s of data", logger=LOG, interval_s=10.0)
            valid_batch = None  # the validation segments' data, built at the first validation, shared by the rest
            points = validation_points(start_resource_s, entry["resource_s"], training_config.get("validation_every_s"))
            if rung == 0 and spec.physics_effects is not None:
                # a hybrid's untrained state is its physical layer (the ANN's output zero): a candidate too, so
                # the search never reports a hybrid that validates worse than its physical layer
                points = [start_resource_s] + points
            for target_s in points:
                trainer.train_until(target_s, progress)
                valid_batch = valid_batch or validation_batch(spec, valid)
                shared = (read_physical_layer_rollout(physical_layer_rollout_path, model, valid,
                                                      physical_layer_sources(fmu_path, calibration_path,
                                                                             diagnosed_path))
                          if physical_layer_rollout_path and trainer.steps == 0 else None)
                if shared is not None:  # the untrained hybrid: its search's shared rollout, scored with this loss
                    metrics = score_states(*shared, valid_batch, valid, hyper.loss, weights, objective, statistics)
                    LOG.info("trial %s: the untrained state is the physical layer; its validation scores the "
                             "search's shared rollout %s", trial_id, physical_layer_rollout_path)
                else:
                    metrics = validate(model, valid, hyper.loss, weights, objective, statistics, valid_batch)
                metrics.update(resource_s=trainer.resource_used_s, rung=rung)
                validations.append(metrics)
                LOG.info("trial %s: validation at %.4g s of data: objective %.4g, %s", trial_id,
                         trainer.resource_used_s, metrics["objective"],
                         ", ".join(f"{signal} MAE {metrics[f'{signal}_mae']:.4g} "
                                   f"{roles.signals[signal].unit if signal in roles.signals else ''}".rstrip()
                                   for signal in valid.target_signals))
                if metrics["finite"] and metrics["objective"] < best.get("objective", math.inf):
                    best = dict(metrics)
                    best_model = {key: value.clone() for key, value in model.state_dict().items()}
            progress.finish()
            if not best:
                status, reason = "diverged", "open-loop validation diverged (non-finite states)"
    except TrialDiverged as err:
        status, reason = "diverged", str(err)
    except Exception as err:  # the search goes on; the failure is recorded
        status, reason = "failed", f"{type(err).__name__}: {err}"
        LOG.error("trial %s rung %d failed:\n%s", trial_id, rung, traceback.format_exc())
    if status != "ok":
        LOG.warning("trial %s rung %d ends: %s (%s)", trial_id, rung, status, reason)
    reported = best if status == "ok" else {}
    if best_model is not None:  # the reported model: the best validated state so far
        model.load_state_dict(best_model)
    result = {
        "trial_id": trial_id, "bracket": bracket, "rung": rung, "config": config_index, "hash": entry["hash"],
        "status": status, "reason": reason, "objective": _finite_or_none(reported.get("objective", math.inf)),
        "validation": {key: _finite_or_none(value) for key, value in reported.items()},
        "resource_s": trainer.resource_used_s if trainer else 0.0, "target_resource_s": entry["resource_s"],
        "steps": trainer.steps if trainer else 0, "skipped_steps": trainer.skipped_steps if trainer else 0,
        "delay_s": model.delay_s(), "gates": model.gate_values(), "coefficients": model.physics_coefficients(),
        "hyperparameters": entry["hyperparameters"],
        "checkpoint": str(checkpoint_path), "last_rung": rung == entry["last_rung"],
        "curve": _curve(trainer.history if trainer else [], int(training_config.get("curve_points", 200))),
        "validations": [{key: _finite_or_none(value) for key, value in v.items()} for v in validations],
        "fmu": {"path": str(fmu_path), "sha256": file_sha256(fmu_path),
                "calibration": str(calibration_path) if calibration_path else None},
        "target_weights": weights, "objective_weights": objective.weights,
    }
    checkpoint = {
        "format": CHECKPOINT_FORMAT, "status": status, "reason": reason, "bracket": bracket, "rung": rung,
        "config": config_index, "hash": entry["hash"], "spec": spec.to_dict(), "statistics": statistics,
        "hyperparameters": entry["hyperparameters"], "trainer": trainer.state_dict() if trainer else None,
        "model": model.state_dict(), "best": best, "validations": validations, "fmu": result["fmu"],
    }
    track = bool(track and plan.get("tracking"))
    queued = track and rung_logging == "at_search_end"
    result["mlflow_run_id"] = None
    result["tracking"] = {"status": "queued" if queued else "deferred" if track else "off", "error": ""}
    checkpoint["mlflow_run_id"] = mlflow_run_id
    result["wall_time_s"] = time.perf_counter() - wall_start
    # checkpoint and result first: whatever happens to the tracking store, the rung is kept
    with atomic_path(checkpoint_path) as tmp:
        torch.save(checkpoint, tmp)
    write_json_atomic(result_path, result)
    if queued:
        from hybridfmu.training.search_tracking import record_pending

        record_pending(plan_path, result, result_path, "")
    elif track:
        result["mlflow_run_id"], result["tracking"] = _track_rung(
            plan, plan_path, result, result_path, trainer.history if trainer else [], model, spec, mlflow_run_id,
            tracking_options or {})
        write_json_atomic(result_path, result)
    LOG.info("trial %s rung %d: %s, objective %s, %.4g s of data, %d steps (%d skipped), delays %s, %.1f s wall",
             trial_id, rung, status, result["objective"], result["resource_s"], result["steps"],
             result["skipped_steps"], describe_delays(result["delay_s"]), result["wall_time_s"])
    return result
