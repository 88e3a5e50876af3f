"""MLflow tracking: defaults, retries on a locked store, and two training processes logging at once."""

import json
from pathlib import Path
import subprocess
import sys
import textwrap

import pytest

from hybridfmu.tracking import default_tracking_uri, experiment_name, retry_locked, tracking_uri

WORKER = textwrap.dedent('''
    import json, sys
    import torch
    from hybridfmu.model import NeuralFmu, NeuralFmuSpec
    from hybridfmu.training.search_tracking import log_trial_rung

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
                      "validations": validations, "delay_s": {"inputs": 1e-5}, "skipped_steps": 3,
                      "gates": {"v": {"g_F": 1.0, "g_A": 0.3}}, "checkpoint": "c.pt"}
            run_id = log_trial_rung(tracking, "search-1", result, history, model, spec, run_id)
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

    from hybridfmu.training.search_tracking import start_search

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
        assert artifacts == {"rung1/model"}
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


def test_log_sends_params_tags_and_metrics_in_the_fewest_batches_mlflow_accepts(tmp_path):
    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking.mlflow_store import Tracker, log_batches

    assert log_batches([], [], []) == []
    assert [tuple(map(len, b)) for b in log_batches(list(range(5)), list(range(3)), list(range(40)))] == [(5, 3, 40)]
    sizes = [tuple(map(len, b)) for b in log_batches(list(range(150)), list(range(120)), list(range(2500)))]
    assert sizes == [(100, 100, 800), (50, 20, 930), (0, 0, 770)]
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    tracker = Tracker(uri)
    run_id = tracker.call("create_run", tracker.experiment_id("batches")).info.run_id
    tracker.log(run_id, params={f"p{k}": k for k in range(150)}, tags={f"t{k}": k for k in range(120)},
                metrics=[("m", float(k), k) for k in range(2500)])
    client = MlflowClient(tracking_uri=uri)
    logged = client.get_run(run_id).data
    assert len(logged.params) == 150 and len([t for t in logged.tags if t.startswith("t")]) == 120
    assert sorted(m.step for m in client.get_metric_history(run_id, "m")) == list(range(2500))


# --- faults: store check, bounded retries, idempotent logging, stale runs, moved stores ----------------

def test_check_tracking_store_fails_fast_and_creates_nothing(tmp_path):
    import socket
    import time

    from hybridfmu.config import ConfigError
    from hybridfmu.tracking import check_tracking_store

    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    start = time.perf_counter()
    with pytest.raises(ConfigError) as raised:
        check_tracking_store(f"http://127.0.0.1:{port}", "config/cases/x.yaml", timeout_s=2.0)
    message = str(raised.value)
    assert time.perf_counter() - start < 3.0 and "\n" not in message
    for part in ("config/cases/x.yaml", "config.mlflow.tracking_uri", f"http://127.0.0.1:{port}", "does not answer"):
        assert part in message
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match="is not a folder"):
        check_tracking_store(f"sqlite:///{tmp_path / 'file' / 'sub' / 'mlflow.db'}", "c.yaml")
    check_tracking_store(default_tracking_uri(tmp_path / "new" / "results"), "c.yaml")
    assert not (tmp_path / "new").exists()


def test_a_password_in_the_tracking_uri_is_never_echoed():
    """A server URI with credentials: the check probes the server without them in the host, and the message
    shows the user but not the password."""
    import socket

    from hybridfmu.config import ConfigError
    from hybridfmu.tracking import check_tracking_store, redacted_uri

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    uri = f"https://alice:s3cret@127.0.0.1:{port}/mlflow"
    with pytest.raises(ConfigError) as raised:
        check_tracking_store(uri, "c.yaml", timeout_s=2.0)
    message = str(raised.value)
    assert "s3cret" not in message and f"https://alice:***@127.0.0.1:{port}/mlflow" in message
    assert "does not answer" in message and "Connection refused" in message  # the server probed, not "alice"
    assert redacted_uri("sqlite:////tmp/a.db") == "sqlite:////tmp/a.db"
    assert redacted_uri("http://bob@host/") == "http://bob@host/"


def test_retry_budget_bounds_the_wait():
    import time

    def locked():
        raise RuntimeError("(sqlite3.OperationalError) database is locked")

    start = time.perf_counter()
    with pytest.raises(RuntimeError, match="locked"):
        retry_locked(locked, attempts=100, base_delay_s=0.05, budget_s=0.5)
    assert time.perf_counter() - start < 1.5


def _rung_result(rung, history, validations):
    return {"trial_id": "b0c0", "bracket": 0, "rung": rung, "config": 0, "hash": "abc", "status": "ok", "reason": "",
            "objective": 0.5 / (rung + 1), "hyperparameters": {"lr": 1e-3}, "resource_s": history[-1][0],
            "fmu": {"path": "IPBMotor.fmu", "sha256": "0" * 64}, "validation": {"objective": 0.5 / (rung + 1)},
            "validations": validations, "delay_s": {"inputs": 1e-5}, "skipped_steps": 0, "gates": {"v": {"g_F": 1.0}},
            "checkpoint": "c.pt"}


def test_logging_is_idempotent_and_order_free(tmp_path):
    """A rung logged twice (a rerun) adds no rows; a rung logged late (after the next one) adds only its own."""
    from mlflow.tracking import MlflowClient

    from hybridfmu.training.search_tracking import log_trial_rung, start_search

    uri = default_tracking_uri(tmp_path)
    tracking = start_search(uri, "case", "search-1", "case", {"R": 3})
    spec = {"state_names": ["p"]}
    state = {"w": __import__("torch").zeros(2)}
    history = [[0.001 * (k + 1), 1.0 / (k + 1), 0.0, 1.0] for k in range(20)]
    rung0 = _rung_result(0, history[:10], [{"objective": 0.5, "resource_s": history[9][0]}])
    rung1 = _rung_result(1, history, rung0["validations"] + [{"objective": 0.25, "resource_s": history[-1][0]}])
    run_id = log_trial_rung(tracking, "search-1", rung1, history, state, spec)  # rung 1 first (rung 0 deferred)
    assert log_trial_rung(tracking, "search-1", rung1, history, state, spec) == run_id  # a rerun of rung 1
    log_trial_rung(tracking, "search-1", rung0, history[:10], state, spec)  # rung 0 caught up later
    client = MlflowClient(uri)
    assert sorted(m.step for m in client.get_metric_history(run_id, "train_loss")) == list(range(1, 21))
    assert sorted(m.step for m in client.get_metric_history(run_id, "val_objective")) == [10, 20]
    assert sorted(m.step for m in client.get_metric_history(run_id, "best_val_objective")) == [10, 20]
    children = client.search_runs([tracking["experiment_id"]], filter_string="tags.`hybridfmu.trial` = 'b0c0'")
    assert len(children) == 1 and children[0].info.status == "FINISHED"


def _dead_process():
    """(pid, start) of a process that has ended."""
    from hybridfmu.tracking.jobs import process_start

    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.5)"])
    start = process_start(child.pid)
    child.wait()
    return child.pid, start


def test_runs_left_running_by_dead_jobs_are_ended(tmp_path):
    import socket

    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking.jobs import owner_tags
    from hybridfmu.tracking.mlflow_store import Tracker
    from hybridfmu.training.search_tracking import end_stale_runs

    tracker = Tracker(default_tracking_uri(tmp_path))
    experiment = tracker.experiment_id("case")
    pid, start = _dead_process()
    dead = tracker.get_or_create_run(experiment, {"hybridfmu.trial": "dead"}, "dead")
    tracker.log(dead, tags={"hybridfmu.host": socket.gethostname(), "hybridfmu.pid": str(pid),
                            "hybridfmu.pid_start": str(start)})
    alive = tracker.get_or_create_run(experiment, {"hybridfmu.trial": "alive"}, "alive")
    tracker.log(alive, tags=owner_tags())
    other_host = tracker.get_or_create_run(experiment, {"hybridfmu.trial": "other"}, "other")
    tracker.log(other_host, tags={"hybridfmu.host": "elsewhere", "hybridfmu.pid": str(pid)})
    assert end_stale_runs(tracker, experiment) == [dead]
    client = MlflowClient(tracker.uri)
    ended = client.get_run(dead)
    assert ended.info.status == "KILLED" and f"PID {pid}" in ended.data.tags["hybridfmu.ended_reason"]
    assert {client.get_run(r).info.status for r in (alive, other_host)} == {"RUNNING"}


def test_moved_results_folder_keeps_its_artifacts(tmp_path):
    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking.mlflow_store import Tracker

    old = tmp_path / "old" / "results"
    tracker = Tracker(default_tracking_uri(old))
    run_id = tracker.call("create_run", tracker.experiment_id("case")).info.run_id
    (tmp_path / "note.txt").write_text("kept")
    tracker.log_artifact(run_id, tmp_path / "note.txt")
    new = tmp_path / "moved" / "results"
    new.parent.mkdir()
    (tmp_path / "old" / "results").rename(new)
    command = [sys.executable, "-m", "hybridfmu.tracking.relocate", str(new)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    client = MlflowClient(default_tracking_uri(new))
    assert client.get_run(run_id).info.artifact_uri.startswith((new / "mlartifacts").as_uri())
    assert (Path(client.download_artifacts(run_id, "note.txt", str(tmp_path))).read_text()) == "kept"
    again = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert "0 experiment(s) and 0 run(s)" in again.stdout
    missing = subprocess.run([sys.executable, "-m", "hybridfmu.tracking.relocate", str(tmp_path / "none")],
                             capture_output=True, text=True, timeout=120)
    assert missing.returncode == 1 and "mlflow.db" in missing.stderr


# --- jobs: watchdog, output lock, interrupts ----------------------------------------------------------

FAKE_SNAKEMAKE = textwrap.dedent('''
    # stands in for Snakemake: starts the job given on its command line and waits for it
    import subprocess, sys
    from hybridfmu.tracking.jobs import forward_interrupt
    forward_interrupt()
    job = subprocess.Popen([sys.executable, "-c", sys.argv[1], *sys.argv[2:]])
    print(job.pid, flush=True)
    try:
        job.wait()
    except KeyboardInterrupt:
        job.wait()
        print("interrupted", flush=True)
''')

JOB = textwrap.dedent('''
    import logging, sys, time
    from hybridfmu.tracking.jobs import job_guard
    logging.basicConfig(filename=sys.argv[1], level=logging.INFO)
    with job_guard(sys.argv[2], "test job"):
        open(sys.argv[1] + ".started", "w").close()
        while True:
            sum(range(10000))
''')


def _fake_snakemake(tmp_path, log, lock):
    folder = tmp_path / "bin"
    folder.mkdir(exist_ok=True)
    script = folder / "snakemake"  # a process named like Snakemake is a job's owner
    script.write_text(FAKE_SNAKEMAKE)
    owner = subprocess.Popen([sys.executable, str(script), JOB, str(log), str(lock)], stdout=subprocess.PIPE, text=True)
    job_pid = int(owner.stdout.readline())
    _wait_for(lambda: Path(str(log) + ".started").exists(), 60)
    return owner, job_pid


def _wait_for(condition, timeout_s):
    import time

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    raise AssertionError(f"condition not met within {timeout_s} s")


def test_job_stops_when_its_snakemake_is_killed(tmp_path):
    import os
    import signal

    from hybridfmu.tracking.jobs import process_start

    log, lock = tmp_path / "job.log", tmp_path / "out" / "job.lock"
    owner, job_pid = _fake_snakemake(tmp_path, log, lock)
    assert json.loads(lock.read_text())["pid"] == job_pid
    os.kill(owner.pid, signal.SIGKILL)
    owner.wait()
    _wait_for(lambda: process_start(job_pid) is None, 15)
    assert "Snakemake process (PID %d) that started this job is gone" % owner.pid in log.read_text()


def test_interrupt_reaches_the_job_at_once(tmp_path):
    import os
    import signal
    import time

    log, lock = tmp_path / "job.log", tmp_path / "out" / "job.lock"
    owner, job_pid = _fake_snakemake(tmp_path, log, lock)
    start = time.perf_counter()
    os.kill(owner.pid, signal.SIGINT)  # only Snakemake gets it, as from `kill -INT`
    out, _ = owner.communicate(timeout=30)
    assert "interrupted" in out and time.perf_counter() - start < 10


def test_a_new_job_takes_over_from_an_orphan(tmp_path):
    import os

    from hybridfmu.tracking.jobs import OutputLock, process_start

    lock = tmp_path / "out" / "job.lock"
    orphan = subprocess.Popen([sys.executable, "-c", textwrap.dedent('''
        import sys, time
        from hybridfmu.tracking.jobs import OutputLock
        held = OutputLock(sys.argv[1])
        held.acquire()
        print("locked", flush=True)
        time.sleep(600)
    '''), str(lock)], stdout=subprocess.PIPE, text=True)
    assert orphan.stdout.readline().strip() == "locked"
    taken = OutputLock(lock, grace_s=5.0)
    stopped = taken.acquire(timeout_s=30)
    assert stopped["pid"] == orphan.pid and orphan.wait(timeout=10) != 0
    assert process_start(orphan.pid) is None and json.loads(lock.read_text())["pid"] == os.getpid()
    taken.release()


OWNER_PROBE = textwrap.dedent('''
    import json, os
    from hybridfmu.tracking.jobs import snakemake_ancestor, workflow_process
    from hybridfmu.training.search_tracking import workflow_owner_tags
    workflow = workflow_process()
    print(json.dumps({"parent": os.getppid(), "ancestor": snakemake_ancestor().pid,
                      "workflow": workflow.pid if workflow else None, "tags": workflow_owner_tags()}))
''')


@pytest.mark.parametrize("remote", [False, True], ids=["workflow", "cluster_job"])
def test_the_search_is_owned_by_the_workflow_not_by_a_cluster_jobs_snakemake(tmp_path, remote):
    """Under the workflow's Snakemake the search's parent run records that process; under a cluster job's
    Snakemake (--mode remote, as the Slurm executor runs each job) it records no PID, so that no later job
    ends it as the run of a dead process (the job's Snakemake ends with its job), while the watchdog still
    watches the job's own Snakemake."""
    folder = tmp_path / "bin"
    folder.mkdir()
    fake = folder / "snakemake"
    fake.write_text("import subprocess, sys\nsys.exit(subprocess.run([sys.executable, '-c', sys.argv[1]]).returncode)\n")
    extra = ["--mode", "remote"] if remote else ["-j2"]
    done = subprocess.run([sys.executable, str(fake), OWNER_PROBE, *extra], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    assert seen["ancestor"] == seen["parent"]
    if remote:
        assert seen["workflow"] is None
        assert seen["tags"]["hybridfmu.pid"] == seen["tags"]["hybridfmu.snakemake_pid"] == ""
    else:
        assert seen["workflow"] == seen["parent"] and seen["tags"]["hybridfmu.pid"] == str(seen["parent"])


def test_a_lock_held_by_another_hosts_job_is_waited_for_not_stopped(tmp_path):
    """A lock whose holder ran on another host (a cluster job on another node): its PID means nothing here;
    the new job waits, then fails naming the host and the Slurm job, and stops no local process."""
    from hybridfmu.tracking.jobs import OutputLock, OutputLockError, process_start

    lock = tmp_path / "out" / "job.lock"
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent('''
        import json, sys, time
        from hybridfmu.tracking.jobs import OutputLock
        held = OutputLock(sys.argv[1])
        held.acquire()
        record = json.loads(open(sys.argv[1]).read())
        record.update(host="node17", slurm_job_id="4711")
        held._handle.seek(0)
        held._handle.truncate()
        held._handle.write(json.dumps(record))
        held._handle.flush()
        print("locked", flush=True)
        time.sleep(600)
    '''), str(lock)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(OutputLockError, match=r"on node17 \(Slurm job 4711; `scancel 4711` stops it\)"):
            OutputLock(lock, grace_s=1.0).acquire(timeout_s=2)
        assert process_start(holder.pid) is not None and holder.poll() is None
    finally:
        holder.kill()
        holder.wait()


def test_select_best_catches_up_on_queued_rungs(tmp_path):
    """A rung whose logging failed is logged by select_best's catch-up, best.json gets the trial's run id,
    the search run is finished; with the store gone, the catch-up reports instead of failing."""
    import torch
    from mlflow.tracking import MlflowClient

    from hybridfmu.training.search_tracking import catch_up_search, finish_search, record_pending, start_search

    uri = default_tracking_uri(tmp_path / "store")
    tracking = start_search(uri, "case", "search-1", "case", {"R": 3})
    hpo = tmp_path / "hpo"
    hpo.mkdir()
    (hpo / "plan.json").write_text(json.dumps({"search_id": "search-1", "tracking": tracking}))
    history = [[0.001 * (k + 1), 1.0 / (k + 1), 0.0, 1.0] for k in range(10)]
    result = _rung_result(0, history, [{"objective": 0.5, "resource_s": history[-1][0]}])
    result["checkpoint"] = str(hpo / "checkpoint.pt")
    torch.save({"format": 1, "status": "ok", "bracket": 0, "rung": 0, "config": 0, "spec": {"state_names": ["p"]},
                "model": {"w": torch.zeros(2)}, "validations": result["validations"],
                "trainer": {"history": history}}, hpo / "checkpoint.pt")
    (hpo / "result.json").write_text(json.dumps(result))
    record_pending(hpo / "plan.json", result, hpo / "result.json", "store locked")
    (hpo / "summary.json").write_text("{}")
    (hpo / "best.json").write_text(json.dumps({"trial_id": "b0c0", "mlflow_run_id": None, "validation": {
        "objective": 0.5}, "summary": str(hpo / "summary.json")}))
    assert catch_up_search(hpo / "plan.json", best_path=hpo / "best.json")
    run_id = json.loads((hpo / "best.json").read_text())["mlflow_run_id"]
    client = MlflowClient(uri)
    assert len(client.get_metric_history(run_id, "train_loss")) == 10 and not list((hpo / "tracking_pending").iterdir())
    parent = client.get_run(tracking["parent_run_id"])
    assert parent.info.status == "FINISHED" and parent.data.tags["best_run_id"] == run_id
    (tmp_path / "store" / "mlflow.db").unlink()
    assert finish_search(tracking, None, hpo / "summary.json") is False
    assert catch_up_search(hpo / "plan.json") is False


def test_unreachable_http_store_fails_within_the_bound():
    """MLflow's own HTTP retries wait about 4 minutes; the tracker's bound (mlflow.http_retries,
    mlflow.request_timeout_s) makes a lost server an error within seconds."""
    import socket
    import time

    from hybridfmu.tracking.mlflow_store import Tracker

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    start = time.perf_counter()
    with pytest.raises(Exception, match=f"127.0.0.1:{port}"):
        Tracker(f"http://127.0.0.1:{port}", request_timeout_s=1.0, http_retries=1, retry_budget_s=1.0).experiment_id("x")
    assert time.perf_counter() - start < 20
