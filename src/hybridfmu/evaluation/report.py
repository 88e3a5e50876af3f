"""The case report ``report.md``: improvement factors per target signal next to a reference's (the
paper's, from config ``evaluation.reference``), hyperparameters, the learned input delay against the
true one, and the figures. Labels and units come from the case's roles."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hybridfmu.evaluation.figures import squared_unit
from hybridfmu.model.delay import format_delay

#: Measures of the improvement table: key suffix -> (text, squared unit?).
_MEASURE_TEXT = {"mae": ("MAE", False), "mse": ("MSE", True), "rmse": ("RMSE", False)}


def _signals_of(metrics: dict[str, Any]) -> list[str]:
    """Target signals of a metrics object (field ``signals``, else read from the ``<signal>_mae`` keys)."""
    if metrics.get("signals"):
        return list(metrics["signals"])
    return [key[:-4] for key in metrics["fmu"] if key.endswith("_mae")]


def _unit(units: dict[str, str] | None, signal: str, measure: str) -> str:
    unit = (units or {}).get(signal, "")
    return squared_unit(unit) if _MEASURE_TEXT[measure][1] else (unit or "-")


def reference_factors(reference: dict[str, Any] | None) -> dict[tuple[str, str], tuple[str, float]]:
    """(role, metric key) -> (text, factor) of the reference's improvement factors (config
    ``evaluation.reference.factors``: ``[{role, metric, factor, note}]``)."""
    out = {}
    for item in (reference or {}).get("factors", []) or []:
        note = f" ({item['note']})" if item.get("note") else ""
        out[(item["role"], item["metric"])] = (f"×{float(item['factor']):g}{note}", float(item["factor"]))
    return out


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


def _gates_text(gates: Any) -> str:
    if isinstance(gates, dict) and all(isinstance(v, dict) for v in gates.values()):
        return "; ".join(f"{state}: " + ", ".join(f"{name} = {_number(value, 4)}" for name, value in values.items())
                         for state, values in gates.items())
    return str(gates)


def improvement_table(metrics_by_role: dict[str, dict], units: dict[str, str] | None = None,
                      reference: dict[str, Any] | None = None) -> list[str]:
    """Markdown table: per role, target signal and measure: FMU error, neural FMU error, this run's factor and
    the reference's."""
    name = (reference or {}).get("name", "reference")
    factors = reference_factors(reference)
    lines = [f"| data | signal | measure | FMU | neural FMU | improvement (this run) | improvement ({name}) |",
             "|---|---|---|---|---|---|---|"]
    for role, metrics, signal, text, key, unit in _measure_rows(metrics_by_role, units):
        ref = factors.get((role, key), ("not reported", None))[0]
        lines.append(f"| {role} | {signal} | {text} | {_number(metrics['fmu'][key])} {unit} | "
                     f"{_number(metrics['neural_fmu'][key])} {unit} | ×{_number(metrics['improvement'][key])} "
                     f"| {ref} |")
    return lines


def _measure_rows(metrics_by_role: dict[str, dict], units: dict[str, str] | None):
    """(role, its metrics, signal, measure text, metric key, unit) of every measure the FMU's errors hold."""
    for role, metrics in metrics_by_role.items():
        for signal in _signals_of(metrics):
            for measure, (text, _) in _MEASURE_TEXT.items():
                key = f"{signal}_{measure}"
                if key in metrics["fmu"]:
                    yield role, metrics, signal, text, key, _unit(units, signal, measure)


#: Column titles of the compared models.
MODEL_TITLES = {"fmu": "FMU", "fmu_effects": "FMU + diagnosed effects", "neural_fmu": "neural FMU",
                "hybrid": "hybrid (FMU + effects + ANN)", "ceiling": "ceiling (true plant)"}


def spread_text(stats: dict[str, Any] | None, digits: int = 3, percent: bool = False, factor: bool = False) -> str:
    """``median [min – max]`` of :func:`hybridfmu.evaluation.metrics.summary_statistics` (``n/a`` without values);
    ``percent``: as percentages; ``factor``: with a leading ×."""
    if not stats or stats.get("median") is None:
        return "n/a"
    if percent:
        fmt = lambda v: f"{100.0 * v:.0f} %" if 100.0 * v >= 9.95 else f"{100.0 * v:.1f} %"  # noqa: E731
    else:
        fmt = lambda v: ("×" if factor else "") + _number(float(v), digits)  # noqa: E731
    if stats.get("n", 0) <= 1 or stats["min"] == stats["max"]:
        return fmt(stats["median"])
    return f"{fmt(stats['median'])} [{fmt(stats['min'])} – {fmt(stats['max'])}]"


def distribution_table(metrics_by_role: dict[str, dict]) -> list[str]:
    """Markdown table of every model over the maneuvers of each role: median [min – max] of the factors against
    the FMU (FMU error / model error) per target signal, over the whole record (MAE, MSE), over windows
    restarted from the measured state (windowed MAE) and, where the case has a controller, driven by it (closed-loop
    MAE), of the share of time within the tolerance and of how often the model left it; [] when the metrics hold no
    distribution."""
    lines: list[str] = []
    measures = [("mae", "MAE"), ("mse", "MSE"), ("mae_windowed", "windowed MAE")]
    if any(key.endswith("_mae_closed_loop_factor") for metrics in metrics_by_role.values()
           for values in (metrics.get("distribution") or {}).values() for key in values):
        measures.append(("mae_closed_loop", "closed-loop MAE"))
    for role, metrics in metrics_by_role.items():
        stats = metrics.get("distribution")
        if not stats:
            continue
        signals = _signals_of(metrics)
        if not lines:
            lines = ["| data | maneuvers | model | " + " | ".join(f"{s} {text} vs FMU" for s in signals
                                                                   for _, text in measures)
                     + " | within tolerance | exits |", "|---|---|---|" + "---|" * (len(measures) * len(signals))
                     + "---|---|"]
        for model, values in stats.items():
            cells = [spread_text(values.get(f"{s}_{m}_factor"), factor=True) if model != "fmu" else "×1"
                     for s in signals for m, _ in measures]
            cells += [spread_text(values.get("in_tolerance_share"), percent=True),
                      spread_text(values.get("tolerance_exits"))]
            lines.append(f"| {role} | {len(metrics.get('maneuvers', []))} | {MODEL_TITLES.get(model, model)} | "
                         + " | ".join(cells) + " |")
    return lines


def tolerance_text(metrics_by_role: dict[str, dict], units: dict[str, str] | None = None) -> str:
    """The tolerance of the in-tolerance metrics and where it comes from, or "" without one."""
    tolerance = next((m["tolerance"] for m in metrics_by_role.values() if m.get("tolerance")), None)
    if not tolerance:
        return ""
    bounds = ", ".join(f"|{signal} error| ≤ {_number(value, 4)} {(units or {}).get(signal, '')}".rstrip()
                       for signal, value in tolerance["signals"].items())
    return f"Within tolerance: {bounds} ({tolerance['source']})."


def warning_lines(metrics_by_role: dict[str, dict]) -> list[str]:
    """Every maneuver where a model is worse than its own physics, as Markdown list items (``[]`` when none)."""
    return [f"- **WARNING** {role}: {line}" for role, metrics in metrics_by_role.items()
            for line in metrics.get("warnings", [])]


def models_table(metrics_by_role: dict[str, dict], units: dict[str, str] | None = None) -> list[str]:
    """Markdown table of every model the metrics hold (FMU, FMU + diagnosed effects, neural FMU, hybrid): per role,
    target signal and measure the error and, in brackets, the factor by which it is below the FMU's; [] when the
    metrics hold only the FMU and the neural FMU (the improvement table shows them)."""
    from hybridfmu.evaluation.comparison import MODELS

    models = [m for m in MODELS if all(m in metrics for metrics in metrics_by_role.values())]
    if len(models) <= 2:
        return []
    lines = ["| data | signal | measure | " + " | ".join(MODEL_TITLES[m] for m in models) + " |",
             "|---|---|---|" + "---|" * len(models)]
    for role, metrics, signal, text, key, unit in _measure_rows(metrics_by_role, units):
        cells = []
        for model in models:
            cell = f"{_number(metrics[model][key])} {unit}".rstrip()
            if model != "fmu":
                factor = metrics["improvement" if model == "neural_fmu" else f"improvement_{model}"][key]
                cell += f" (×{_number(factor)})"
            cells.append(cell)
        lines.append(f"| {role} | {signal} | {text} | " + " | ".join(cells) + " |")
    return lines


def zoom_table(metrics_by_role: dict[str, dict], units: dict[str, str] | None = None) -> list[str]:
    """Markdown table of the zoomed intervals with the improvement of the signal each was chosen for."""
    lines = ["| data | maneuver | interval [s] | chosen for | how | FMU MAE | neural FMU MAE | improvement MAE | "
             "improvement MSE |", "|---|---|---|---|---|---|---|---|---|"]
    for role, metrics in metrics_by_role.items():
        for zoom in metrics.get("zooms", []):
            q = zoom["signal"]
            unit = _unit(units, q, "mae")
            how = zoom["source"] + (f" ({zoom['criterion']})" if zoom.get("criterion") else "")
            lines.append(
                f"| {role} | {zoom['maneuver']} | {zoom['t_start_s']:.3f} – {zoom['t_end_s']:.3f} | {q} | "
                f"{how} | {_number(zoom['fmu'][f'{q}_mae'])} {unit} | "
                f"{_number(zoom['neural_fmu'][f'{q}_mae'])} {unit} | ×{_number(zoom['improvement'][f'{q}_mae'])} | "
                f"×{_number(zoom['improvement'][f'{q}_mse'])} |")
    return lines


def verdicts(metrics_by_role: dict[str, dict], reference: dict[str, Any] | None = None) -> list[str]:
    """One line per factor the reference reports: does this run reach it?"""
    name = (reference or {}).get("name", "reference")
    lines = []
    for (role, key), (text, bound) in reference_factors(reference).items():
        if role not in metrics_by_role or key not in metrics_by_role[role]["improvement"]:
            continue
        factor = metrics_by_role[role]["improvement"][key]
        signal, _, measure = key.rpartition("_")
        reached = factor is None or factor >= bound
        lines.append(f"- {role} {signal} {_MEASURE_TEXT.get(measure, (measure,))[0]}: ×{_number(factor)} against "
                     f"the {name}'s {text} — {'reached' if reached else 'not reached'}.")
    return lines


def delay_lines(dt_s: dict[str, float] | None, true_dt_s: dict[str, float | None] | None,
                truth_source: str | None, reference: dict[str, Any] | None = None,
                estimates: dict[str, Any] | None = None, bounds_s: dict[str, list[float]] | None = None,
                on_top_of: str | None = None) -> list[str]:
    """A table of the learned input delays per group, beside the time-offset stage's estimate and, when the
    case has a ground truth, the true offset of the group's logged inputs.

    Args:
        dt_s: {group: learned delay (s)}; true_dt_s: {group: true offset (s), None where its inputs differ}.
        estimates: {group: the time-offset stage's estimate}: its summary entry (``delay_s``, and
            ``standard_error_s`` shown as ± where there is one) or the delay in s.
        bounds_s: {group: [low, high] (s)} of the groups that learned within narrower bounds than the
            config's range (a column of its own when there are any).
        on_top_of: what already shifts the inputs before the learned delays act (a hybrid's physical layer
            with its diagnosed time offset). The learned delays are then only the rest, so they are not set
            against the true offsets; a sentence says so.
    """
    if not dt_s:
        return ["The model has no learned input delay."]
    if not isinstance(dt_s, dict):
        dt_s = {"inputs": float(dt_s)}
    compared = true_dt_s if on_top_of is None else None  # the rest of an offset is not compared with the truth
    header = "| input group | learned Δt | time-offset estimate |"
    rule = "|---|---|---|"
    if bounds_s:
        header += " learned within |"
        rule += "---|"
    if compared is not None:
        header += " true offset | learned − true |"
        rule += "---|---|"
    lines = [header, rule]
    for group, value in dt_s.items():
        row = f"| {group} | {format_delay(value)} | {estimate_text((estimates or {}).get(group))} |"
        if bounds_s:
            band = bounds_s.get(group)
            row += (" the config's range |" if band is None
                    else f" {format_delay(band[0])} … {format_delay(band[1])} |")
        if compared is not None:
            truth = compared.get(group)
            error = "" if truth is None else format_delay(value - truth)
            row += (" its inputs are offset differently | - |" if truth is None
                    else f" {format_delay(truth)} | {'' if error.startswith('-') else '+'}{error} |")
        lines.append(row)
    lines.append("")
    if on_top_of is not None:
        lines.append(f"These delays act on top of {on_top_of}: they are what remains of the inputs' time offset, "
                     "so they are not set against the true offsets" + (f" of {truth_source}" if truth_source else "")
                     + ".")
    elif compared is not None:
        lines.append(f"True offsets from {truth_source} (convention u_true(t) = u_logged(t + Δt)).")
    else:
        lines.append("The true time offsets are unknown, as for any measured case; only an emulated bench writes "
                     "them beside its logs, for scoring.")
    if (reference or {}).get("input_delay_s") is not None:
        lines.append(f"{reference.get('name', 'reference')}: Δt ≈ {format_delay(reference['input_delay_s'])} "
                     "(one delay for all inputs).")
    return lines


def diagnosed_offsets_text(effects: list[str] | None) -> str | None:
    """'the physical layer's diagnosed time_offset(d_a,d_b)' when a hybrid's physical layer (its effect names)
    already shifts inputs in time, else None (its learned delays are then the whole offset)."""
    offsets = [name for name in effects or [] if name.startswith("time_offset(")]
    return f"the physical layer's diagnosed {', '.join(offsets)}" if offsets else None


def estimate_text(estimate: Any) -> str:
    """A time-offset estimate for the delay table: '28.45 µs ± 0.61 µs' (with its standard error), '28.45 µs',
    or '-' (none). ``estimate``: a group entry of the time-offset summary, a delay in s, or None."""
    if estimate is None:
        return "-"
    if not isinstance(estimate, dict):
        return format_delay(estimate)
    error = estimate.get("standard_error_s")
    text = format_delay(estimate["delay_s"])
    return text if error is None else f"{text} ± {format_delay(error)}"


def hyperparameter_lines(hyperparameters: dict[str, Any]) -> list[str]:
    """Markdown table of the chosen hyperparameters."""
    lines = ["| hyperparameter | value |", "|---|---|"]
    for name, value in hyperparameters.items():
        lines.append(f"| {name} | {_number(value, 4) if isinstance(value, float) else value} |")
    return lines


def render_report(case: str, metrics_by_role: dict[str, dict], hyperparameters: dict[str, Any],
                  best_summary: dict[str, Any], dt_s: float | None, gates: Any, true_dt_s: float | None,
                  truth_source: str | None, figures: list[ReportFigure], mlflow_run: dict[str, Any] | None,
                  units: dict[str, str] | None = None, reference: dict[str, Any] | None = None,
                  delay_estimates: dict[str, Any] | None = None,
                  hybrid_delay_estimates: dict[str, Any] | None = None) -> str:
    """The report as Markdown text.

    Args:
        case: case name.
        metrics_by_role: ``{"validation": metrics, "test": metrics}`` as written by ``evaluate``.
        hyperparameters: the best configuration's hyperparameters.
        best_summary: other facts about the best trial (trial id, validation loss, resource ...).
        dt_s: learned input delays ({group: s}) or None; gates: the learned gates.
        true_dt_s, truth_source: the true offset of each delay group ({group: s}) and where it comes from, or None.
        delay_estimates: the time-offset stage's estimate of each group ({group: summary entry or s}).
        hybrid_delay_estimates: the same on the hybrid's physical layer (rule ``hybrid_time_offset``), beside
            the hybrid's delays; None: ``delay_estimates``.
        figures: the figures, paths relative to the report.
        mlflow_run: ``{"tracking_uri", "experiment", "run_id"}`` of the evaluation run, or None.
        units: target signal -> unit (``Signal.unit``) for the tables.
        reference: config ``evaluation.reference`` (``name``, ``factors``, ``input_delay_s``, ``figures``).
    """
    name = (reference or {}).get("name", "reference")
    out = [f"# Neural FMU against FMU — case `{case}`", "",
           "Open-loop simulations over the whole validation and test maneuvers, from their first sample "
           "(recorded inputs), against the measurements of the target signals. Improvement = FMU error / "
           f"neural FMU error; the factors the {name} reports are given beside this run's where configured.", "",
           "## Improvement factors", ""]
    out += improvement_table(metrics_by_role, units, reference) + [""] + verdicts(metrics_by_role, reference) + [""]
    spread = distribution_table(metrics_by_role)
    if spread:
        out += ["## Over the maneuvers", "",
                "Each model over every maneuver of a role on its own: median [min – max]. A factor is the FMU's "
                "error over the model's on that maneuver, over the whole record or over short windows each "
                "started from the measured state (windowed: how accurate a model is while it has not drifted "
                "away); closed loop, where the case declares its control software: the software drives each model "
                "from the logged setpoints, as in a software-in-the-loop test, and the model's response is compared "
                "with the measured one; the ceiling, where the case has one, is the best any "
                "model could reach in this test (for an emulated case, the true plant from the same "
                "measured state, driven by the logged inputs or by the same control software). "
                + tolerance_text(metrics_by_role, units), ""] + spread + [""]
    warnings = warning_lines(metrics_by_role)
    out += ["## Warnings", ""] + (warnings or ["- none: no model is worse than its own physics on any maneuver "
                                               "(whole-record MAE of every target signal)."]) + [""]
    models = models_table(metrics_by_role, units)
    if models:
        has_hybrid = any(metrics.get("hybrid") for metrics in metrics_by_role.values())
        out += ["## All models", "",
                "The FMU plus the effects the diagnosis identified (with the diagnosis' fitted values) and the neural "
                "FMU as in the paper" + (", and the hybrid: the same ANN trained on top of the FMU plus the effects"
                                         if has_hybrid else " (the case trains no hybrid: model.physics_terms is none)")
                + ". In brackets: the FMU's error over the model's.", ""] + models + [""]
    out += ["## Zoomed intervals", "",
            "Chosen where the FMU and the data part most, from the FMU's error alone (`auto`), or set in the "
            "config (`config`).", ""]
    out += zoom_table(metrics_by_role, units) + [""]
    first = next(iter(metrics_by_role.values()), {})
    out += ["## Learned input delay and gates", ""] + delay_lines(dt_s, true_dt_s, truth_source, reference,
                                                                         delay_estimates, first.get("delay_bounds_s"))
    out += [f"- gates (ẋ = g_F·ẋ_FMU + g_A·ẋ_ANN): {_gates_text(gates)}", ""]
    hybrid = next((m["hybrid_learned"] for m in metrics_by_role.values() if m.get("hybrid_learned")), None)
    if hybrid:
        effects = ", ".join(hybrid.get("effects") or []) or "no effects"
        out += ["### The hybrid's delays and gates", "",
                f"Physical layer: the FMU plus {effects} (trial {hybrid.get('trial_id')}).", ""]
        if hybrid.get("trial_id") == "physical_layer":
            out += [f"**{PHYSICAL_LAYER_CHOSEN}**", ""]
        out += delay_lines(hybrid.get("dt_s"), true_dt_s, truth_source, None,
                           hybrid_delay_estimates if hybrid_delay_estimates is not None else delay_estimates,
                           hybrid.get("delay_bounds_s"), diagnosed_offsets_text(hybrid.get("effects")))
        out += [f"- gates: {_gates_text(hybrid.get('gates'))}", ""]
        out += coefficient_lines(hybrid.get("coefficients"))
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


def coefficient_lines(coefficients: dict[str, dict[str, float]] | None) -> list[str]:
    """Markdown table of a hybrid's trained effect coefficients beside the diagnosis' values (none when they
    were fixed)."""
    if not coefficients:
        return []
    out = ["The effects' coefficients, trained with the ANN from the diagnosis' values "
           "(`model.physics_coefficient_step`):", "", "| coefficient | diagnosed | trained | change |",
           "|---|---|---|---|"]
    for name, values in coefficients.items():
        diagnosed, trained = float(values["diagnosed"]), float(values["trained"])
        change = f"{(trained - diagnosed) / abs(diagnosed) * 100:+.1f} %" if diagnosed else "–"
        cell = name.replace("|", "\\|")  # an effect name such as coulomb(v)*|F| inside a table cell
        out.append(f"| `{cell}` | {_number(diagnosed, 4)} | {_number(trained, 4)} | {change} |")
    return out + [""]


def figure_caption(name: str, maneuver_roles: dict[str, str], time_offset: dict[str, Any] | None,
                   signal_labels: dict[str, str] | None = None, reference: dict[str, Any] | None = None) -> str:
    """Caption of figure ``name`` (see ``plots.draw_all`` for the names).

    Args:
        signal_labels: target signal -> label (``Signal.label``).
        reference: config ``evaluation.reference``; ``figures: {role: {kind: number}}`` names the reference's
            figure for ``<role>`` and kind ``<signal>`` / ``<signal>_zoom``, and ``time_offset``.
    """
    reference = reference or {}
    numbers = reference.get("figures", {}) or {}
    ref_name = reference.get("name", "reference")
    if name == "time_offset":
        number = numbers.get("time_offset")
        text = "Time offset between data and model" + (f" (cf. {ref_name} Fig. {number})" if number else "")
        if time_offset:
            text += (f": maneuver '{time_offset['maneuver']}', {time_offset['t_start_s']:.4f}–"
                     f"{time_offset['t_end_s']:.4f} s; estimated input delay {time_offset['input_delay_s'] * 1e6:.1f} µs")
        return text + "."
    if name == "training_curves":
        return "Training curves of every trial (training loss against seconds of training data), best trial below."
    if name == "hyperband":
        return "Hyperband: validation objective of every trial at each rung against the resource, by bracket."
    for maneuver, role in maneuver_roles.items():
        for signal, label in (signal_labels or {}).items():
            for kind, what in ((signal, "whole trajectory"), (f"{signal}_zoom", "zoomed intervals")):
                if name == f"{maneuver}_{kind}":
                    number = (numbers.get(role, {}) or {}).get(kind)
                    cf = f" (cf. {ref_name} Fig. {number})" if number else ""
                    return f"{role.capitalize()} maneuver '{maneuver}': {label}, {what}, open loop{cf}."
    return name


def true_input_delay(truth_paths: list[str], groups: dict[str, list[str]] | None = None,
                     input_channels: dict[str, str | None] | None = None
                     ) -> tuple[dict[str, float | None] | None, str | None]:
    """The true offset of each input group (s) from the bench's ground-truth files, and the file it comes from.

    Reads ``time_offset.input_delay_s`` (convention u_true(t) = u_logged(t + input_delay_s), the same
    as the neural FMU's learned delay) and ``time_offset.channels``, the logged channels it applies to (all
    inputs when absent); the other inputs are true to 0. A group whose inputs have different true offsets
    gets None.

    Args:
        groups: {group: FMU inputs} of the learned delays (None: one group "inputs" of ``input_channels``).
        input_channels: {FMU input: raw channel it is read from, None for a derived signal}.

    Returns:
        ({group: s or None}, file) or (None, None) when there is no truth file.

    Raises:
        ValueError: the files disagree, or the field is missing (names the file).
    """
    from hybridfmu.io import read_json

    found: list[tuple[float, tuple[str, ...] | None, str]] = []
    for path in truth_paths:
        truth = read_json(path)
        try:
            offset = truth["time_offset"]
            channels = offset.get("channels")
            found.append((float(offset["input_delay_s"]), None if channels is None else tuple(channels), str(path)))
        except (KeyError, TypeError, AttributeError):
            raise ValueError(f"{path}: field 'time_offset.input_delay_s' missing (expected a bench ground truth)") from None
    if not found:
        return None, None
    if len({(value, channels) for value, channels, _ in found}) > 1:
        raise ValueError(f"ground-truth files disagree on time_offset (input_delay_s, channels): {found}")
    value, channels, source = found[0]
    input_channels = input_channels or {}
    groups = groups or {"inputs": list(input_channels)}
    result: dict[str, float | None] = {}
    for group, inputs in groups.items():
        values = {value if channels is None or input_channels.get(name) in channels else 0.0 for name in inputs}
        result[group] = values.pop() if len(values) == 1 else None
    return result, source


def group_estimate_text(group: str, entry: dict[str, Any]) -> str:
    """One input group's time-offset estimate (an entry of the summary's ``groups``) as report text."""
    text = (f"{group} {estimate_text(entry)} ({entry['windows']} windows of "
            f"{entry.get('window_samples', '?')} steps")
    if not entry.get("identified", True):
        text += f"; not identified: {entry.get('not_identified_because') or 'see the log'}"
    return text + ")"


def learned_delay_facts(best: dict[str, Any], time_offset: dict[str, Any], truth_paths: list[str],
                        roles: Any) -> tuple[dict[str, float | None] | None, str | None, dict[str, float]]:
    """What the delay table needs besides the learned delays: ({group: true offset} or None, the truth's
    file, {group: the time-offset stage's estimate (its summary entry)}); ``best`` is ``hpo/best.json`` (its
    ``model_spec``)."""
    learned_groups = (best.get("model_spec") or {}).get("delay_groups") or {"inputs": list(roles.input_names)}
    input_channels = {name: roles.signals[roles.inputs[name]].channel for name in roles.input_names}
    true_dt_s, truth_source = true_input_delay(truth_paths, learned_groups, input_channels)
    return true_dt_s, truth_source, dict(time_offset.get("groups") or {})


def chosen_by_text(selection: dict[str, Any] | None) -> str:
    """How the search chose its best configuration (``best.json``'s ``selection``), for the report."""
    if not selection or selection.get("by") != "maneuvers":
        return "the validation objective"
    rank = selection.get("objective_rank")
    rank_text = "the physical layer (ANN at zero)," if rank is None else f"rank {rank} by the objective"
    among = (f"{len(selection['finalists'])} candidates: the finalists and the physical layer"
             if selection.get("physical_layer") is not None else f"{len(selection['finalists'])} finalists")
    return (f"open loop over the whole {' and '.join(selection['maneuvers'])} maneuvers (error "
            f"{_number(selection['score'], 3)} of the FMU's; {rank_text} among {among})")


#: What the report says when a hybrid's search chose its physical layer (no trained configuration beat it without
#: being worse on one of the whole maneuvers).
PHYSICAL_LAYER_CHOSEN = ("No trained configuration of the hybrid's search beat its physical layer over the whole "
                         "train and validation maneuvers without being worse on one of them: the hybrid is the FMU + "
                         "effects with its ANN at zero (the ANN adds nothing here).")


def hybrid_estimates(path: str | Path | None) -> dict[str, dict[str, Any]] | None:
    """{group: summary entry} of the time-offset estimates on the hybrid's physical layer (rule
    ``hybrid_time_offset``), or None without the file."""
    if not path:
        return None
    from hybridfmu.io import read_json

    return dict(read_json(path).get("groups") or {})


def chosen_from_data_lines(record_paths: list[str | Path]) -> list[str]:
    """Markdown list items of every setting a stage chose from the data where the config left it out: the grid
    (``data/grid.json``'s ``text`` and its inputs' conventions ``between_samples``) and each record's ``chosen_from_data`` sentences (a search's plan, the
    time-offset stage), in the order given; [] when the config set everything."""
    from hybridfmu.io import read_json

    lines = []
    for path in record_paths:
        record = read_json(path)
        if record.get("chosen_from") == "data" and record.get("text"):
            lines.append(f"- ingest.rate_hz = {record['text']}")
        lines += [f"- roles.between_samples.{name} = {entry['text']}"
                  for name, entry in (record.get("between_samples") or {}).items()]
        lines += [f"- {sentence}" for sentence in record.get("chosen_from_data") or []]
    return lines


def write_report(report_path: str | Path, case: str, metrics_paths: list[str], best_path: str | Path,
                 run_path: str | Path, time_offset_summary_path: str | Path, figure_paths: dict[str, str],
                 truth_paths: list[str], roles: Any, reference: dict[str, Any] | None = None,
                 log_to_mlflow: bool = True, hybrid_time_offset_path: str | Path | None = None,
                 chosen_paths: list[str] | None = None) -> Path:
    """Write ``report.md`` (figures linked relative to it) and add it and the figures to the evaluation's
    MLflow run.

    Args:
        metrics_paths: ``metrics/<role>.json``; best_path: ``hpo/best.json``; run_path: the evaluation run record.
        time_offset_summary_path: the time-offset window's summary.
        figure_paths: figure name -> PNG path.
        truth_paths: ground-truth JSON files (may be empty: no "true" delay then).
        roles: :class:`hybridfmu.data.roles.CaseRoles` (labels and units of the target signals).
        reference: config ``evaluation.reference`` (factors and figures to compare with), or None.
        hybrid_time_offset_path: the time-offset estimates on the hybrid's physical layer (rule
            ``hybrid_time_offset``, where the hybrid's delays start), or None.
        chosen_paths: records of the settings chosen from the data (``data/grid.json``, the searches' plans;
            :func:`chosen_from_data_lines`); the time-offset summary's are added.
    """
    import os

    from hybridfmu.evaluation.best import best_trial_summary
    from hybridfmu.io import read_json, write_text_atomic

    metrics_by_role = {Path(path).stem: read_json(path) for path in metrics_paths}
    best = read_json(best_path)
    summary = best_trial_summary(best, best_path)
    first = next(iter(metrics_by_role.values()))
    run = read_json(run_path)
    time_offset = read_json(time_offset_summary_path)
    true_dt_s, truth_source, estimates_s = learned_delay_facts(best, time_offset, truth_paths, roles)
    maneuver_roles = {m: role for role, metrics in metrics_by_role.items() for m in metrics.get("maneuvers", [])}
    folder = Path(report_path).parent
    signals = {name: roles.signals[name] for name in roles.target_signals}
    labels = {name: signal.label for name, signal in signals.items()}
    units = {name: signal.unit for name, signal in signals.items()}
    figures = [ReportFigure(os.path.relpath(path, folder),
                            figure_caption(name, maneuver_roles, time_offset, labels, reference))
               for name, path in figure_paths.items()]
    best_facts = {key: summary[key] for key in ("trial_id", "bracket", "rung", "objective", "resource_s",
                                                "mlflow_run_id") if summary.get(key) is not None}
    best_facts["chosen by"] = chosen_by_text(best.get("selection"))
    text = render_report(case, metrics_by_role, summary["hyperparameters"], best_facts, first.get("dt_s"),
                         first.get("gates"), true_dt_s, truth_source, figures, run, units, reference, estimates_s,
                         hybrid_estimates(hybrid_time_offset_path))
    changes = ", ".join(
        f"{signal} MSE {_number(time_offset['mse_without_delay'][signal])} → "
        f"{_number(time_offset['mse_with_delay'][signal])} {squared_unit(units.get(signal, ''))}"
        for signal in time_offset.get("signals", []))
    max_lag_s = time_offset.get("max_lag_s")
    edge_text = (f"That is the edge of the ±{max_lag_s * 1e6:.1f} µs searched (config.evaluation.time_offset."
                 "max_lag_s): the best shift lies there or beyond, or the FMU's other errors decide it. "
                 if max_lag_s and abs(abs(time_offset["input_delay_s"]) - max_lag_s) <= 1e-3 * max_lag_s else "")
    text += ("\n## Time offset seen from the FMU alone\n\n"
             f"Fitting an input delay to the FMU on a short window of '{time_offset['maneuver']}' "
             f"({time_offset['t_start_s']:.4f}–{time_offset['t_end_s']:.4f} s) gives "
             f"{time_offset['input_delay_s'] * 1e6:.1f} µs ({changes}). " + edge_text +
             "On one window the delay also absorbs the FMU's other errors there, so this "
             "estimate is indicative only. Each input group's estimate over many short windows after its inputs "
             "change (the start of the learned delays when `model.input_delay.init_s` is `time_offset`): "
             + "; ".join(group_estimate_text(group, entry)
                         for group, entry in (time_offset.get("groups") or {}).items()) + ".\n")
    chosen = chosen_from_data_lines([*(chosen_paths or []), time_offset_summary_path])
    if chosen:
        text += ("\n## Chosen from the data\n\nSettings the case config leaves out, chosen from this case's logs "
                 "and grid (a value in the config always wins):\n\n" + "\n".join(chosen) + "\n")
    write_text_atomic(report_path, text)
    if log_to_mlflow:
        from hybridfmu.evaluation.tracking import log_report_artifacts

        log_report_artifacts(run_path, list(figure_paths.values()), report_path)
    return Path(report_path)
