"""A case's figures over several seeds (target ``robustness``): a result is a property, not a draw.

Every seed of ``robustness.seeds`` reruns the whole case with that master seed (for an emulated case: the bench's
noise, the searches' draws, the training windows, the diagnosis' resampling all change) in a results folder of
its own, ``<results_dir>/robustness/seed<seed>/``; the case's own seed is the case's own run. The summary pools
every (seed, maneuver) of the test maneuvers: per model the median, min and max of each factor against the FMU,
and every pair where the hybrid is worse than its own physics (the FMU + the diagnosed effects).
"""

from __future__ import annotations

import copy
import logging
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import yaml

from hybridfmu.evaluation.metrics import summary_statistics
from hybridfmu.io import read_json, write_json_atomic, write_text_atomic

LOG = logging.getLogger(__name__)

#: The models the summary pools, in the order of its table.
ROBUSTNESS_MODELS = ("neural_fmu", "fmu_effects", "hybrid", "ceiling")


def seed_results_dir(results_dir: str, seed: int) -> str:
    """Where the run of ``seed`` writes: ``<results_dir>/robustness/seed<seed>``."""
    return f"{results_dir}/robustness/seed{int(seed)}"


def seed_config(config: Mapping[str, Any], seed: int) -> dict[str, Any]:
    """The case config of one seed: ``seed`` as its master seed, outputs under :func:`seed_results_dir`; a bench
    case's logs are the bench's outputs there (its maneuvers' ``raw`` paths follow); a user's logs stay where
    they are."""
    changed = copy.deepcopy(dict(config))
    results_dir = str(config.get("results_dir", "results"))
    changed["seed"] = int(seed)
    changed["results_dir"] = seed_results_dir(results_dir, seed)
    changed.pop("robustness", None)
    if "bench" in changed:
        for name, maneuver in changed["maneuvers"].items():
            maneuver["raw"] = f"{changed['results_dir']}/{changed['case']}/raw/{name}.mf4"
    return changed


def run_seed(config: Mapping[str, Any], seed: int, config_path: str | Path, snakefile: str | Path,
             cores: int, metrics_path: str | Path, log_path: str | Path) -> dict[str, Any]:
    """Run the whole case with ``seed`` (Snakemake in a process of its own, in the same working directory, without
    a lock of its own: its outputs lie under :func:`seed_results_dir`) and copy its test metrics.

    Args:
        config: the case config; seed: the master seed of this run.
        config_path: where the seed's config is written (YAML).
        snakefile: the workflow's Snakefile; cores: cores of the run.
        metrics_path: output: the seed's ``metrics/test.json``, copied.
        log_path: the nested run's Snakemake output (progress: one line per finished job here).

    Raises:
        RuntimeError: the seed's run failed (names its log).
    """
    changed = seed_config(config, seed)
    Path(config_path).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(config_path, yaml.safe_dump(changed, sort_keys=False))
    results = Path(changed["results_dir"]) / changed["case"]
    command = [sys.executable, "-m", "snakemake", f"-j{int(cores)}", "--snakefile", str(snakefile), "--configfile",
               str(config_path), "--nolock", "--rerun-incomplete", "--nocolor", str(results / "metrics" / "test.json")]
    LOG.info("seed %d: %s", seed, " ".join(command))
    started = time.perf_counter()
    with open(log_path, "w") as log:
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, text=True)
        while process.poll() is None:
            time.sleep(30.0)
            finished = Path(log_path).read_text(errors="replace").count("Finished job")
            LOG.info("seed %d: %d jobs finished, %.0f s", seed, finished, time.perf_counter() - started)
    if process.returncode != 0:
        raise RuntimeError(f"seed {seed}: the case's run failed (exit {process.returncode}); see {log_path}")
    metrics = read_json(results / "metrics" / "test.json")
    write_json_atomic(metrics_path, metrics)
    LOG.info("seed %d: done in %.0f s; test metrics copied to %s", seed, time.perf_counter() - started, metrics_path)
    return metrics


def summarize(metrics_by_seed: Mapping[int, Mapping[str, Any]]) -> dict[str, Any]:
    """Pool the test metrics of several seeds.

    Args:
        metrics_by_seed: seed -> that seed's ``metrics/test.json`` (``per_maneuver``, ``signals``).

    Returns:
        ``{"seeds", "maneuvers", "signals", "models": {model: {"<signal>_<measure>_factor": {"median", "min",
        "max", "n"}, "in_tolerance_share": ..., "<signal>_mae_windowed_factor": ..., "<signal>_mae_closed_loop_factor":
        ...}}, "hybrid_worse_than_fmu_effects":
        [{"seed", "maneuver", "signal", "hybrid_mae", "fmu_effects_mae"}]}`` over every (seed, maneuver); a factor is
        the FMU's error over the model's on that maneuver.
    """
    if not metrics_by_seed:
        raise ValueError("robustness: no seed to summarize")
    seeds = sorted(int(seed) for seed in metrics_by_seed)
    signals = list(next(iter(metrics_by_seed.values()))["signals"])
    maneuvers: list[str] = []
    values: dict[str, dict[str, list]] = {}
    worse = []
    for seed in seeds:
        metrics = metrics_by_seed[seed]
        for maneuver, entry in metrics["per_maneuver"].items():
            if maneuver not in maneuvers:
                maneuvers.append(maneuver)
            for model in ROBUSTNESS_MODELS:
                if model not in entry:
                    continue
                improvement = entry["improvement" if model == "neural_fmu" else f"improvement_{model}"]
                target = values.setdefault(model, {})
                for signal in signals:
                    for measure in ("mae", "mse"):
                        target.setdefault(f"{signal}_{measure}_factor", []).append(improvement[f"{signal}_{measure}"])
                    for kind in ("windowed", "closed_loop"):
                        errors = entry.get(kind) or {}
                        if model in errors and "fmu" in errors and errors[model].get(f"{signal}_mae"):
                            target.setdefault(f"{signal}_mae_{kind}_factor", []).append(
                                errors["fmu"][f"{signal}_mae"] / errors[model][f"{signal}_mae"])
                tolerance = (entry.get("in_tolerance") or {}).get(model)
                if tolerance:
                    target.setdefault("in_tolerance_share", []).append(tolerance["in_tolerance_share"])
            if "hybrid" in entry and "fmu_effects" in entry:
                for signal in signals:
                    hybrid, physics = entry["hybrid"][f"{signal}_mae"], entry["fmu_effects"][f"{signal}_mae"]
                    if hybrid > physics:
                        worse.append({"seed": seed, "maneuver": maneuver, "signal": signal, "hybrid_mae": hybrid,
                                      "fmu_effects_mae": physics})
    models = {model: {key: summary_statistics(items) for key, items in stats.items()} for model, stats in values.items()}
    return {"seeds": seeds, "maneuvers": maneuvers, "signals": signals, "models": models,
            "hybrid_worse_than_fmu_effects": worse}


def reference_comparison(summary: Mapping[str, Any], reference: Mapping[str, Any] | None) -> list[dict[str, Any]]:
    """The reference's test factors (config ``evaluation.reference.factors`` with role ``test``, e.g. the paper's)
    beside the neural FMU's median over every (seed, maneuver) and the ceiling's median in the same metric.

    Returns ``[{"metric", "factor", "note", "neural_fmu_median", "reached", "ceiling_median"}]`` (``reached``: the
    median is at least the reference's factor; None where the summary has no such metric).
    """
    rows = []
    models = summary["models"]
    for item in (reference or {}).get("factors") or []:
        if item.get("role") != "test":
            continue
        key = f"{item['metric']}_factor"
        median = ((models.get("neural_fmu") or {}).get(key) or {}).get("median")
        ceiling = ((models.get("ceiling") or {}).get(key) or {}).get("median")
        rows.append({"metric": item["metric"], "factor": float(item["factor"]), "note": item.get("note", ""),
                     "neural_fmu_median": median, "ceiling_median": ceiling,
                     "reached": None if median is None else bool(median >= float(item["factor"]))})
    return rows


def summary_markdown(case: str, summary: Mapping[str, Any], wall_s: Mapping[int, float] | None = None,
                     jobs: Mapping[int, int] | None = None) -> str:
    """The summary as the documentation quotes it: one row per model, median [min – max] over every (seed, maneuver)."""
    from hybridfmu.evaluation.report import MODEL_TITLES, spread_text

    signals = summary["signals"]
    measures = [(f"{s}_mae_factor", f"{s} MAE vs FMU") for s in signals] + \
               [(f"{s}_mse_factor", f"{s} MSE vs FMU") for s in signals] + \
               [(f"{s}_mae_windowed_factor", f"{s} windowed MAE vs FMU") for s in signals]
    if any(f"{s}_mae_closed_loop_factor" in stats for stats in summary["models"].values() for s in signals):
        measures += [(f"{s}_mae_closed_loop_factor", f"{s} closed-loop MAE vs FMU") for s in signals]
    lines = [f"Case `{case}` over {len(summary['seeds'])} seeds ({', '.join(map(str, summary['seeds']))}) and "
             f"{len(summary['maneuvers'])} test maneuvers, every (seed, maneuver) on its own: median [min – max] "
             f"(`snakemake -j2 robustness`, `{{results}}/{case}/robustness/summary.json`).", "",
             "| model | " + " | ".join(text for _, text in measures) + " | within tolerance |",
             "|---|" + "---|" * (len(measures) + 1)]
    for model in ROBUSTNESS_MODELS:
        stats = summary["models"].get(model)
        if not stats:
            continue
        cells = [spread_text(stats.get(key), factor=True) for key, _ in measures]
        cells.append(spread_text(stats.get("in_tolerance_share"), percent=True))
        lines.append(f"| {MODEL_TITLES.get(model, model)} | " + " | ".join(cells) + " |")
    compared = summary.get("reference") or []
    if compared:
        name = summary.get("reference_name") or "the reference"
        parts = []
        for row in compared:
            signal, measure = row["metric"].rsplit("_", 1)
            metric = f"{signal} {measure.upper()}"
            if row["neural_fmu_median"] is None:
                parts.append(f"{metric} ×{row['factor']:.3g}: not measured")
                continue
            verdict = "reached" if row["reached"] else "not reached"
            ceiling = "" if row["ceiling_median"] is None else f", the ceiling's ×{row['ceiling_median']:.3g}"
            parts.append(f"{metric} ×{row['factor']:.3g} against the neural FMU's median "
                         f"×{row['neural_fmu_median']:.3g}: {verdict}{ceiling}")
        lines += ["", f"The neural FMU against the reference's test factors ({name}, config `evaluation.reference`): "
                  + "; ".join(parts) + "."]
    worse = summary["hybrid_worse_than_fmu_effects"]
    lines += ["", "The hybrid is worse than the FMU + diagnosed effects (whole-record MAE) on: " +
              ("; ".join(f"seed {w['seed']} {w['maneuver']} ({w['signal']})" for w in worse) if worse else
               "no (seed, maneuver).")]
    if wall_s:
        jobs = jobs or {}
        lines += ["", "Wall time of each seed's run on this machine: " + ", ".join(
            f"seed {seed} {seconds / 60:.0f} min" + (f" for {jobs[seed]} jobs" if seed in jobs else "")
            for seed, seconds in sorted(wall_s.items())) + "." + (
            " A run that resumed an interrupted one counts only the jobs it ran, and only their time." if jobs
            else "")]
    return "\n".join(lines) + "\n"


def write_summary(case: str, metrics_paths: Mapping[int, str | Path], summary_path: str | Path,
                  markdown_path: str | Path, wall_s: Mapping[int, float] | None = None,
                  reference: Mapping[str, Any] | None = None, jobs: Mapping[int, int] | None = None
                  ) -> dict[str, Any]:
    """Rule ``robustness_summary``: :func:`summarize` of the seeds' test metrics (seed -> ``test.json``), with the
    neural FMU beside ``reference`` (config ``evaluation.reference``, :func:`reference_comparison`), written as
    JSON and as the documentation's Markdown (with each seed's wall time and, given ``jobs``, the number of jobs
    its run ran)."""
    summary = summarize({int(seed): read_json(path) for seed, path in metrics_paths.items()})
    if reference and reference.get("factors"):
        summary["reference_name"] = reference.get("name") or "the reference"
        summary["reference"] = reference_comparison(summary, reference)
    write_json_atomic(summary_path, summary)
    write_text_atomic(markdown_path, summary_markdown(case, summary, wall_s, jobs))
    return summary


def seed_wall_times(benchmark_paths: Sequence[str | Path], seeds: Sequence[int]) -> dict[int, float]:
    """Wall time (s) of each seed's run from its Snakemake benchmark file (first column of the second line)."""
    out = {}
    for seed, path in zip(seeds, benchmark_paths):
        lines = Path(path).read_text().splitlines()
        if len(lines) >= 2:
            out[int(seed)] = float(lines[1].split("\t")[0])
    return out


def seed_job_counts(run_log_paths: Sequence[str | Path], seeds: Sequence[int]) -> dict[int, int]:
    """Jobs each seed's nested run ran, from its Snakemake output (``run.log``: the last "N of M steps" line's M,
    else the count of finished jobs); seeds without a log are left out. A run that resumed an interrupted one ran
    only the jobs that were missing."""
    out = {}
    for seed, path in zip(seeds, run_log_paths):
        if not Path(path).is_file():
            continue
        text = Path(path).read_text(errors="replace")
        steps = re.findall(r"^\d+ of (\d+) steps", text, flags=re.MULTILINE)
        out[int(seed)] = int(steps[-1]) if steps else text.count("Finished job")
    return out
