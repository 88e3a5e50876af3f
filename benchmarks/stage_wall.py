"""Wall time of one stage (a Snakemake rule) rerun on a finished run's inputs, for one or more commits side by side.

For each commit (``--commit``, default HEAD; repeatable) the repository is cloned into a temporary folder, the
folders ``--inputs`` of a finished run's case results (``--results``, e.g. ``results/ipb``) are copied into the
clone's results, and ``snakemake -j1 --forcerun <rule> <target>`` reruns that one rule there with the clone's
``src`` first on the Python path (no install needed; ``--rerun-triggers mtime``, so only the forced rule runs).
Commits and ``--repeats`` alternate, so that a before/after comparison shares the machine's load. The figure is the
rule's wall time from Snakemake's benchmark file (``{results}/benchmarks/<rule>/<rule>.tsv``, or ``--benchmark``
for a rule with wildcards; seconds); run it
from the folder that holds ``--results`` (the finished run's project).

``--cores N`` gives the job N cores (``snakemake -jN``; a rule that declares threads gets up to N). Each run's
``--target`` is compared with the first commit's first run: a JSON file with the keys that differ on every
run (:data:`VOLATILE_KEYS`: an MLflow run id, elapsed times) left out, any other file byte for byte.

Prints a table and, last line, a JSON object: per commit the rule's wall times (s) and their median, whether
its outputs equal the first commit's, and the ratio of the first commit's median to each other's.
``--field KEY`` (a dotted key of a JSON target, e.g. ``which.found_effects``) adds that value of each commit's first
run to the table, and whether it equals the first commit's, for outputs that differ as a whole but must agree on it.
``--markdown FILE`` writes the table as Markdown (for the docs: ``python -m hybridfmu.evaluation.measured_blocks
--block <name>=FILE``).

    python benchmarks/stage_wall.py --results results/ipb --rule diagnose --target results/ipb/diagnosis/diagnosis.json
        --inputs fmu data segments calibration [--commit 357ca3c --commit HEAD] [--configfile FILE] [--repeats 1]
        [--cores 1] [--field which.found_effects] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from workflow_wall import clone, resolve


#: Keys of a JSON output whose values differ on every run, left out when outputs are compared.
VOLATILE_KEYS = frozenset({"mlflow_run_id", "elapsed_s"})


def comparable(path: Path) -> object:
    """What of an output file must be the same on every run: a JSON file's content without
    :data:`VOLATILE_KEYS` (at any depth), any other file's bytes."""
    if path.suffix != ".json":
        return path.read_bytes()

    def strip(value: object) -> object:
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in VOLATILE_KEYS}
        if isinstance(value, list):
            return [strip(v) for v in value]
        return value

    return strip(json.loads(path.read_text()))


def field_value(path: Path, key: str) -> object:
    """The value at the dotted ``key`` of the JSON file ``path`` (None where a part of it is missing)."""
    value: object = json.loads(path.read_text())
    for part in key.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    return value


def touch_tree(folder: Path) -> None:
    """Give every file under ``folder`` the current time (the copied inputs newer than the clone's sources)."""
    now = time.time()
    for path in folder.rglob("*"):
        if path.is_file():
            os.utime(path, (now, now))


def run_stage(checkout: Path, results: Path, inputs: list[str], rule: str, target: str,
              configfile: str | None, cores: int = 1, benchmark: str | None = None) -> dict:
    """Copy the inputs into ``checkout`` and rerun ``rule`` with ``cores`` cores; returns {"rule_s", "command_s",
    "output"} (``output``: :func:`comparable` of the target)."""
    case_results = checkout / results
    for name in inputs:
        shutil.copytree(results / name, case_results / name, symlinks=True)
    touch_tree(case_results)
    command = [sys.executable, "-m", "snakemake", f"-j{int(cores)}", "--rerun-triggers=mtime", "--forcerun",
               rule]
    if configfile:
        command += ["--configfile", configfile]
    command += ["--", target]
    env = dict(os.environ, PYTHONPATH=str(checkout / "src"))
    log = checkout / "stage_wall.log"
    start = time.perf_counter()
    with open(log, "w") as out:
        status = subprocess.run(command, cwd=checkout, env=env, stdout=out, stderr=subprocess.STDOUT).returncode
    command_s = time.perf_counter() - start
    text = log.read_text(errors="replace")
    if status:
        raise RuntimeError(f"{' '.join(command)} in {checkout} failed ({status}):\n" + "\n".join(text.splitlines()[-30:]))
    tsv = case_results / "benchmarks" / (benchmark or f"{rule}/{rule}.tsv")
    if not tsv.is_file():
        raise FileNotFoundError(f"{tsv}: the rule {rule!r} wrote no benchmark file (is it the rule's name?)")
    with tsv.open() as stream:
        rows = list(csv.DictReader(stream, delimiter="\t"))
    return {"rule_s": float(rows[-1]["s"]), "command_s": command_s, "output": comparable(checkout / target),
            "path": checkout / target}


def agreement(value: object, first: object) -> str:
    """Whether a field's ``value`` equals the first commit's: the same, the same list in another order, or not."""
    if value == first:
        return "the same"
    if isinstance(value, list) and isinstance(first, list) and sorted(map(str, value)) == sorted(map(str, first)):
        return "the same, in another order"
    return "**differs**"


def _shown(value: object) -> str:
    """A field's value as table text (a list joined by commas, a Markdown table's bar escaped)."""
    text = ", ".join(map(str, value)) if isinstance(value, list) else str(value)
    return text.replace("|", "\\|")


def markdown(summary: dict, rule: str, results: str, ratios: dict, target: str, cores: int,
             fields: list[str] | None = None) -> str:
    """The table of the runs as Markdown (with each of ``fields`` of the target per commit)."""
    fields = fields or []
    lines = [f"Rule `{rule}` rerun on the inputs of `{results}`, one job at a time with {cores} core(s), side by side "
             f"on this machine ({os.cpu_count()} cores; `benchmarks/stage_wall.py`):", "",
             f"| commit | wall time of the rule | runs | against the first commit | `{Path(target).name}` as the "
             "first commit's |" + "".join(f" `{key}` |" for key in fields),
             "|---|---|---|---|---|" + "---|" * len(fields)]
    first = next(iter(summary.values()))
    for commit, figures in summary.items():
        runs = ", ".join(f"{s:.0f} s" for s in figures["rule_s"])
        same = "the same" if figures["same_output"] else "**differs**"
        shown = ""
        for key in fields:
            value = figures["fields"][key]
            agrees = "" if figures is first else f" ({agreement(value, first['fields'][key])})"
            shown += f" {_shown(value)}{agrees} |"
        lines.append(f"| {commit[:10]} | {figures['median_s']:.0f} s | {runs} | ×{ratios[commit]:.2f} | {same} |"
                     + shown)
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", required=True, type=Path, help="a finished run's case results, e.g. results/ipb")
    parser.add_argument("--rule", required=True, help="the rule to rerun, e.g. diagnose")
    parser.add_argument("--target", required=True, help="an output of the rule, relative to the repository")
    parser.add_argument("--inputs", nargs="+", required=True, help="folders of --results the rule reads")
    parser.add_argument("--commit", action="append", help="commit to run (repeatable; default HEAD)")
    parser.add_argument("--configfile", default=None, help="case config (default: the demo)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--cores", type=int, default=1, help="cores of the job (snakemake -jN)")
    parser.add_argument("--benchmark", default=None,
                        help="the rule's benchmark file under <results>/benchmarks (default <rule>/<rule>.tsv; a "
                             "rule with wildcards names its own, e.g. train_rung/hybrid/b2_r0_c4.tsv)")
    parser.add_argument("--field", action="append", default=[],
                        help="a dotted key of the JSON target shown per commit (repeatable), e.g. which.found_effects")
    parser.add_argument("--markdown", type=Path, default=None, help="write the table as Markdown to this file")
    args = parser.parse_args()
    commits = [resolve(c) for c in (args.commit or ["HEAD"])]
    results = args.results
    if results.is_absolute() or not results.is_dir():
        raise SystemExit(f"--results {results}: expected an existing folder relative to the repository's results "
                         "layout, e.g. results/ipb")
    summary = {c: {"rule_s": [], "command_s": [], "same_output": True} for c in commits}
    reference = None
    with tempfile.TemporaryDirectory(prefix="hybridfmu-stage-") as tmp:
        for repeat in range(args.repeats):
            for commit in commits:
                label = f"{commit[:10]} run {repeat + 1}/{args.repeats}"
                print(f"{label} ...", file=sys.stderr, flush=True)
                checkout = clone(commit, Path(tmp) / f"{commit[:10]}-{repeat}")
                figures = run_stage(checkout, results, args.inputs, args.rule, args.target, args.configfile,
                                    args.cores, args.benchmark)
                output = figures.pop("output")
                target_path = figures.pop("path")
                if repeat == 0:
                    summary[commit]["fields"] = {key: field_value(target_path, key) for key in args.field}
                reference = output if reference is None else reference
                summary[commit]["same_output"] &= output == reference
                print(f"  {label}: rule {args.rule} in {figures['rule_s']:.0f} s, {args.target} "
                      f"{'as the first' if output == reference else 'differs from the first'}", file=sys.stderr,
                      flush=True)
                for key in ("rule_s", "command_s"):
                    summary[commit][key].append(figures[key])
                shutil.rmtree(checkout, ignore_errors=True)
    for figures in summary.values():
        figures["median_s"] = statistics.median(figures["rule_s"])
    first = summary[commits[0]]["median_s"]
    ratios = {c: first / figures["median_s"] for c, figures in summary.items()}
    print(f"{'commit':<12} {'median, s':>10}  {'vs first':>8}  {'output':>8}  runs, s")
    for commit, figures in summary.items():
        print(f"{commit[:10]:<12} {figures['median_s']:>10.0f}  {ratios[commit]:>7.2f}x  "
              f"{'same' if figures['same_output'] else 'DIFFERS':>8}  "
              + ", ".join(f"{s:.0f}" for s in figures["rule_s"]))
        for key, value in figures["fields"].items():
            print(f"  {key}: {_shown(value)}")
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown(summary, args.rule, str(results), ratios, args.target, args.cores,
                                          args.field))
    print(json.dumps({"rule": args.rule, "results": str(results), "commits": summary, "ratios": ratios}))


if __name__ == "__main__":
    main()
