"""The calibration's MLflow run: fitted values as params, RMS errors before/after as metrics, the
figure and the record as artifacts.

The run is named ``calibration`` and lives in the case's experiment (``mlflow.experiment``, else
the case name) of the store ``mlflow.tracking_uri`` (else ``sqlite:///<results_dir>/mlflow.db``);
it is tagged ``hybridfmu.role = calibration``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, Iterable

from hybridfmu.calibration.result import Calibration

LOG = logging.getLogger(__name__)


def flat_params(calibration: Calibration) -> dict[str, float]:
    """``{parameter: value}`` of the fitted parameters and ``{"x0/<maneuver>/<state>": value}``."""
    params: dict[str, float] = {name: calibration.parameters[name] for name in calibration.fitted}
    for maneuver, states in calibration.initial_states.items():
        params.update({f"x0/{maneuver}/{state}": value for state, value in states.items()})
    return params


def flat_metrics(calibration: Calibration) -> dict[str, float]:
    """``{"<before|after>/<maneuver>/<signal>_rmse": value}`` and the costs ``<phase>/cost``."""
    flat: dict[str, float] = {}
    for stage in ("before", "after"):
        for maneuver, values in (calibration.metrics.get(stage) or {}).items():
            flat.update({f"{stage}/{maneuver}/{key}": float(v) for key, v in values.items()})
    for phase, summary in (calibration.metrics.get("phases") or {}).items():
        flat[f"{phase.replace(':', '/')}/cost_start"] = float(summary["cost_start"])
        flat[f"{phase.replace(':', '/')}/cost"] = float(summary["cost"])
    return flat


def log_calibration_run(config: dict[str, Any], calibration: Calibration, artifacts: Iterable[str | Path]) -> str:
    """Create the run ``calibration`` and log params, metrics and ``artifacts``; return its run id."""
    from hybridfmu.tracking import Tracker, experiment_name, redacted_uri, tracking_uri

    uri = tracking_uri(config.get("mlflow"), config.get("results_dir", "results"))
    experiment = experiment_name(config.get("mlflow"), config["case"])
    tracker = Tracker(uri)
    experiment_id = tracker.experiment_id(experiment)
    tags = {"hybridfmu.role": "calibration", "case": config["case"]}
    run_id = tracker.call("create_run", experiment_id, tags=tags, run_name="calibration").info.run_id
    try:
        tracker.log(run_id, params=flat_params(calibration),
                    metrics=[(name, value, 0) for name, value in flat_metrics(calibration).items()],
                    tags={"fitted": ",".join(calibration.fitted) or "-"})
        for path in artifacts:
            tracker.log_artifact(run_id, path, artifact_path="calibration")
    except Exception:
        tracker.set_status(run_id, "FAILED")
        raise
    tracker.set_status(run_id, "FINISHED")
    LOG.info("MLflow calibration run %s in experiment %r (%s)", run_id, experiment, redacted_uri(uri))
    return run_id
