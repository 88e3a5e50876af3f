"""MLflow tracking: defaults, retries on a locked store, and two training processes logging at once."""

import json
import subprocess
import sys
import textwrap

import pytest

from hybridfmu.tracking import default_tracking_uri, experiment_name, retry_locked, tracking_uri

WORKER = textwrap.dedent('''
    import json, sys
    import torch
    from hybridfmu.model import NeuralFmu, NeuralFmuSpec
    from hybridfmu.tracking.search import log_trial_rung

    tracking, worker = json.loads(sys.argv[1]), int(sys.argv[2])
    spec = NeuralFmuSpec(state_names=["p", "v"], input_names=["f"], corrected_states=["v"], ann_states=["v"],
                         ann_inputs=[], ann_derivatives=[], sample_period_s=1e-4)
    model = NeuralFmu(lambda x, u: torch.stack([x[:, 1], u[:, 0] - x[:, 0]], dim=1), spec, None)
    for trial in range(3):
        run_id, history, validations = None, [], []
        for rung in range(2):
            start = len(history)
            history += [[0.01 * (k + 1), 1.0 / (k + 1), float(k % 50 == 7), 1.0] for k in range(start, start + 150)]
            validations.append({"objective": 0.5 / (rung + 1), "resource_s": history[-1][0],
                                "position_mae": 0.2 / (rung + 1), "position_rmse": None})
            result = {"trial_id": f"b{worker}c{trial}", "bracket": worker, "rung": rung, "config": trial,
                      "hash": "abc", "status": "ok", "reason": "", "objective": 0.5 / (rung + 1), "hyperparameters": {"lr": 1e-3, "width": 8},
                      "fmu": {"path": "IPBMotor.fmu", "sha256": "0" * 64}, "resource_s": history[-1][0],
                      "validation": {"objective": 0.5 / (rung + 1), "position_mae": 0.1, "position_mse": 0.01,
                                     "position_rmse": 0.1, "loss": 0.3},
                      "validations": validations, "delay_s": 1e-5, "skipped_steps": 3,
                      "gates": {"v": {"g_F": 1.0, "g_A": 0.3}}, "checkpoint": "c.pt"}
            run_id = log_trial_rung(tracking, "search-1", result, history, model, spec, run_id,
                                    since_resource_s=history[start - 1][0] if start else 0.0)
    print("done", worker)
''')


def test_uri_and_experiment_defaults(tmp_path):
    assert tracking_uri({"tracking_uri": ""}, tmp_path / "r") == f"sqlite:///{(tmp_path / 'r').resolve()}/mlflow.db"
    assert tracking_uri(None, "results") == default_tracking_uri("results")
    assert tracking_uri({"tracking_uri": "http://server:5000"}, "results") == "http://server:5000"
    assert experiment_name({"experiment": ""}, "ipb") == "ipb" and experiment_name({"experiment": "x"}, "ipb") == "x"


def test_retry_on_locked_database_only():
    calls = []

    def flaky():
        calls.append(1)
        if len(calls) < 3:
            raise RuntimeError("(sqlite3.OperationalError) database is locked")
        return "ok"

    assert retry_locked(flaky, base_delay_s=0.001) == "ok" and len(calls) == 3

    def broken():
        calls.append(1)
        raise ValueError("no such run")

    calls.clear()
    with pytest.raises(ValueError, match="no such run"):
        retry_locked(broken, base_delay_s=0.001)
    assert len(calls) == 1


def _run_workers(tmp_path, script, args_per_worker):
    path = tmp_path / "worker.py"
    path.write_text(script)
    workers = [subprocess.Popen([sys.executable, str(path), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True) for args in args_per_worker]
    outputs = [worker.communicate(timeout=300) for worker in workers]
    for worker, (out, err) in zip(workers, outputs):
        assert worker.returncode == 0, err[-3000:]
    return [out for out, _ in outputs]


def test_two_processes_create_a_fresh_store_at_once(tmp_path):
    uri = default_tracking_uri(tmp_path)
    script = textwrap.dedent('''
        import sys
        from hybridfmu.tracking import Tracker
        tracker = Tracker(sys.argv[1])
        experiment = tracker.experiment_id("case")
        run = tracker.get_or_create_run(experiment, {"worker": sys.argv[2]}, run_name="w" + sys.argv[2])
        tracker.log(run, metrics=[("m", float(k), k) for k in range(50)])
        print(experiment)
    ''')
    outputs = _run_workers(tmp_path, script, [(uri, "0"), (uri, "1")])
    assert outputs[0].strip() == outputs[1].strip()
    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    runs = client.search_runs([outputs[0].strip()])
    assert sorted(r.data.tags["worker"] for r in runs) == ["0", "1"]
    for run in runs:
        assert len(client.get_metric_history(run.info.run_id, "m")) == 50


def test_two_training_processes_log_everything(tmp_path):
    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking.search import start_search

    uri = default_tracking_uri(tmp_path)
    tracking = start_search(uri, "case", "search-1", "case", {"R": 9, "eta": 3})
    assert start_search(uri, "case", "search-1", "case", {"R": 9, "eta": 3}) == tracking  # found, not duplicated
    _run_workers(tmp_path, WORKER, [(json.dumps(tracking), "0"), (json.dumps(tracking), "1")])
    client = MlflowClient(uri)
    runs = client.search_runs([tracking["experiment_id"]], filter_string="tags.`hybridfmu.search_id` = 'search-1'")
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == tracking["parent_run_id"]]
    assert sorted(r.data.tags["hybridfmu.trial"] for r in children) == [f"b{w}c{t}" for w in (0, 1) for t in range(3)]
    for run in children:
        run_id = run.info.run_id
        assert run.info.status == "FINISHED"
        assert run.data.params["hp.lr"] == "0.001" and run.data.tags["config_hash"] == "abc"
        losses = client.get_metric_history(run_id, "train_loss")
        assert len(losses) == 300 and sorted(m.step for m in losses) == [10 * (k + 1) for k in range(300)]
        assert [m.step for m in sorted(client.get_metric_history(run_id, "val_objective"), key=lambda m: m.step)] == [
            1500, 3000]
        assert run.data.metrics["best_val_objective"] == 0.25
        assert run.data.metrics["val_position_mae"] == 0.1 and "val_position_rmse" not in run.data.metrics
        artifacts = {a.path for a in client.list_artifacts(run_id, "rung1")}
        assert {"rung1/model", "rung1/training_curve.png"} <= artifacts
        model_files = {a.path for a in client.list_artifacts(run_id, "rung1/model")}
        assert model_files == {"rung1/model/state_dict.pt", "rung1/model/model_info.json"}


def test_keys_with_characters_mlflow_refuses_are_logged_under_a_safe_name(tmp_path):
    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking.mlflow_store import Tracker, mlflow_key

    assert mlflow_key("x2.parameter(k2).relative_error") == "x2.parameter_k2_.relative_error"
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tracker = Tracker(uri)
    run_id = tracker.call("create_run", tracker.experiment_id("keys")).info.run_id
    tracker.log(run_id, params={"time_offset(u1,u2)": 1.0}, metrics=[("gap/coulomb(v)*|u|", 0.5, 0)])
    logged = MlflowClient(tracking_uri=uri).get_run(run_id).data
    assert logged.params == {"time_offset_u1_u2_": "1.0"}
    assert logged.metrics == {"gap/coulomb_v___u_": 0.5}
