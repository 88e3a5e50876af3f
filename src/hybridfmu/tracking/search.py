"""MLflow records of a hyperparameter search: the parent run (one per search), a child run per
configuration with per-rung metrics stepped by the resource (ms of training data), the model and the
training curve as artifacts."""

from __future__ import annotations

import json
import logging
import math
import tempfile
from pathlib import Path
from typing import Any

from hybridfmu.tracking.mlflow_store import Tracker, git_commit

LOG = logging.getLogger(__name__)


def start_search(uri: str, experiment: str, search_id: str, case: str, params: dict[str, Any],
                 artifact_root: str | Path | None = None) -> dict[str, str]:
    """Create (or find, by the tag ``search_id``) the parent run of a search; returns the tracking record
    ``{"uri", "experiment", "experiment_id", "parent_run_id"}`` that the training jobs use."""
    tracker = Tracker(uri, artifact_root)
    experiment_id = tracker.experiment_id(experiment)
    tags = {"hybridfmu.search_id": search_id, "hybridfmu.role": "search"}
    run_id = tracker.get_or_create_run(experiment_id, tags, run_name=f"hyperband-{search_id[:8]}")
    extra = {"case": case}
    commit = git_commit()
    if commit:
        extra["git_commit"] = commit
    tracker.log(run_id, params=params, tags=extra)
    LOG.info("MLflow search run %s in experiment %r (%s)", run_id, experiment, uri)
    return {"uri": uri, "experiment": experiment, "experiment_id": experiment_id, "parent_run_id": run_id}


def log_trial_rung(tracking: dict[str, str], search_id: str, result: dict[str, Any], history: list[list[float]],
                   model: Any, spec: Any, run_id: str | None = None, since_resource_s: float = 0.0) -> str:
    """Log one rung of a configuration to its child run (found by tags, created at its first rung).

    Metrics (step = resource in ms of training data): ``train_loss`` per optimizer step; at every validation
    ``val_objective``, ``val_loss`` and ``val_<signal>_mae`` / ``_mse`` / ``_rmse`` per target signal;
    at the rung's end ``best_val_objective``, ``delay_s``, ``skipped_steps`` and the gates. Artifacts under ``rung<r>/``: ``model/state_dict.pt``,
    ``model/model_info.json`` (architecture, FMU path and hash) and ``training_curve.png``.
    ``history`` holds every step so far ([resource_s, loss, skipped, gradient norm]); steps up to
    ``since_resource_s`` (logged by earlier rungs) are not logged again.
    """
    import torch

    tracker = Tracker(tracking["uri"])
    experiment_id = tracking["experiment_id"]
    tags = {"hybridfmu.search_id": search_id, "hybridfmu.trial": result["trial_id"]}
    if run_id is None:
        run_id = tracker.get_or_create_run(experiment_id, tags, run_name=result["trial_id"],
                                           parent_run_id=tracking["parent_run_id"])
    tracker.set_status(run_id, "RUNNING")
    params = {f"hp.{key}": value for key, value in result["hyperparameters"].items()}
    params.update({"bracket": result["bracket"], "config": result["config"]})
    run_tags = {"bracket": result["bracket"], "rung": result["rung"], "config_hash": result["hash"],
                "status": result["status"], "reason": result["reason"][:500], "fmu_path": result["fmu"]["path"],
                "fmu_sha256": result["fmu"]["sha256"]}
    commit = git_commit()
    if commit:
        run_tags["git_commit"] = commit
    metrics = [("train_loss", loss, int(round(1000 * resource_s))) for resource_s, loss, *_ in history
               if math.isfinite(loss) and resource_s > since_resource_s]
    step = int(round(1000 * result["resource_s"]))
    for validation in result["validations"]:
        resource_s = validation.get("resource_s")
        if resource_s is None or resource_s <= since_resource_s:
            continue
        for key in validation_metric_keys(validation, with_loss=True):
            metrics.append((f"val_{key}", validation[key], int(round(1000 * resource_s))))
    if result["objective"] is not None:
        metrics.append(("best_val_objective", result["objective"], step))
    metrics.append(("delay_s", result["delay_s"], step))
    metrics.append(("skipped_steps", float(result["skipped_steps"]), step))
    for state, gates in result["gates"].items():
        for gate, value in gates.items():
            metrics.append((f"gate_{gate}_{state}", value, step))
    tracker.log(run_id, params=params, metrics=metrics, tags=run_tags)
    with tempfile.TemporaryDirectory(prefix="hybridfmu-mlflow-") as tmp:
        folder = Path(tmp) / f"rung{result['rung']}"
        (folder / "model").mkdir(parents=True)
        torch.save(model.state_dict(), folder / "model" / "state_dict.pt")
        info = {"spec": spec.to_dict(), "hyperparameters": result["hyperparameters"], "fmu": result["fmu"],
                "delay_s": result["delay_s"], "gates": result["gates"], "checkpoint": result["checkpoint"]}
        (folder / "model" / "model_info.json").write_text(json.dumps(info, indent=2, default=str))
        plot_training_curve(history, result, folder / "training_curve.png")
        tracker.call("log_artifacts", run_id, str(folder), artifact_path=folder.name)
    tracker.set_status(run_id, "FINISHED" if result["status"] == "ok" else "FAILED")
    return run_id


#: Suffixes of the per-signal error measures of a validation record (``<signal>_<measure>``).
MEASURE_SUFFIXES = ("_mae", "_mse", "_rmse")


def validation_metric_keys(validation: dict[str, Any], with_loss: bool) -> list[str]:
    """Keys of a validation record logged as metrics: ``objective`` (and ``loss``), then every
    ``<signal>_mae`` / ``_mse`` / ``_rmse``, skipping missing (None) values."""
    keys = ["objective", "loss"] if with_loss else ["objective"]
    keys += [key for key in validation if key.endswith(MEASURE_SUFFIXES)]
    return [key for key in keys if validation.get(key) is not None]


def finish_search(tracking: dict[str, str], best: dict[str, Any] | None, summary_path: str | Path) -> None:
    """Record the best trial on the parent run, attach the summary, and end the parent run."""
    tracker = Tracker(tracking["uri"])
    run_id = tracking["parent_run_id"]
    if best is not None:
        tags = {"best_trial": best["trial_id"], "best_run_id": best.get("mlflow_run_id") or ""}
        metrics = [(f"best_val_{key}", best["validation"][key], 0)
                   for key in validation_metric_keys(best["validation"], with_loss=False)]
        tracker.log(run_id, metrics=metrics, tags=tags)
    tracker.log_artifact(run_id, summary_path)
    tracker.set_status(run_id, "FINISHED" if best is not None else "FAILED")


def plot_training_curve(history: list[list[float]], result: dict[str, Any], path: str | Path) -> Path:
    """Training loss per step against the resource (s of data), skipped steps marked, validation objective
    at the rung ends."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    ok = [(r, l) for r, l, skipped, *_ in history if not skipped and math.isfinite(l)]
    bad = [(r, l) for r, l, skipped, *_ in history if skipped and math.isfinite(l)]
    if ok:
        ax.plot(*zip(*ok), lw=0.8, label="training loss (per step)")
    if bad:
        ax.plot(*zip(*bad), "rx", label="skipped step")
    val = [(v["resource_s"], v["objective"]) for v in result["validations"]
           if v.get("objective") is not None and v.get("resource_s") is not None]
    if val:
        ax.plot(*zip(*val), "ko-", label="validation objective (open loop)")
    ax.set_xlabel("training data processed (s)")
    ax.set_ylabel("loss (normalised, -)")
    ax.set_yscale("log")
    ax.set_title(f"Trial {result['trial_id']} up to rung {result['rung']} ({result['status']})")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)
