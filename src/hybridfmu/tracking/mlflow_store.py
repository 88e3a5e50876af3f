"""MLflow access for concurrent Snakemake jobs.

- URI: config ``mlflow.tracking_uri``, default ``sqlite:///<absolute results_dir>/mlflow.db``.
- SQLite under concurrent writers: every call is retried with exponential backoff and jitter while the
  database is locked; the store is created (schema migrations) under an exclusive file lock, so two jobs
  that open a fresh database at once do not race.
- Experiments and runs are found by name / tags before they are created, so a rerun reuses them.
- Bounded waiting: retries stop after ``retry_budget_s`` (config ``mlflow.retry_budget_s``); HTTP stores are
  asked with ``mlflow.request_timeout_s`` and ``mlflow.http_retries`` instead of MLflow's own minutes of
  retries. :func:`check_tracking_store` checks the store when the workflow starts (seconds, creates nothing).
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import random
import re
import time
from pathlib import Path
from typing import Any, Callable, Iterator, TypeVar

LOG = logging.getLogger(__name__)
T = TypeVar("T")

#: Substrings of errors that mean "try again": SQLite lock contention.
RETRYABLE_MESSAGES = ("database is locked", "database table is locked", "disk i/o error", "unable to open database")

#: Defaults of the ``mlflow`` config section's fault settings (src/hybridfmu/schemas/mlflow.schema.yaml).
DEFAULT_RETRY_BUDGET_S = 60.0
DEFAULT_REQUEST_TIMEOUT_S = 10.0
DEFAULT_HTTP_RETRIES = 2


def retry_settings(mlflow_config: dict[str, Any] | None) -> dict[str, float]:
    """``{"retry_budget_s", "request_timeout_s", "http_retries"}`` of the ``mlflow`` config section."""
    section = mlflow_config or {}
    return {"retry_budget_s": float(section.get("retry_budget_s", DEFAULT_RETRY_BUDGET_S)),
            "request_timeout_s": float(section.get("request_timeout_s", DEFAULT_REQUEST_TIMEOUT_S)),
            "http_retries": int(section.get("http_retries", DEFAULT_HTTP_RETRIES))}


def default_tracking_uri(results_dir: str | Path) -> str:
    return f"sqlite:///{Path(results_dir).resolve() / 'mlflow.db'}"


def tracking_uri(mlflow_config: dict[str, Any] | None, results_dir: str | Path) -> str:
    """The configured tracking URI, or the SQLite store under ``results_dir``."""
    uri = (mlflow_config or {}).get("tracking_uri") or ""
    return uri or default_tracking_uri(results_dir)


def experiment_name(mlflow_config: dict[str, Any] | None, case: str) -> str:
    """The configured experiment, or the case name (one experiment per case)."""
    return (mlflow_config or {}).get("experiment") or case


class StoreBusyError(RuntimeError):
    """The tracking store stayed locked or unreadable through every retry (another process holds it)."""


def _busy(err: Exception, waited_s: float, attempts: int) -> StoreBusyError:
    first = str(err).splitlines()[0][:200] if str(err) else type(err).__name__
    return StoreBusyError(f"the MLflow store stayed busy through {attempts} attempts over {waited_s:.1f} s ({first}): "
                          "another process holds it (a second workflow or an `mlflow ui` on the same SQLite file?); "
                          "wait for it and rerun, give config.mlflow.retry_budget_s more seconds, or use a tracking "
                          "server (docs/tracking.md)")


def retry_locked(fn: Callable[..., T], *args: Any, attempts: int = 15, base_delay_s: float = 0.05,
                 max_delay_s: float = 5.0, budget_s: float | None = None, **kwargs: Any) -> T:
    """Call ``fn``; while it fails because the database is locked, wait (exponential backoff with jitter)
    and call again, up to ``attempts`` times and, with ``budget_s``, until the waits would exceed
    ``budget_s`` seconds in all. Other errors propagate at once.

    Raises:
        StoreBusyError: the store was still locked at the last attempt (says how long it waited and what to do).
    """
    started = time.perf_counter()
    for attempt in range(attempts):
        try:
            return fn(*args, **kwargs)
        except Exception as err:  # MLflow wraps SQLAlchemy errors in its own exception types
            text = str(err).lower()
            if not any(message in text for message in RETRYABLE_MESSAGES):
                raise
            waited = time.perf_counter() - started  # an attempt itself may block (SQLite's own busy timeout)
            if attempt == attempts - 1:
                raise _busy(err, waited, attempt + 1) from err
            delay = min(max_delay_s, base_delay_s * 2 ** attempt) * (0.5 + random.random())
            if budget_s is not None:
                if waited >= budget_s:
                    raise _busy(err, waited, attempt + 1) from err
                delay = min(delay, budget_s - waited)
            LOG.info("MLflow store busy (%s); retrying in %.2f s", text.splitlines()[0][:120], delay)
            time.sleep(delay)
    raise AssertionError("unreachable")


@contextlib.contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


_MLFLOW_KEY_INVALID = re.compile(r"[^A-Za-z0-9_\-. :/]")


def mlflow_key(name: str) -> str:
    """A param/metric/tag key MLflow accepts: characters other than letters, digits, ``_ - . : /`` and
    spaces become ``_`` (effect names such as ``parameter(k2)`` or ``time_offset(u1,u2)`` carry others)."""
    return _MLFLOW_KEY_INVALID.sub("_", str(name))[:250]


def sqlite_database(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI, else None."""
    return Path(uri[len("sqlite:///"):]) if uri.startswith("sqlite:///") else None


def bound_http_requests(request_timeout_s: float, http_retries: int) -> None:
    """Bound MLflow's HTTP requests of this process (its defaults retry for about 4 minutes)."""
    os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] = str(max(1, int(round(request_timeout_s))))
    os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] = str(max(0, int(http_retries)))
    os.environ["MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR"] = "1"


#: MLflow's limits of one ``log_batch`` call: params, tags (each), and entries in all.
MAX_PARAMS_TAGS_PER_BATCH = 100
MAX_ENTRIES_PER_BATCH = 1000


def log_batches(params: list[Any], tags: list[Any],
                metrics: list[Any]) -> list[tuple[list[Any], list[Any], list[Any]]]:
    """``(params, tags, metrics)`` split into the fewest batches within MLflow's limits (params and tags first,
    metrics filling each batch up); none for nothing to log."""
    batches = []
    while params or tags or metrics:
        batch_params, params = params[:MAX_PARAMS_TAGS_PER_BATCH], params[MAX_PARAMS_TAGS_PER_BATCH:]
        batch_tags, tags = tags[:MAX_PARAMS_TAGS_PER_BATCH], tags[MAX_PARAMS_TAGS_PER_BATCH:]
        room = MAX_ENTRIES_PER_BATCH - len(batch_params) - len(batch_tags)
        batch_metrics, metrics = metrics[:room], metrics[room:]
        batches.append((batch_params, batch_tags, batch_metrics))
    return batches


class Tracker:
    """An MLflow client with retries. ``artifact_root``: folder for the artifacts of experiments this
    tracker creates (default: ``mlartifacts`` beside a SQLite database). ``create``: create a missing SQLite
    store (False: a missing database is an error naming it, e.g. for a store lost during the search).
    ``retry_budget_s``: most seconds one call waits for a locked store (None: unbounded attempts only)."""

    def __init__(self, uri: str, artifact_root: str | Path | None = None, *, create: bool = True,
                 retry_budget_s: float | None = DEFAULT_RETRY_BUDGET_S,
                 request_timeout_s: float = DEFAULT_REQUEST_TIMEOUT_S, http_retries: int = DEFAULT_HTTP_RETRIES) -> None:
        from mlflow.tracking import MlflowClient

        self.uri = uri
        self.retry_budget_s = retry_budget_s
        database = sqlite_database(uri)
        if artifact_root is None and database is not None:
            artifact_root = database.parent / "mlartifacts"
        self.artifact_root = Path(artifact_root).resolve() if artifact_root is not None else None
        if uri.startswith(("http://", "https://")):
            bound_http_requests(request_timeout_s, http_retries)
        if database is None:
            self.client = MlflowClient(tracking_uri=uri)
        else:
            if not create and not database.is_file():
                raise FileNotFoundError(f"{database}: MLflow store (tracking URI {redacted_uri(uri)}) does not "
                                        "exist any more")
            # The store is created (schema migrations) on first use: do it under an exclusive file lock,
            # so that jobs opening a fresh database at the same time do not race.
            with _file_lock(database.with_name(database.name + ".lock")):
                self.client = MlflowClient(tracking_uri=uri)
                self.call("search_experiments", max_results=1)

    def call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        """``client.<method>(*args, **kwargs)`` with retries while the store is locked.

        Raises:
            StoreBusyError: the store stayed locked; names the store's URI (without credentials).
        """
        try:
            return retry_locked(getattr(self.client, method), *args, budget_s=self.retry_budget_s, **kwargs)
        except StoreBusyError as err:
            raise StoreBusyError(f"{redacted_uri(self.uri)}: {err}") from err.__cause__

    def experiment_id(self, name: str) -> str:
        """Id of experiment ``name``, created if missing (safe when another job creates it meanwhile)."""
        experiment = self.call("get_experiment_by_name", name)
        if experiment is not None:
            return experiment.experiment_id
        location = (self.artifact_root / name).as_uri() if self.artifact_root is not None else None
        try:
            return self.call("create_experiment", name, artifact_location=location)
        except Exception:
            experiment = self.call("get_experiment_by_name", name)
            if experiment is None:
                raise
            return experiment.experiment_id

    def find_run(self, experiment_id: str, tags: dict[str, str]) -> str | None:
        """Id of the oldest live run carrying all ``tags``, or None."""
        clauses = " and ".join(f"tags.`{key}` = '{value}'" for key, value in sorted(tags.items()))
        runs = self.call("search_runs", [experiment_id], filter_string=clauses, order_by=["attributes.start_time ASC"],
                         max_results=10)
        return runs[0].info.run_id if runs else None

    def get_or_create_run(self, experiment_id: str, tags: dict[str, str], run_name: str,
                          parent_run_id: str | None = None) -> str:
        """The run with ``tags`` (found by them), or a new one with them (a child of ``parent_run_id``)."""
        found = self.find_run(experiment_id, tags)
        if found is not None:
            return found
        return self.create_run(experiment_id, tags, run_name, parent_run_id)

    def create_run(self, experiment_id: str, tags: dict[str, str], run_name: str,
                   parent_run_id: str | None = None) -> str:
        """A new run (status RUNNING) with ``tags``, a child of ``parent_run_id`` if given; returns its id."""
        all_tags = dict(tags)
        if parent_run_id:
            all_tags["mlflow.parentRunId"] = parent_run_id
        run = self.call("create_run", experiment_id, tags=all_tags, run_name=run_name)
        return run.info.run_id

    def log(self, run_id: str, params: dict[str, Any] | None = None,
            metrics: list[tuple[str, float, int]] | None = None, tags: dict[str, Any] | None = None) -> None:
        """Log params, metrics ``(key, value, step)`` and tags in as few ``log_batch`` calls as MLflow's batch
        limits allow (one for up to 100 params, 100 tags and 1000 entries in all)."""
        from mlflow.entities import Metric, Param, RunTag

        timestamp = int(time.time() * 1000)
        params = [Param(mlflow_key(k), str(v)[:6000]) for k, v in (params or {}).items()]
        tags = [RunTag(mlflow_key(k), str(v)[:5000]) for k, v in (tags or {}).items()]
        metric_rows = [Metric(mlflow_key(k), float(v), timestamp, int(step)) for k, v, step in (metrics or [])]
        for batch_params, batch_tags, batch_metrics in log_batches(params, tags, metric_rows):
            self.call("log_batch", run_id, params=batch_params, tags=batch_tags, metrics=batch_metrics)

    def log_artifact(self, run_id: str, path: str | Path, artifact_path: str | None = None) -> None:
        self.call("log_artifact", run_id, str(path), artifact_path=artifact_path)

    def set_status(self, run_id: str, status: str) -> None:
        """RUNNING, FINISHED or FAILED."""
        if status == "RUNNING":
            self.call("update_run", run_id, status="RUNNING")
        else:
            self.call("set_terminated", run_id, status=status)


def redacted_uri(uri: str) -> str:
    """``uri`` for messages and logs: a password in it (``https://user:password@host/``) replaced by ``***``."""
    from urllib.parse import urlsplit, urlunsplit

    try:
        parts = urlsplit(str(uri))
        password = parts.password
    except ValueError:
        return str(uri)
    if not password:
        return str(uri)
    host = parts.netloc.rsplit("@", 1)[1]
    return urlunsplit(parts._replace(netloc=f"{parts.username}:***@{host}"))


def _nearest_existing(path: Path) -> Path:
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


#: URI schemes of the tracking stores MLflow offers (a database URI may name its driver: ``postgresql+psycopg2``).
TRACKING_SCHEMES = ("sqlite", "file", "http", "https", "postgresql", "mysql", "mssql", "databricks", "databricks-uc")


def _scheme_problem(uri: str) -> str | None:
    """Why the URI's scheme names no MLflow store (a typo such as ``sqllite:`` or ``htp:``), or None."""
    if "://" not in uri and not uri.startswith("sqlite:"):
        return None  # a plain path: a local folder store
    scheme = uri.split(":", 1)[0].lower()
    if scheme.split("+", 1)[0] in TRACKING_SCHEMES:
        return None
    return f"{scheme!r} is no tracking store scheme; expected one of {', '.join(TRACKING_SCHEMES)}"


def _writable_folder_problem(folder: Path) -> str | None:
    """Why no file can be created in the existing ``folder``, or None: a file is created and removed there (the
    permission bits alone do not say it for root, a read-only mount or a full disk)."""
    import tempfile

    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".hybridfmu-probe-"):
            pass
    except OSError as err:
        return f"no file can be created in {folder} ({err.strerror or err})"
    return None


def _http_problem(probe: str, timeout_s: float) -> str | None:
    """Why the HTTP(S) server at ``probe`` is no usable MLflow tracking server, or None."""
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(probe.rstrip("/") + "/health", timeout=timeout_s):
            pass
    except urllib.error.HTTPError:
        pass  # an MLflow server without /health, a proxy asking to log in: the API call below decides
    except (urllib.error.URLError, OSError, ValueError) as err:
        reason = getattr(err, "reason", err)
        return f"the server does not answer within {timeout_s:g} s ({reason})"
    api = probe.rstrip("/") + "/api/2.0/mlflow/experiments/search?max_results=1"
    try:
        with urllib.request.urlopen(api, timeout=timeout_s):
            return None
    except urllib.error.HTTPError as err:
        if err.code in (401, 403):
            return None  # it asks for credentials: MLflow's client sends them (MLFLOW_TRACKING_USERNAME/PASSWORD)
        if err.code == 404:
            return (f"the server answers but has no MLflow tracking API (HTTP 404 at {api}); expected the address "
                    "of an MLflow tracking server (mlflow server)")
        return None  # other answers (a method the server refuses, a server error) are the first use's to report
    except (urllib.error.URLError, OSError, ValueError) as err:
        reason = getattr(err, "reason", err)
        return f"the server's MLflow API does not answer within {timeout_s:g} s ({reason})"


def _store_problem(uri: str, timeout_s: float) -> str | None:
    """Why the store at ``uri`` cannot be used, or None (creates nothing that stays)."""
    scheme = _scheme_problem(uri)
    if scheme is not None:
        return scheme
    database = sqlite_database(uri)
    if uri.startswith("sqlite:") and database is None:
        return "a SQLite URI must be sqlite:///<absolute path of the database file>"
    if database is not None or uri.startswith("file:") or "://" not in uri:
        path = database if database is not None else Path(uri[len("file://"):] if uri.startswith("file://") else uri)
        target = path if database is None else path.parent
        if database is not None and database.exists():
            if not database.is_file():
                return f"{database} is not a file"
            if not os.access(database, os.R_OK | os.W_OK):
                return f"the database {database} is not writable"
        existing = _nearest_existing(target)
        if not existing.is_dir():
            return f"{existing} is not a folder, so {target} cannot be created"
        if not os.access(existing, os.W_OK | os.X_OK):
            return f"the folder {existing} is not writable"
        return _writable_folder_problem(existing)
    if uri.startswith(("http://", "https://")):
        from urllib.parse import urlsplit, urlunsplit

        parts = urlsplit(uri)  # the probe without credentials in the URL (urllib reads them as part of the host)
        return _http_problem(urlunsplit(parts._replace(netloc=parts.netloc.rsplit("@", 1)[-1])), timeout_s)
    return None  # other stores (databases, Databricks ...) are checked by their first use


def check_tracking_store(uri: str, config_file: str | Path, timeout_s: float = 5.0) -> None:
    """Fail fast when the tracking store cannot be used: a URI scheme no MLflow store has (a typo), a SQLite or
    folder store whose folder cannot be created or written (a file is created there and removed again), an
    HTTP(S) server that does not answer within ``timeout_s`` or answers without MLflow's tracking API. Leaves
    nothing behind (safe in a dry run).

    Raises:
        hybridfmu.config.ConfigError: one line naming ``config_file``, ``config.mlflow.tracking_uri``, the URI
            and why.
    """
    from hybridfmu.config import ConfigError

    problem = _store_problem(uri, timeout_s)
    if problem is not None:
        raise ConfigError(f"{config_file}: config.mlflow.tracking_uri: the MLflow store {redacted_uri(uri)} cannot be "
                          f"used: {problem.replace(uri, redacted_uri(uri))}")
