"""MLflow tracking of the hyperparameter search: experiment per case, parent run per search, child run per
configuration; safe with several jobs writing to one SQLite store at once."""

from .mlflow_store import (Tracker, default_tracking_uri, experiment_name, git_commit, retry_locked,
                           tracking_uri)

__all__ = ["Tracker", "default_tracking_uri", "experiment_name", "git_commit", "retry_locked", "tracking_uri"]
