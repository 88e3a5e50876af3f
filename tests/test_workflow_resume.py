"""Kill -9 of Snakemake while training jobs run, then ``--rerun-incomplete``: the search ends exactly as an
uninterrupted one (best.json, every result's objective, every checkpoint's model state), every training job
of the resumed run runs once, no job is left running, and the MLflow store is consistent (no run left
RUNNING, one run per trial, no metric row twice).

The upstream stages (bench, ingest, calibration, training data) run once; the folder is then copied, so
both searches start from the same files. The tiny case runs with a smaller Hyperband budget.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

from test_workflow_e2e import REPO, TINY, snakemake

pytestmark = pytest.mark.slow

PREPARED = ["results/tiny/hpo/prepared/train.npz", "results/tiny/hpo/prepared/validation.npz",
            "results/tiny/hpo/prepared/statistics.json"]
BEST = "results/tiny/hpo/best.json"


def processes_under(folder: Path) -> list[int]:
    """PIDs of live processes whose command line names ``folder`` (Snakemake, its jobs)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            args = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if str(folder) in args and state not in ("Z", "X"):
            found.append(int(entry.name))
    return found


def running_train_jobs(hpo: Path) -> dict[str, int]:
    """Output folder -> PID of train_rung jobs holding their output lock and alive."""
    from hybridfmu.tracking.jobs import ProcessId

    jobs = {}
    for lock in hpo.glob("b*/r*/c*/job.lock"):
        try:
            record = json.loads(lock.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if record and ProcessId(record["pid"], record["start"]).alive():
            jobs[str(lock.parent.relative_to(hpo))] = record["pid"]
    return jobs


def train_jobs_started(output: str) -> list[str]:
    """b<bracket>/r<rung>/c<config> of every train_rung job a Snakemake run started (in order)."""
    started, in_train = [], False
    for line in output.splitlines():
        if line.strip().startswith(("rule ", "localrule ")):
            in_train = line.strip().split()[1].rstrip(":") == "train_rung"
        elif in_train and line.strip().startswith("wildcards:"):
            values = dict(item.strip().split("=") for item in line.split(":", 1)[1].split(","))
            started.append(f"b{values['bracket']}/r{values['rung']}/c{values['config']}")
            in_train = False
    return started


@pytest.fixture(scope="module")
def searches(tmp_path_factory):
    root = tmp_path_factory.mktemp("resume")
    config = yaml.safe_load(TINY.read_text())
    config["hpo"]["max_resource_s"] = 0.04
    configfile = root / "tiny_resume.yaml"
    configfile.write_text(yaml.safe_dump(config, sort_keys=False))
    straight, killed = root / "straight", root / "killed"
    straight.mkdir()
    snakemake(straight, configfile, *PREPARED)
    shutil.copytree(straight, killed, symlinks=True)  # copy2 keeps the times: nothing upstream reruns
    start = time.perf_counter()
    snakemake(straight, configfile, BEST)
    straight_s = time.perf_counter() - start

    command = [sys.executable, "-m", "snakemake", "-j2", "--snakefile", str(REPO / "Snakefile"), "--directory",
               str(killed), "--configfile", str(configfile), "--nocolor", BEST]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    hpo = killed / "results" / "tiny" / "hpo"
    with open(root / "killed.log", "w") as log:
        first = subprocess.Popen(command, cwd=REPO, stdout=log, stderr=subprocess.STDOUT, env=env)
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and first.poll() is None:
            # after one rung is done, while others are training
            if list(hpo.glob("b*/r*/c*/result.json")) and running_train_jobs(hpo):
                break
            time.sleep(0.2)
        assert first.poll() is None, (root / "killed.log").read_text()[-4000:]
        victims = running_train_jobs(hpo)
        os.kill(first.pid, signal.SIGKILL)
        first.wait()
    done_before = {str(p.parent.relative_to(hpo)) for p in hpo.glob("b*/r*/c*/result.json")}
    # the watchdog of each job stops it once its Snakemake process is gone
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and running_train_jobs(hpo):
        time.sleep(0.2)
    left = running_train_jobs(hpo)
    logs = {name: (killed / "results/tiny/logs/train_rung/hpo" / f"{name.replace('/', '_')}.log").read_text()
            for name in victims}
    snakemake(killed, configfile, "--unlock")  # the killed Snakemake could not release its directory lock
    resumed = snakemake(killed, configfile, BEST, "--rerun-incomplete")
    return {"straight": straight, "killed": killed, "victims": victims, "left": left, "logs": logs,
            "done_before": done_before, "resumed": resumed.stdout + resumed.stderr, "straight_s": straight_s}


def test_orphans_stop_and_every_job_runs_once(searches):
    assert searches["victims"] and not searches["left"], searches["left"]
    for name, text in searches["logs"].items():
        assert "that started this job is gone" in text, (name, text[-2000:])
    started = train_jobs_started(searches["resumed"])
    assert len(started) == len(set(started)), started
    hpo = searches["killed"] / "results" / "tiny" / "hpo"
    every = {str(p.parent.relative_to(hpo)) for p in hpo.glob("b*/r*/c*/result.json")}
    assert set(started) | searches["done_before"] == every
    assert set(searches["victims"]) <= set(started)
    assert not processes_under(searches["killed"])


def test_resumed_search_equals_the_uninterrupted_one(searches):
    a, b = (searches[k] / "results" / "tiny" / "hpo" for k in ("straight", "killed"))
    best_a, best_b = (json.loads((h / "best.json").read_text()) for h in (a, b))
    for key in ("trial_id", "hyperparameters", "objective", "validation", "delay_s", "gates"):
        assert best_a[key] == best_b[key], key
    results = sorted(str(p.relative_to(a)) for p in a.glob("b*/r*/c*/result.json"))
    assert results == sorted(str(p.relative_to(b)) for p in b.glob("b*/r*/c*/result.json"))
    for name in results:
        ra, rb = json.loads((a / name).read_text()), json.loads((b / name).read_text())
        assert ra["objective"] == rb["objective"] and ra["steps"] == rb["steps"], name
        assert rb["tracking"]["status"] == "logged", (name, rb["tracking"])
        ca = torch.load(a / name.replace("result.json", "checkpoint.pt"), weights_only=False)
        cb = torch.load(b / name.replace("result.json", "checkpoint.pt"), weights_only=False)
        assert ca["model"].keys() == cb["model"].keys()
        for key in ca["model"]:
            assert torch.equal(ca["model"][key], cb["model"][key]), (name, key)


def test_mlflow_store_is_consistent(searches):
    from mlflow.tracking import MlflowClient

    counts = {}
    for name in ("straight", "killed"):
        hpo = searches[name] / "results" / "tiny" / "hpo"
        plan = json.loads((hpo / "plan.json").read_text())
        client = MlflowClient(plan["tracking"]["uri"])
        runs = client.search_runs([plan["tracking"]["experiment_id"]], max_results=1000)
        assert not [r.info.run_name for r in runs if r.info.status == "RUNNING"]
        trials = {json.loads(p.read_text())["trial_id"] for p in hpo.glob("b*/r*/c*/result.json")}
        children = [r for r in runs if r.data.tags.get("hybridfmu.search_id") == plan["search_id"]
                    and "hybridfmu.trial" in r.data.tags]
        assert sorted(r.data.tags["hybridfmu.trial"] for r in children) == sorted(trials)
        rows = {}
        for run in children:
            for key in run.data.metrics:
                steps = [m.step for m in client.get_metric_history(run.info.run_id, key)]
                assert len(steps) == len(set(steps)), (run.info.run_name, key)
                rows[(run.data.tags["hybridfmu.trial"], key)] = len(steps)
        counts[name] = rows
    assert counts["straight"] == counts["killed"]
