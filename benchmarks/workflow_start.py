"""How long Snakemake takes to start the workflow (parse the Snakefile, check the case config, plan the jobs):
paid by every `snakemake` call and, on a cluster, twice by every job (the Slurm executor starts Snakemake in
the job, and again under srun).

For each commit (``--commit``, default HEAD; repeatable) the repository is cloned into a temporary folder and
``snakemake -n`` (a dry run, which plans every job of the case from scratch) runs ``--repeats`` times with that
clone's ``src`` first on the Python path; commits alternate, so a before/after comparison shares the machine's
load. Prints a table and, last line, a JSON object: per commit the wall times (s) and their median.

    python benchmarks/workflow_start.py [--commit 86e0e98 --commit HEAD] [--configfile config/cases/tiny.yaml]
        [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent


def clone(commit: str, folder: Path) -> Path:
    """A checkout of ``commit`` of this repository in ``folder``/<short hash>."""
    full = subprocess.run(["git", "-C", str(HERE), "rev-parse", "--verify", f"{commit}^{{commit}}"],
                          capture_output=True, text=True, check=True).stdout.strip()
    target = folder / full[:10]
    subprocess.run(["git", "clone", "-q", str(HERE), str(target)], check=True)
    subprocess.run(["git", "-C", str(target), "checkout", "-q", full], check=True)
    return target


def dry_run_s(checkout: Path, configfile: str, workdir: Path) -> float:
    """Wall time (s) of one ``snakemake -n`` of ``checkout``'s workflow in the empty folder ``workdir``."""
    env = {**os.environ, "PYTHONPATH": str(checkout / "src")}
    command = [sys.executable, "-m", "snakemake", "-n", "-q", "--snakefile", str(checkout / "Snakefile"),
               "--configfile", str(checkout / configfile), "--directory", str(workdir)]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env=env, cwd=workdir)
    elapsed_s = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"snakemake -n of {checkout.name} failed:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return elapsed_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--commit", action="append", help="commit to time (repeatable; default HEAD)")
    parser.add_argument("--configfile", default="config/cases/tiny.yaml", help="case config, in the repository")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    commits = args.commit or ["HEAD"]
    with tempfile.TemporaryDirectory() as folder:
        checkouts = {commit: clone(commit, Path(folder)) for commit in commits}
        times: dict[str, list[float]] = {commit: [] for commit in commits}
        for repeat in range(args.repeats):
            for commit, checkout in checkouts.items():
                workdir = Path(folder) / f"run_{checkout.name}_{repeat}"
                workdir.mkdir()
                times[commit].append(dry_run_s(checkout, args.configfile, workdir))
                print(f"repeat {repeat + 1}/{args.repeats}, {commit}: {times[commit][-1]:.2f} s", file=sys.stderr,
                      flush=True)
    medians = {commit: statistics.median(values) for commit, values in times.items()}
    print(f"snakemake -n --configfile {args.configfile} ({args.repeats} runs each, median wall time)")
    print(f"{'commit':<16} {'median (s)':>10} {'min (s)':>8} {'max (s)':>8} {'x first':>8}")
    first = medians[commits[0]]
    for commit in commits:
        print(f"{commit:<16} {medians[commit]:>10.2f} {min(times[commit]):>8.2f} {max(times[commit]):>8.2f} "
              f"{first / medians[commit]:>8.2f}")
    print(json.dumps({"configfile": args.configfile, "wall_s": times, "median_s": medians}))


if __name__ == "__main__":
    main()
