"""Does the hybrid's training improve on its physical layer? Rung 0 of its search at several learning-rate ranges.

A hybrid starts as its physical layer (the FMU plus the diagnosed effects, the ANN's output exactly zero), which is
already close to the measurement; a learning rate that suits the neural FMU (whose FMU is far from it) may throw
that start away. For each ``--lr LOW:HIGH`` this script reruns the first rung of the hybrid's search brackets
(``--bracket``, default 1 and 2) on a finished run's inputs (``--results``, e.g. ``results/ipb``: its FMU, data,
segments, calibration, diagnosis, prepared search data and the hybrid's delay start are copied into a fresh clone
of ``--commit``, default HEAD), with that run's case config (``--configfile``, default ``config/config.yaml`` where
this runs) and its hybrid search space except the learning rate, which is drawn log-uniformly from that range (the
same draws of every other hyperparameter: the plan's seed is the config's master seed).
Only the validation segments judge (each trial's open-loop objective over them, as the search ranks it); nothing
reads a test maneuver.

Per range it prints each trial's learning rate, its objective before training (the physical layer's, the same for
every trial), after each validation, and at its best, and sums them up: how many trials end better than the
physical layer, the median ratio of the final objective to the physical layer's, and the worst. Last line: a JSON
object with all of it. ``--markdown FILE`` writes the summary table (for the docs: ``python -m
hybridfmu.evaluation.measured_blocks --block hybrid_learning_rate=FILE``).

    python benchmarks/hybrid_search_space.py --results results/ipb --lr 1e-3:5e-3 --lr 1e-5:3e-4
        [--bracket 1 --bracket 2] [--jobs 2] [--configfile config/config.yaml] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

from stage_wall import touch_tree
from workflow_wall import clone, resolve

#: What the hybrid's first rung reads of a finished run's case results.
HYBRID_INPUTS = ("fmu", "data", "segments", "calibration", "diagnosis", "hpo/prepared", "hybrid/time_offset.json")


def learning_rate_range(text: str) -> tuple[float, float]:
    """``LOW:HIGH`` -> (low, high), 0 < low <= high."""
    try:
        low, high = (float(part) for part in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--lr {text!r}: expected LOW:HIGH, e.g. 1e-5:3e-4") from None
    if not 0 < low <= high:
        raise argparse.ArgumentTypeError(f"--lr {text!r}: expected 0 < LOW <= HIGH")
    return low, high


def copy_inputs(results: Path, checkout: Path) -> None:
    """Copy the hybrid's inputs of ``results`` into the checkout's results, newer than its sources."""
    for name in HYBRID_INPUTS:
        source, target = results / name, checkout / results / name
        if not source.exists():
            raise SystemExit(f"{source}: missing; expected a finished run's case results (its {name})")
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir():
            shutil.copytree(source, target)
        else:
            shutil.copy2(source, target)
    touch_tree(checkout / results)


def override(config_path: Path, low: float, high: float, folder: Path) -> Path:
    """A config file that gives the hybrid's search the case config's search space with lr in [low, high]."""
    config = yaml.safe_load(config_path.read_text())
    hpo = config.get("hpo") or {}
    search = ((hpo.get("searches") or {}).get("hybrid") or {})
    space = dict(search.get("search_space") or hpo.get("search_space") or {})
    if not space:
        raise SystemExit(f"{config_path}: hpo.search_space: missing (the hybrid's search space to vary)")
    space["lr"] = {"distribution": "loguniform", "low": low, "high": high}
    path = folder / f"lr_{low:g}_{high:g}.yaml"
    path.write_text(yaml.safe_dump({"hpo": {"searches": {"hybrid": {**search, "search_space": space}}}}))
    return path


def trials(checkout: Path, results: Path, brackets: list[int]) -> list[dict]:
    """Rung 0's trials of the brackets: id, lr, the objective at each validation (resource s, objective) and the
    best."""
    out = []
    for bracket in brackets:
        for path in sorted((checkout / results / "hybrid" / f"b{bracket}" / "r0").glob("c*/result.json")):
            result = json.loads(path.read_text())
            history = [(float(v.get("resource_s", 0.0)), float(v["objective"])) for v in result.get("validations")
                       or [] if v.get("objective") is not None]
            out.append({"trial": result.get("trial_id"), "lr": float((result.get("hyperparameters") or {})["lr"]),
                        "history": history, "best": result.get("objective"), "status": result.get("status")})
    return out


def run_range(commit: str, results: Path, configfile: Path, low: float, high: float, brackets: list[int],
              jobs: int, folder: Path) -> list[dict]:
    """Rung 0 of the brackets with lr in [low, high] in a fresh clone, with the finished run's case config
    ``configfile`` (absolute) and the learning-rate override; returns :func:`trials`."""
    checkout = clone(commit, folder / f"lr_{low:g}_{high:g}")
    copy_inputs(results, checkout)
    extra = override(configfile, low, high, checkout)
    targets = [str(results / "hybrid" / f"b{b}" / "r0" / "selection.json") for b in brackets]
    command = [sys.executable, "-m", "snakemake", f"-j{jobs}", "--rerun-triggers", "mtime", "--configfile",
               str(configfile), str(extra), "--", *targets]
    log = checkout / "hybrid_search_space.log"
    with open(log, "w") as stream:
        status = subprocess.run(command, cwd=checkout, env=dict(os.environ, PYTHONPATH=str(checkout / "src")),
                                stdout=stream, stderr=subprocess.STDOUT).returncode
    if status:
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-30:])
        raise RuntimeError(f"{' '.join(command)} in {checkout} failed ({status}):\n{tail}")
    return trials(checkout, results, brackets)


def summarise(found: list[dict]) -> dict:
    """Against the physical layer (every trial's objective before training): trials better at the end, the median
    and worst ratio of the final objective to it, and of the best one."""
    start = [t["history"][0][1] for t in found if t["history"] and t["history"][0][0] == 0.0]
    if not start:
        raise SystemExit("no trial validated its untrained state (resource 0): is this a hybrid's search?")
    layer = start[0]
    final = [t["history"][-1][1] / layer for t in found if t["history"]]
    best = [float(t["best"]) / layer for t in found if t["best"] is not None]
    return {"physical_layer_objective": layer, "trials": len(found),
            "better_at_the_end": sum(r < 1.0 for r in final), "final_ratio_median": statistics.median(final),
            "final_ratio_worst": max(final), "best_ratio_median": statistics.median(best)}


def markdown(summaries: dict[str, dict], results: str, brackets: list[int], seed: object) -> str:
    """The summary table as Markdown (``seed``: the case config's master seed, which drew the plan)."""
    lines = [f"The hybrid's search, rung 0 of bracket(s) {', '.join(map(str, brackets))} rerun on the inputs of "
             f"`{results}` (master seed {seed}) at each learning-rate range (the rest of the search space as "
             "configured; `benchmarks/hybrid_search_space.py`): each trial's validation objective after its "
             "training, as a ratio to its physical layer's (the untrained hybrid; below 1: training helped).", "",
             "| learning rate | trials | better than the physical layer at the end | median ratio at the end | "
             "worst ratio at the end |", "|---|---|---|---|---|"]
    for label, s in summaries.items():
        lines.append(f"| {label} | {s['trials']} | {s['better_at_the_end']} | {s['final_ratio_median']:.3g} | "
                     f"{s['final_ratio_worst']:.3g} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--results", required=True, type=Path, help="a finished run's case results, e.g. results/ipb")
    parser.add_argument("--lr", action="append", type=learning_rate_range, required=True,
                        help="learning-rate range LOW:HIGH (repeatable)")
    parser.add_argument("--bracket", action="append", type=int, help="bracket whose rung 0 runs (default 1 and 2)")
    parser.add_argument("--jobs", type=int, default=2, help="jobs at a time (snakemake -jN)")
    parser.add_argument("--commit", default="HEAD")
    parser.add_argument("--configfile", type=Path, default=Path("config/config.yaml"),
                        help="the finished run's case config (default: config/config.yaml where this runs)")
    parser.add_argument("--markdown", type=Path, default=None, help="write the summary table to this file")
    args = parser.parse_args()
    if args.results.is_absolute() or not args.results.is_dir():
        raise SystemExit(f"--results {args.results}: expected an existing folder like results/ipb, relative to the "
                         "folder this runs in")
    brackets = args.bracket or [1, 2]
    configfile = args.configfile.resolve()
    if not configfile.is_file():
        raise SystemExit(f"--configfile {args.configfile}: no such file; expected the finished run's case config")
    seed = (yaml.safe_load(configfile.read_text()) or {}).get("seed")
    commit = resolve(args.commit)
    found, summaries = {}, {}
    with tempfile.TemporaryDirectory(prefix="hybridfmu-hybrid-lr-") as tmp:
        for low, high in args.lr:
            label = f"{low:g} to {high:g}"
            print(f"lr {label}: rung 0 of bracket(s) {brackets} ...", file=sys.stderr, flush=True)
            found[label] = run_range(commit, args.results, configfile, low, high, brackets, args.jobs, Path(tmp))
            summaries[label] = summarise(found[label])
            for t in found[label]:
                path = " -> ".join(f"{objective:.4g}" for _, objective in t["history"])
                best = "none" if t["best"] is None else f"{float(t['best']):.4g}"
                print(f"  {t['trial']}: lr {t['lr']:.3g}: {path} (best {best}, {t['status']})", file=sys.stderr)
    print(f"{'learning rate':<22} {'trials':>6} {'better':>6} {'median end/layer':>17} {'worst end/layer':>16}")
    for label, s in summaries.items():
        print(f"{label:<22} {s['trials']:>6} {s['better_at_the_end']:>6} {s['final_ratio_median']:>17.3g} "
              f"{s['final_ratio_worst']:>16.3g}")
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(markdown(summaries, str(args.results), brackets, seed))
    print(json.dumps({"results": str(args.results), "seed": seed, "brackets": brackets, "summaries": summaries,
                      "trials": found}))


if __name__ == "__main__":
    main()
