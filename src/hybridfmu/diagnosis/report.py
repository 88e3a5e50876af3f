"""Outputs of the diagnosis: ``diagnosis.json``, ``report.md`` and the figures, and the MLflow run."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hybridfmu.diagnosis import figures
from hybridfmu.diagnosis.export import DIAGNOSED_MODEL, save_diagnosed
from hybridfmu.diagnosis.result import is_finding
from hybridfmu.io import write_json_atomic, write_text_atomic
from hybridfmu.numerics import one_math_thread
from hybridfmu.tracking.provenance import code_version

if TYPE_CHECKING:
    from hybridfmu.diagnosis.result import DiagnosisResult, HeldOutCheck

LOGGER = logging.getLogger("hybridfmu.diagnosis")

FIGURES = {
    "equation_error.png": figures.equation_error_figure,
    "regions.png": figures.regions_figure,
    "candidates.png": figures.candidates_figure,
    "effects.png": figures.effects_figure,
}
OPEN_LOOP_FIGURES = {
    "waterfall.png": figures.waterfall_figure,
    "open_loop_test.png": figures.open_loop_figure,
    "error_growth.png": figures.growth_figure,
}


def json_safe(value: Any) -> Any:
    """JSON-safe copy: NumPy to Python, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_safe(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(float(value)) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def table_cell(text: str) -> str:
    """Text for a Markdown table cell (``|`` escaped, as in ``coulomb(v)*|u|``)."""
    return str(text).replace("|", "\\|")


def equations_text(item: dict[str, Any]) -> str:
    """``d<state>/dt`` of every equation a named effect acts on (a change of an input or a parameter acts on
    several), the one it explains most first."""
    states = [item["equation"]] + [s for s in item.get("equations") or [] if s != item["equation"]]
    return ", ".join(f"d{s}/dt" for s in states)


def _relative_error_text(item: dict[str, Any]) -> str:
    """``+4.1 %``: a chosen parameter error's ``relative_error`` (a fraction) in percent."""
    row = next((r for r in item.get("parameters", []) if r["name"] == "relative_error"), None)
    if row is None or row.get("value") is None:
        return "relative error not reported"
    return f"{100.0 * float(row['value']):+.3g} %"


def group_text(group: dict[str, Any]) -> str:
    """``A and B`` / ``A, B and C`` of a group of effects the data do not tell apart."""
    names = group["effects"]
    return " and ".join([", ".join(names[:-1]), names[-1]]) if len(names) > 1 else names[0]


def not_identified(chosen: list[dict[str, Any]]) -> list[str]:
    """``<effect>: <parameter>`` of every fitted parameter of the chosen effects that the data do not identify
    (:mod:`hybridfmu.diagnosis.identification`)."""
    return [f"{c['effect']}: {p['name']}" for c in chosen for p in c["parameters"] if p.get("identified") is False]


def rival_text(item: dict[str, Any]) -> str | None:
    """``parameter(b): relative_error 4.05, with time_offset(tau_load) beside it 1.51`` for a chosen effect whose
    estimate rests on leaving out a rival (:class:`hybridfmu.diagnosis.selection.Rival`), or None."""
    rivals = item.get("rivals") or []
    if not rivals:
        return None
    values = {p["name"]: p["value"] for p in item["parameters"]}
    parts = []
    for rival in rivals:
        moved = ", ".join(f"{name} {format_number(value, 3)}" for name, value in rival["values"].items())
        parts.append(f"with {rival['effect']} beside it {moved}")
    own = ", ".join(f"{name} {format_number(values.get(name), 3)}" for name in rivals[0]["values"])
    return f"{item['effect']}: {own}; " + "; ".join(parts)


def verdict(result: DiagnosisResult) -> str:
    """One paragraph: which equation carries the gap, what was found, how far it shrank."""
    problem = result.problem
    where = result.where
    chosen = result.which.chosen
    parts = []
    carrier = where["carrier"]
    if carrier:
        s = where["states"][carrier]
        parts.append(f"The equation of {problem.labels.get(carrier, carrier)} ({carrier}) carries the largest gap "
                     f"(equation error {s['rms_residual']:.3g} {s['unit']} RMS, {s['ratio_to_noise']:.2f} x its "
                     "noise floor).")
    if chosen:
        named = [c for c in chosen if is_finding(c)]
        unmodelled = [c for c in named if c["kind"] != "parameter"]
        errors = [c for c in named if c["kind"] == "parameter"]
        if unmodelled:
            names = ", ".join(f"{k}. {c['effect']} in {equations_text(c)}" for k, c in enumerate(unmodelled, 1))
            parts.append(f"Unmodelled effects named (rank order): {names}.")
        else:
            parts.append("No unmodelled effect is named.")
        if errors:
            names = ", ".join(f"{c['effect']} ({_relative_error_text(c)})" for c in errors)
            parts.append(f"Parameter errors of the model: {names}.")
        adjusted = [c["effect"] for c in chosen if c.get("role") == "adjustment"]
        if adjusted:
            parts.append("Fitted beside them, not named (the data support it, and leaving it out would move a named "
                         f"estimate out of its interval): {', '.join(adjusted)}.")
        unsure = [f"{c['effect']} in {equations_text(c)}" for c in chosen if c.get("role") == "unconfirmed"]
        if unsure:
            parts.append("In the model but not named, unconfirmed (it lowers the pooled fit's criterion, but no size of "
                         "it is identified: the fitting maneuvers, the bootstrap or a rival leave open whether it is "
                         f"there at all): {', '.join(unsure)}.")
        for group in result.which.groups:
            parts.append(f"{group_text(group)} cannot be told apart by these data (their estimates correlate "
                         f"at {max(abs(p['correlation']) for p in group['pairs']):.2f}): only their joint effect is "
                         "determined.")
        resting = [text for text in map(rival_text, chosen) if text]
        if resting:
            parts.append("Estimates resting on a term left out (the data support it beside the named effects, "
                         "below the thresholds of naming; the 90 % intervals reach both values): "
                         + " | ".join(resting) + ".")
        vague = not_identified(chosen)
        if vague:
            parts.append("Not identified with these data (the 90 % interval of the combined uncertainty covers zero or "
                         f"spans more than a factor 10): {', '.join(vague)}.")
    else:
        ratios = ", ".join(f"d{k}/dt: {v['ratio_to_noise']:.2f}" for k, v in where["states"].items())
        parts.append("No candidate effect explains a significant part of the equation error: nothing is named "
                     f"(equation error / noise floor: {ratios}).")
    far = result.how_far
    if far:
        before, after = far.before, far.after
        quoted = "; ".join(f"{problem.labels.get(s, s)} RMS {before[f'{sig}_rmse']:.4g} -> {after[f'{sig}_rmse']:.4g} "
                           f"{problem.unit(s)}" for s, sig in ((s, problem.state_signal[s])
                                                                  for s in problem.target_weights))
        parts.append(f"Open loop on the held-out test data: {quoted} (normalised gap {far.gap_before:.4g} -> "
                     f"{far.gap_after:.4g}, factor {far.shrink_factor:.3g}"
                     + (f"; the effects beyond the parameter corrections {_factor(far.effect_shrink_factor)}"
                        + (f", over the windows {_factor(far.window_effect_shrink_factor)}"
                           if far.window_effect_shrink_factor is not None else "")
                        if far.parameters_only else "") + ").")
        hold = far.standstill_hold or {}
        if hold.get("band") is not None:
            state = hold["state"]
            parts.append(f"The diagnosed model holds {problem.labels.get(state, state)} at rest by its friction below "
                         f"{hold['band']:.4g} {problem.unit(state)} (the band with the smallest open-loop gap over "
                         f"the fitting maneuvers {', '.join(hold['maneuvers'])}; the held-out figures above include it).")
    elif result.how_far_not_run:
        parts.append(f"Held-out check not run: {result.how_far_not_run}")
    return " ".join(parts)


def settings_digest(section: dict[str, Any]) -> str:
    """A short fingerprint (12 hex digits of SHA-256) of a config's ``diagnosis`` section as written: two diagnoses
    with the same digest were asked for with the same settings (keys in any order)."""
    import hashlib
    import json

    text = json.dumps(json_safe(section), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def diagnosis_record(result: DiagnosisResult, config: dict[str, Any]) -> dict[str, Any]:
    """The content of ``diagnosis.json``."""
    problem = result.problem
    which = result.which
    far = result.how_far
    growth = result.growth
    settings = result.settings
    record = {
        "case": config.get("case"),
        "code": code_version(),  # which code made this record (a summary over many records names it)
        # which settings made it: the case config's diagnosis section as written (a summary over many records
        # that should share them checks that they do)
        "settings_digest": settings_digest(config.get("diagnosis") or {}),
        "maneuvers": {name: m["role"] for name, m in config["maneuvers"].items()},
        "fit_maneuvers": result.fit_names, "test_maneuvers": result.test_names,
        "calibration": result.calibration, "model_parameters": result.model_parameters,
        "report_scale": dict(settings.get("report_scale") or {}),
        "method": {
            "equation_error": "measured one-sample change minus the model's (RK4 step for one_step_states, "
                              "trapezoid for the others) with inputs held over each sample (a continuous input at its "
                              "mean over the sample, config.roles.between_samples), averaged with a Hann kernel",
            "unmeasured_states": "taken from an open-loop simulation of the calibrated model",
            "kernel_s": settings.get("kernel_s"), "kernel_choice": problem.kernel_choice,
            "state_from_derivative": settings.get("state_from_derivative"),
            "input_lag_compensation_s": settings.get("input_lag_compensation_s", {}),
            "selection": settings.get("selection", {}), "plugins": settings.get("plugins", []),
        },
        "problem": {"state_names": problem.state_names, "input_names": problem.input_names,
                    "measured_states": [problem.state_names[i] for i in problem.measured],
                    "unmeasured_states": [problem.state_names[i] for i in problem.unmeasured],
                    "equations": [problem.state_names[i] for i in problem.equations],
                    "signals": {**problem.state_signal, **problem.input_signal},
                    "units": problem.units, "labels": problem.labels, "targets": problem.target_weights},
        "verdict": verdict(result),
        "where": {
            "equations": result.where,
            "regions": result.regions,
            "open_loop_growth": [{k: v for k, v in item.items() if k != "normalised_error"} for item in (growth or [])],
        },
        "which": {
            "found_effects": which.found_effects,
            "chosen": which.chosen, "equations": which.equations, "steps": which.steps,
            "calibration": which.calibration,
            "skipped_candidates": which.skipped,
            "periodic_orders": which.periodic_orders,
            "indistinguishable": which.groups,
        },
        "how_far": None if far is None else held_out_record(far),
        "how_far_not_run": result.how_far_not_run if far is None else None,
    }
    return json_safe(record)


def held_out_record(far: HeldOutCheck) -> dict[str, Any]:
    """``diagnosis.json``'s ``how_far``: the check without its trajectories and model; the window figures only when
    the check ran over windows."""
    record = {"steps": far.steps, "before": far.before, "after": far.after, "gap_before": far.gap_before,
              "gap_after": far.gap_after, "shrink_factor": far.shrink_factor, "notes": far.notes}
    if far.windowed:
        record.update(window=far.window, window_gap_before=far.window_gap_before,
                      window_gap_after=far.window_gap_after)
    record.update(parameters_only=far.parameters_only, parameter_shrink_factor=far.parameter_shrink_factor,
                  effect_shrink_factor=far.effect_shrink_factor, standstill_hold=far.standstill_hold)
    if far.windowed:
        record.update(window_parameter_shrink_factor=far.window_parameter_shrink_factor,
                      window_effect_shrink_factor=far.window_effect_shrink_factor)
    return record


def window_text(window: dict[str, Any] | None) -> str:
    """How long the held-out check's restarted windows are and why, one sentence (empty without a record)."""
    if not window:
        return ""
    if window.get("chosen") != "data":
        return f"The windowed gap restarts the models from the measured state every {window['window_s']:.4g} s " \
               "(diagnosis.open_loop.window_s)."
    takes = ", ".join(f"{n} {v:.3g} s" for n, v in window["take_off_s"].items())
    return (f"The windowed gap restarts the models from the measured state every {window['window_s']:.4g} s: the "
            f"median time the model alone, restarted at {window['starts']} points of the fitting maneuvers, stays "
            f"within the growth threshold of the data ({takes}; at most {window['longest_s']:.3g} s).")


def format_number(value: Any, digits: int = 4) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _factor(value: float | None) -> str:
    """A shrink factor as ``×<value>`` (3 significant digits), ``-`` when there is none."""
    return "-" if value is None else f"×{value:.3g}"


def attribution_sentence(far: dict[str, Any]) -> str:
    """The held-out shrink split into the parameter corrections' and the named effects' parts (report wording)."""
    only = far["parameters_only"]
    corrected = ", ".join(only["effects"]) or "none"
    windowed = far.get("window_effect_shrink_factor") is not None
    return (f"Attributed: the model with only its parameter errors corrected ({corrected}) has the normalised gap "
            f"{format_number(only.get('gap'))}" + (f" (windowed {format_number(only.get('window_gap'))})" if windowed
                                                     else "") +
            f", a factor {_factor(far.get('parameter_shrink_factor'))} from the model alone"
            + (f" (windowed {_factor(far.get('window_parameter_shrink_factor'))})" if windowed else "") +
            f"; the named effects on top of it shrink the gap by {_factor(far.get('effect_shrink_factor'))}"
            + (f" (windowed {_factor(far.get('window_effect_shrink_factor'))})" if windowed else "") +
            ". This second factor is what the effects themselves explain on the held-out data; it is about ×1 when "
            "they explain nothing there.")


#: Units the report expresses scaled effect sizes in, where their dimension fits (pint's ``to_preferred``).
PREFERRED_UNITS = ("N", "m", "s", "rad", "V", "A")


def scaled_size(value: float, unit: str, scale: str | None) -> str:
    """``value`` (in ``unit``) times the quantity ``scale`` (e.g. "1.2 kg"), in the preferred units; "-" without a
    scale or where the unit or the scale is no quantity pint reads."""
    if not scale or not unit:
        return "-"
    from hybridfmu.units import UREG, UnitError, parse_quantity, parse_unit

    try:
        quantity = (float(value) * parse_unit(unit)) * parse_quantity(scale)
        preferred = quantity.to_preferred([UREG.Unit(name) for name in PREFERRED_UNITS])
    except (UnitError, ValueError, TypeError, AttributeError, KeyError) as err:
        LOGGER.debug("no scaled size for %s %s x %s: %s", value, unit, scale, err)
        return "-"
    return f"{preferred.magnitude:.4g} {preferred.units:~P}"


def periodic_order_lines(searches: dict[str, dict[str, Any]]) -> list[str]:
    """Markdown lines on the periodic orders found in the data (``which.periodic_orders``); none when every
    periodic effect's orders were configured."""
    if not searches:
        return []
    lines = ["Periodic orders found in the equation errors of the fitting maneuvers (not configured):", ""]
    for label, found in searches.items():
        shares = ", ".join(f"{k} ({100 * found['explained_share'][str(k)]:.2g} % of the error's energy)"
                           for k in found["orders"])
        lines.append(f"- {label}: orders up to {found['max_order_resolved']} resolved by the fitting kernel; "
                     f"searched: {shares or 'none'}")
    return lines + [""]


def kernel_note(method: dict[str, Any]) -> str:
    """The report's line on the Hann kernel: its length and, when the config left it out, why."""
    choice = method.get("kernel_choice")
    if not choice:
        return f"- Kernel: {format_number(method.get('kernel_s'))} s (config diagnosis.kernel_s)."
    return (f"- Kernel: {format_number(choice['kernel_s'])} s ({choice['samples']} samples; config diagnosis.kernel_s "
            f"is null): {choice['reason']}.")


def report_markdown(record: dict[str, Any], figure_names: list[str]) -> str:
    """``report.md``: the diagnosis in words, tables and figures (names with labels and units of the roles)."""
    prob = record["problem"]
    labels, units = prob["labels"], prob["units"]

    def named(state: str) -> str:
        return f"{labels.get(state, state)} (`{state}`)"

    lines = [f"# Diagnosis of the sim-to-real gap: case `{record['case']}`", "", record["verdict"], ""]
    eq = record["where"]["equations"]
    lines += ["## Where", "", "### Equation error per state", "",
              "Kernel-averaged equation error (measured minus model derivative) at the fitting centres of all "
              "maneuvers; the noise floor is the same quantity computed from a realisation of the measurement noise "
              "on the measured states. Measured states: " + ", ".join(named(s) for s in prob["measured_states"]) + "."]
    if prob["unmeasured_states"]:
        lines += ["", "Unmeasured states (" + ", ".join(f"`{s}`" for s in prob["unmeasured_states"]) + ") have no "
                  "estimated derivative; where an examined equation depends on them, their values come from an "
                  "open-loop simulation of the calibrated model (so its error there includes theirs)."]
    lines += ["", "| equation | RMS residual | noise floor | ratio | spread of derivative | normalised excess | "
              "depends on unmeasured |", "|---|---|---|---|---|---|---|"]
    for name, s in eq["states"].items():
        lines.append(f"| d{name}/dt, {labels.get(name, name)} [{s['unit']}] | {format_number(s['rms_residual'])} | "
                     f"{format_number(s['noise_floor'])} | {format_number(s['ratio_to_noise'], 3)} | {format_number(s['derivative_spread'])} | "
                     f"{format_number(s['normalised_excess'], 3)} | {', '.join(s['depends_on_unmeasured']) or '-'} |")
    if eq["carrier"]:
        lines += ["", f"The gap is carried mainly by the equation of **{named(eq['carrier'])}**."]
    lines += ["", "### Operating regions", ""]
    for state, info in record["where"]["regions"].items():
        lines.append(f"**Equation of {named(state)}** ({info['unit']}):")
        lines += [f"- {s}" for s in info["statements"]]
        top = info.get("top_time_bins", [])[:4]
        if top:
            lines += ["", "Time spans with the most residual energy: " + "; ".join(
                f"{t['maneuver']} {t['t_start_s']:.4g}-{t['t_end_s']:.4g} s ({100 * t['energy_share']:.0f} %, "
                f"{format_number(t['ratio_to_noise'], 3)} x noise)" for t in top) + "."]
        lines.append("")
    growth = record["where"]["open_loop_growth"]
    if growth:
        lines += ["### Over time: where the open-loop error grows", "",
                  "| maneuver | role | target | normalised error first exceeds the threshold at | final |",
                  "|---|---|---|---|---|"]
        for item in growth:
            for signal, t in item["targets"].items():
                at = "never" if t["exceeds_threshold_at_s"] is None else f"{t['exceeds_threshold_at_s']:.4g} s"
                lines.append(f"| {item['maneuver']} | {item['role']} | {signal} | {at} "
                             f"({format_number(item['threshold_relative'])} x spread) | {format_number(t['final_normalised_error'], 3)} |")
        lines.append("")
    which = record["which"]
    lines += ["## Which", ""]
    if not which["chosen"]:
        lines += ["No candidate effect is named: none removes enough of the equation error "
                  "(see the candidate tables below).", ""]
    for group in which.get("indistinguishable") or []:
        pairs = "; ".join(f"{a} and {b}: r = {format_number(p['correlation'], 3)}"
                          for p in group["pairs"] for a, b in [p["effects"]])
        lines += [f"**Not told apart:** {group_text(group)}. Their coefficients' estimates correlate ({pairs}), so the "
                  "data fix their joint effect but not how it splits between them; read their sizes together.", ""]
    if which["chosen"]:
        lines += ["Each parameter's combined SE is the largest of the regression's, the bootstrap's and the standard "
                  "deviation of the fitting maneuvers each fitted alone; a size whose 90 % interval covers zero or spans "
                  "more than a factor 10, or a positive scale searched on a log scale (a smoothing) whose interval on "
                  "that scale spans more than a factor 10, is not identified by these data (a location such as a "
                  "threshold is not judged).", ""]
    for c in which["chosen"]:
        acting = [named(e) for e in c.get("equations") or [c["equation"]]]
        scale = (record.get("report_scale") or {}).get(c["equation"])
        lines += [f"### {c['rank']}. `{c['effect']}` in the equation of {named(c['equation'])}"
                  + (f" (one value in the equations of {', '.join(acting)})" if len(acting) > 1 else "")
                  + {"adjustment": " — an adjustment, not a finding",
                     "unconfirmed": " — unconfirmed: no size of it is identified, not a finding"}.get(c.get("role"), ""),
                  "",
                  f"{c['description']}: `{c['formula']}` (in {c['equation_unit']}). Drop-one score {c['score']:.4g} "
                  "(increase of the residual sum of squares without it, in residual variances).", "",
                  "| parameter | value | SE (regression) | SE (bootstrap over segments) | unit | spread over fitting "
                  "maneuvers | 90 % interval (combined SE) | identified |" + (f" × {scale} |" if scale else ""),
                  "|---|---|---|---|---|---|---|---|" + ("---|" if scale else "")]
        for p in c["parameters"]:
            stab = c["stability"].get(p["name"])
            spread = f"{100 * stab['relative_spread']:.1f} %" if stab else "-"
            interval = p.get("interval_90")
            interval = f"{format_number(interval[0], 3)} .. {format_number(interval[1], 3)}" if interval else "-"
            judged = {True: "yes", False: f"no: {p.get('not_identified_because')}", None: "-"}[p.get("identified")]
            lines.append(f"| {p['name']} | {format_number(p['value'], 5)} | {format_number(p['se'], 3)} | {format_number(p.get('se_bootstrap'), 3)} "
                         f"| {p['unit'] or '-'} | {spread} | {interval} | {judged} |"
                         + (f" {scaled_size(p['value'], p['unit'], scale)} |" if scale else ""))
        lines.append("")
        for rival in c.get("rivals") or []:
            moved = ", ".join(f"{name} {format_number(value, 4)}" for name, value in rival["values"].items())
            lines += [f"Fitted with `{rival['effect']}` beside it: {moved}. The data support that term too (BIC "
                      f"{format_number(rival['bic_drop'], 4)} lower with it), but it was not named ("
                      f"{rival['rejected_because'] or 'it entered no step'}); the data do not decide between the "
                      "two estimates, and the 90 % intervals above reach both.", ""]
    lines += ["### Candidates and selection steps", "",
              "All examined equations are fitted together, each in units of its noise floor: a change of an input "
              "or a model parameter takes one value in every equation it acts on; a local term acts on its own. "
              "A candidate's residual removed is measured on the equation(s) it acts on.", ""]
    for state, info in which["equations"].items():
        lines.append(f"- **Equation of {named(state)}**: {info['n_candidates']} candidates, {info['n_samples']} samples, "
                     f"{100 * info['explained_share']:.1f} % of the residual explained by the chosen effects "
                     f"({', '.join(info['chosen']) or 'none'}); chosen per fitting maneuver alone: "
                     f"{info['selection_per_maneuver'] or '-'}")
    lines.append("")
    if which.get("calibration"):
        lines += ["Parameter errors are fitted from the start (a calibration in equation-error form, refitted with "
                  "every candidate); each is kept only if it would pass the selection's thresholds entering last.", "",
                  "| parameter error | equation(s) | relative error | BIC drop | outcome |", "|---|---|---|---|---|"]
        for row in which["calibration"]:
            where = ", ".join(f"d{e}/dt" for e in row.get("equations") or [])
            error = (f"not identifiable with these data (its sensitivity is a combination of "
                     f"{', '.join(row['not_identifiable_with'])})" if row.get("not_identifiable_with")
                     else format_number(row.get("relative_parameter_error"), 3))
            lines.append(f"| {table_cell(row['effect'])} | {where} | {table_cell(error)} | "
                         f"{format_number(row.get('bic_drop'), 4)} | {table_cell(row['outcome'])} |")
        lines.append("")
    for k, step in enumerate(which.get("steps") or [], start=1):
        title = f"Step {k} (exchange): {step['chosen']} {step['reason']}" if step.get("kind") == "exchange" else \
            f"Step {k}: {step['reason']}" + (f" ({step['chosen']})" if step.get("chosen") else "")
        lines += [title + ".", "",
                  "| candidate | equation(s) | setting | residual removed | BIC drop |", "|---|---|---|---|---|"]
        ranked = sorted(step["candidates"], key=lambda c: c["bic"])[:12]
        for cand in ranked:
            setting = ", ".join(f"{key}={format_number(v, 4)}" for key, v in cand["setting"].items()) or "-"
            where = ", ".join(f"d{e}/dt" for e in cand.get("equations") or [])
            lines.append(f"| {table_cell(cand['effect'])} | {where} | {setting} | {100 * cand['relative_improvement']:.2f} % | "
                         f"{format_number(cand.get('bic_drop'), 4)} |")
        if len(step["candidates"]) > len(ranked):
            lines.append(f"| ... {len(step['candidates']) - len(ranked)} more | | | | |")
        lines.append("")
    if which["skipped_candidates"]:
        lines += ["Left out: " + "; ".join(f"{k} ({v})" for k, v in which["skipped_candidates"].items()), ""]
    lines += periodic_order_lines(which.get("periodic_orders") or {})
    far = record.get("how_far")
    if far:
        signals = [prob["signals"][s] for s in prob["targets"]]
        states = list(prob["targets"])
        head = " | ".join(f"{labels.get(s, s)} RMS [{units.get(s, '') or '-'}] | MAE" for s in states)
        windowed = "window_gap" in far["before"]
        refitted = any("refit" in s for s in far["steps"])
        how = ("each variant, the model alone among them, recalibrated with its effects by output error on the train "
               "maneuver(s) (the calibration's parameters, the effects' coefficients and refined settings, the "
               "unmeasured initial states; diagnosis.open_loop.refit), each from the optimum of the variant before "
               "it and from the new effect at zero coefficients, so the train cost does not rise where zero switches the "
               "effect off (an additive term, an input or parameter change)") if refitted else \
            "the equation-error fits of the effects added to the calibrated model"
        lines += ["## How far", "",
                  "Open loop on the held-out test maneuver(s) (no fit saw them) from the smoothed measured initial "
                  "state (a local polynomial fit over diagnosis.smoothing_s, so that one noisy sample does not decide "
                  "the start; unmeasured states from the calibration), with the chosen effects added one at a time in "
                  "rank order: "
                  "additive terms in their equations, input effects on the logged inputs, parameter errors as corrected "
                  f"parameters; {how}. The normalised gap is the target-weighted MAE over the spread of each target."
                  + (" " + window_text(far.get("window")) if windowed else ""),
                  "", f"| model | {head} | normalised gap |" + (" windowed gap |" if windowed else "") +
                  (" train cost |" if refitted else ""),
                  "|---|" + "---|---|" * len(states) + "---|" + ("---|" if windowed else "") +
                  ("---|" if refitted else "")]
        for s in far["steps"]:
            cells = " | ".join(f"{format_number(s.get(f'{sig}_rmse'))} | {format_number(s.get(f'{sig}_mae'))}" for sig in signals)
            lines.append(f"| {table_cell(s['model'])} | {cells} | {format_number(s.get('gap'))} |" +
                         (f" {format_number(s.get('window_gap'))} |" if windowed else "") +
                         (f" {format_number(s['refit']['cost'])} |" if "refit" in s else (" - |" if refitted else "")))
        lines += ["", f"Normalised gap: {format_number(far['gap_before'])} -> {format_number(far['gap_after'])}, factor "
                      f"{format_number(far['shrink_factor'], 3)}. The evaluation (report.md, summary.md) simulates the "
                      "same FMU + effects from the raw first sample of each maneuver, as it does every model, so its "
                      "errors differ from these by what the start's noise makes."]
        if far.get("parameters_only"):
            lines += ["", attribution_sentence(far)]
        risen = [s["model"] for s in far["steps"] if (s.get("refit") or {}).get("above_previous")]
        if risen:
            lines += ["", "**The train cost rose** with " + ", ".join(table_cell(m) for m in risen) + ": the "
                      "recalibration started from the variant before and could not bring it back, because the effect "
                      "acts at any coefficients (a limit, an overflow); its figures are a local optimum."]
        last = next((s for s in reversed(far["steps"]) if "refit" in s), None)
        if last is not None:
            lines += ["", f"Recalibrated variables of the last variant ({table_cell(last['model'])}; train cost "
                          f"{format_number(last['refit']['cost_start'])} -> {format_number(last['refit']['cost'])}, "
                          f"{last['refit']['evaluations']} simulations):", "",
                      "| variable | start | recalibrated |", "|---|---|---|"]
            lines += [f"| {table_cell(name)} | {format_number(v['start'])} | {format_number(v['fitted'])} |"
                      for name, v in last["refit"]["variables"].items()]
        lines += [f"- {note}" for note in far.get("notes", [])] + [""]
    else:
        reason = record.get("how_far_not_run") or "The held-out check on test maneuvers was not run."
        lines += ["## How far", "", f"**Not run.** {reason}", ""]
    lines += ["## Figures", ""] + [f"![{name}]({name})" for name in figure_names] + [""]
    lines += ["## Notes", "",
              "- The diagnosis reads only the FMU, its calibration, the ingested logs and their segments.",
              kernel_note(record["method"]),
              "- Standard errors: regression ones assume independent samples one kernel length apart; bootstrap ones "
              "resample segment blocks with the nonlinear settings fixed.", ""]
    return "\n".join(lines)


def write_outputs(result: DiagnosisResult, config: dict[str, Any], out_dir: str | Path) -> dict[str, Any]:
    """Write ``diagnosis.json``, ``report.md``, the figures and the diagnosed model (``diagnosed_model.pkl``,
    :mod:`hybridfmu.diagnosis.export`) to ``out_dir``; return the record and paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    dpi = int(result.settings.get("figures_dpi") or 120)
    record = diagnosis_record(result, config)
    makers = dict(FIGURES)
    if result.how_far:
        makers.update(OPEN_LOOP_FIGURES)
    written = []
    for name, maker in makers.items():
        written.append(maker(result, out_dir / name, dpi))
    if result.diagnosed is not None:
        save_diagnosed(result.diagnosed, out_dir / DIAGNOSED_MODEL)
    write_json_atomic(out_dir / "diagnosis.json", record)
    write_text_atomic(out_dir / "report.md", report_markdown(record, [p.name for p in written]))
    return {"record": record, "figures": written, "json": out_dir / "diagnosis.json", "report": out_dir / "report.md"}


def log_to_mlflow(record: dict[str, Any], paths: dict[str, Any], config: dict[str, Any]) -> str:
    """Log the diagnosis as an MLflow run (tag ``hybridfmu.role = diagnosis``); return the run id."""
    from hybridfmu.tracking import Tracker, experiment_name, redacted_uri, tracking_uri

    uri = tracking_uri(config.get("mlflow"), Path(config.get("results_dir", "results")).resolve())
    tracker = Tracker(uri)
    experiment_id = tracker.experiment_id(experiment_name(config.get("mlflow"), config["case"]))
    run_id = tracker.call("create_run", experiment_id, tags={"hybridfmu.role": "diagnosis", "case": config["case"]},
                          run_name="diagnosis").info.run_id
    try:
        metrics = []
        for state, s in record["where"]["equations"]["states"].items():
            metrics.append((f"where/{state}/rms_residual", s["rms_residual"], 0))
            metrics.append((f"where/{state}/ratio_to_noise", s["ratio_to_noise"], 0))
        far = record.get("how_far")
        if far:
            for step_index, step in enumerate(far["steps"]):
                for key, value in step.items():
                    if key not in ("model", "effects", "per_maneuver") and isinstance(value, (int, float)):
                        metrics.append((f"how_far/{key}", value, step_index))
            for key in ("gap_before", "gap_after", "shrink_factor", "parameter_shrink_factor", "effect_shrink_factor",
                        "window_parameter_shrink_factor", "window_effect_shrink_factor"):
                if far.get(key) is not None:
                    metrics.append((f"gap/{key}", far[key], 0))
        params = {"found_effects": ",".join(record["which"]["found_effects"]) or "none"}
        for c in record["which"]["chosen"]:
            for p in c["parameters"]:
                params[f"{c['equation']}.{c['effect']}.{p['name']}"[:250]] = f"{p['value']:.6g}"
        tracker.log(run_id, params=params, metrics=[m for m in metrics if m[1] is not None])
        for path in [paths["json"], paths["report"], *paths["figures"]]:
            tracker.log_artifact(run_id, path, artifact_path="diagnosis")
    except Exception:
        tracker.set_status(run_id, "FAILED")
        raise
    tracker.set_status(run_id, "FINISHED")
    LOGGER.info("MLflow diagnosis run %s (%s)", run_id, redacted_uri(uri))
    return run_id


def diagnose(config: dict[str, Any], fmu_path: str | Path, data_paths: dict[str, str | Path],
             segments_paths: dict[str, str | Path], out_dir: str | Path, mlflow: bool = True,
             calibration_path: str | Path | None = None, workers: int = 1) -> dict[str, Any]:
    """Diagnose the sim-to-real gap of a case; write ``diagnosis.json``, ``report.md`` and figures.

    Args:
        config: validated case config (sections ``diagnosis``, ``signals``, ``transforms``, ``roles``, ``model``,
            ``maneuvers``, ``fmu``, ``mlflow``).
        fmu_path: the case's FMU.
        data_paths, segments_paths: maneuver -> ingested Parquet / segments JSON (all maneuvers of the case).
        out_dir: ``{results}/diagnosis``.
        mlflow: log the run to MLflow.
        calibration_path: ``{results}/calibration/calibration.json`` (calibrated parameters and unmeasured
            initial states), or None for the FMU with ``config.fmu.parameters``.
        workers: processes the diagnosis may use (the rule's threads; the same results with any number).
    Returns:
        The ``diagnosis.json`` record.
    """
    from hybridfmu.diagnosis.run import analyse

    with one_math_thread():  # workers are processes: each computes on one thread, as every job does
        result = analyse(config, fmu_path, data_paths, segments_paths, calibration_path, workers=workers)
    paths = write_outputs(result, config, out_dir)
    if mlflow:
        paths["record"]["mlflow_run_id"] = log_to_mlflow(paths["record"], paths, config)
        write_json_atomic(paths["json"], paths["record"])
    LOGGER.info("diagnosis: %s", paths["record"]["verdict"])
    return paths["record"]
