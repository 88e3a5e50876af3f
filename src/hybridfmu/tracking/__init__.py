"""MLflow tracking: the store (experiment per case, runs, retries; safe with several jobs writing to one SQLite
store at once) and the jobs that write to it (:mod:`hybridfmu.tracking.jobs`: jobs that are killed or lose the
store). The stages log their own runs on top of it: a search's parent and child runs in
:mod:`hybridfmu.training.search_tracking`, the calibration, diagnosis and evaluation runs beside their stages.
Which code made a result: :mod:`hybridfmu.tracking.provenance`."""

from .mlflow_store import (StoreBusyError, Tracker, check_tracking_store, default_tracking_uri, experiment_name,
                           redacted_uri, retry_locked, retry_settings, tracking_uri)
from .provenance import code_version, git_commit

__all__ = ["StoreBusyError", "Tracker", "check_tracking_store", "code_version", "default_tracking_uri",
           "experiment_name", "git_commit", "redacted_uri", "retry_locked", "retry_settings", "tracking_uri"]
