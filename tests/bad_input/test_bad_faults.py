"""Faults around the search: an unreachable or unusable MLflow store, a store lost during the search, damaged
or foreign checkpoints. Each is answered by an error naming the file and the field (or what was expected),
and what was already written stays intact."""

import json
import socket
import time

import pytest
import torch

from bad_input.conftest import assert_intact, assert_names, snapshot
from hybridfmu.config import ConfigError
from hybridfmu.tracking import check_tracking_store, default_tracking_uri


def closed_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_unreachable_tracking_server(outputs):
    before = snapshot(outputs)
    uri = f"http://127.0.0.1:{closed_port()}"
    start = time.perf_counter()
    with pytest.raises(ConfigError) as raised:
        check_tracking_store(uri, "config/cases/tiny.yaml", timeout_s=2.0)
    assert time.perf_counter() - start < 5.0
    message = str(raised.value)
    assert_names(message, "config/cases/tiny.yaml", "config.mlflow.tracking_uri", uri, "does not answer")
    assert "\n" not in message
    assert_intact(outputs, before)


def test_store_folder_that_cannot_be_created(outputs):
    before = snapshot(outputs)
    blocker = outputs / "data" / "earlier.json"  # a file where the store's folder would be
    uri = f"sqlite:///{blocker / 'mlruns' / 'mlflow.db'}"
    with pytest.raises(ConfigError) as raised:
        check_tracking_store(uri, "case.yaml")
    assert_names(str(raised.value), "case.yaml", "config.mlflow.tracking_uri", uri, str(blocker), "not a folder")
    assert_intact(outputs, before)


@pytest.mark.parametrize("uri", ["sqllite:////tmp/results/mlflow.db", "htp://127.0.0.1:5000"])
def test_tracking_uri_with_a_scheme_typo(outputs, uri):
    before = snapshot(outputs)
    with pytest.raises(ConfigError) as raised:
        check_tracking_store(uri, "case.yaml", timeout_s=2.0)
    assert_names(str(raised.value), "case.yaml", "config.mlflow.tracking_uri", uri, "no tracking store scheme",
                 "sqlite, file, http")
    assert_intact(outputs, before)


def test_store_folder_where_no_file_can_be_created(outputs):
    """The permission bits say a root process may write to /proc; creating a file there fails. The check tries it
    and leaves nothing behind."""
    before = snapshot(outputs)
    uri = "sqlite:////proc/hybridfmu-results/mlflow.db"
    with pytest.raises(ConfigError) as raised:
        check_tracking_store(uri, "case.yaml")
    assert_names(str(raised.value), "case.yaml", "config.mlflow.tracking_uri", uri, "no file can be created in /proc")
    assert_intact(outputs, before)
    check_tracking_store(default_tracking_uri(outputs / "store"), "case.yaml")
    assert_intact(outputs, before)  # the probe of a usable folder leaves no file either


def test_tracking_uri_of_a_web_server_that_is_no_mlflow_server(outputs, tmp_path):
    import functools
    import http.server
    import threading

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    handler = functools.partial(Quiet, directory=str(tmp_path))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        uri = f"http://127.0.0.1:{server.server_address[1]}"
        with pytest.raises(ConfigError) as raised:
            check_tracking_store(uri, "case.yaml", timeout_s=2.0)
    finally:
        server.shutdown()
    assert_names(str(raised.value), "case.yaml", "config.mlflow.tracking_uri", uri, "HTTP 404",
                 "no MLflow tracking API")


def test_a_store_held_locked_by_another_process_while_a_search_is_planned(outputs):
    """Another process holds the SQLite store (an exclusive transaction) while the search's parent run is created:
    after its retry budget the planning stops with one error naming the store, how long it waited and what to do,
    and creates no plan."""
    import sqlite3

    from hybridfmu.tracking import StoreBusyError
    from hybridfmu.training.search_tracking import start_search

    uri = default_tracking_uri(outputs / "store")
    start_search(uri, "case", "s0", "case", {"R": 1})  # the store exists
    before = snapshot(outputs)
    holder = sqlite3.connect(str(outputs / "store" / "mlflow.db"), timeout=0.1)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        started = time.perf_counter()
        with pytest.raises(StoreBusyError) as raised:
            from hybridfmu.tracking import Tracker

            Tracker(uri, retry_budget_s=1.0).call("get_experiment_by_name", "case")
        assert time.perf_counter() - started < 75.0  # one attempt may block for SQLite's own busy timeout
    finally:
        holder.rollback()
        holder.close()
    message = str(raised.value)
    assert_names(message, str(outputs / "store" / "mlflow.db"), "stayed busy", "database is locked",
                 "config.mlflow.retry_budget_s")
    assert_intact(outputs, before)


def test_corrupt_checkpoint(outputs):
    from hybridfmu.training.checkpoint import load_checkpoint

    path = outputs / "hpo" / "b1" / "r0" / "c2" / "checkpoint.pt"
    path.parent.mkdir(parents=True)
    path.write_bytes(b"PK\x03\x04 truncated by a full disk")
    before = snapshot(outputs)
    with pytest.raises(ValueError) as raised:
        load_checkpoint(path)
    assert_names(str(raised.value), str(path), "expected a trial checkpoint")
    assert_intact(outputs, before)


def test_best_json_naming_a_corrupt_checkpoint(outputs):
    from hybridfmu.training.inference import load_trained_neural_fmu

    checkpoint = outputs / "hpo" / "best_model.pt"
    checkpoint.parent.mkdir(parents=True)
    checkpoint.write_bytes(b"\x00" * 64)
    best = outputs / "hpo" / "best.json"
    best.write_text(json.dumps({"checkpoint": str(checkpoint)}))
    before = snapshot(outputs)
    with pytest.raises(ValueError) as raised:
        load_trained_neural_fmu(best, outputs / "IPBMotor.fmu")
    assert_names(str(raised.value), str(checkpoint), "expected a trial checkpoint")
    assert_intact(outputs, before)


def test_checkpoint_of_another_format(outputs):
    from hybridfmu.training.checkpoint import load_checkpoint

    path = outputs / "hpo" / "foreign.pt"
    path.parent.mkdir(parents=True)
    torch.save({"model": {}, "format": 7}, path)
    before = snapshot(outputs)
    with pytest.raises(ValueError) as raised:
        load_checkpoint(path)
    assert_names(str(raised.value), str(path), "'format'", "expected 1")
    assert_intact(outputs, before)


def test_tracking_store_lost_during_the_search(outputs):
    """The store's database is gone: opening it names the database (it is not silently created anew), the
    catch-up of queued rungs reports and keeps the queue, and nothing already written changes."""
    from hybridfmu.tracking.mlflow_store import Tracker
    from hybridfmu.training.search_tracking import catch_up_search, sync_pending

    database = outputs / "store" / "mlflow.db"
    uri = default_tracking_uri(outputs / "store")
    hpo = outputs / "hpo"
    (hpo / "tracking_pending").mkdir(parents=True)
    (hpo / "plan.json").write_text(json.dumps({"search_id": "s1", "tracking": {
        "uri": uri, "experiment": "case", "experiment_id": "1", "parent_run_id": "abc"}}))
    (hpo / "tracking_pending" / "b0_r0_c0.json").write_text(json.dumps({
        "trial_id": "b0c0", "bracket": 0, "rung": 0, "config": 0, "result": str(hpo / "b0/r0/c0/result.json"),
        "checkpoint": str(hpo / "b0/r0/c0/checkpoint.pt"), "error": "store locked"}))
    before = snapshot(outputs)
    with pytest.raises(FileNotFoundError) as raised:
        Tracker(uri, create=False)
    assert_names(str(raised.value), str(database), "does not exist")
    with pytest.raises(FileNotFoundError, match=str(database)):
        sync_pending(hpo / "plan.json")
    assert catch_up_search(hpo / "plan.json", {"retry_budget_s": 0.5}) is False
    assert not database.exists()
    assert_intact(outputs, before)
