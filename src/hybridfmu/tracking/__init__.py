"""MLflow tracking of the hyperparameter search: experiment per case, parent run per search, child run per
configuration; safe with several jobs writing to one SQLite store at once, and with jobs that are killed or
lose the store (see :mod:`hybridfmu.tracking.jobs` and :mod:`hybridfmu.tracking.search`)."""

from .mlflow_store import (Tracker, check_tracking_store, default_tracking_uri, experiment_name, git_commit,
                           retry_locked, retry_settings, tracking_uri)

__all__ = ["Tracker", "check_tracking_store", "default_tracking_uri", "experiment_name", "git_commit", "retry_locked",
           "retry_settings", "tracking_uri"]
