"""The evaluation's MLflow run: metrics, learned quantities, figures and the report as artifacts.

The run lives in the case's experiment (config ``mlflow.experiment``, else the case name) of the
tracking store ``mlflow.tracking_uri`` (else ``sqlite:///<absolute results_dir>/mlflow.db``), and
is linked to the best training trial by the tag ``best_trial_run_id``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Iterable

from hybridfmu.evaluation.metrics import METRIC_KEYS
from hybridfmu.io import read_json, write_json_atomic

LOG = logging.getLogger(__name__)


def resolve_tracking(mlflow_config: dict[str, Any] | None, results_dir: str | Path, case: str) -> tuple[str, str]:
    """(tracking URI, experiment name) of a case, with the defaults of the ``mlflow`` config section."""
    mlflow_config = mlflow_config or {}
    uri = mlflow_config.get("tracking_uri") or f"sqlite:///{Path(results_dir).resolve() / 'mlflow.db'}"
    return uri, mlflow_config.get("experiment") or case


def _experiment_id(client: Any, name: str, results_dir: str | Path) -> str:
    experiment = client.get_experiment_by_name(name)
    if experiment is not None:
        return experiment.experiment_id
    artifacts = (Path(results_dir).resolve() / "mlartifacts" / name).as_uri()
    try:
        return client.create_experiment(name, artifact_location=artifacts)
    except Exception:  # created meanwhile by a concurrent job
        experiment = client.get_experiment_by_name(name)
        if experiment is None:
            raise
        return experiment.experiment_id


def flat_metrics(metrics_by_role: dict[str, dict]) -> dict[str, float]:
    """MLflow metric names -> values, e.g. ``test/neural_fmu/angle_mae``, ``test/improvement/angle_mse``."""
    flat: dict[str, float] = {}
    for role, metrics in metrics_by_role.items():
        for model in ("fmu", "neural_fmu", "improvement"):
            for key in METRIC_KEYS:
                value = metrics[model][key]
                if value is not None:
                    flat[f"{role}/{model}/{key}"] = float(value)
    return flat


def log_evaluation_run(run_path: str | Path, tracking_uri: str, experiment: str, results_dir: str | Path,
                       metrics_by_role: dict[str, dict], metric_files: Iterable[str | Path],
                       params: dict[str, Any], best_trial_run_id: str | None, case: str) -> dict[str, str]:
    """Create the evaluation run, log metrics, parameters and the metric files; write ``run_path``.

    Args:
        run_path: JSON file that records ``{"tracking_uri", "experiment", "experiment_id", "run_id"}``
            (the report rule adds the figures to the same run).
        metrics_by_role: ``{"validation": ..., "test": ...}`` as written by ``evaluate``.
        metric_files: files logged as artifacts under ``metrics/``.
        params: parameters of the run (hyperparameters of the best trial, learned dt ...).
        best_trial_run_id: MLflow run id of the best training trial, or None.
    """
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    experiment_id = _experiment_id(client, experiment, results_dir)
    tags = {"stage": "evaluation", "case": case, "mlflow.runName": "evaluation"}
    if best_trial_run_id:
        tags["best_trial_run_id"] = best_trial_run_id
    run = client.create_run(experiment_id, tags=tags)
    run_id = run.info.run_id
    try:
        for name, value in params.items():
            client.log_param(run_id, name, str(value)[:6000])
        for name, value in flat_metrics(metrics_by_role).items():
            client.log_metric(run_id, name, value)
        for path in metric_files:
            client.log_artifact(run_id, str(path), artifact_path="metrics")
    except Exception:
        client.set_terminated(run_id, status="FAILED")
        raise
    client.set_terminated(run_id, status="FINISHED")
    info = {"tracking_uri": tracking_uri, "experiment": experiment, "experiment_id": experiment_id, "run_id": run_id}
    write_json_atomic(run_path, info)
    LOG.info("MLflow evaluation run %s in experiment %r (%s)", run_id, experiment, tracking_uri)
    return info


def log_report_artifacts(run_path: str | Path, figures: Iterable[str | Path], report_path: str | Path) -> None:
    """Add the figures (under ``figures/``) and the report to the evaluation run recorded in ``run_path``."""
    from mlflow.tracking import MlflowClient

    info = read_json(run_path)
    for key in ("tracking_uri", "run_id"):
        if key not in info:
            raise ValueError(f"{run_path}: field {key!r} missing (expected the evaluation run written by evaluate)")
    client = MlflowClient(tracking_uri=info["tracking_uri"])
    for path in figures:
        client.log_artifact(info["run_id"], str(path), artifact_path="figures")
    client.log_artifact(info["run_id"], str(report_path))
    LOG.info("added %s and the figures to MLflow run %s", report_path, info["run_id"])
