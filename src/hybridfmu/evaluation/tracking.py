"""The evaluation's MLflow run: metrics, learned quantities, figures and the report as artifacts.

The run lives in the case's experiment (config ``mlflow.experiment``, else the case name) of the
tracking store ``mlflow.tracking_uri`` (else ``sqlite:///<absolute results_dir>/mlflow.db``), is
tagged ``hybridfmu.role = evaluation`` and is linked to the best training trial by the tag
``best_trial_run_id``; while RUNNING it names the writing process (tags ``hybridfmu.pid`` ...), so a run
left RUNNING by a killed job is ended (KILLED) by the next run. Store access goes through :class:`hybridfmu.tracking.Tracker` (retries while
a concurrent job holds the SQLite lock).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Iterable

from hybridfmu.io import read_json, write_json_atomic

LOG = logging.getLogger(__name__)


def resolve_tracking(mlflow_config: dict[str, Any] | None, results_dir: str | Path, case: str) -> tuple[str, str]:
    """(tracking URI, experiment name) of a case, with the defaults of the ``mlflow`` config section."""
    from hybridfmu.tracking import experiment_name, tracking_uri

    return tracking_uri(mlflow_config, results_dir), experiment_name(mlflow_config, case)


def flat_metrics(metrics_by_role: dict[str, dict]) -> dict[str, float]:
    """MLflow metric names -> values, ``<role>/<model>/<signal>_<measure>``, e.g. ``test/neural_fmu/angle_mae``
    (model: fmu, neural_fmu, improvement, and those of fmu_effects, hybrid, ceiling, improvement_<model> the
    metrics hold; all maneuvers of the role together), and ``<role>/<statistic>/<model>/<key>`` the median, min
    and max over the role's maneuvers (``distribution``), e.g. ``test/median/hybrid/angle_mae_factor``."""
    from hybridfmu.evaluation.comparison import FURTHER_MODELS

    flat: dict[str, float] = {}
    for role, metrics in metrics_by_role.items():
        further = [k for m in FURTHER_MODELS if m in metrics for k in (m, f"improvement_{m}")]
        for model in ("fmu", "neural_fmu", "improvement", *further):
            for key, value in metrics[model].items():
                if value is not None:
                    flat[f"{role}/{model}/{key}"] = float(value)
        for model, stats in (metrics.get("distribution") or {}).items():
            for key, values in stats.items():
                for statistic in ("median", "min", "max"):
                    if values.get(statistic) is not None:
                        flat[f"{role}/{statistic}/{model}/{key}"] = float(values[statistic])
    return flat


def log_evaluation_run(run_path: str | Path, tracking_uri: str, experiment: str, metrics_by_role: dict[str, dict],
                       metric_files: Iterable[str | Path], params: dict[str, Any], best_trial_run_id: str | None,
                       case: str) -> dict[str, str]:
    """Create the evaluation run, log metrics, parameters and the metric files; write ``run_path``.

    Args:
        run_path: JSON file that records ``{"tracking_uri", "experiment", "experiment_id", "run_id"}``
            (the report rule adds the figures to the same run).
        metrics_by_role: ``{"validation": ..., "test": ...}`` as written by ``evaluate``.
        metric_files: files logged as artifacts under ``metrics/``.
        params: parameters of the run (hyperparameters of the best trial, learned dt ...).
        best_trial_run_id: MLflow run id of the best training trial (tag ``best_trial_run_id``), or None.
    """
    from hybridfmu.tracking import Tracker, redacted_uri
    from hybridfmu.tracking.jobs import owner_tags
    from hybridfmu.training.search_tracking import end_stale_runs

    tracker = Tracker(tracking_uri)
    experiment_id = tracker.experiment_id(experiment)
    end_stale_runs(tracker, experiment_id)  # runs left RUNNING by killed jobs
    tags = {"hybridfmu.role": "evaluation", "case": case, **owner_tags()}
    if best_trial_run_id:
        tags["best_trial_run_id"] = best_trial_run_id
    warnings = [f"{role}: {line}" for role, metrics in metrics_by_role.items() for line in metrics.get("warnings", [])]
    if warnings:  # a trained model worse than its own physics somewhere (the report lists where)
        tags["WARN"] = f"{len(warnings)} warning(s): " + "; ".join(warnings)[:4000]
    run_id = tracker.call("create_run", experiment_id, tags=tags, run_name="evaluation").info.run_id
    try:
        tracker.log(run_id, params=params,
                    metrics=[(name, value, 0) for name, value in flat_metrics(metrics_by_role).items()])
        for path in metric_files:
            tracker.log_artifact(run_id, path, artifact_path="metrics")
    except Exception:
        tracker.set_status(run_id, "FAILED")
        raise
    tracker.set_status(run_id, "FINISHED")
    info = {"tracking_uri": tracking_uri, "experiment": experiment, "experiment_id": experiment_id, "run_id": run_id}
    write_json_atomic(run_path, info)
    LOG.info("MLflow evaluation run %s in experiment %r (%s)", run_id, experiment, redacted_uri(tracking_uri))
    return info


def log_report_artifacts(run_path: str | Path, figures: Iterable[str | Path], report_path: str | Path) -> None:
    """Add the figures (under ``figures/``) and the report to the evaluation run recorded in ``run_path``."""
    from hybridfmu.tracking import Tracker

    info = read_json(run_path)
    for key in ("tracking_uri", "run_id"):
        if key not in info:
            raise ValueError(f"{run_path}: field {key!r} missing (expected the evaluation run written by evaluate)")
    tracker = Tracker(info["tracking_uri"])
    for path in figures:
        tracker.log_artifact(info["run_id"], path, artifact_path="figures")
    tracker.log_artifact(info["run_id"], report_path)
    LOG.info("added %s and the figures to MLflow run %s", report_path, info["run_id"])
