"""MLflow records of a hyperparameter search: the parent run (one per search), a child run per
configuration with per-rung metrics stepped by the resource (ms of training data), the model and the
training curve as artifacts."""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import math
import os
import tempfile
import time
from pathlib import Path
from typing import Any, Iterator

from hybridfmu.io import read_json, write_json_atomic
from hybridfmu.tracking.mlflow_store import Tracker, redacted_uri
from hybridfmu.tracking.provenance import git_commit

LOG = logging.getLogger(__name__)


def start_search(uri: str, experiment: str, search_id: str, case: str, params: dict[str, Any],
                 artifact_root: str | Path | None = None) -> dict[str, str]:
    """Create (or find, by the tag ``search_id``) the parent run of a search; returns the tracking record
    ``{"uri", "experiment", "experiment_id", "parent_run_id"}`` that the training jobs use."""
    tracker = Tracker(uri, artifact_root)
    experiment_id = tracker.experiment_id(experiment)
    end_stale_runs(tracker, experiment_id)
    tags = {"hybridfmu.search_id": search_id, "hybridfmu.role": "search"}
    run_id = tracker.get_or_create_run(experiment_id, tags, run_name=f"hyperband-{search_id[:8]}")
    _mark_running(tracker, run_id, workflow_owner_tags())
    extra = {"case": case}
    commit = git_commit()
    if commit:
        extra["git_commit"] = commit
    tracker.log(run_id, params=params, tags=extra)
    LOG.info("MLflow search run %s in experiment %r (%s)", run_id, experiment, redacted_uri(uri))
    return {"uri": uri, "experiment": experiment, "experiment_id": experiment_id, "parent_run_id": run_id}


def _state_dict(model: Any) -> dict[str, Any]:
    return model.state_dict() if hasattr(model, "state_dict") else dict(model)


def _spec_dict(spec: Any) -> dict[str, Any]:
    return spec.to_dict() if hasattr(spec, "to_dict") else dict(spec)


def logged_steps(tracker: Tracker, run_id: str, keys: set[str]) -> dict[str, set[int]]:
    """Steps already logged per metric key of a run (only keys the run has)."""
    present = set(tracker.call("get_run", run_id).data.metrics)
    return {key: {m.step for m in tracker.call("get_metric_history", run_id, key)} for key in keys & present}


def new_metric_rows(tracker: Tracker, run_id: str, metrics: list[tuple[str, float, int]]) -> list[tuple[str, float, int]]:
    """``metrics`` without the (key, step) pairs the run already has: logging a rung twice (a rerun, a
    resumed workflow, tracking caught up later) adds no rows."""
    from hybridfmu.tracking.mlflow_store import mlflow_key

    done = logged_steps(tracker, run_id, {mlflow_key(key) for key, _, _ in metrics})
    rows, seen = [], set()
    for key, value, step in metrics:
        name = mlflow_key(key)
        if step in done.get(name, ()) or (name, step) in seen:
            continue
        seen.add((name, step))
        rows.append((key, value, step))
    return rows


def _mark_running(tracker: Tracker, run_id: str, owner: dict[str, str]) -> None:
    """Record who writes the run (tags), then mark it RUNNING (in that order: a run RUNNING under a dead
    owner is ended by :func:`end_stale_runs`)."""
    tracker.log(run_id, tags=owner)
    tracker.set_status(run_id, "RUNNING")


def workflow_owner_tags() -> dict[str, str]:
    """Owner tags of a search's parent run: the Snakemake process of the workflow (else this process). In a
    cluster job (Slurm) the workflow's process is not an ancestor and may run on another host: no PID is
    recorded then, so that the parent run is never taken for a dead job's run (it outlives every job; the
    search's last job, select_best, ends it)."""
    from hybridfmu.tracking.jobs import owner_tags, workflow_process

    tags = owner_tags()
    workflow = workflow_process()
    if workflow is not None:
        tags["hybridfmu.pid"], tags["hybridfmu.pid_start"] = str(workflow.pid), str(workflow.start)
    elif tags["hybridfmu.snakemake_pid"]:  # a cluster job's Snakemake (--mode remote)
        for key in ("hybridfmu.pid", "hybridfmu.pid_start", "hybridfmu.snakemake_pid", "hybridfmu.snakemake_start"):
            tags[key] = ""
    return tags


def resume_parent(tracker: Tracker, parent_run_id: str) -> None:
    """Mark the search's parent run RUNNING again (owned by this workflow) if it was ended meanwhile (a
    killed workflow, a rung rerun after the search finished)."""
    if tracker.call("get_run", parent_run_id).info.status != "RUNNING":
        _mark_running(tracker, parent_run_id, workflow_owner_tags())


def log_trial_rung(tracking: dict[str, str], search_id: str, result: dict[str, Any], history: list[list[float]],
                   model: Any, spec: Any, run_id: str | None = None, tracker: Tracker | None = None) -> str:
    """Log one rung of a configuration to its child run (found by tags, created at its first rung).

    Metrics (step = resource in ms of training data): ``train_loss`` per optimizer step; at every validation
    ``val_objective``, ``val_loss`` and ``val_<signal>_mae`` / ``_mse`` / ``_rmse`` per target signal;
    at the rung's end ``best_val_objective``, ``delay_s``, ``skipped_steps`` and the gates (the MLflow UI draws their
    curves; the search's figure ``training_curves.png`` of rule ``plot`` draws every trial's). Artifacts under
    ``rung<r>/``: ``model/state_dict.pt`` and ``model/model_info.json`` (architecture, FMU path and hash).
    ``history`` holds every step so far ([resource_s, loss, skipped, gradient norm]); rows the run already has
    (same key and step: earlier rungs, an earlier attempt of this rung) are not logged again, so logging is
    idempotent and rungs may be logged in any order. ``model``: the module or its state dict; ``spec``: the
    :class:`NeuralFmuSpec` or its dict. The run is tagged with the writing process (``hybridfmu.pid`` ...)
    while RUNNING.
    """
    import torch

    from hybridfmu.tracking.jobs import owner_tags

    tracker = tracker or Tracker(tracking["uri"], create=False)
    experiment_id = tracking["experiment_id"]
    tags = {"hybridfmu.search_id": search_id, "hybridfmu.trial": result["trial_id"]}
    owner = owner_tags()
    if run_id is None:
        run_id = tracker.find_run(experiment_id, tags)
    if run_id is None:  # the trial's first rung: a new run, RUNNING from the start and tagged with its writer
        run_id = tracker.create_run(experiment_id, {**tags, **owner}, run_name=result["trial_id"],
                                    parent_run_id=tracking["parent_run_id"])
    else:
        _mark_running(tracker, run_id, owner)
    params = {f"hp.{key}": value for key, value in result["hyperparameters"].items()}
    params.update({"bracket": result["bracket"], "config": result["config"]})
    run_tags = {"bracket": result["bracket"], "rung": result["rung"], "config_hash": result["hash"],
                "status": result["status"], "reason": result["reason"][:500], "fmu_path": result["fmu"]["path"],
                "fmu_sha256": result["fmu"]["sha256"]}
    commit = git_commit()
    if commit:
        run_tags["git_commit"] = commit
    metrics = [("train_loss", loss, int(round(1000 * resource_s))) for resource_s, loss, *_ in history
               if math.isfinite(loss)]
    step = int(round(1000 * result["resource_s"]))
    for validation in result["validations"]:
        resource_s = validation.get("resource_s")
        if resource_s is None:
            continue
        for key in validation_metric_keys(validation, with_loss=True):
            metrics.append((f"val_{key}", validation[key], int(round(1000 * resource_s))))
    if result["objective"] is not None:
        metrics.append(("best_val_objective", result["objective"], step))
    for group, value in result["delay_s"].items():
        metrics.append((f"delay_s_{group}", value, step))
    metrics.append(("skipped_steps", float(result["skipped_steps"]), step))
    for state, gates in result["gates"].items():
        for gate, value in gates.items():
            metrics.append((f"gate_{gate}_{state}", value, step))
    tracker.log(run_id, params=params, metrics=new_metric_rows(tracker, run_id, metrics), tags=run_tags)
    with tempfile.TemporaryDirectory(prefix="hybridfmu-mlflow-") as tmp:
        folder = Path(tmp) / f"rung{result['rung']}"
        (folder / "model").mkdir(parents=True)
        torch.save(_state_dict(model), folder / "model" / "state_dict.pt")
        info = {"spec": _spec_dict(spec), "hyperparameters": result["hyperparameters"], "fmu": result["fmu"],
                "delay_s": result["delay_s"], "gates": result["gates"], "checkpoint": result["checkpoint"]}
        (folder / "model" / "model_info.json").write_text(json.dumps(info, indent=2, default=str))
        tracker.call("log_artifacts", run_id, str(folder), artifact_path=folder.name)
    tracker.set_status(run_id, "FINISHED" if result["status"] == "ok" else "FAILED")
    resume_parent(tracker, tracking["parent_run_id"])
    return run_id


def end_stale_runs(tracker: Tracker, experiment_id: str, search_id: str | None = None) -> list[str]:
    """End the runs of an experiment (of one search, with ``search_id``) left RUNNING by a process that is
    gone (owner tags ``hybridfmu.pid`` ... on this host): status KILLED, tag ``hybridfmu.ended_reason`` says
    why. Runs of live processes, of other hosts and without owner tags are left alone. Returns their ids."""
    import socket

    from hybridfmu.tracking.jobs import owner_alive

    clauses = ["attributes.status = 'RUNNING'"]
    if search_id:
        clauses.append(f"tags.`hybridfmu.search_id` = '{search_id}'")
    runs = tracker.call("search_runs", [experiment_id], filter_string=" and ".join(clauses), max_results=1000)
    ended = []
    for run in runs:
        tags = run.data.tags
        if owner_alive(tags) is not False:
            continue
        reason = (f"ended as KILLED at {time.strftime('%Y-%m-%dT%H:%M:%S')} by PID {os.getpid()} on "
                  f"{socket.gethostname()}: the process that wrote it (PID {tags.get('hybridfmu.pid')}, Snakemake PID "
                  f"{tags.get('hybridfmu.snakemake_pid') or '-'}) is gone")
        tracker.log(run.info.run_id, tags={"hybridfmu.ended_reason": reason})
        tracker.set_status(run.info.run_id, "KILLED")
        LOG.warning("MLflow run %s (%s) %s", run.info.run_id, run.info.run_name, reason)
        ended.append(run.info.run_id)
    return ended


# --- tracking that failed, caught up later ------------------------------------------------------------

def pending_folder(plan_path: str | Path) -> Path:
    """Folder of the rungs whose MLflow logging failed (one JSON per rung), beside the search plan."""
    return Path(plan_path).parent / "tracking_pending"


@contextlib.contextmanager
def trial_lock(plan_path: str | Path, trial_id: str, timeout_s: float = 120.0) -> Iterator[None]:
    """Exclusive right to log trial ``trial_id`` (a job logging its rung and a catch-up of an earlier rung of
    the same trial do not interleave their idempotence checks)."""
    path = Path(plan_path).parent / "tracking_locks" / f"{trial_id}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    deadline = time.monotonic() + timeout_s
    with open(path, "a") as handle:
        while True:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"{path}: trial {trial_id} locked by another job for {timeout_s:.0f} s") from None
                time.sleep(0.1)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def record_pending(plan_path: str | Path, result: dict[str, Any], result_path: str | Path, error: str) -> Path:
    """Queue a rung for later logging by :func:`sync_pending`: its logging failed (``error`` says why), or the
    search logs its rungs at its end (``error`` empty; config ``mlflow.rung_logging: at_search_end``)."""
    entry = pending_folder(plan_path) / f"b{result['bracket']}_r{result['rung']}_c{result['config']}.json"
    write_json_atomic(entry, {"trial_id": result["trial_id"], "bracket": result["bracket"], "rung": result["rung"],
                              "config": result["config"], "result": str(result_path),
                              "checkpoint": str(result["checkpoint"]), "error": error})
    return entry


def drop_pending(plan_path: str | Path, result: dict[str, Any]) -> None:
    entry = pending_folder(plan_path) / f"b{result['bracket']}_r{result['rung']}_c{result['config']}.json"
    entry.unlink(missing_ok=True)


def sync_pending(plan_path: str | Path, tracker: Tracker | None = None, **tracker_options: Any) -> dict[str, str]:
    """Log every queued rung (from its result and checkpoint) and remove it from the queue; idempotent.

    Returns ``{trial_id: run_id}`` of the rungs logged. Entries whose result or checkpoint is gone (the rung is
    being redone) are dropped: the new attempt logs itself. Errors of the store propagate (entries stay).
    """
    from hybridfmu.training.checkpoint import load_checkpoint

    folder = pending_folder(plan_path)
    entries = sorted(folder.glob("b*_r*_c*.json"), key=lambda p: (read_json(p)["rung"], p.name)) if folder.is_dir() else []
    if not entries:
        return {}
    plan = read_json(plan_path)
    tracking = plan.get("tracking")
    if not tracking:
        return {}
    tracker = tracker or Tracker(tracking["uri"], create=False, **tracker_options)
    logged = {}
    for entry_path in entries:
        entry = read_json(entry_path)
        result_path, checkpoint_path = Path(entry["result"]), Path(entry["checkpoint"])
        if not result_path.is_file() or not checkpoint_path.is_file():
            entry_path.unlink(missing_ok=True)
            continue
        result = read_json(result_path)
        checkpoint = load_checkpoint(checkpoint_path)
        with trial_lock(plan_path, result["trial_id"]):
            trainer = checkpoint.get("trainer") or {}
            run_id = log_trial_rung(tracking, plan["search_id"], result, trainer.get("history", []),
                                    checkpoint["model"], checkpoint["spec"], tracker=tracker)
        entry_path.unlink(missing_ok=True)
        logged[result["trial_id"]] = run_id
        if entry["error"]:
            LOG.info("MLflow: logged %s rung %d later (run %s); it had failed: %s", result["trial_id"],
                     result["rung"], run_id, entry["error"])
        else:
            LOG.info("MLflow: logged %s rung %d (run %s), queued until the search's end", result["trial_id"],
                     result["rung"], run_id)
    return logged


def trial_run_id(tracker: Tracker, tracking: dict[str, str], search_id: str, trial_id: str) -> str | None:
    """The MLflow run of a trial (found by its tags), or None."""
    return tracker.find_run(tracking["experiment_id"], {"hybridfmu.search_id": search_id, "hybridfmu.trial": trial_id})


#: Suffixes of the per-signal error measures of a validation record (``<signal>_<measure>``).
MEASURE_SUFFIXES = ("_mae", "_mse", "_rmse")


def validation_metric_keys(validation: dict[str, Any], with_loss: bool) -> list[str]:
    """Keys of a validation record logged as metrics: ``objective`` (and ``loss``), then every
    ``<signal>_mae`` / ``_mse`` / ``_rmse``, skipping missing (None) values."""
    keys = ["objective", "loss"] if with_loss else ["objective"]
    keys += [key for key in validation if key.endswith(MEASURE_SUFFIXES)]
    return [key for key in keys if validation.get(key) is not None]


def finish_search(tracking: dict[str, str], best: dict[str, Any] | None, summary_path: str | Path,
                  **tracker_options: Any) -> bool:
    """Record the best trial on the parent run, attach the summary, and end the parent run.

    Returns whether that worked: a store that fails (locked too long, lost, unreachable) is logged as a
    warning, not raised, since the search's files are complete; select_best's catch-up
    (:func:`catch_up_search`) tries again and the parent run is ended by the next start otherwise."""
    try:
        tracker = Tracker(tracking["uri"], create=False, **tracker_options)
        run_id = tracking["parent_run_id"]
        if best is not None:
            tags = {"best_trial": best["trial_id"], "best_run_id": best.get("mlflow_run_id") or "",
                    "best_chosen_by": (best.get("selection") or {}).get("by", "objective")}
            metrics = [(f"best_val_{key}", best["validation"][key], 0)
                       for key in validation_metric_keys(best["validation"], with_loss=False)]
            tracker.log(run_id, metrics=new_metric_rows(tracker, run_id, metrics), tags=tags)
        tracker.log_artifact(run_id, summary_path)
        tracker.set_status(run_id, "FINISHED" if best is not None else "FAILED")
        return True
    except Exception as err:
        LOG.warning("MLflow: the search run %s was not finished (%s: %s); the search's files are complete",
                    tracking.get("parent_run_id"), type(err).__name__, str(err).splitlines()[0] if str(err) else "")
        return False


def catch_up_search(plan_path: str | Path, tracker_options: dict[str, Any] | None = None,
                    best_path: str | Path | None = None) -> bool:
    """Bring the search's MLflow records up to date; never raises (the search's files are what counts).

    Logs the queued rungs (:func:`sync_pending`), ends runs of the search left RUNNING by dead jobs, and
    with ``best_path`` writes the best trial's run id into best.json (field ``mlflow_run_id``) if it was
    logged late. Returns whether the store was reached.
    """
    plan = read_json(plan_path)
    tracking = plan.get("tracking")
    if not tracking:
        return False
    try:
        tracker = Tracker(tracking["uri"], create=False, **(tracker_options or {}))
        sync_pending(plan_path, tracker)
        end_stale_runs(tracker, tracking["experiment_id"], plan["search_id"])
        if best_path is not None:
            best = read_json(best_path)
            if not best.get("mlflow_run_id"):
                run_id = trial_run_id(tracker, tracking, plan["search_id"], best["trial_id"])
                if run_id:
                    best = {**best, "mlflow_run_id": run_id}
                    write_json_atomic(best_path, best)
                    tracker.log(tracking["parent_run_id"], tags={"best_run_id": run_id})
            if tracker.call("get_run", tracking["parent_run_id"]).info.status != "FINISHED" and best.get("summary"):
                return finish_search(tracking, best, best["summary"], **(tracker_options or {}))
        return True
    except Exception as err:
        remaining = sorted(p.name for p in pending_folder(plan_path).glob("*.json"))
        LOG.warning("MLflow store %s not reachable (%s: %s); %d rung(s) stay queued for logging in %s",
                    tracking["uri"], type(err).__name__, str(err).splitlines()[0] if str(err) else "",
                    len(remaining), pending_folder(plan_path))
        return False
