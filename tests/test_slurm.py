"""The workflow on a Slurm cluster: the tiny case through the Slurm profile (workflow/profiles/slurm), every job
a Slurm job, MLflow through a tracking server; and how jobs judge runs written by other nodes' Slurm jobs.

Runs where ``sbatch`` is on PATH, against the cluster it reaches: in CI the single-node cluster that
``workflow/profiles/slurm/local_cluster.sh start`` sets up on the machine. The workflow runs in a temporary
directory with the repository's Snakefile; the MLflow server (SQLite backend, artifacts in the temporary
directory) runs on a free port on localhost for the duration of the module. The tiny case runs without its
hybrid (the hybrid's search runs the same rules as the neural FMU's; tests/test_workflow_e2e.py runs both) and
with a smaller Hyperband budget: every rule still runs, and the run is about the jobs, not the models.
"""

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import time
import urllib.request
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "config" / "cases" / "tiny.yaml"
PROFILE = REPO / "workflow" / "profiles" / "slurm"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("sbatch") is None,
                       reason="no Slurm here (sbatch not on PATH); `bash workflow/profiles/slurm/local_cluster.sh "
                              "start` sets up a single-node cluster"),
]

# Rules of the tiny case's default target: each runs as (at least) one Slurm job.
TINY_RULES = {"build_fmu", "emulate_bench", "check_bench_spread", "ingest", "select_segments", "calibrate",
              "simulate_baseline", "time_offset", "hpo_prepare", "hpo_plan", "train_rung", "select_rung",
              "select_best", "simulate_best", "evaluate", "plot", "report", "diagnose", "summary",
              "simulate_ceiling", "compare_neural_fmu", "export"}
SUBMITTED = re.compile(r"Job \d+ has been submitted with SLURM jobid (\d+) \(log: (\S+)\)")


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _answers(url: str) -> bool:
    try:
        with urllib.request.urlopen(url, timeout=2) as response:
            return response.status == 200
    except OSError:
        return False


@pytest.fixture(scope="module")
def cluster():
    """The cluster answers (sinfo) and the executor plugin is installed; else the test fails and says why."""
    info = subprocess.run(["sinfo", "--noheader", "--format=%P %a %D %T"], capture_output=True, text=True, timeout=30)
    if info.returncode != 0 or not info.stdout.strip():
        pytest.fail(f"sbatch is on PATH but the cluster does not answer (sinfo: {info.stderr.strip()!r}); "
                    "start it: bash workflow/profiles/slurm/local_cluster.sh start")
    try:
        import snakemake_executor_plugin_slurm  # noqa: F401
    except ImportError:
        pytest.fail("snakemake-executor-plugin-slurm is not installed: pip install '.[slurm]'")
    return info.stdout.strip()


@pytest.fixture(scope="module")
def mlflow_server(tmp_path_factory):
    """A local MLflow tracking server (SQLite backend); its URI. Stopped at the end of the module."""
    folder = tmp_path_factory.mktemp("mlflow_server")
    port = _free_port()
    uri = f"http://127.0.0.1:{port}"
    log = open(folder / "server.log", "w")
    server = subprocess.Popen(
        [sys.executable, "-m", "mlflow", "server", "--host", "127.0.0.1", "--port", str(port), "--workers", "1",
         "--backend-store-uri", f"sqlite:///{folder / 'mlflow.db'}", "--artifacts-destination",
         str(folder / "artifacts")],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not _answers(f"{uri}/health"):
            if server.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"the MLflow server did not start on {uri}:\n"
                                     f"{(folder / 'server.log').read_text()[-3000:]}")
            time.sleep(0.5)
        yield uri
    finally:
        if server.poll() is None:
            os.killpg(server.pid, signal.SIGTERM)  # the server and its workers (its own session)
            try:
                server.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(server.pid, signal.SIGKILL)
                server.wait()
        log.close()


@pytest.fixture(scope="module")
def slurm_run(cluster, mlflow_server, tmp_path_factory):
    workdir = tmp_path_factory.mktemp("tiny_slurm")
    config = yaml.safe_load(TINY.read_text())
    config["model"]["physics_terms"] = "none"
    config["hpo"]["max_resource_s"] = 0.04
    configfile = workdir / "tiny_slurm.yaml"
    configfile.write_text(yaml.safe_dump(config, sort_keys=False))
    command = [sys.executable, "-m", "snakemake", "--profile", str(PROFILE), "--snakefile", str(REPO / "Snakefile"),
               "--directory", str(workdir), "--configfile", str(configfile), "--nocolor",
               "--config", f"mlflow={{tracking_uri: '{mlflow_server}'}}",
               # the local cluster has no accounts; status checks every few seconds for short jobs
               "--slurm-no-account", "--slurm-init-seconds-before-status-checks", "3"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    print(f"cluster: {cluster}\nrunning: {' '.join(command)}", flush=True)
    start = time.perf_counter()
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=1800, env=env)
    elapsed_s = time.perf_counter() - start
    (workdir / "snakemake.out").write_text(result.stdout + "\n" + result.stderr)
    if result.returncode != 0:
        raise AssertionError(f"snakemake --profile workflow/profiles/slurm failed ({result.returncode}) after "
                             f"{elapsed_s:.0f} s:\n{result.stdout[-4000:]}\n{result.stderr[-12000:]}")
    print(f"tiny workflow through Slurm: {elapsed_s:.1f} s", flush=True)
    results = workdir / config.get("results_dir", "results") / config["case"]
    return workdir, results, config, result.stdout + result.stderr, mlflow_server


def _submitted(output: str) -> dict[str, list[str]]:
    """Slurm job ids by rule, from the executor's submission lines (the log path names the rule)."""
    jobs: dict[str, list[str]] = {}
    for job_id, log in SUBMITTED.findall(output):
        rule = re.search(r"slurm_logs/rule_([A-Za-z0-9_]+)/", log)
        assert rule, log
        jobs.setdefault(rule.group(1), []).append(job_id)
    return jobs


def _slurm_states(job_ids: list[str]) -> dict[str, str]:
    """Final states of Slurm jobs: from the job-completion log when the cluster keeps one as a text file
    (local_cluster.sh does), else from squeue (finished jobs stay listed for MinJobAge)."""
    states: dict[str, str] = {}
    config = subprocess.run(["scontrol", "show", "config"], capture_output=True, text=True, timeout=30).stdout
    settings = dict(re.findall(r"^(\w+)\s*=\s*(\S*)", config, flags=re.MULTILINE))
    jobcomp = Path(settings.get("JobCompLoc", ""))
    if settings.get("JobCompType") == "jobcomp/filetxt" and jobcomp.is_file():
        for line in jobcomp.read_text().splitlines():
            fields = dict(re.findall(r"(\w+)=(\S*)", line))
            if fields.get("JobId") in job_ids:
                states[fields["JobId"]] = fields.get("JobState", "")
    missing = [job_id for job_id in job_ids if job_id not in states]
    if missing:
        listed = subprocess.run(["squeue", f"--jobs={','.join(missing)}", "--states=all", "--noheader",
                                 "--format=%i|%T"], capture_output=True, text=True, timeout=30).stdout
        states.update(line.split("|", 1) for line in listed.split() if "|" in line)
    return states


def test_the_tiny_case_runs_as_slurm_jobs(slurm_run):
    workdir, results, config, output, _ = slurm_run
    for path in ("report.md", "hpo/best.json", "diagnosis/diagnosis.json", "metrics/test.json"):
        assert (results / path).is_file(), path
    jobs = _submitted(output)
    assert set(jobs) == TINY_RULES, (sorted(jobs), output[-3000:])
    all_ids = [job_id for ids in jobs.values() for job_id in ids]
    assert len(set(all_ids)) == len(all_ids)
    states = _slurm_states(all_ids)
    assert {job_id: states.get(job_id) for job_id in all_ids} == {job_id: "COMPLETED" for job_id in all_ids}
    # each job's Slurm log (kept by the profile) shows the rule running in the job
    for rule, ids in jobs.items():
        logs = list((workdir / ".snakemake" / "slurm_logs" / f"rule_{rule}").rglob("*.log"))
        assert {log.stem for log in logs} >= set(ids), (rule, logs)
        for log in logs:
            if log.stem in ids:  # "rule <name>:" or, for a checkpoint, "checkpoint <name>:"
                assert re.search(rf"^(rule|checkpoint) {rule}:$", log.read_text(errors="replace"), re.MULTILINE), log
    rungs = sorted(results.glob("*/b*/r*/c*/result.json"))  # the neural FMU's search
    assert {path.relative_to(results).parts[0] for path in rungs} == {"hpo"}
    assert len(jobs["train_rung"]) == len(rungs) > 0
    assert len(jobs["emulate_bench"]) == len(jobs["ingest"]) == len(config["maneuvers"])


def test_every_training_job_is_recorded_in_the_mlflow_server(slurm_run):
    from mlflow.tracking import MlflowClient

    _, results, config, output, uri = slurm_run
    train_jobs = set(_submitted(output)["train_rung"])
    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name(config["mlflow"].get("experiment") or config["case"])
    assert experiment is not None, [e.name for e in client.search_experiments()]
    runs = client.search_runs([experiment.experiment_id], max_results=1000)
    searches = [run for run in runs if run.data.tags.get("hybridfmu.role") == "search"]
    assert len(searches) == 1, [run.info.run_name for run in runs]  # the neural FMU's
    parents = {run.info.run_id for run in searches}
    trials = {run.info.run_id: run for run in runs
              if run.data.tags.get("mlflow.parentRunId") in parents and "hybridfmu.trial" in run.data.tags}

    result_paths = sorted(results.glob("*/b*/r*/c*/result.json"))
    rung_results = [json.loads(path.read_text()) for path in result_paths]
    configurations = {(path.relative_to(results).parts[0], r["trial_id"]) for path, r in zip(result_paths, rung_results)}
    assert len(rung_results) == len(train_jobs)
    # one run per configuration, one rung folder of artifacts per train_rung job
    assert {result["mlflow_run_id"] for result in rung_results} == set(trials)
    assert len({(run.data.tags["mlflow.parentRunId"], run.data.tags["hybridfmu.trial"]) for run in trials.values()}) \
        == len(configurations) == len(trials)
    logged_rungs = sorted((run_id, artifact.path) for run_id in trials
                          for artifact in client.list_artifacts(run_id) if artifact.path.startswith("rung"))
    assert logged_rungs == sorted((r["mlflow_run_id"], f"rung{r['rung']}") for r in rung_results)
    assert len(logged_rungs) == len(train_jobs)
    for run in trials.values():
        assert run.info.status == "FINISHED", (run.info.run_name, run.info.status)
        assert "best_val_objective" in run.data.metrics
        # written inside a Slurm job of this run: the tag names one of the train_rung jobs
        assert run.data.tags.get("hybridfmu.slurm_job_id") in train_jobs, run.data.tags
    # each search's parent run outlives every job: no job took it for a dead job's run
    for parent in searches:
        assert parent.info.status == "FINISHED"
        assert parent.data.tags.get("best_run_id") in trials
    assert not [run.info.run_name for run in runs if "hybridfmu.ended_reason" in run.data.tags]


def test_runs_of_another_nodes_slurm_job_end_when_the_job_ends(cluster, tmp_path):
    """A run written by a Slurm job on another host: alive while squeue reports the job running, ended as
    KILLED by end_stale_runs once the job is gone."""
    from mlflow.tracking import MlflowClient

    from hybridfmu.tracking import default_tracking_uri
    from hybridfmu.tracking.jobs import owner_alive, slurm_job_state
    from hybridfmu.tracking.mlflow_store import Tracker
    from hybridfmu.training.search_tracking import end_stale_runs

    submitted = subprocess.run(["sbatch", "--parsable", "--job-name=hybridfmu-owner-test", "--mem=100",
                                f"--output={tmp_path / 'job.out'}", "--wrap", "sleep 300"],
                               capture_output=True, text=True, timeout=30)
    assert submitted.returncode == 0, submitted.stderr
    job_id = submitted.stdout.strip().split(";")[0]
    try:
        deadline = time.monotonic() + 60
        while slurm_job_state(job_id) != "RUNNING":
            assert time.monotonic() < deadline, f"job {job_id}: {slurm_job_state(job_id)}"
            time.sleep(0.5)
        tags = {"hybridfmu.host": "another-node", "hybridfmu.pid": "4242", "hybridfmu.pid_start": "1",
                "hybridfmu.slurm_job_id": job_id}
        assert owner_alive(tags) is True
        tracker = Tracker(default_tracking_uri(tmp_path / "results"))
        experiment = tracker.experiment_id("case")
        run_id = tracker.get_or_create_run(experiment, {"hybridfmu.trial": "b0c0"}, "b0c0")
        tracker.log(run_id, tags=tags)
        assert end_stale_runs(tracker, experiment) == []
    finally:
        subprocess.run(["scancel", job_id], capture_output=True, timeout=30)
    deadline = time.monotonic() + 60
    while slurm_job_state(job_id) in (None, "RUNNING", "COMPLETING"):
        assert time.monotonic() < deadline, f"job {job_id}: {slurm_job_state(job_id)}"
        time.sleep(0.5)
    assert owner_alive(tags) is False
    assert end_stale_runs(tracker, experiment) == [run_id]
    ended = MlflowClient(tracker.uri).get_run(run_id)
    assert ended.info.status == "KILLED" and "PID 4242" in ended.data.tags["hybridfmu.ended_reason"]
    # a job Slurm no longer knows, or no answer: unknown, the run is left alone
    assert owner_alive({**tags, "hybridfmu.slurm_job_id": "999999999"}) is None


def test_a_job_in_a_slurm_job_watches_its_job_steps_snakemake(cluster, tmp_path):
    """In a real Slurm job started as the Slurm executor starts one (a Snakemake process with --mode remote,
    its job step under srun): the watchdog's owner is the job step's Snakemake, the search's parent run
    records no PID, and the run's tags name the Slurm job."""
    folder = tmp_path / "bin"
    folder.mkdir()
    fake = folder / "snakemake"  # a process named like Snakemake, as the executor runs it
    fake.write_text(textwrap.dedent('''
        import subprocess, sys
        sys.exit(subprocess.run([sys.executable, "-c", sys.argv[1]]).returncode)
    '''))
    probe = textwrap.dedent('''
        import json, os
        from hybridfmu.tracking.jobs import owner_tags, snakemake_ancestor, workflow_process
        from hybridfmu.training.search_tracking import workflow_owner_tags
        print(json.dumps({"ancestor": snakemake_ancestor().pid, "parent": os.getppid(),
                          "workflow": workflow_process() and workflow_process().pid,
                          "tags": owner_tags(), "workflow_tags": workflow_owner_tags()}))
    ''')
    script = tmp_path / "job.sh"
    script.write_text(f"#!/bin/sh\nexec srun -n1 {sys.executable} {fake} \"$PROBE\" --mode remote\n")
    env = {**os.environ, "PROBE": probe}
    done = subprocess.run(["sbatch", "--parsable", "--wait", "--mem=500", f"--chdir={REPO}",
                           f"--output={tmp_path / 'job.out'}", str(script)],
                          capture_output=True, text=True, timeout=300, env=env)
    out = (tmp_path / "job.out").read_text() if (tmp_path / "job.out").exists() else ""
    assert done.returncode == 0, done.stderr + out
    job_id = done.stdout.strip().split(";")[0]
    seen = json.loads(out.strip().splitlines()[-1])
    assert seen["ancestor"] == seen["parent"]  # the job step's Snakemake
    assert seen["workflow"] is None
    assert seen["tags"]["hybridfmu.slurm_job_id"] == job_id
    assert seen["tags"]["hybridfmu.snakemake_pid"] == str(seen["parent"])
    assert seen["workflow_tags"]["hybridfmu.pid"] == "" and seen["workflow_tags"]["hybridfmu.snakemake_pid"] == ""
