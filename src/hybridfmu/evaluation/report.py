"""The case report ``report.md``: improvement factors next to the paper's, hyperparameters,
the learned input delay against the true one, and the figures."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hybridfmu.evaluation.metrics import METRIC_KEYS

#: Improvement factors the paper reports (FMU error / neural FMU error), with the figure they come
#: from: (role, metric key) -> (text, lower bound as float).
PAPER_FACTORS: dict[tuple[str, str], tuple[str, float]] = {
    ("validation", "angle_mae"): ("×4.6 (Figs. 9-10)", 4.6),
    ("validation", "angle_mse"): ("×61 (Figs. 9-10)", 61.0),
    ("test", "angle_mae"): ("×5.4 (Fig. 13)", 5.4),
    ("test", "angle_mse"): ("×74 (Fig. 13)", 74.0),
    ("test", "speed_mae"): ("×2 and more (Fig. 15)", 2.0),
}
#: The input delay the paper learned (s), for comparison.
PAPER_DT_S = -1.995e-5

_METRIC_TEXT = {"angle_mae": ("angle", "MAE", "rad"), "angle_mse": ("angle", "MSE", "rad²"),
                "speed_mae": ("speed", "MAE", "rad/s"), "speed_mse": ("speed", "MSE", "(rad/s)²")}


@dataclass(frozen=True)
class ReportFigure:
    """A figure of the report: its path relative to the report, and its caption."""

    path: str
    caption: str


def _number(value: Any, digits: int = 3) -> str:
    if value is None:
        return "unbounded"
    if isinstance(value, float) and not math.isfinite(value):
        return "n/a"
    if isinstance(value, (int, float)):
        return f"{value:.{digits}g}"
    return str(value)


def improvement_table(metrics_by_role: dict[str, dict]) -> list[str]:
    """Markdown table: for each role and metric, FMU error, neural FMU error, this run's factor and the paper's."""
    lines = ["| data | quantity | measure | FMU | neural FMU | improvement (this run) | improvement (paper) |",
             "|---|---|---|---|---|---|---|"]
    for role, metrics in metrics_by_role.items():
        for key in METRIC_KEYS:
            quantity, measure, unit = _METRIC_TEXT[key]
            paper = PAPER_FACTORS.get((role, key), ("not reported", None))[0]
            factor = metrics["improvement"][key]
            lines.append(f"| {role} | {quantity} | {measure} | {_number(metrics['fmu'][key])} {unit} | "
                         f"{_number(metrics['neural_fmu'][key])} {unit} | ×{_number(factor)} | {paper} |")
    return lines


def zoom_table(metrics_by_role: dict[str, dict]) -> list[str]:
    """Markdown table of the zoomed intervals with the improvement of the quantity each was chosen for."""
    lines = ["| data | maneuver | interval [s] | chosen for | how | FMU MAE | neural FMU MAE | improvement MAE | "
             "improvement MSE |", "|---|---|---|---|---|---|---|---|---|"]
    for role, metrics in metrics_by_role.items():
        for zoom in metrics.get("zooms", []):
            q = zoom["quantity"]
            unit = _METRIC_TEXT[f"{q}_mae"][2]
            lines.append(
                f"| {role} | {zoom['maneuver']} | {zoom['t_start_s']:.3f} – {zoom['t_end_s']:.3f} | {q} | "
                f"{zoom['source']} | {_number(zoom['fmu'][f'{q}_mae'])} {unit} | "
                f"{_number(zoom['neural_fmu'][f'{q}_mae'])} {unit} | ×{_number(zoom['improvement'][f'{q}_mae'])} | "
                f"×{_number(zoom['improvement'][f'{q}_mse'])} |")
    return lines


def verdicts(metrics_by_role: dict[str, dict]) -> list[str]:
    """One line per factor the paper reports: does this run reach it?"""
    lines = []
    for (role, key), (text, bound) in PAPER_FACTORS.items():
        if role not in metrics_by_role:
            continue
        factor = metrics_by_role[role]["improvement"][key]
        quantity, measure, _ = _METRIC_TEXT[key]
        reached = factor is None or factor >= bound
        lines.append(f"- {role} {quantity} {measure}: ×{_number(factor)} against the paper's {text} — "
                     f"{'reached' if reached else 'not reached'}.")
    return lines


def delay_lines(dt_s: float | None, true_dt_s: float | None, truth_source: str | None) -> list[str]:
    """Lines on the learned input delay, against the ground truth when the case has one."""
    lines = []
    if dt_s is None:
        return ["The model has no learned input delay."]
    lines.append(f"- learned input delay Δt: {dt_s:.4g} s ({dt_s * 1e6:.2f} µs)")
    if true_dt_s is not None:
        error = dt_s - true_dt_s
        lines.append(f"- true time offset of the logged inputs ({truth_source}): {true_dt_s:.4g} s "
                     f"({true_dt_s * 1e6:.2f} µs); learned minus true: {error * 1e6:.2f} µs")
    else:
        lines.append("- the case has no ground truth for the time offset (no truth file beside the raw logs)")
    lines.append(f"- paper: Δt ≈ {PAPER_DT_S:.4g} s")
    return lines


def hyperparameter_lines(hyperparameters: dict[str, Any]) -> list[str]:
    """Markdown table of the chosen hyperparameters."""
    lines = ["| hyperparameter | value |", "|---|---|"]
    for name, value in hyperparameters.items():
        lines.append(f"| {name} | {_number(value, 4) if isinstance(value, float) else value} |")
    return lines


def render_report(case: str, metrics_by_role: dict[str, dict], hyperparameters: dict[str, Any],
                  best_summary: dict[str, Any], dt_s: float | None, gates: Any, true_dt_s: float | None,
                  truth_source: str | None, figures: list[ReportFigure], mlflow_run: dict[str, Any] | None) -> str:
    """The report as Markdown text.

    Args:
        case: case name.
        metrics_by_role: ``{"validation": metrics, "test": metrics}`` as written by ``evaluate``.
        hyperparameters: the best configuration's hyperparameters.
        best_summary: other facts about the best trial (trial id, validation loss, resource ...).
        dt_s: learned input delay (s) or None; gates: the learned gates.
        true_dt_s, truth_source: the true offset (s) and where it comes from, or None.
        figures: the figures, paths relative to the report.
        mlflow_run: ``{"tracking_uri", "experiment", "run_id"}`` of the evaluation run, or None.
    """
    out = [f"# Neural FMU against FMU — case `{case}`", "",
           "Open-loop simulations over the whole validation and test maneuvers, from their first sample "
           "(recorded inputs, no controller), against the measurements. Improvement = FMU error / neural FMU "
           "error; the factors the paper reports for its braking-system motor are given beside this run's.", "",
           "## Improvement factors", ""]
    out += improvement_table(metrics_by_role) + [""] + verdicts(metrics_by_role) + [""]
    out += ["## Zoomed intervals", "",
            "Chosen where the FMU and the data part most, from the FMU's error alone (`auto`), or set in the "
            "config (`config`).", ""]
    out += zoom_table(metrics_by_role) + [""]
    out += ["## Learned input delay and gates", ""] + delay_lines(dt_s, true_dt_s, truth_source)
    out += [f"- gates: {gates}", ""]
    out += ["## Best hyperparameters", ""]
    if best_summary:
        out += [", ".join(f"{k}: {_number(v, 4) if isinstance(v, float) else v}" for k, v in best_summary.items()), ""]
    out += hyperparameter_lines(hyperparameters) + [""]
    if mlflow_run:
        out += ["## MLflow", "",
                f"Evaluation run `{mlflow_run.get('run_id')}` in experiment `{mlflow_run.get('experiment')}` "
                f"(tracking URI `{mlflow_run.get('tracking_uri')}`).", ""]
    out += ["## Figures", ""]
    for figure in figures:
        out += [f"![{figure.caption}]({figure.path})", "", f"*{figure.caption}*", ""]
    return "\n".join(out)
