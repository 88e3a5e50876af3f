"""One table of every case's held-out results, as the README's headline quotes them.

Each case contributes the factors by which each model's whole-record MAE of every target signal is below the
FMU's, and the share of time each model stays within the case's tolerance of the measurement: median
[min – max] over the held-out maneuvers. A case folder with a pooled seed study (``robustness/summary.json``,
``snakemake -j2 robustness``) is quoted over every (seed, maneuver); otherwise its run's ``metrics/test.json``.
Below the table, each case's caveats as the run wrote them: how often a model is worse than its own physics
and, where the case names a reference, whether the neural FMU reaches it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hybridfmu.evaluation.report import MODEL_TITLES, spread_text
from hybridfmu.io import read_json

HEADLINE_MODELS = ("neural_fmu", "fmu_effects", "hybrid", "ceiling")
"""The table's model columns, in order (the FMU is the reference of every factor)."""


def case_results(case_dir: str | Path) -> dict[str, Any]:
    """The held-out figures of one case folder (``results/<case>``).

    Returns:
        ``{"case", "source", "signals", "maneuvers", "seeds", "models", "worse"}``: ``models`` maps each model to
        its statistics (``<signal>_mae_factor``, ``in_tolerance_share``: ``{median, min, max, n}``); ``seeds`` is
        empty for one run; ``worse`` lists each caveat as a sentence; ``source`` is the file read.

    Raises:
        FileNotFoundError: the folder has neither ``robustness/summary.json`` nor ``metrics/test.json``; names both.
    """
    case_dir = Path(case_dir)
    pooled, single = case_dir / "robustness" / "summary.json", case_dir / "metrics" / "test.json"
    if pooled.is_file():
        summary = read_json(pooled)
        worse = summary.get("hybrid_worse_than_fmu_effects") or []
        pairs = len(summary["seeds"]) * len(summary["maneuvers"]) * len(summary["signals"])
        caveats = [f"the hybrid is worse than the FMU + diagnosed effects, its own physics, in {len(worse)} of "
                   f"{pairs} (seed, maneuver, signal)"]
        for row in summary.get("reference") or []:
            if row.get("neural_fmu_median") is None:
                continue
            signal, measure = row["metric"].rsplit("_", 1)
            caveats.append(f"the neural FMU's median {signal} {measure.upper()} factor ×{row['neural_fmu_median']:.3g} "
                           f"against the reference's ×{row['factor']:.3g} ({summary.get('reference_name') or 'config'}"
                           "): " + ("reached" if row["reached"] else "not reached"))
        return {"case": case_dir.name, "source": pooled, "signals": summary["signals"],
                "maneuvers": summary["maneuvers"], "seeds": summary["seeds"], "models": summary["models"],
                "worse": caveats}
    if not single.is_file():
        raise FileNotFoundError(f"{case_dir}: neither {pooled} nor {single}; run the case's workflow first")
    metrics = read_json(single)
    warnings = metrics.get("warnings") or []
    caveats = [f"{len(warnings)} warning(s) of a model worse than its own physics on a test maneuver"
               + (": " + "; ".join(warnings) if warnings else "")]
    return {"case": case_dir.name, "source": single, "signals": metrics["signals"],
            "maneuvers": metrics.get("maneuvers", []), "seeds": [], "models": metrics.get("distribution") or {},
            "worse": caveats}


def _held_out_text(results: dict[str, Any]) -> str:
    count = len(results["maneuvers"])
    text = f"{count} test maneuver{'s' if count != 1 else ''}"
    if results["seeds"]:
        text += f" × {len(results['seeds'])} seeds"
    return text


def headline_markdown(case_dirs: list[str | Path]) -> str:
    """The headline table over ``case_dirs`` (in the given order) and each case's caveats, as Markdown.

    Raises:
        FileNotFoundError: as :func:`case_results`.
        ValueError: no case folder given.
    """
    if not case_dirs:
        raise ValueError("the headline needs at least one results/<case> folder")
    cases = [case_results(case_dir) for case_dir in case_dirs]
    lines = ["| case | held out | measure | " + " | ".join(MODEL_TITLES[m] for m in HEADLINE_MODELS) + " |",
             "|---|---|---|" + "---|" * len(HEADLINE_MODELS)]
    for results in cases:
        measures = [(f"{s}_mae_factor", f"{s} MAE vs FMU", {"factor": True}) for s in results["signals"]]
        measures.append(("in_tolerance_share", "within tolerance", {"percent": True}))
        for index, (key, text, style) in enumerate(measures):
            first = index == 0
            cells = []
            for model in HEADLINE_MODELS:
                stats = (results["models"].get(model) or {}).get(key)
                cells.append(spread_text(stats, **style) if stats else "–")
            lines.append(f"| {'`' + results['case'] + '`' if first else ''} | "
                         f"{_held_out_text(results) if first else ''} | {text} | " + " | ".join(cells) + " |")
    lines += ["", "Median [min – max] over the held-out test maneuvers (and master seeds) of each case, each judged on "
              "its own, open loop over its whole record from the measured initial state; a factor is the FMU's "
              "error divided by the model's (above ×1: better than the FMU); – : not part of the case (the ceiling, "
              "the true plant, exists only for an emulated bench). Caveats:", ""]
    lines += [f"- `{results['case']}` ({results['source'].parent.name}/{results['source'].name}): "
              + "; ".join(results["worse"]) for results in cases]
    return "\n".join(lines) + "\n"
