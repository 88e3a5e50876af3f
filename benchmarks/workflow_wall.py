"""Wall time of a whole workflow run from a fresh clone, for one or more commits side by side.

For each commit (``--commit``, default HEAD; repeatable) the repository is cloned into a temporary folder and
``snakemake -j<jobs> [--configfile <case>]`` runs there from scratch, with that clone's ``src`` first on the
Python path (no install needed); commits and ``--repeats`` alternate, so that a before/after comparison
shares the machine's load. Progress lines go to stderr (the jobs finished so far, every 60 s).

Prints a table and, last line, a JSON object: per commit the wall times (s), the number of jobs Snakemake ran,
and the median. ``--markdown FILE`` writes the table as Markdown (for the README: ``python -m
hybridfmu.evaluation.measured_blocks --block workflow_wall=FILE``), naming the machine's processor, since the
wall time depends on it as much as on the number of cores; with ``--target-min M``
it adds whether each commit's median is within M minutes. ``--keep DIR`` keeps the last run's ``results``
folder of each commit in DIR/<commit>.

    python benchmarks/workflow_wall.py [--commit 6b70e2d --commit HEAD] [--configfile config/paper.yaml]
        [--jobs 2] [--repeats 1] [--markdown FILE] [--target-min 30] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from hybridfmu.io import atomic_path

HERE = Path(__file__).resolve().parent.parent


def resolve(commit: str) -> str:
    """The full hash of ``commit`` in this repository."""
    return subprocess.run(["git", "-C", str(HERE), "rev-parse", "--verify", f"{commit}^{{commit}}"],
                          capture_output=True, text=True, check=True).stdout.strip()


def clone(commit: str, folder: Path) -> Path:
    """A fresh clone of this repository at ``commit`` in ``folder``."""
    subprocess.run(["git", "clone", "-q", str(HERE), str(folder)], check=True)
    subprocess.run(["git", "-C", str(folder), "checkout", "-q", commit], check=True)
    return folder


def _watch(log: Path, label: str, start: float, stop: threading.Event) -> None:
    """Every 60 s: the jobs finished so far according to Snakemake's log."""
    while not stop.wait(60.0):
        text = log.read_text(errors="replace") if log.exists() else ""
        done = re.findall(r"(\d+) of (\d+) steps \((\d+)%\) done", text)
        status = f"{done[-1][0]} of {done[-1][1]} jobs" if done else "starting"
        print(f"  {label}: {status}, {time.perf_counter() - start:.0f} s", file=sys.stderr, flush=True)


def run_workflow(checkout: Path, configfile: str | None, jobs: int, label: str) -> dict:
    """``snakemake -j<jobs>`` in ``checkout``; returns {"wall_s", "jobs"}; raises with the log's tail."""
    command = [sys.executable, "-m", "snakemake", "-j", str(jobs)]
    if configfile:
        command += ["--configfile", configfile]
    env = dict(os.environ, PYTHONPATH=str(checkout / "src"))
    log = checkout / "workflow_wall.log"
    stop = threading.Event()
    start = time.perf_counter()
    watcher = threading.Thread(target=_watch, args=(log, label, start, stop), daemon=True)
    watcher.start()
    try:
        with open(log, "w") as out:
            status = subprocess.run(command, cwd=checkout, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    finally:
        stop.set()
    wall_s = time.perf_counter() - start
    text = log.read_text(errors="replace")
    if status:
        raise RuntimeError(f"{' '.join(command)} in {checkout} failed ({status}):\n" + "\n".join(text.splitlines()[-30:]))
    done = re.findall(r"(\d+) of (\d+) steps \(100%\) done", text)
    return {"wall_s": wall_s, "jobs": int(done[-1][1]) if done else 0}


def processor_name(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The processor's model name as the kernel reports it (``model name`` in /proc/cpuinfo), or
    ``platform.processor()`` where there is no such file."""
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or "unknown processor"


def markdown(summary: dict, configfile: str | None, jobs: int, target_min: float | None = None,
             processor: str | None = None) -> str:
    """The table of the runs as Markdown.

    Args:
        summary: commit -> {"wall_s": [s, ...], "jobs": n, "median_s": s}.
        target_min: a wall-time target in minutes: a last column says whether each median is within it.
        processor: the machine's processor (default: :func:`processor_name`).
    """
    case = f"--configfile {configfile}" if configfile else "(the demo)"
    how = "side by side on this machine" if len(summary) > 1 else "on this machine"
    processor = processor or processor_name()
    header, rule = "| commit | jobs | wall time | runs |", "|---|---|---|---|"
    if target_min is not None:
        header, rule = header + f" within {target_min:g} min |", rule + "---|"
    lines = [f"`snakemake -j{jobs} {case}` from a fresh clone, {how} ({os.cpu_count()} cores, {processor}; "
             f"`benchmarks/workflow_wall.py`):", "", header, rule]
    for commit, figures in summary.items():
        runs = ", ".join(f"{s / 60:.1f} min" for s in figures["wall_s"])
        row = f"| {commit[:10]} | {figures['jobs']} | {figures['median_s'] / 60:.1f} min | {runs} |"
        if target_min is not None:
            row += " yes |" if figures["median_s"] <= 60.0 * target_min else " no |"
        lines.append(row)
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--commit", action="append", help="commit to run (repeatable; default HEAD)")
    parser.add_argument("--configfile", default=None, help="case config (default: the demo)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--markdown", type=Path, default=None, help="write the table as Markdown to this file")
    parser.add_argument("--target-min", type=float, default=None,
                        help="a wall-time target in minutes; the Markdown says whether each commit is within it")
    parser.add_argument("--keep", type=Path, default=None, help="keep each commit's last results folder here")
    args = parser.parse_args()
    commits = [resolve(c) for c in (args.commit or ["HEAD"])]
    summary = {c: {"wall_s": [], "jobs": 0} for c in commits}
    with tempfile.TemporaryDirectory(prefix="hybridfmu-wall-") as tmp:
        for repeat in range(args.repeats):
            for commit in commits:
                label = f"{commit[:10]} run {repeat + 1}/{args.repeats}"
                print(f"{label} ...", file=sys.stderr, flush=True)
                checkout = clone(commit, Path(tmp) / f"{commit[:10]}-{repeat}")
                figures = run_workflow(checkout, args.configfile, args.jobs, label)
                print(f"  {label}: {figures['jobs']} jobs in {figures['wall_s']:.0f} s", file=sys.stderr, flush=True)
                summary[commit]["wall_s"].append(figures["wall_s"])
                summary[commit]["jobs"] = figures["jobs"]
                if args.keep:
                    target = args.keep / commit[:10]
                    shutil.rmtree(target, ignore_errors=True)
                    shutil.copytree(checkout / "results", target, symlinks=True)
                shutil.rmtree(checkout, ignore_errors=True)
    for figures in summary.values():
        figures["median_s"] = statistics.median(figures["wall_s"])
    print(f"{'commit':<12} {'jobs':>5} {'median wall, s':>15}  runs, s")
    for commit, figures in summary.items():
        print(f"{commit[:10]:<12} {figures['jobs']:>5} {figures['median_s']:>15.0f}  "
              + ", ".join(f"{s:.0f}" for s in figures["wall_s"]))
    if args.markdown:
        with atomic_path(args.markdown) as tmp:
            tmp.write_text(markdown(summary, args.configfile, args.jobs, args.target_min))
    print(json.dumps({"configfile": args.configfile, "jobs": args.jobs, "commits": summary}))


if __name__ == "__main__":
    main()
