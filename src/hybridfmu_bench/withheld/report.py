"""The withheld-effect check's summary: ``summary.csv``, ``summary.md``, ``detection.png`` and ``confusion.png``.

Every case is scored by :func:`hybridfmu_bench.withheld.scoring.score_case`; this module aggregates:

- per bench effect, from its single cases: the detection rate against the effect size (the effect's RMS share of
  the equation error, see :mod:`~hybridfmu_bench.withheld.scoring`) and the measured **detection limit**:
  the smallest effect size above which every single case of the effect was detected (the smallest detected size
  above the largest missed one; "not reached" when the largest one was missed; when none was missed the limit is
  at most the smallest size tested);
- over the cases whose withheld effects are all at or above their limits (singles and pairs): the exact-set
  accuracy, the median parameter error, the median windowed shrink of the open-loop gap and the share of cases
  with a windowed shrink >= the target (3 by default; the targets: ``withheld.targets``);
- the none cases: whether nothing (but true parameter offsets) was named in every seed, and the false alarms the
  thresholds stood against: per equation, the strongest candidate rejected at the last selection step with its
  BIC drop, relative improvement, explained share and explained mean square / noise beside the thresholds of
  ``diagnosis.selection``;
- the motor parameter offsets every case carries: how often each was found and its error.

The seeds are split (``withheld.calibration_seeds``): the detection limits are set on the calibration seeds'
cases only, and the false-alarm margins shown are theirs (the seeds any threshold of ``diagnosis.selection`` may be
chosen on); the evaluation seeds' cases are scored with those limits and nothing else, so their measures are out of
sample. Every measure is reported for both; without evaluation seeds the report says its figures are in sample.

``summary.md`` has no heading of its own, so it can be copied into the documentation's block ``withheld``
(``python -m hybridfmu.evaluation.measured_blocks --block withheld=results/withheld/summary.md``).
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.diagnosis.report import table_cell
from hybridfmu.tracking.provenance import describe
from hybridfmu_bench.withheld.scoring import effect_size, rejected_candidates, score_case, selection_thresholds
from hybridfmu.io import atomic_path, read_json, write_text_atomic

__all__ = ["SUMMARY_COLUMNS", "DEFAULT_TARGETS", "summarise", "detection_limit", "detection_limits",
           "above_limits", "aggregate", "background_sizes", "confusion_matrix", "confusion_figure",
           "detection_figure", "summary_markdown", "false_alarms", "split_seeds"]

#: Columns of ``summary.csv`` (per-effect columns hold one value per withheld effect, ';'-joined in the order of
#: ``true_effects``):
#:
#: case, seed, kind (single / pair / none), stratum (size stratum of a single case, 1 = smallest);
#: true_effects; size_scale (the bench's size scale against the main case's effect); effect_size (RMS share of the
#: equation error the effect explains alone); detected (per effect); found_effects (named effects as bench
#: effects, true offsets left out); named_effects (the diagnosis' names, rank order); extra_effects (named, not
#: withheld, not a true offset); exact (found set == withheld set); where_correct (every withheld effect named in
#: an equation it acts on); named_in (per effect: the equations it was named in); parameter_error_pct (per
#: effect: |fitted - true| / |true| x 100 of its size parameter, or missed / mismatch / n/a);
#: parameter_error_with_rival_pct (per effect: the same with the named effect's first rival beside it, empty where no
#: rival moves it); true_size_parameters
#: and fitted_size_parameters (JSON: the compared values in the bench's units); true_params and fitted_params
#: (JSON: all bench parameters, all fitted physical parameters); background_found (conditions of
#: withheld.background the diagnosis named: present in every case, not extras); offsets_true (JSON: parameter -> relative offset
#: of the bench), offsets_found, offsets_missed, offset_errors_pct (JSON: |fitted - true| / |true| x 100 of the
#: relative offset); gap_before, gap_after, gap_shrink (whole test maneuver, normalised open-loop gap);
#: window_gap_before, window_gap_after, shrink_factor (the same over open-loop windows of
#: diagnosis.open_loop.window_s: before / after); effect_shrink, window_effect_shrink (the shrink of the named effects on
#: top of the parameter corrections, whole maneuver and windows: the diagnosis' effect_shrink_factor);
#: interval_covers_truth (the 90 % intervals of every fitted size parameter contain the truth; empty: none fitted);
#: ratio_to_noise (JSON: equation error / noise floor per equation); split (calibration / evaluation: the seed's
#: role); above_limit (every withheld effect at or above its detection limit set on the calibration seeds).
SUMMARY_COLUMNS = ["case", "seed", "split", "above_limit", "kind", "stratum", "true_effects", "size_scale",
                   "effect_size", "detected", "found_effects", "named_effects", "extra_effects", "exact",
                   "where_correct", "named_in", "parameter_error_pct", "parameter_error_with_rival_pct",
                   "true_size_parameters",
                   "fitted_size_parameters", "true_params", "fitted_params", "background_found", "offsets_true",
                   "offsets_found", "offsets_missed", "offset_errors_pct", "gap_before", "gap_after", "gap_shrink",
                   "window_gap_before", "window_gap_after", "shrink_factor", "effect_shrink", "window_effect_shrink",
                   "interval_covers_truth", "ratio_to_noise"]

#: Targets of the check (``withheld.targets`` overrides them).
DEFAULT_TARGETS = {"exact_set_accuracy": 0.9, "median_parameter_error_pct": 15.0, "windowed_shrink": 3.0}


# ----------------------------------------------------------------------------------------- detection

def detection_limit(points: list[tuple[float | None, bool]]) -> dict[str, Any]:
    """The detection limit from (effect size, detected) points of one effect.

    Returns ``limit`` (the smallest detected size above the largest missed one; None when not reached),
    ``reached`` (False when the largest size was missed or there is no point), ``all_detected`` (then the limit is
    the smallest size tested, an upper bound), ``largest_missed``, ``n`` and ``n_detected`` (points with a size).
    """
    pts = sorted((float(s), bool(d)) for s, d in points if s is not None and math.isfinite(float(s)))
    out = {"limit": None, "reached": False, "all_detected": False, "largest_missed": None, "n": len(pts),
           "n_detected": sum(d for _, d in pts)}
    if not pts:
        return out
    missed = [s for s, d in pts if not d]
    if not missed:
        out.update(limit=pts[0][0], reached=True, all_detected=True)
        return out
    out["largest_missed"] = max(missed)
    above = [s for s, d in pts if s > out["largest_missed"]]
    if above:
        out.update(limit=min(above), reached=True)
    return out


def _single_points(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    points: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if r["kind"] != "single":
            continue
        effect = r["true_effects"][0]
        points.setdefault(effect, []).append({"effect_size": r["effect_size"][0], "detected": r["detected"][0],
                                              "size_scale": r["size_scale"][0], "case": r["case"]})
    return points


def detection_limits(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per bench effect (from its single cases): :func:`detection_limit` plus ``size_scale_at_limit`` (the bench
    size scale of the case at the limit) and ``detection_rate``."""
    out = {}
    for effect, pts in sorted(_single_points(rows).items()):
        limit = detection_limit([(p["effect_size"], p["detected"]) for p in pts])
        at = [p["size_scale"] for p in pts if limit["limit"] is not None and p["effect_size"] == limit["limit"]]
        limit["size_scale_at_limit"] = at[0] if at else None
        limit["detection_rate"] = sum(p["detected"] for p in pts) / len(pts) if pts else None
        limit["cases"] = len(pts)
        out[effect] = limit
    return out


def background_sizes(records: dict[str, dict[str, Any]], rows: list[dict[str, Any]],
                     expected: dict[str, list[str]]) -> dict[str, float | None]:
    """Per bench effect with single cases: the median of its effect-size measure in the none cases (what its
    candidates explain where the bench has no effect, e.g. surrogates of the parameter offsets): effect sizes
    near it are not evidence of the effect."""
    nones = [records[r["case"]] for r in rows if r["kind"] == "none"]
    out = {}
    for effect in sorted(_single_points(rows)):
        values = [v for v in (effect_size(rec, list(expected.get(effect, []))) for rec in nones) if v is not None]
        out[effect] = _median(values)
    return out


def above_limits(row: dict[str, Any], limits: dict[str, dict[str, Any]]) -> bool:
    """True when the case has withheld effects and every one's effect size is at or above its reached limit."""
    if not row["true_effects"]:
        return False
    for effect, size in zip(row["true_effects"], row["effect_size"]):
        limit = limits.get(effect) or {}
        if not limit.get("reached") or size is None or size < limit["limit"]:
            return False
    return True


def _coverage(rows: list[dict[str, Any]]) -> dict[str, dict[str, int]]:
    """Per bench effect: how many fitted size parameters' 90 % intervals contain the truth (``covered``), of how many
    that have one (``n``), over every case."""
    out: dict[str, dict[str, int]] = {}
    for row in rows:
        for detail in row.get("effects_detail") or []:
            covers = detail.get("interval_covers_truth")
            if covers is None:
                continue
            entry = out.setdefault(detail["effect"], {"covered": 0, "n": 0})
            entry["covered"] += bool(covers)
            entry["n"] += 1
    return out


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def aggregate(rows: list[dict[str, Any]], limits: dict[str, dict[str, Any]],
              targets: dict[str, float] | None = None) -> dict[str, Any]:
    """The check's measures and verdicts (module docstring). A verdict is True (met), False (not met) or None (no
    case to judge on)."""
    targets = {**DEFAULT_TARGETS, **(targets or {})}
    above = [r for r in rows if above_limits(r, limits)]
    errors = [e for r in above for e in r["parameter_error_pct"] if isinstance(e, float)]
    mismatches = sum(e == "mismatch" for r in above for e in r["parameter_error_pct"])
    # the same estimates, each with its first rival beside it where one moves it
    pairs = [(e, w) for r in above
             for e, w in zip(r["parameter_error_pct"],
                             r.get("parameter_error_with_rival_pct") or [None] * len(r["parameter_error_pct"]))
             if isinstance(e, float)]
    errors_rival = [w if isinstance(w, float) else e for e, w in pairs]
    shrinks = [r["shrink_factor"] for r in above if r["shrink_factor"] is not None]
    whole = [r["gap_shrink"] for r in above if r["gap_shrink"] is not None]
    nones = [r for r in rows if r["kind"] == "none"]
    with_effects = [r for r in rows if r["true_effects"]]
    effect_shrinks = [r["window_effect_shrink"] for r in above if r["exact"] and r.get("window_effect_shrink") is not None]
    none_shrinks = [r["window_effect_shrink"] for r in nones if r.get("window_effect_shrink") is not None]
    exact = sum(bool(r["exact"]) for r in above) / len(above) if above else None
    median_error = _median(errors)
    median_shrink = _median(shrinks)
    result = {
        "n_cases": len(rows), "n_with_effects": sum(bool(r["true_effects"]) for r in rows), "n_above": len(above),
        "above_cases": [r["case"] for r in above],
        "exact_set_accuracy": exact, "n_exact": sum(bool(r["exact"]) for r in above),
        "exact_set_accuracy_all": sum(bool(r["exact"]) for r in with_effects) / len(with_effects)
        if with_effects else None, "n_exact_all": sum(bool(r["exact"]) for r in with_effects),
        "median_parameter_error_pct": median_error, "n_parameter_errors": len(errors), "n_mismatches": mismatches,
        "median_parameter_error_with_rival_pct": _median(errors_rival),
        "n_with_rival": sum(isinstance(w, float) for _, w in pairs),
        "median_windowed_shrink": median_shrink, "n_shrinks": len(shrinks),
        "fraction_windowed_shrink_at_target": sum(s >= targets["windowed_shrink"] for s in shrinks) / len(shrinks)
        if shrinks else None,
        "median_whole_shrink": _median(whole),
        "median_window_effect_shrink_exact": _median(effect_shrinks), "n_effect_shrinks": len(effect_shrinks),
        "max_window_effect_shrink_none": max(none_shrinks) if none_shrinks else None,
        "interval_coverage": _coverage(rows),
        "where_correct": sum(bool(r["where_correct"]) for r in above) / len(above) if above else None,
        "n_none": len(nones), "none_clean": sum(bool(r["exact"]) for r in nones),
        "targets": targets,
    }
    result["verdicts"] = {
        "exact_set_accuracy": None if exact is None else exact >= targets["exact_set_accuracy"],
        "median_parameter_error_pct": None if median_error is None
        else median_error <= targets["median_parameter_error_pct"],
        "windowed_shrink": None if median_shrink is None else median_shrink >= targets["windowed_shrink"],
        "none_names_nothing": None if not nones else all(r["exact"] for r in nones),
    }
    return result


def per_effect_errors(rows: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per bench effect over ``rows``: the parameter errors (%) of its estimates, ``n``, ``median``, ``min``, ``max``,
    ``median_with_rival`` (each with its first rival beside it where one moves it) and ``n_with_rival``."""
    out: dict[str, dict[str, Any]] = {}
    for r in rows:
        rival = r.get("parameter_error_with_rival_pct") or [None] * len(r["true_effects"])
        for effect, error, with_rival in zip(r["true_effects"], r["parameter_error_pct"], rival):
            if not isinstance(error, float):
                continue
            entry = out.setdefault(effect, {"errors": [], "with_rival": [], "n_with_rival": 0})
            entry["errors"].append(error)
            entry["with_rival"].append(with_rival if isinstance(with_rival, float) else error)
            entry["n_with_rival"] += isinstance(with_rival, float)
    return {effect: {"n": len(e["errors"]), "median": _median(e["errors"]), "min": min(e["errors"]),
                     "max": max(e["errors"]), "median_with_rival": _median(e["with_rival"]),
                     "n_with_rival": e["n_with_rival"]} for effect, e in sorted(out.items())}


def false_alarms(records: dict[str, dict[str, Any]], rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """For the none cases: per equation the strongest rejected candidate
    (:func:`~hybridfmu_bench.withheld.scoring.rejected_candidates`) with the case id."""
    out = []
    for r in rows:
        if r["kind"] == "none":
            out += [{"case": r["case"], **item} for item in rejected_candidates(records[r["case"]])]
    return out


# ----------------------------------------------------------------------------------------- confusion

def confusion_matrix(rows: list[dict[str, Any]]) -> tuple[list[str], np.ndarray]:
    """Detection matrix over the cases, rows = withheld effect, columns = found effect (same labels, "none" last).

    Per case: a withheld effect that was found counts on the diagonal, one that was missed in the "none" column;
    an extra (found, not withheld; true parameter offsets are not found effects) counts in the "none" row; a case
    without effects that finds nothing counts at ("none", "none"). ``true_effects``/``found_effects``: lists.
    """
    effects = sorted({e for r in rows for key in ("true_effects", "found_effects") for e in r[key]})
    labels = effects + ["none"]
    matrix = np.zeros((len(labels), len(labels)), dtype=int)
    for r in rows:
        true, found = list(r["true_effects"]), list(r["found_effects"])
        for effect in true:
            column = effect if effect in found else "none"
            matrix[labels.index(effect), labels.index(column)] += 1
        for effect in found:
            if effect not in true:
                matrix[labels.index("none"), labels.index(effect)] += 1
        if not true and not found:
            matrix[labels.index("none"), labels.index("none")] += 1
    return labels, matrix


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def confusion_figure(rows: list[dict[str, Any]], path: str | Path, dpi: int = 120) -> Path:
    """Confusion matrix (counts of cases) of withheld (rows) against found (columns) effects."""
    plt = _pyplot()
    labels, matrix = confusion_matrix(rows)
    fig, ax = plt.subplots(figsize=(2.5 + 0.8 * len(labels), 1.8 + 0.6 * len(labels)))
    ax.imshow(matrix, cmap="Blues", vmin=0, vmax=max(int(matrix.max()), 1))
    for i in range(matrix.shape[0]):
        for j in range(matrix.shape[1]):
            if matrix[i, j]:
                ax.text(j, i, str(matrix[i, j]), ha="center", va="center",
                        color="white" if matrix[i, j] > matrix.max() / 2 else "black")
    ax.set_xticks(range(len(labels)), labels, rotation=40, ha="right", fontsize=8)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ax.set_xlabel("effect found by the diagnosis (none = missed); count of cases")
    ax.set_ylabel("effect withheld from the FMU (none = found although not withheld)")
    ax.set_title(f"Withheld-effect check: detections over {len(rows)} cases (all sizes)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)


def detection_figure(rows: list[dict[str, Any]], limits: dict[str, dict[str, Any]], path: str | Path,
                     background: dict[str, float | None] | None = None, dpi: int = 120, bins: int = 5) -> Path:
    """Detection against effect size, one panel per bench effect (its single cases): every case as a point at
    1 (detected) or 0 (missed), the detection rate in ``bins`` log-spaced bins over all effect sizes (at the
    geometric mean size of the bin's cases), the measured detection limit (dashed) and the effect-size measure in
    the none cases (dotted, :func:`background_sizes`). x: effect size (RMS share of the equation error, -, log)."""
    background = background or {}
    plt = _pyplot()
    points = _single_points(rows)
    effects = sorted(points) or ["(no single case)"]
    sizes = [p["effect_size"] for pts in points.values() for p in pts if p["effect_size"]]
    floor = 1e-3
    lo = max(min(sizes), floor) if sizes else floor
    hi = max(max(sizes), lo * 10) if sizes else 1.0
    edges = np.geomspace(lo * 0.999, hi * 1.001, bins + 1)
    ncols = min(len(effects), 4)
    nrows = math.ceil(len(effects) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.4 * ncols, 2.8 * nrows), squeeze=False, sharex=True,
                             sharey=True)
    for ax in axes.flat[len(effects):]:
        ax.set_visible(False)
    for ax, effect in zip(axes.flat, effects):
        pts = points.get(effect, [])
        x = np.array([max(p["effect_size"] or floor, floor) for p in pts])
        y = np.array([1.0 if p["detected"] else 0.0 for p in pts])
        ax.scatter(x[y > 0], y[y > 0], s=18, color="tab:green", zorder=3, label="case detected")
        ax.scatter(x[y == 0], y[y == 0], s=18, color="tab:red", zorder=3, label="case missed")
        centres, rates = [], []
        for a, b in zip(edges[:-1], edges[1:]):
            inside = (x >= a) & (x < b)
            if inside.any():
                centres.append(float(np.exp(np.mean(np.log(x[inside])))))
                rates.append(float(y[inside].mean()))
        if centres:
            ax.plot(centres, rates, "-o", color="tab:blue", markersize=3, label="detection rate (log bins)")
        if background.get(effect):
            ax.axvline(max(background[effect], floor), color="grey", linestyle=":", linewidth=1.2,
                       label="effect size in the none cases")
        limit = limits.get(effect) or {}
        if limit.get("reached"):
            ax.axvline(limit["limit"], color="k", linestyle="--", linewidth=1, label="measured limit")
            title = f"{effect}\nlimit " + ("≤ " if limit["all_detected"] else "") + f"{limit['limit']:.3g}"
        else:
            title = f"{effect}\nlimit not reached"
        ax.set_title(title, fontsize=9)
        ax.set_xscale("log")
        ax.set_ylim(-0.1, 1.1)
        ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("effect size: RMS share of the equation error (-)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("detected (1) / missed (0); rate (-)", fontsize=8)
    legend: dict[str, Any] = {}
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    fig.legend(list(legend.values()), list(legend), fontsize=7, loc="lower center", ncol=5, frameon=False)
    fig.suptitle("Withheld-effect check: detection against effect size (single cases, all seeds)", fontsize=10)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
    return Path(path)


# ----------------------------------------------------------------------------------------- markdown

def _num(value: Any, digits: int = 3) -> str:
    if value is None or isinstance(value, str):
        return "–" if value is None else value
    if isinstance(value, float) and not math.isfinite(value):
        return "–"
    return f"{float(value):.{digits}g}"


def _pct(value: float | None) -> str:
    return "–" if value is None else f"{100 * value:.0f} %"


def _names(values: list[str]) -> str:
    return table_cell(", ".join(values) or "none")


def _verdict(value: bool | None) -> str:
    return "no case to judge" if value is None else ("met" if value else "NOT met")


def split_seeds(seeds: list[int], calibration_seeds: list[int] | None) -> dict[int, str]:
    """Seed -> ``calibration`` or ``evaluation``: the seeds of ``withheld.calibration_seeds`` (all of them when it is
    None) calibrate, the others evaluate."""
    chosen = set(seeds if calibration_seeds is None else calibration_seeds)
    return {int(seed): "calibration" if seed in chosen else "evaluation" for seed in seeds}


#: the measures of the README's short table (:func:`headline_markdown`), keys of :func:`_measure_rows`
HEADLINE_MEASURES = ("exact_above", "exact_all", "parameter_error", "effect_shrink_exact", "effect_shrink_none",
                     "none_clean")


def _measure_rows(by_split: dict[str, dict[str, Any] | None], only: tuple[str, ...] | None = None) -> list[str]:
    """The measures table: one column per split (calibration, evaluation), target, verdict (on the evaluation seeds
    when there are any); ``only``: the keys of the rows to show (all by default), in the table's order."""
    splits = [name for name, m in by_split.items() if m is not None]
    judged = by_split.get("evaluation") or by_split["calibration"]
    t, v = judged["targets"], judged["verdicts"]

    def row(label: str, cell, target: str = "–", verdict: str = "–") -> str:
        return f"| {label} | " + " | ".join(cell(by_split[name]) for name in splits) + f" | {target} | {verdict} |"

    def mismatches(m):
        return f", {m['n_mismatches']} mismatch" if m["n_mismatches"] else ""

    w = _num(t["windowed_shrink"])
    rows = [
        ("n_above", row("cases with effects, all at or above their limits",
                        lambda m: f"{m['n_above']} of {m['n_with_effects']}")),
        ("exact_above", row("exact set of named effects, cases above the limits (an extra or a miss is an error)",
                            lambda m: f"{_pct(m['exact_set_accuracy'])} ({m['n_exact']}/{m['n_above']})",
                            f"≥ {_pct(t['exact_set_accuracy'])}", _verdict(v["exact_set_accuracy"]))),
        ("exact_all", row("exact set of named effects, every case with effects (no limit applied)",
                          lambda m: f"{_pct(m['exact_set_accuracy_all'])} ({m['n_exact_all']}/{m['n_with_effects']})")),
        ("parameter_error", row("median parameter error, cases above the limits",
                                lambda m: f"{_num(m['median_parameter_error_pct'])} % (n = {m['n_parameter_errors']}"
                                          f"{mismatches(m)})",
                                f"≤ {_num(t['median_parameter_error_pct'])} %",
                                _verdict(v["median_parameter_error_pct"]))),
        ("parameter_error_rival", row("the same, each estimate with its first rival beside it where one moves it",
                                      lambda m: f"{_num(m.get('median_parameter_error_with_rival_pct'))} % "
                                                f"({m.get('n_with_rival', 0)} of {m['n_parameter_errors']} moved)")),
        ("windowed_shrink", row("median windowed shrink of the open-loop gap, cases above the limits",
                                lambda m: f"×{_num(m['median_windowed_shrink'])} (n = {m['n_shrinks']})", f"≥ ×{w}",
                                _verdict(v["windowed_shrink"]))),
        ("shrink_at_target", row(f"cases with windowed shrink ≥ ×{w}",
                                 lambda m: _pct(m["fraction_windowed_shrink_at_target"]))),
        ("whole_shrink", row("median whole-maneuver shrink", lambda m: f"×{_num(m['median_whole_shrink'])}")),
        ("effect_shrink_exact", row("median windowed shrink of the named effects on top of the parameter "
                                    "corrections, exact cases",
                                    lambda m: f"×{_num(m.get('median_window_effect_shrink_exact'))} "
                                              f"(n = {m.get('n_effect_shrinks', 0)})")),
        ("effect_shrink_none", row("largest windowed shrink of the named effects, none cases",
                                   lambda m: f"×{_num(m.get('max_window_effect_shrink_none'))}")),
        ("where", row("named in the equation it acts on", lambda m: _pct(m["where_correct"]))),
        ("none_clean", row("none case names nothing (every seed)", lambda m: f"{m['none_clean']}/{m['n_none']}",
                           "all", _verdict(v["none_names_nothing"]))),
    ]
    header = ["| measure | " + " | ".join(f"{name} seeds" for name in splits) + " | target | verdict |",
              "|---|" + "---|" * len(splits) + "---|---|"]
    return header + [text for key, text in rows if only is None or key in only] + [""]


def code_versions(records: dict[str, dict[str, Any]]) -> dict[str, int]:
    """Which code diagnosed the cases: short version name (:func:`hybridfmu.tracking.provenance.describe` of a
    record's ``code``) -> number of cases, most cases first."""
    counts: dict[str, int] = {}
    for record in records.values():
        name = describe(record.get("code"))
        counts[name] = counts.get(name, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def settings_versions(records: dict[str, dict[str, Any]]) -> dict[str, list[str]]:
    """Which diagnosis settings the cases were diagnosed with: ``settings_digest`` of each record
    (:func:`hybridfmu.diagnosis.report.settings_digest`; ``unrecorded`` for records from before it) -> the cases,
    most cases first."""
    groups: dict[str, list[str]] = {}
    for case, record in records.items():
        groups.setdefault(str(record.get("settings_digest") or "unrecorded"), []).append(case)
    return dict(sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0])))


def settings_sentence(groups: dict[str, list[str]]) -> str:
    """What :func:`settings_versions` says, for the summaries: nothing when every case shares its settings, else a
    warning naming each group (a suite resumed after a change of the diagnosis section, or cases copied from another
    suite, mixes settings, so its figures belong to none of them)."""
    known = {digest: cases for digest, cases in groups.items() if digest != "unrecorded"}
    if len(known) <= 1:
        return ""
    listed = "; ".join(f"{digest}: {len(cases)} case{'s' if len(cases) != 1 else ''} (e.g. {sorted(cases)[0]})"
                       for digest, cases in groups.items())
    return (f"**WARNING: the cases were diagnosed with {len(known)} different diagnosis settings** ({listed}); "
            "these figures belong to none of them (regenerate the cases' configs, `snakemake -j2 withheld --forcerun "
            "withheld_case`, and diagnose them again).")


def code_sentence(versions: dict[str, int]) -> str:
    """What :func:`code_versions` says, as a sentence for the summaries: one version named, or a warning that a run
    resumed across a code change mixes the cases of several."""
    if len(versions) == 1:
        name = next(iter(versions))
        if name == describe(None):
            return "The diagnoses do not record the code that made them."
        return f"Every case was diagnosed by the code at {name}."
    listed = ", ".join(f"{name}: {n} case{'s' if n != 1 else ''}" for name, n in versions.items())
    return (f"**WARNING: the cases were diagnosed by {len(versions)} versions of the code** ({listed}); a run resumed "
            "across a code change mixes them, so these figures belong to no one version (`snakemake -j2 withheld "
            "--forcerun withheld_diagnose` diagnoses every case again).")


def headline_markdown(by_split: dict[str, dict[str, Any] | None], settings: dict[str, Any]) -> str:
    """The README's short account of the check: which seeds calibrate and which evaluate, and the measures of
    :data:`HEADLINE_MEASURES` per split (every number from the run; the full account is ``summary.md``)."""
    seeds = settings.get("seeds", [])
    calibration_seeds = settings.get("calibration_seeds") or seeds
    evaluation_seeds = [s for s in seeds if s not in calibration_seeds]
    n_cases = sum((m or {}).get("n_cases", 0) for m in by_split.values())
    if evaluation_seeds:
        intro = (f"Diagnosis checked on {n_cases} emulated cases with effects withheld from the FMU: the detection "
                 f"limits are set on the cases of seeds {', '.join(map(str, calibration_seeds))}; the cases of seeds "
                 f"{', '.join(map(str, evaluation_seeds))} are scored with them (out of sample; the verdict judges "
                 "them).")
    else:
        intro = (f"Diagnosis checked on {n_cases} emulated cases with effects withheld from the FMU; every seed sets "
                 "the detection limits it is judged by (in sample).")
    if settings.get("code"):
        intro += " " + code_sentence(settings["code"])
    mixed = settings_sentence(settings.get("diagnosis_settings") or {})
    if mixed:
        intro += " " + mixed
    return "\n".join([intro, "", *_measure_rows(by_split, HEADLINE_MEASURES)])


def summary_markdown(rows: list[dict[str, Any]], limits: dict[str, dict[str, Any]],
                     by_split: dict[str, dict[str, Any] | None], alarms: list[dict[str, Any]],
                     thresholds: dict[str, float], settings: dict[str, Any],
                     background: dict[str, float | None] | None = None) -> str:
    """The Markdown block of the check (no heading; every number from the run). ``limits``: set on the calibration
    seeds' cases; ``by_split``: :func:`aggregate` of the ``calibration`` and the ``evaluation`` seeds' cases (None
    without evaluation seeds); ``settings``: the suite's ``seeds``, ``calibration_seeds``, ``size_range``,
    ``sizes_per_effect``, ``offset_scale_range`` (from the draw records), ``code`` (:func:`code_versions`);
    ``background``: :func:`background_sizes`."""
    background = background or {}
    seeds = ", ".join(str(s) for s in settings.get("seeds", []))
    calibration_seeds = settings.get("calibration_seeds") or settings.get("seeds", [])
    evaluation_seeds = [s for s in settings.get("seeds", []) if s not in calibration_seeds]
    size_lo, size_hi = settings.get("size_range") or (None, None)
    offset_lo, offset_hi = settings.get("offset_scale_range") or (None, None)
    kinds = {kind: sum(r["kind"] == kind for r in rows) for kind in ("single", "pair", "none")}
    calibration_rows = [r for r in rows if r.get("split", "calibration") == "calibration"]
    if evaluation_seeds:
        split = (f"Seeds {', '.join(map(str, calibration_seeds))} calibrate: the detection limits are set on their "
                 "cases, and the false-alarm margins below are theirs (the cases any threshold of diagnosis.selection "
                 f"may be chosen on). Seeds {', '.join(map(str, evaluation_seeds))} evaluate: their cases are scored "
                 "with those limits and change nothing, so their column is out of sample.")
    else:
        split = ("Every seed calibrates (withheld.calibration_seeds holds them all; no evaluation seed): the "
                 "detection limits are set on the same cases they judge, so every figure below is in sample.")
    if settings.get("code"):
        split += " " + code_sentence(settings["code"])
    mixed = settings_sentence(settings.get("diagnosis_settings") or {})
    if mixed:
        split += " " + mixed
    lines = [
        f"Withheld-effect check: {len(rows)} cases (seeds {seeds}: {kinds['single']} single, "
        f"{kinds['pair']} pair, {kinds['none']} none), whose bench has effects the FMU lacks (size scale "
        f"{_num(size_lo)}–{_num(size_hi)} x the demo's, {settings.get('sizes_per_effect')} log strata per effect and "
        f"seed) and motor parameter offsets (x{_num(offset_lo)}–{_num(offset_hi)} the demo bench's). Effect size = the RMS share of the equation error left by the calibrated parameter "
        "errors that the effect explains alone (square root of its best first-step relative improvement; for an "
        "effect named as a parameter error, the share it removes entering last); in the none cases it measures "
        "what the effect's candidates explain without the effect.",
        "",
        split,
        "",
        "Single cases of the calibration seeds, which set the limits:",
        "",
        "| bench effect | single cases | detected | detection limit (effect size) | size scale at the limit | "
        "effect size in the none cases | median parameter error | named where it acts |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for effect, limit in limits.items():
        singles = [r for r in calibration_rows if r["kind"] == "single" and r["true_effects"] == [effect]]
        errors = [r["parameter_error_pct"][0] for r in singles if isinstance(r["parameter_error_pct"][0], float)]
        mismatch = sum(r["parameter_error_pct"][0] == "mismatch" for r in singles)
        detected = [r for r in singles if r["detected"][0]]
        where = sum(bool(r["where_correct"]) for r in detected)
        if limit["reached"]:
            text = ("≤ " if limit["all_detected"] else "") + _num(limit["limit"])
        else:
            text = "not reached"
        lines.append(f"| {effect} | {limit['cases']} | {limit['n_detected']}/{limit['n']} | {text} | "
                     f"{_num(limit['size_scale_at_limit'])} | {_num(background.get(effect))} | "
                     f"{_num(_median(errors))} %{f' ({mismatch} mismatch)' if mismatch else ''} | "
                     f"{where}/{len(detected)} |")
    lines += ["", "Measures per split of the seeds (limits from the calibration seeds; the verdict judges the "
              + ("evaluation seeds):" if evaluation_seeds else "calibration seeds, in sample):"), ""]
    lines += _measure_rows(by_split)
    coverage = (by_split.get("evaluation") or by_split["calibration"]).get("interval_coverage") or {}
    if coverage:
        lines += ["90 % intervals of the fitted size parameters (combined uncertainty, "
                  "hybridfmu.diagnosis.identification) that contain the truth, every case of the "
                  + ("evaluation" if evaluation_seeds else "calibration") + " seeds:", "",
                  "| bench effect | covered | share |", "|---|---|---|"]
        lines += [f"| {effect} | {c['covered']}/{c['n']} | {_pct(c['covered'] / c['n'])} |"
                  for effect, c in sorted(coverage.items())]
        lines.append("")
    judged = [r for r in rows if r.get("split", "calibration") == ("evaluation" if evaluation_seeds else "calibration")
              and above_limits(r, limits)]
    per_effect = per_effect_errors(judged)
    if per_effect:
        lines += ["Parameter error per bench effect, cases above the limits of the "
                  + ("evaluation" if evaluation_seeds else "calibration")
                  + " seeds (median [min – max]; with the rival: each estimate with its first rival beside it "
                  "where one moves it):", "",
                  "| bench effect | estimates | median parameter error | with the rival | moved by a rival |",
                  "|---|---|---|---|---|"]
        lines += [f"| {effect} | {e['n']} | {_num(e['median'])} % [{_num(e['min'])} – {_num(e['max'])}] | "
                  f"{_num(e['median_with_rival'])} % | {e['n_with_rival']} |" for effect, e in per_effect.items()]
        lines.append("")
    lines += _offset_lines(rows)
    lines += _alarm_lines(alarms, thresholds)
    errors = [r for r in rows if (r.get("above_limit") and not r["exact"]) or (r["kind"] == "none" and not r["exact"])]
    if errors:
        lines += ["Wrong sets (cases above the limits, and none cases):", "",
                  "| case | split | withheld | found | effect size | named |", "|---|---|---|---|---|---|"]
        lines += [f"| {r['case']} | {r.get('split', 'calibration')} | {_names(r['true_effects'])} | "
                  f"{_names(r['found_effects'])} | {', '.join(_num(s) for s in r['effect_size']) or '–'} | "
                  f"{_names(r['named_effects'])} |" for r in errors]
        lines.append("")
    pairs = [r for r in rows if r["kind"] == "pair"]
    if pairs:
        lines += ["| pair case | split | effect sizes | found | exact | parameter errors (%) | windowed shrink | "
                  "of it the named effects' |", "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {r['case']} | {r.get('split', 'calibration')} | "
                  f"{', '.join(f'{e} {_num(s)}' for e, s in zip(r['true_effects'], r['effect_size']))}"
                  f" | {_names(r['found_effects'])} | {r['exact']} | "
                  f"{', '.join(_num(e) for e in r['parameter_error_pct'])} | ×{_num(r['shrink_factor'])} | "
                  f"×{_num(r.get('window_effect_shrink'))} |"
                  for r in pairs]
        lines.append("")
    lines += ["Windowed shrink: the normalised open-loop gap over windows started from the measured state (their "
              "length diagnosis.open_loop.window_s, by default chosen on each case's fitting maneuvers: how long the "
              "model alone stays near the data), FMU before / FMU + the named effects after; whole-maneuver: the same over "
              "the whole test maneuver; the named effects': FMU with only the named parameter errors corrected before / "
              "FMU + the named effects after (about ×1 where the named effects explain nothing on the test data). Per case: {files[0]}; figures: {files[1]} (detection against effect size per "
              "effect), {files[2]} (withheld against found effects).".format(files=settings.get("files") or
                                                                          ("summary.csv", "detection.png",
                                                                           "confusion.png")), ""]
    return "\n".join(lines)


def _offset_lines(rows: list[dict[str, Any]]) -> list[str]:
    found: dict[str, list[float | None]] = {}
    total: dict[str, int] = {}
    for r in rows:
        for p in r["offsets_true"]:
            total[p] = total.get(p, 0) + 1
        for p in r["offsets_found"]:
            found.setdefault(p, []).append(r["offset_errors_pct"].get(p))
    if not total:
        return []
    lines = ["Motor parameter offsets (every case; the FMU keeps its nominal values): a named parameter(<p>) for an "
             "offset parameter is a correct finding, not an extra.", "",
             "| parameter | found in | median error of the relative offset |", "|---|---|---|"]
    for p in sorted(total):
        errors = [e for e in found.get(p, []) if e is not None]
        lines.append(f"| {p} | {len(found.get(p, []))}/{total[p]} | {_num(_median(errors))} % |")
    return lines + [""]


def _alarm_lines(alarms: list[dict[str, Any]], thresholds: dict[str, float]) -> list[str]:
    if not alarms:
        return []
    th = thresholds
    lines = ["False alarms the thresholds stood against (none cases: per equation, the strongest candidate rejected "
             "at the last selection step; thresholds of diagnosis.selection):", "",
             f"| case | equation | accepted before | strongest rejected | "
             f"BIC drop (≥ {_num(th.get('min_bic_drop'))}) | "
             f"relative improvement (≥ {_num(th.get('min_relative_improvement'))}) | explained share "
             f"(≥ {_num(th.get('min_share_of_initial'))}) | "
             f"explained / noise (≥ {_num(th.get('min_explained_to_noise'))})"
             " | reason |",
             "|---|---|---|---|---|---|---|---|---|"]
    for a in alarms:
        lines.append(f"| {a['case']} | {a['equation']} | {_names(a['chosen_before'])} | {table_cell(a['effect'] or '–')} | "
                     f"{_num(a['bic_drop'])} | {_num(a['relative_improvement'])} | {_num(a['explained_share'])} | "
                     f"{_num(a['explained_to_noise'])} | {table_cell(a['reason'] or '–')} |")
    return lines + [""]


# ----------------------------------------------------------------------------------------- files

def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else ""
    if isinstance(value, list):
        return ";".join("nan" if v is None else _cell(v) for v in value)
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, default=float)
    return str(value)


def write_csv(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """``summary.csv`` (columns :data:`SUMMARY_COLUMNS`)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=SUMMARY_COLUMNS)
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _cell(row[k]) for k in SUMMARY_COLUMNS})
    return write_text_atomic(path, buffer.getvalue())


def summarise(names: list[str], diagnosis_paths: list[str | Path], truth_paths: list[str | Path],
              draw_paths: list[str | Path], csv_path: str | Path, confusion_path: str | Path,
              detection_path: str | Path, markdown_path: str | Path, expected: dict[str, list[str]] | None = None,
              targets: dict[str, float] | None = None,
              background: dict[str, list[str]] | None = None,
              calibration_seeds: list[int] | None = None,
              headline_path: str | Path | None = None) -> dict[str, Any]:
    """Score every case against its ground truth and write the CSV, the figures, the Markdown block and (to
    ``headline_path``, if given) the README's short account (:func:`headline_markdown`).

    Args:
        names: case ids; ``diagnosis_paths``, ``truth_paths`` (one truth file per case, any maneuver),
            ``draw_paths``: the case's ``diagnosis.json``, truth and draw record, in the same order.
        expected: ``withheld.expected`` (bench effect -> diagnosis effect name patterns).
        targets: ``withheld.targets`` (over :data:`DEFAULT_TARGETS`).
        background: ``withheld.background`` (condition present in every case -> diagnosis effect name patterns).
        calibration_seeds: ``withheld.calibration_seeds`` (None: every seed calibrates, nothing is out of sample).

    Returns:
        ``rows`` (scored cases with their ``split`` and ``above_limit``), ``limits`` (per effect, from the
        calibration seeds), ``by_split`` (:func:`aggregate` with verdicts of the ``calibration`` and the
        ``evaluation`` seeds, None without any), ``measures`` (the evaluation seeds', else the calibration seeds'),
        ``alarms`` (calibration seeds), ``background`` (:func:`background_sizes`).
    """
    if not (len(names) == len(diagnosis_paths) == len(truth_paths) == len(draw_paths)):
        raise ValueError("withheld summary: expected one diagnosis, truth and draw file per case, got "
                         f"{len(names)} cases, {len(diagnosis_paths)}, {len(truth_paths)} and {len(draw_paths)} files")
    expected = dict(expected or {})
    records, draws, rows = {}, {}, []
    for name, d, t, w in zip(names, diagnosis_paths, truth_paths, draw_paths):
        records[name], draws[name] = read_json(d), read_json(w)
        row = score_case(records[name], read_json(t), draws[name], expected, background)
        if row["case"] != name:
            raise ValueError(f"{w}: draw record of case {row['case']!r}, expected {name!r}")
        rows.append(row)
    seeds = sorted({d["seed"] for d in draws.values()})
    unknown = sorted(set(calibration_seeds or []) - set(seeds))
    if unknown:
        raise ValueError(f"config.withheld.calibration_seeds: {unknown} are not seeds of the suite {seeds}")
    split = split_seeds(seeds, calibration_seeds)
    for row in rows:
        row["split"] = split[int(row["seed"])]
    calibration_rows = [r for r in rows if r["split"] == "calibration"]
    evaluation_rows = [r for r in rows if r["split"] == "evaluation"]
    limits = detection_limits(calibration_rows)
    for row in rows:
        row["above_limit"] = above_limits(row, limits)
    by_split = {"calibration": aggregate(calibration_rows, limits, targets),
                "evaluation": aggregate(evaluation_rows, limits, targets) if evaluation_rows else None}
    alarms = false_alarms(records, calibration_rows)
    thresholds = selection_thresholds(next(iter(records.values()))) if records else {}
    first = next(iter(draws.values()), {})
    settings = {"seeds": seeds, "calibration_seeds": [s for s in seeds if split[s] == "calibration"],
                "size_range": first.get("size_range"),
                "sizes_per_effect": max((d.get("strata") or 0 for d in draws.values()), default=0) or "–",
                "offset_scale_range": first.get("offset_scale_range"), "code": code_versions(records),
                "diagnosis_settings": settings_versions(records),
                "files": [Path(p).name for p in (csv_path, detection_path, confusion_path)]}
    write_csv(rows, csv_path)
    confusion_figure(rows, confusion_path)
    background = background_sizes(records, calibration_rows, expected)
    detection_figure(calibration_rows, limits, detection_path, background)
    write_text_atomic(markdown_path, summary_markdown(rows, limits, by_split, alarms, thresholds, settings, background))
    if headline_path is not None:
        write_text_atomic(headline_path, headline_markdown(by_split, settings))
    return {"rows": rows, "limits": limits, "measures": by_split["evaluation"] or by_split["calibration"],
            "by_split": by_split, "alarms": alarms, "background": background}

