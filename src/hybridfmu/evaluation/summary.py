"""The measured figures of one case's run, as the documentation quotes them.

Rule ``summary`` renders ``{RESULTS}/summary.md`` from the run's own outputs: the open-loop test errors
of the (calibrated) FMU, the neural FMU and the diagnosis-corrected FMU per target signal, and the
improvement factors. :mod:`hybridfmu.evaluation.measured_blocks` copies it into the documentation's block
``<case>``, so no measured number there is typed by hand.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from hybridfmu.io import atomic_path, read_json


def _number(value: Any) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return f"{float(value):.4g}"


def _factor(reference: Any, candidate: Any) -> str:
    if reference is None or candidate in (None, 0):
        return "–"
    return f"×{float(reference) / float(candidate):.3g}"


def _square(value: Any) -> float | None:
    return None if value is None else float(value) ** 2


def model_terms_text(which: dict[str, Any]) -> str:
    """The terms the FMU + diagnosed effects model carries, in words: the named effects (``found_effects``), then the
    terms it also carries without naming them (``chosen`` records with the role ``adjustment`` or ``unconfirmed``),
    e.g. ``overflow(x1->x2); also in the model, not named: parameter(k2) (unconfirmed)``; ``none`` without terms."""
    named = ", ".join(which.get("found_effects", []))
    beside = [f"{item['effect']} ({item['role']})" for item in which.get("chosen", [])
              if item.get("role") in ("adjustment", "unconfirmed")]
    beside_text = f"also in the model, not named: {', '.join(dict.fromkeys(beside))}" if beside else ""
    return "; ".join(part for part in (named, beside_text) if part) or "none"


def case_summary(case: str, test_metrics: dict[str, Any], diagnosis: dict[str, Any] | None,
                 units: dict[str, str]) -> str:
    """Markdown lines quoting one run's test figures.

    Args:
        case: case name.
        test_metrics: ``metrics/test.json`` (objects ``fmu`` and ``neural_fmu`` with ``<signal>_<measure>``,
            list ``signals``).
        diagnosis: ``diagnosis/diagnosis.json`` (``how_far.before/after`` with ``<signal>_rmse``; steps with a
            ``refit`` record: the FMU was recalibrated with the effects), or None.
        units: signal -> unit ("" for dimensionless).

    Returns:
        With a ``distribution`` in the metrics, first each model over the test maneuvers one by one: median
        [min – max] of the factors against the FMU, of the share of time within the tolerance and of the exits
        from it, the ceiling beside them, and every warning of a model worse than its own physics. Then a
        table over all test maneuvers together: one row per target signal and model with RMSE and MAE, and
        the factors by which each model's MAE and MSE are below the FMU's (the paper's two measures; the
        MSE factor is the square of the RMSE factor), and a note that the diagnosed effects are in rank order.
    """
    from hybridfmu.evaluation.report import distribution_table, tolerance_text, warning_lines

    far = (diagnosis or {}).get("how_far") or {}
    effects = model_terms_text((diagnosis or {}).get("which", {})).replace("|", "\\|")
    maneuvers = test_metrics.get("maneuvers", [])
    lines = []
    spread = distribution_table({"test": test_metrics})
    if spread:
        warnings = warning_lines({"test": test_metrics})
        closed = closed_loop_table(test_metrics, units)
        lines += [f"Case `{case}`, {len(maneuvers)} test maneuver(s) ({', '.join(maneuvers)}), each open loop over "
                  "its whole record from the measured initial state"
                  + (" and in closed loop (driven by the case's control software from the logged setpoints)"
                     if closed else "") + "; median [min – max] over them. "
                  + tolerance_text({"test": test_metrics}, units), ""] + spread + [""]
        if closed:
            lines += ["Closed loop, each model's error against the measurement (median [min – max] over the "
                      "maneuvers):", ""] + closed + [""]
        lines += (warnings or ["No model is worse than its own physics on any test maneuver."]) + [""]
        lines += ["All test maneuvers together:", ""]
    else:
        lines += [f"Case `{case}`, test maneuver(s) {', '.join(maneuvers)}, "
                  f"open loop over the whole record ({_number(test_metrics.get('duration_s'))} s):", ""]
    lines += ["| signal | model | RMSE | MAE | MAE vs FMU | MSE vs FMU |", "|---|---|---|---|---|---|"]
    for signal in test_metrics["signals"]:
        unit = f" {units.get(signal, '')}".rstrip()
        fmu = test_metrics["fmu"]
        rows = [("FMU", fmu), ("neural FMU", test_metrics["neural_fmu"])]
        effects_errors = test_metrics.get("fmu_effects") or far.get("after")
        if effects_errors:
            refitted = any("refit" in step for step in far.get("steps", []))
            rows.append((f"FMU + diagnosed effects{', recalibrated' if refitted else ''} ({effects})", effects_errors))
        if test_metrics.get("hybrid"):
            rows.append(("hybrid: FMU + diagnosed effects + ANN", test_metrics["hybrid"]))
        if test_metrics.get("ceiling"):
            rows.append(("ceiling: the true plant (the best any model could reach)", test_metrics["ceiling"]))
        for label, values in rows:
            rmse, mae = values.get(f"{signal}_rmse"), values.get(f"{signal}_mae")
            lines.append(f"| {signal} | {label} | {_number(rmse)}{unit} | {_number(mae)}{unit} | "
                         f"{_factor(fmu.get(f'{signal}_mae'), mae)} | "
                         f"{_factor(_square(fmu.get(f'{signal}_rmse')), _square(rmse))} |")
    if effects != "none" and (test_metrics.get("fmu_effects") or far.get("after")):
        lines += ["", "The diagnosed effects are listed by their rank in the diagnosis (drop-one score, "
                  "`diagnosis/report.md`), not in the order its forward selection added them."]
    return "\n".join(lines) + "\n"


def closed_loop_table(metrics: dict[str, Any], units: dict[str, str]) -> list[str]:
    """Markdown table of each model's closed-loop MAE per target signal over a role's maneuvers (median [min – max],
    model units), or [] when the metrics have no closed loop."""
    from hybridfmu.evaluation.report import MODEL_TITLES, spread_text

    stats = metrics.get("distribution") or {}
    signals = list(metrics.get("signals") or [])
    models = [m for m, values in stats.items() if any(f"{s}_mae_closed_loop" in values for s in signals)]
    if not models:
        return []
    lines = ["| model | " + " | ".join(f"{s} closed-loop MAE ({units.get(s, '')})".replace(" ()", "")
                                     for s in signals) + " |", "|---|" + "---|" * len(signals)]
    for model in models:
        lines.append(f"| {MODEL_TITLES.get(model, model)} | "
                     + " | ".join(spread_text(stats[model].get(f"{s}_mae_closed_loop")) for s in signals) + " |")
    return lines


def write_case_summary(out_path: str | Path, case: str, test_metrics_path: str | Path,
                       diagnosis_path: str | Path | None, units: dict[str, str], best_path: str | Path | None = None,
                       time_offset_path: str | Path | None = None, truth_paths: list[str] | None = None,
                       roles: Any = None, hybrid_time_offset_path: str | Path | None = None) -> Path:
    """Render :func:`case_summary` from the run's files and write it atomically; with ``best_path``,
    ``time_offset_path`` and ``roles`` the learned input delays follow (beside the time-offset stage's
    estimates, the hybrid's beside those on its physical layer (``hybrid_time_offset_path``) when it has them,
    and the ground truth of ``truth_paths`` when there is one)."""
    from hybridfmu.evaluation.report import (delay_lines, diagnosed_offsets_text, hybrid_estimates,
                                              learned_delay_facts)

    diagnosis = read_json(diagnosis_path) if diagnosis_path else None
    test_metrics = read_json(test_metrics_path)
    text = case_summary(case, test_metrics, diagnosis, units)
    if best_path and time_offset_path and roles is not None and test_metrics.get("dt_s"):
        true_dt_s, source, estimates = learned_delay_facts(read_json(best_path), read_json(time_offset_path),
                                                             list(truth_paths or []), roles)
        text += "\nLearned input delays of the neural FMU:\n\n" + "\n".join(
            delay_lines(test_metrics["dt_s"], true_dt_s, Path(source).name if source else None, None,
                        estimates, test_metrics.get("delay_bounds_s"))) + "\n"
        hybrid = test_metrics.get("hybrid_learned") or {}
        if hybrid.get("dt_s"):
            own = hybrid_estimates(hybrid_time_offset_path)
            text += "\nLearned input delays of the hybrid:\n\n" + "\n".join(
                delay_lines(hybrid["dt_s"], true_dt_s, Path(source).name if source else None, None,
                            own if own is not None else estimates, hybrid.get("delay_bounds_s"),
                            diagnosed_offsets_text(hybrid.get("effects")))) + "\n"
    with atomic_path(out_path) as tmp:
        Path(tmp).write_text(text)
    return Path(out_path)
