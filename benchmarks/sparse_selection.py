"""Forward selection with BIC against SINDy's sparse regression (pysindy STLSQ), side by side on the withheld suite.

For every case of a finished withheld suite (``snakemake -j2 withheld``) it rebuilds the diagnosis' candidate
features from the case's ingested logs (:mod:`hybridfmu.diagnosis.sparse`: each candidate at its setting
fitted alone beside the calibrated parameter errors, rows in noise-floor units), runs STLSQ over a grid of
thresholds and scores what it names with the suite's own scoring (:func:`hybridfmu_bench.withheld.scoring.
score_case`, the case's ground truth). The forward selection's names come from the case's ``diagnosis.json``
and are scored the same way. The threshold is chosen as the suite chooses the forward selection's: the smallest
that names nothing in every none case. Both methods are measured on the cases above the forward selection's
detection limits (:func:`hybridfmu_bench.withheld.report.aggregate`).

Prints a table; the last line is a JSON object with the figures. ``--markdown FILE`` writes the table for the
documentation (block ``sparse_selection``).

    python benchmarks/sparse_selection.py [--config config/config.yaml] [--withheld results/withheld]
        [--jobs 2] [--cases PATTERN] [--markdown FILE]
"""

from __future__ import annotations

import argparse
import copy
import fnmatch
import json
import logging
import multiprocessing
import time
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.config import load_case_config

ROOT = Path(__file__).resolve().parents[1]
LOG = logging.getLogger("sparse_selection")
#: STLSQ thresholds tried (noise-floor units of a unit-length column).
THRESHOLDS = [1.0, 3.0, 10.0, 20.0, 30.0, 50.0, 70.0, 100.0, 150.0, 200.0, 300.0, 500.0, 700.0, 1000.0, 2000.0, 3000.0]


def _chosen_items(terms: list, problem: Any) -> list[dict[str, Any]]:
    """``which.chosen`` entries of a diagnosis record for ``terms`` (what the scoring reads)."""
    from hybridfmu.diagnosis.joint import effect_equations

    items = []
    for term in terms:
        equations = [problem.state_names[eq] for eq in effect_equations(term.effect)]
        cov = np.zeros((len(term.coef), len(term.coef)))
        items.append({"effect": term.effect.name, "kind": term.effect.kind, "equation": equations[0],
                      "equations": equations, "parameters": term.effect.physical(term.coef, cov, term.setting, {}),
                      "coefficients": dict(zip(term.effect.coefficient_names(term.setting), map(float, term.coef)))})
    return items


def score_case_files(case: str, withheld: Path, fmu: Path, expected: dict, background: dict) -> dict[str, Any]:
    """Forward selection's row and STLSQ's rows (per threshold) of one case, with the feature-building time."""
    from hybridfmu.diagnosis.corrected_model import simulator_for
    from hybridfmu.diagnosis.inputs import load_inputs
    from hybridfmu.diagnosis.run import prepare_all, selection_inputs
    from hybridfmu.diagnosis.selection import SelectionSettings
    from hybridfmu.diagnosis.sparse import candidate_features, stlsq_select
    from hybridfmu_bench.withheld.suite import load_case, without_bench
    from hybridfmu_bench.withheld.scoring import score_case

    config = without_bench(load_case(withheld / "cases" / f"{case}.yaml"))
    maneuvers = list(config["maneuvers"])
    record = json.loads((withheld / case / "diagnosis" / "diagnosis.json").read_text())
    truth = json.loads((withheld / case / "raw" / f"{maneuvers[-1]}.truth.json").read_text())
    draw = json.loads((withheld / "cases" / f"{case}.draw.json").read_text())
    started = time.perf_counter()
    inputs = load_inputs(config, fmu, {m: withheld / case / "data" / f"{m}.parquet" for m in maneuvers},
                         {m: withheld / case / "segments" / f"{m}.json" for m in maneuvers})
    prepared, fit_names, _ = prepare_all(inputs.problem, inputs.model, inputs.measured, simulator_for(inputs.model))
    selection = selection_inputs(prepared, fit_names, inputs.problem, inputs.model)
    sel = SelectionSettings.from_config(inputs.settings.get("selection"))
    features = candidate_features(selection.stacked, selection.candidates, selection.calibrate, fit_names,
                                  sel.refine_iterations)
    elapsed = time.perf_counter() - started
    forward = score_case(record, truth, draw, expected, background)
    sparse = {}
    for threshold in THRESHOLDS:
        fit = stlsq_select(features, threshold)
        variant = copy.deepcopy(record)
        items = _chosen_items(fit.terms, inputs.problem)
        variant["which"]["chosen"] = items
        variant["which"]["found_effects"] = [i["effect"] for i in items]
        sparse[threshold] = score_case(variant, truth, draw, expected, background)
    return {"case": case, "forward": forward, "sparse": sparse, "features_s": elapsed,
            "n_columns": int(features.design.shape[1])}


def _work(args: tuple) -> dict[str, Any]:
    logging.basicConfig(level=logging.WARNING)
    return score_case_files(*args)


def compare(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Both methods' measures on the cases above the forward selection's detection limits, and STLSQ's per
    threshold; the chosen threshold: the smallest naming nothing in every none case."""
    from hybridfmu_bench.withheld.report import aggregate, detection_limits

    forward_rows = [r["forward"] for r in results]
    limits = detection_limits(forward_rows)
    forward = aggregate(forward_rows, limits)
    per_threshold = {}
    for threshold in THRESHOLDS:
        rows = [r["sparse"][threshold] for r in results]
        above = aggregate(rows, limits)
        above_exact = [r for r in rows if r["case"] in forward["above_cases"]]
        per_threshold[threshold] = {
            "none_clean": above["none_clean"], "n_none": above["n_none"],
            "exact_above": sum(bool(r["exact"]) for r in above_exact) / len(above_exact) if above_exact else None,
            "exact_all": sum(bool(r["exact"]) for r in rows if r["true_effects"]) /
            max(sum(bool(r["true_effects"]) for r in rows), 1),
            "median_parameter_error_pct": _median([e for r in above_exact for e in r["parameter_error_pct"]
                                                   if isinstance(e, float)]),
            "named_per_case": float(np.mean([len(r["found_effects"]) for r in rows])),
        }
    clean = [t for t in THRESHOLDS if per_threshold[t]["none_clean"] == per_threshold[t]["n_none"]]
    chosen = clean[0] if clean else None
    forward_all = [r for r in forward_rows if r["true_effects"]]
    return {
        "n_cases": len(results), "n_above": forward["n_above"],
        "forward": {"none_clean": forward["none_clean"], "n_none": forward["n_none"],
                    "exact_above": forward["exact_set_accuracy"],
                    "exact_all": sum(bool(r["exact"]) for r in forward_all) / max(len(forward_all), 1),
                    "median_parameter_error_pct": forward["median_parameter_error_pct"],
                    "named_per_case": float(np.mean([len(r["found_effects"]) for r in forward_rows]))},
        "stlsq": per_threshold, "chosen_threshold": chosen,
        "median_features_s": float(np.median([r["features_s"] for r in results])),
    }


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100.0 * value:.0f} %"


def markdown(summary: dict[str, Any]) -> str:
    """The comparison as a Markdown table (forward selection, STLSQ at the chosen threshold, STLSQ per threshold)."""
    def row(label: str, m: dict[str, Any]) -> str:
        error = m["median_parameter_error_pct"]
        return (f"| {label} | {m['none_clean']}/{m['n_none']} | {_pct(m['exact_above'])} | {_pct(m['exact_all'])} | "
                f"{'-' if error is None else f'{error:.3g} %'} | {m['named_per_case']:.2f} |")

    lines = [f"Withheld suite, {summary['n_cases']} cases ({summary['n_above']} above the forward selection's "
             "detection limits); STLSQ on unit-length columns in noise-floor units, threshold chosen as the "
             "smallest that names nothing in every none case:", "",
             "| method | none cases clean | exact set, above limits | exact set, all effect cases | "
             "median parameter error, above limits | effects named per case |", "|---|---|---|---|---|---|",
             row("forward selection + BIC (the diagnosis)", summary["forward"])]
    chosen = summary["chosen_threshold"]
    if chosen is not None:
        lines.append(row(f"STLSQ (pysindy), threshold {chosen:g}", summary["stlsq"][chosen]))
    lines += ["", "STLSQ per threshold:", "", "| threshold | none cases clean | exact set, above limits | "
              "exact set, all effect cases | median parameter error, above limits | effects named per case |",
              "|---|---|---|---|---|---|"]
    lines += [row(f"{t:g}", m) for t, m in summary["stlsq"].items()]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=ROOT / "config" / "config.yaml")
    parser.add_argument("--withheld", type=Path, default=None, help="the suite's folder (default <results>/withheld)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--cases", default="*", help="fnmatch pattern of case names")
    parser.add_argument("--markdown", type=Path, default=None)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    config = load_case_config(args.config)
    results_dir = ROOT / config.get("results_dir", "results")
    withheld = args.withheld or results_dir / "withheld"
    fmu = results_dir / config["case"] / "fmu" / f"{config['fmu']['model_name']}.fmu"
    section = config.get("withheld", {})
    cases = sorted(p.name[:-len(".draw.json")] for p in (withheld / "cases").glob("*.draw.json"))
    cases = [c for c in cases if fnmatch.fnmatch(c, args.cases)]
    missing = [c for c in cases if not (withheld / c / "diagnosis" / "diagnosis.json").is_file()]
    if not cases or missing:
        raise SystemExit(f"{withheld}: no finished withheld suite ({len(missing)} of {len(cases)} cases without "
                         "diagnosis.json); run `snakemake -j2 withheld` first")
    jobs = [(c, withheld, fmu, section.get("expected", {}), section.get("background", {})) for c in cases]
    results, started = [], time.perf_counter()
    with multiprocessing.Pool(max(1, args.jobs)) as pool:
        for k, result in enumerate(pool.imap_unordered(_work, jobs), start=1):
            results.append(result)
            elapsed = time.perf_counter() - started
            LOG.info("%d/%d cases (%s: %d columns), %.2f cases/min, %.0f s left", k, len(jobs), result["case"],
                     result["n_columns"], 60.0 * k / elapsed, elapsed / k * (len(jobs) - k))
    results.sort(key=lambda r: r["case"])
    summary = compare(results)
    text = markdown(summary)
    print(text)
    if args.markdown:
        tmp = args.markdown.with_suffix(args.markdown.suffix + ".tmp")
        tmp.write_text(text)
        tmp.replace(args.markdown)
    print(json.dumps({k: v for k, v in summary.items()}, default=float))


if __name__ == "__main__":
    main()
