"""Cost of the Hyperband search's jobs: a fixed slice of the search run by Snakemake, job by job.

Prepares the demo case's search inputs once (a Snakemake run up to ``hpo/prepared`` in a temporary folder,
or ``--inputs`` from an earlier run), then for every checkout given with ``--repo`` (default: this one)
copies them, plans the search with that checkout (rule hpo_plan) and times the slice: the train_rung and
select_rung jobs of one bracket up to one rung (``--bracket``, ``--rung``; ``--configs N``: only rung 0 of
the bracket's first N configurations), ``--jobs`` at a time, exactly as ``snakemake -j<jobs>`` runs them.
Several ``--repo`` (e.g. an older checkout from ``git worktree add /tmp/before HEAD``) and ``--repeats``
are interleaved, so that a before/after comparison shares the machine's load.

Each job process is observed from the inside (a ``sitecustomize`` hook on PYTHONPATH, active only for this
benchmark): start-up = process start to the first training step (interpreter, imports, FMU, data,
checkpoint), the open-loop validations' seconds, and the process's wall time.

With several ``--jobs`` (e.g. ``--jobs 1 --jobs 2``) the slice runs at each; ``--markdown FILE`` writes the
scaling table of the first checkout for the documentation (rung-job seconds at each -j, the projected wall time of
the ``--project`` search here and on N nodes like this one; ``python -m hybridfmu.evaluation.measured_blocks
--block search_scaling=FILE``).

Prints a table (medians over the repeats) and, last line, a JSON object:
``s_per_s_data`` (slice wall s per s of training data), ``job_s_per_s_data`` (job-process s per s of data),
``startup_s_per_job``, ``validation_s_per_rung``, ``validation_s_per_call``, ``after_training_s_per_job``
(last validation to process exit: checkpoint, MLflow), ``select_s_per_job``, and, for more than one checkout,
the largest difference of the trials' objectives from the first checkout's.

    python benchmarks/search_slice.py [--repo /tmp/before --repo .] [--bracket 2] [--rung 0] [--configs 4]
        [--jobs 1 --jobs 2] [--repeats 1] [--inputs DIR] [--keep DIR] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent.parent

#: Installed as sitecustomize.py in a folder on the jobs' PYTHONPATH; active only with HYBRIDFMU_SLICE_RECORDS.
HOOK = r'''
import os
if os.environ.get("HYBRIDFMU_SLICE_RECORDS"):
    import atexit, json, sys, time

    def _now():
        return time.clock_gettime(time.CLOCK_BOOTTIME)

    def _process_start():
        with open("/proc/self/stat") as handle:
            fields = handle.read().rsplit(")", 1)[1].split()
        return int(fields[19]) / os.sysconf("SC_CLK_TCK")

    _record = {"start": _process_start(), "first_step": None, "steps": 0, "train_s": 0.0, "validations": [],
               "validation_end": None}

    def _patch_trainer(module):
        original = module.Trainer.step

        def step(self, *args, **kwargs):
            start = _now()
            if _record["first_step"] is None:
                _record["first_step"] = start
            _record["steps"] += 1
            try:
                return original(self, *args, **kwargs)
            finally:
                _record["train_s"] += _now() - start
        module.Trainer.step = step

    def _patch_validation(module):
        original = module.validate

        def validate(*args, **kwargs):
            start = _now()
            try:
                return original(*args, **kwargs)
            finally:
                _record["validation_end"] = _now()
                _record["validations"].append(_record["validation_end"] - start)
        module.validate = validate

    _TARGETS = {"hybridfmu.training.trainer": _patch_trainer, "hybridfmu.training.validation": _patch_validation}

    class _Finder:
        def find_spec(self, name, path, target=None):
            if name not in _TARGETS:
                return None
            for finder in sys.meta_path:
                if finder is self or not hasattr(finder, "find_spec"):
                    continue
                spec = finder.find_spec(name, path, target)
                if spec is not None:
                    break
            else:
                return None
            exec_module = spec.loader.exec_module

            def exec_and_patch(module):
                exec_module(module)
                _TARGETS[name](module)
            spec.loader.exec_module = exec_and_patch
            return spec

    sys.meta_path.insert(0, _Finder())

    def _write():
        main = sys.modules.get("__main__")
        job = getattr(main, "snakemake", None)
        if job is None:
            return
        _record.update(end=_now(), rule=str(job.rule), wildcards=dict(job.wildcards.items()), pid=os.getpid(),
                       module=getattr(sys.modules.get("hybridfmu"), "__file__", None))
        folder = os.environ["HYBRIDFMU_SLICE_RECORDS"]
        with open(os.path.join(folder, f"{os.getpid()}.json"), "w") as handle:
            json.dump(_record, handle)
    atexit.register(_write)
'''


def run(command: list[str], cwd: Path, env: dict[str, str] | None = None, log: Path | None = None) -> float:
    """Run ``command``; returns its wall time (s); raises with the log's tail on failure."""
    start = time.perf_counter()
    with open(log or os.devnull, "w") as out:
        status = subprocess.run(command, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    if status:
        tail = log.read_text().splitlines()[-30:] if log else []
        raise RuntimeError(f"{' '.join(command)} failed ({status}):\n" + "\n".join(tail))
    return time.perf_counter() - start


def snakemake(repo: Path, workdir: Path, targets: list[str], jobs: int, extra: list[str]) -> list[str]:
    return [sys.executable, "-m", "snakemake", "-s", str(repo / "Snakefile"), "-d", str(workdir),
            "--configfile", str(repo / "config" / "config.yaml"), "-j", str(jobs), "--rerun-triggers", "mtime",
            *extra, "--", *targets]


def prepare_inputs(folder: Path, jobs: int) -> None:
    """The demo case up to the prepared training data (FMU, bench logs, ingestion, segments, calibration)."""
    print(f"preparing the demo case's search inputs in {folder} ...", file=sys.stderr)
    folder.mkdir(parents=True, exist_ok=True)
    seconds = run(snakemake(HERE, folder, ["results/ipb/hpo/prepared/statistics.json"], jobs, []), folder,
                  log=folder / "prepare.log")
    print(f"  done in {seconds:.0f} s", file=sys.stderr)


def slice_targets(plan: dict, bracket: int, rung: int, configs: int | None) -> list[str]:
    hpo = "results/ipb/hpo"
    if configs:
        return [f"{hpo}/b{bracket}/r0/c{c}/result.json" for c in range(configs)]
    return [f"{hpo}/b{bracket}/r{rung}/selection.json"]


def run_slice(repo: Path, inputs: Path, folder: Path, args: argparse.Namespace, hook_dir: Path, jobs: int) -> dict:
    """Plan the search with ``repo`` in a copy of ``inputs``, then time the slice, ``jobs`` at a time."""
    shutil.copytree(inputs, folder, symlinks=True)
    for stale in ("results/ipb/hpo/plan.json", "results/mlflow.db", "results/mlartifacts"):
        path = folder / stale
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(repo / "src"), str(hook_dir)]))
    env.pop("HYBRIDFMU_SLICE_RECORDS", None)
    run(snakemake(repo, folder, ["results/ipb/hpo/plan.json"], 1, ["--allowed-rules", "hpo_plan"]), folder, env,
        folder / "plan.log")
    plan = json.loads((folder / "results/ipb/hpo/plan.json").read_text())
    records_dir = folder / "job_records"
    records_dir.mkdir()
    env["HYBRIDFMU_SLICE_RECORDS"] = str(records_dir)
    targets = slice_targets(plan, args.bracket, args.rung, args.configs)
    wall = run(snakemake(repo, folder, targets, jobs, ["--allowed-rules", "train_rung", "select_rung"]),
               folder, env, folder / "slice.log")
    records = [json.loads(path.read_text()) for path in sorted(records_dir.glob("*.json"))]
    train = [r for r in records if r["rule"] == "train_rung"]
    select = [r for r in records if r["rule"] == "select_rung"]
    if not train:
        raise RuntimeError(f"{folder}: no train_rung job was recorded (see slice.log)")
    wrong = {r["module"] for r in train if not str(r["module"]).startswith(str(repo))}
    if wrong:
        raise RuntimeError(f"jobs imported hybridfmu from {wrong}, not from {repo}")
    data_s, objectives = 0.0, {}
    for r in train:
        w = r["wildcards"]
        result = json.loads((folder / f"results/ipb/hpo/b{w['bracket']}/r{w['rung']}/c{w['config']}/result.json")
                            .read_text())
        previous = [v["resource_s"] for v in result["validations"] if v.get("rung") == int(w["rung"]) - 1]
        start_s = max(previous) if previous else 0.0
        data_s += result["resource_s"] - start_s
        objectives[f"b{w['bracket']}r{w['rung']}c{w['config']}"] = result["objective"]
    validations = [v for r in train for v in r["validations"]]
    return {
        "jobs": len(train), "select_jobs": len(select), "wall_s": wall, "data_s": data_s,
        "s_per_s_data": wall / data_s,
        "job_s_per_s_data": sum(r["end"] - r["start"] for r in train) / data_s,
        "startup_s_per_job": statistics.mean(r["first_step"] - r["start"] for r in train),
        "validation_s_per_rung": sum(validations) / len(train),
        "validation_s_per_call": statistics.mean(validations) if validations else 0.0,
        "after_training_s_per_job": statistics.mean(r["end"] - r["validation_end"] for r in train),
        "job_s": statistics.mean(r["end"] - r["start"] for r in train),
        "select_s_per_job": statistics.mean(r["end"] - r["start"] for r in select) if select else 0.0,
        "train_s_per_s_data": sum(r["train_s"] for r in train) / data_s,
        "other_s_per_job": statistics.mean(
            (r["end"] - r["start"]) - (r["first_step"] - r["start"]) - r["train_s"] - sum(r["validations"])
            - (r["end"] - r["validation_end"]) for r in train),
        "objectives": objectives,
    }


FIGURES = [("jobs", "train_rung jobs", "{:.0f}"), ("select_jobs", "select_rung jobs", "{:.0f}"),
           ("data_s", "training data, s", "{:.2f}"), ("wall_s", "slice wall, s", "{:.1f}"),
           ("s_per_s_data", "wall s per s of data", "{:.2f}"), ("job_s_per_s_data", "job s per s of data", "{:.2f}"),
           ("job_s", "train_rung job, s", "{:.2f}"), ("startup_s_per_job", "start-up s/job", "{:.2f}"),
           ("validation_s_per_call", "validation s/call", "{:.2f}"),
           ("validation_s_per_rung", "validation s/rung", "{:.2f}"),
           ("after_training_s_per_job", "after training s/job", "{:.2f}"),
           ("select_s_per_job", "select_rung job, s", "{:.2f}"),
           ("train_s_per_s_data", "training s per s of data", "{:.2f}"),
           ("other_s_per_job", "rest of a job, s", "{:.2f}")]


def _plan_jobs(figures: dict, config_path: Path) -> list[list[tuple[int, float]]]:
    """Per bracket, per rung: (configurations, seconds of one train_rung job) of the Hyperband plan of
    ``config_path``, from the slice's per-job figures: start-up + rest + after-training + its validations +
    training s per s of data times its resource increment."""
    import yaml

    from hybridfmu.training.hyperband import hyperband_brackets
    from hybridfmu.training.trial import validation_points

    config = yaml.safe_load(config_path.read_text())
    hpo, training = config["hpo"], config.get("training", {})
    unit_s = float(hpo["max_resource_s"]) / float(hpo["R"])
    fixed_s = figures["startup_s_per_job"] + figures["other_s_per_job"] + figures["after_training_s_per_job"]
    brackets = []
    for bracket in hyperband_brackets(hpo["R"], hpo["eta"]):
        previous_s, rungs = 0.0, []
        for rung in bracket.rungs:
            target_s = rung.resource_units * unit_s
            validations = len(validation_points(previous_s, target_s, training.get("validation_every_s")))
            rungs.append((rung.n_configs, fixed_s + validations * figures["validation_s_per_call"]
                          + figures["train_s_per_s_data"] * (target_s - previous_s), target_s - previous_s))
            previous_s = target_s
        brackets.append(rungs)
    return brackets


def project(figures: dict, config_path: Path, jobs: int) -> dict:
    """Wall time of a whole search (the Hyperband plan of ``config_path``) from the slice's per-job figures
    (:func:`_plan_jobs`); each (bracket, rung) adds a select_rung job; ``jobs`` run at once (the figures were
    measured with as many running at once, so they include the sharing of the cores)."""
    brackets = _plan_jobs(figures, config_path)
    job_s = sum(n * seconds for rungs in brackets for n, seconds, _ in rungs)
    n_select = sum(len(rungs) for rungs in brackets)
    total_s = job_s + n_select * figures["select_s_per_job"]
    return {"config": str(config_path), "train_rung_jobs": sum(n for rungs in brackets for n, _, _ in rungs),
            "select_rung_jobs": n_select,
            "training_data_s": sum(n * data for rungs in brackets for n, _, data in rungs),
            "projected_min": total_s / jobs / 60.0}


def project_nodes(figures: dict, config_path: Path, workers: int) -> float:
    """Projected wall time (min) of the whole search with ``workers`` jobs at once, each costing what it cost
    in the slice: the larger of the total job time shared by the workers and the longest chain of rungs (a
    rung's jobs wait for the previous rung of their bracket; brackets run side by side)."""
    brackets = _plan_jobs(figures, config_path)
    select_s = figures["select_s_per_job"]
    total_s = sum(n * seconds + select_s for rungs in brackets for n, seconds, _ in rungs)
    chain_s = max(sum(seconds * math.ceil(n / workers) + select_s for n, seconds, _ in rungs) for rungs in brackets)
    return max(total_s / workers, chain_s) / 60.0


def scaling_markdown(summary: dict, jobs_list: list[int], args: argparse.Namespace) -> str:
    """The documentation's scaling table from one checkout's figures at each ``-j``."""
    what = (f"rung 0 of configurations 0..{args.configs - 1}" if args.configs
            else f"bracket {args.bracket}, rungs 0..{args.rung}")
    lines = [f"Search jobs measured on this machine ({os.cpu_count()} cores; `benchmarks/search_slice.py "
             f"--jobs {' --jobs '.join(str(j) for j in jobs_list)}`: the demo's plan, {what}):", "",
             "| snakemake | train_rung job | start-up | validation | after training | training per s of data "
             f"| {args.project.name} projected |", "|---|---|---|---|---|---|---|"]
    for jobs in jobs_list:
        f = summary[jobs]
        lines.append(f"| -j{jobs} | {f['job_s']:.1f} s | {f['startup_s_per_job']:.1f} s | "
                     f"{f['validation_s_per_call']:.2f} s | {f['after_training_s_per_job']:.1f} s | "
                     f"{f['train_s_per_s_data']:.2f} s | {f['projection']['projected_min']:.0f} min |")
    widest = max(jobs_list)
    lines += ["", f"Projected wall time of the {args.project.name} search on N nodes like this one (-j{widest} per "
                  f"node, each job costing what it cost here at -j{widest}):", "",
              "| nodes | jobs at once | projected |", "|---|---|---|"]
    for nodes in (1, 2, 4, 8, 16):
        workers = nodes * widest
        lines.append(f"| {nodes} | {workers} | {project_nodes(summary[widest], args.project, workers):.0f} min |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repo", action="append", type=Path, help="checkout to time (repeatable; default: this one)")
    parser.add_argument("--bracket", type=int, default=2, help="bracket s of the demo's plan (default 2)")
    parser.add_argument("--rung", type=int, default=0, help="up to this rung of the bracket (default 0)")
    parser.add_argument("--configs", type=int, default=None, help="only rung 0 of the first N configurations")
    parser.add_argument("--jobs", type=int, action="append",
                        help="jobs at a time (snakemake -j; repeatable, e.g. --jobs 1 --jobs 2; default 2)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--inputs", type=Path, help="a folder prepared by an earlier run (--keep)")
    parser.add_argument("--keep", type=Path, help="keep the prepared inputs in this folder")
    parser.add_argument("--project", type=Path, default=HERE / "config" / "paper.yaml",
                        help="project the wall time of this case's whole search (default config/paper.yaml)")
    parser.add_argument("--markdown", type=Path, default=None,
                        help="write the scaling table (first checkout, each --jobs) as Markdown to this file")
    args = parser.parse_args()
    jobs_list = args.jobs or [2]
    repos = [repo.resolve() for repo in (args.repo or [HERE])]
    runs_of = [(repo, jobs) for jobs in jobs_list for repo in repos]
    labels = [str(repo) if len(jobs_list) == 1 else f"{repo} -j{jobs}" for repo, jobs in runs_of]
    with tempfile.TemporaryDirectory(prefix="hybridfmu-slice-") as tmp:
        tmp = Path(tmp)
        hook_dir = tmp / "hook"
        hook_dir.mkdir()
        (hook_dir / "sitecustomize.py").write_text(HOOK)
        inputs = args.inputs or args.keep or tmp / "inputs"
        if not (inputs / "results/ipb/hpo/prepared/statistics.json").is_file():
            prepare_inputs(inputs, max(jobs_list))
        runs: dict[str, list[dict]] = {label: [] for label in labels}
        for repeat in range(args.repeats):
            order = list(zip(runs_of, labels))
            if repeat % 2:
                order.reverse()
            for (repo, jobs), label in order:
                folder = tmp / f"run{repeat}_{labels.index(label)}"
                print(f"repeat {repeat + 1}/{args.repeats}: {label} ...", file=sys.stderr)
                runs[label].append(run_slice(repo, inputs, folder, args, hook_dir, jobs))
                shutil.rmtree(folder)
        summary = {label: {key: statistics.median(r[key] for r in runs[label]) for key, *_ in FIGURES}
                   for label in labels}
    what = (f"rung 0 of configurations 0..{args.configs - 1}" if args.configs else f"rungs 0..{args.rung}")
    print(f"search slice: demo plan, bracket {args.bracket}, {what}, snakemake "
          f"{', '.join(f'-j{j}' for j in jobs_list)}, median of {args.repeats} run(s)")
    width = max(28, *(len(label) for label in labels))
    names = [f"[{i}]" for i in range(len(labels))]
    for name, label in zip(names, labels):
        print(f"  {name} {label}")
    print(f"{'':<26}" + "".join(f"{name:>12}" for name in names))
    for key, text, fmt in FIGURES:
        print(f"{text:<26}" + "".join(f"{fmt.format(summary[label][key]):>12}" for label in labels))
    output = {"slice": {"bracket": args.bracket, "rung": args.rung, "configs": args.configs, "jobs": jobs_list,
                        "repeats": args.repeats}, "repos": summary}
    if len(labels) > 1:
        first = runs[labels[0]][0]["objectives"]
        for label in labels[1:]:
            other = runs[label][0]["objectives"]
            diffs = [abs(first[k] - other[k]) for k in first if first[k] is not None and other.get(k) is not None]
            rel = [abs(first[k] - other[k]) / abs(first[k]) for k in first
                   if first[k] and other.get(k) is not None]
            summary[label]["objective_max_abs_diff"] = max(diffs) if diffs else None
            summary[label]["objective_max_rel_diff"] = max(rel) if rel else None
            print(f"objectives of {label} vs {labels[0]}: max abs diff {summary[label]['objective_max_abs_diff']}, "
                  f"max rel diff {summary[label]['objective_max_rel_diff']} ({len(diffs)} trials)")
    if args.project:
        for (_, jobs), label in zip(runs_of, labels):
            summary[label]["projection"] = project(summary[label], args.project, jobs)
        first = summary[labels[0]]["projection"]
        print(f"projection for {args.project.name}: {first['train_rung_jobs']} train_rung + "
              f"{first['select_rung_jobs']} select_rung jobs, {first['training_data_s']:.0f} s of training data: "
              + ", ".join(f"{name} {summary[label]['projection']['projected_min']:.1f} min"
                          for name, label in zip(names, labels)))
        if args.markdown:
            first_repo = {jobs: summary[label] for (repo, jobs), label in zip(runs_of, labels) if repo == repos[0]}
            args.markdown.parent.mkdir(parents=True, exist_ok=True)
            args.markdown.write_text(scaling_markdown(first_repo, jobs_list, args))
    for label in labels:
        summary[label]["objectives"] = runs[label][0]["objectives"]
    print(json.dumps(output))


if __name__ == "__main__":
    main()
