"""The evaluation is an MLflow run of its own, linked to the best trial, with metrics and artifacts."""

import json

from hybridfmu.evaluation.metrics import improvement_factors
from hybridfmu.evaluation.tracking import log_evaluation_run, log_report_artifacts, resolve_tracking


def test_default_tracking_uri_is_absolute(tmp_path):
    uri, experiment = resolve_tracking({"tracking_uri": "", "experiment": ""}, tmp_path / "res", "tiny")
    assert uri == f"sqlite:///{(tmp_path / 'res').resolve()}/mlflow.db" and experiment == "tiny"
    assert resolve_tracking({"tracking_uri": "http://x:5000", "experiment": "e"}, "r", "c") == ("http://x:5000", "e")


def test_evaluation_run_records_metrics_and_artifacts(tmp_path):
    from mlflow.tracking import MlflowClient

    fmu = {"angle_mae": 2.0, "angle_mse": 8.0, "speed_mae": 1.0, "speed_mse": 3.0, "level_rmse": 1.0}
    neural = {"angle_mae": 0.5, "angle_mse": 0.5, "speed_mae": 0.5, "speed_mse": 0.0, "level_rmse": 0.25}
    metrics = {"test": {"fmu": fmu, "neural_fmu": neural, "improvement": improvement_factors(fmu, neural)}}
    metric_file = tmp_path / "test.json"
    metric_file.write_text(json.dumps(metrics["test"]))
    uri, experiment = resolve_tracking({}, tmp_path, "tiny")
    info = log_evaluation_run(tmp_path / "run.json", uri, experiment, metrics, [metric_file],
                              {"dt_s": -2e-5, "width": 8}, "abc123", "tiny")
    assert json.loads((tmp_path / "run.json").read_text())["run_id"] == info["run_id"]
    figure = tmp_path / "fig.png"
    figure.write_bytes(b"\x89PNG fake")
    report = tmp_path / "report.md"
    report.write_text("# report\n")
    log_report_artifacts(tmp_path / "run.json", [figure], report)

    client = MlflowClient(tracking_uri=uri)
    run = client.get_run(info["run_id"])
    assert run.info.status == "FINISHED"
    assert run.data.tags["best_trial_run_id"] == "abc123" and run.data.tags["hybridfmu.role"] == "evaluation"
    assert run.data.metrics["test/improvement/angle_mae"] == 4.0
    assert run.data.metrics["test/improvement/level_rmse"] == 4.0 and run.data.metrics["test/fmu/level_rmse"] == 1.0
    assert "test/improvement/speed_mse" not in run.data.metrics       # unbounded factor is not logged
    assert run.data.params["dt_s"] == "-2e-05"
    artifacts = {a.path for a in client.list_artifacts(info["run_id"])}
    assert {"metrics", "figures", "report.md"} <= artifacts
    assert [a.path for a in client.list_artifacts(info["run_id"], "figures")] == ["figures/fig.png"]


def test_evaluation_run_names_its_process_and_ends_runs_of_dead_jobs(tmp_path):
    """An evaluation killed mid-way leaves its run RUNNING; the next evaluation ends it as KILLED."""
    import os
    import socket
    import subprocess
    import sys

    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking import Tracker
    from hybridfmu.tracking.jobs import process_start

    uri, experiment = resolve_tracking({}, tmp_path, "tiny")
    tracker = Tracker(uri)
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.3)"])
    start = process_start(child.pid)
    child.wait()
    stale = tracker.call("create_run", tracker.experiment_id(experiment), tags={
        "hybridfmu.role": "evaluation", "hybridfmu.host": socket.gethostname(), "hybridfmu.pid": str(child.pid),
        "hybridfmu.pid_start": str(start)}).info.run_id
    metrics = {"test": {"fmu": {"angle_mae": 2.0}, "neural_fmu": {"angle_mae": 1.0}, "improvement": {"angle_mae": 2.0}}}
    info = log_evaluation_run(tmp_path / "run.json", uri, experiment, metrics, [], {}, None, "tiny")
    client = MlflowClient(tracking_uri=uri)
    assert client.get_run(stale).info.status == "KILLED"
    assert "is gone" in client.get_run(stale).data.tags["hybridfmu.ended_reason"]
    assert client.get_run(info["run_id"]).data.tags["hybridfmu.pid"] == str(os.getpid())
