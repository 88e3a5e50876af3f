"""Facts about the best trial of the search, from ``hpo/best.json`` (written by the training)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: Fields of best.json the evaluation needs.
REQUIRED = ("trial_id", "hyperparameters", "checkpoint")


def best_trial_summary(best: dict[str, Any], path: str | Path) -> dict[str, Any]:
    """``{"trial_id", "bracket", "config", "rung", "objective", "resource_s", "mlflow_run_id",
    "hyperparameters"}`` of the best trial.

    Raises:
        ValueError: a required field is missing (names the file and the field).
    """
    for key in REQUIRED:
        if key not in best:
            raise ValueError(f"{path}: field {key!r} missing (expected the best.json of the hyperparameter search)")
    if not isinstance(best["hyperparameters"], dict):
        raise ValueError(f"{path}: field 'hyperparameters' must be a mapping, got {type(best['hyperparameters']).__name__}")
    return {"trial_id": best["trial_id"], "bracket": best.get("bracket"), "config": best.get("config"),
            "rung": best.get("rung"), "objective": best.get("objective"), "resource_s": best.get("resource_s"),
            "mlflow_run_id": best.get("mlflow_run_id"), "hyperparameters": dict(best["hyperparameters"])}
