"""Scoring one withheld case: the diagnosis' findings against the bench's ground truth and the case's draw.

This is the scoring side of the withheld-effect check (:mod:`hybridfmu_bench.withheld.suite`): the only code that
reads the bench's truth (``<case>/raw/<maneuver>.truth.json``) and the draw record (``cases/<case>.draw.json``).

Names. The bench names its effects (``coulomb_friction``, ``cogging``, ...), the diagnosis names generic terms
over roles (``coulomb(omega)``, ``periodic(theta)``, ...). The config's table ``withheld.expected`` maps each
bench effect to fnmatch patterns of diagnosis effect names; a named effect counts as the first bench effect whose
pattern it matches. Every named effect of a case is then one of

- a finding of a withheld effect (it maps to one of the case's bench effects);
- a finding of a true parameter offset: ``parameter(<p>)`` for a parameter the case's bench offsets (reported in
  the offset columns; not an extra effect);
- a finding of a background condition: a property of the bench present in every case, withheld from none and
  modelled by no FMU (e.g. the lag of a sensor), named in ``withheld.background`` (condition -> patterns);
  reported in the column ``background_found``, not an extra effect;
- an extra: anything else (kept under its bench effect's name if it maps to one, else its own name).

``exact`` is True when the set of found effects (withheld findings and extras, not the offsets) equals the
withheld set: an extra or a missed effect makes it False. For a case without effects, exact means that nothing
but true offsets was named.

Effect size (column ``effect_size``). For each withheld effect: the square root of the largest first-step
``relative_improvement`` of the candidates that match the effect's ``withheld.expected`` patterns, over all
examined equations; for a calibrated parameter error, the share of the residual it removes entering last. The
first selection step fits every candidate beside the calibrated parameter errors alone, so this is the share of
the equation error's RMS left by the calibration that the effect can explain by itself (0 = nothing, 1 = all of
it; the rest is noise and the other effect of a pair). It is measured on the case's own data, so cases of
different effects and maneuvers are comparable on one axis; the bench's size scale is reported beside it.

Parameter error (column ``parameter_error_pct``): |fitted - true| / |true| x 100 of the withheld effect's size
parameter, the diagnosis' physical parameter converted to the bench's by :data:`SCORING` (below), from the
top-ranked named effect that maps to it (preferring one named in the equation the effect acts on). J is the
model's inertia (``diagnosis.json`` ``model_parameters.J``, else the bench's nominal J, which the FMU shares);
the PWM frequency is the bench's.

Parameter error with the rival beside (column ``parameter_error_with_rival_pct``): the same for the value the
diagnosis reports with the effect's first rival fitted beside it (``rivals`` of the named effect: a candidate the
data support that was not named, :class:`hybridfmu.diagnosis.selection.Rival`); empty where no rival moves the
estimate.

Where (column ``where_correct``): every withheld effect was named in an equation it acts on (``SCORING``:
torque effects and the inertia in d omega/dt, the dead time and the duty time offset in d i_d/dt or d i_q/dt).
"""

from __future__ import annotations

import fnmatch
import json
import math
import re
from dataclasses import dataclass
from typing import Any, Callable

from hybridfmu.diagnosis.result import is_finding

__all__ = ["SCORING", "EffectScoring", "Conversion", "ScoringContext", "ScoreMismatch", "bench_effect_of",
           "effect_size", "score_case", "rejected_candidates", "selection_thresholds", "true_size"]


class ScoreMismatch(ValueError):
    """The named effect has a different structure than the bench's (e.g. another cogging order)."""


@dataclass(frozen=True)
class ScoringContext:
    """What converts the diagnosis' parameters to the bench's.

    Attributes:
        inertia_kg_m2: the model's rotor inertia J (kg m^2): (rad/s^2) x J = N m.
        pwm_frequency_hz: the bench's PWM frequency (Hz): dead time = duty error / f_pwm.
        true_parameters: the bench parameters of the scored effect (the cogging order to look for).
    """

    inertia_kg_m2: float
    pwm_frequency_hz: float
    true_parameters: dict[str, Any]


@dataclass(frozen=True)
class Conversion:
    """A diagnosis effect (fnmatch ``pattern``) whose physical parameters give the bench's size parameter."""

    pattern: str
    fitted: Callable[[dict[str, float], ScoringContext], float]
    description: str


@dataclass(frozen=True)
class EffectScoring:
    """How a bench effect is scored.

    Attributes:
        size_parameter: the compared quantity (bench parameter name or expression) and ``unit``.
        true_value: bench parameters -> the compared quantity (signed where the sign matters).
        equations: the states whose equation the effect acts on.
        conversions: the diagnosis effects that estimate it.
    """

    size_parameter: str
    unit: str
    true_value: Callable[[dict[str, Any]], float]
    equations: tuple[str, ...]
    conversions: tuple[Conversion, ...]


def _load_coefficient(p: dict[str, float], ctx: ScoringContext) -> float:
    if "coefficient" in p:
        return p["coefficient"] * ctx.inertia_kg_m2
    return 0.5 * (p["coefficient_positive"] + p["coefficient_negative"]) * ctx.inertia_kg_m2


def _cogging_amplitude(p: dict[str, float], ctx: ScoringContext) -> float:
    order = int(ctx.true_parameters["harmonics"][0]["order_per_rev"])
    key = f"amplitude_{order}"
    if key not in p:
        fitted = sorted(int(k.split("_", 1)[1]) for k in p if k.startswith("amplitude_"))
        raise ScoreMismatch(f"order mismatch: drawn {order}, fitted {fitted}")
    return p[key] * ctx.inertia_kg_m2


def _extra_damping(p: dict[str, float], ctx: ScoringContext) -> float:
    r, corrected = p["relative_error"], p["corrected_value"]
    return corrected * r / (1.0 + r)  # corrected - model value


#: Bench effect -> how it is scored (see the module docstring). The conversions follow the diagnosis library's
#: parameters: ``coulomb_level`` etc. are accelerations in d omega/dt ((rad/s)/s, per unit of the regressor),
#: ``time_offset(*).offset_s`` uses the bench's convention (the model should see u(t + offset); the bench logs the
#: duty applied at t with the stamp t + offset_s), ``parameter(J).relative_error`` is J_true / J - 1.
SCORING: dict[str, EffectScoring] = {
    "coulomb_friction": EffectScoring(
        "coulomb_torque_nm", "N m", lambda b: float(b["coulomb_torque_nm"]), ("omega",),
        (Conversion("coulomb(omega)", lambda p, c: p["coulomb_level"] * c.inertia_kg_m2, "coulomb_level x J"),)),
    "viscous_friction": EffectScoring(
        "coefficient_nm_s", "N m s", lambda b: float(b["coefficient_nm_s"]), ("omega",),
        (Conversion("viscous(omega)", lambda p, c: p["coefficient"] * c.inertia_kg_m2, "coefficient x J"),
         Conversion("parameter(b)", _extra_damping, "corrected b - model b"))),
    "load_dependent_friction": EffectScoring(
        "mean of coefficient_apply and coefficient_release", "-",
        lambda b: 0.5 * (float(b["coefficient_apply"]) + float(b["coefficient_release"])), ("omega",),
        (Conversion("coulomb(omega)*|tau_load|", _load_coefficient, "coefficient (mean of both signs) x J"),)),
    "cogging": EffectScoring(
        "amplitude_nm", "N m", lambda b: float(b["harmonics"][0]["amplitude_nm"]), ("omega",),
        (Conversion("periodic(theta)", _cogging_amplitude, "amplitude at the drawn order x J"),)),
    "inverter_deadtime": EffectScoring(
        "deadtime_s", "s", lambda b: float(b["deadtime_s"]), ("i_d", "i_q"),
        (Conversion("deadtime(*)", lambda p, c: p["duty_error"] / c.pwm_frequency_hz, "duty_error / f_pwm"),)),
    "channel_time_offset": EffectScoring(
        "offset_s", "s", lambda b: float(b["offset_s"]), ("i_d", "i_q"),
        (Conversion("time_offset(*)", lambda p, c: p["offset_s"], "offset_s (same sign convention)"),)),
    "inertia_mismatch": EffectScoring(
        "scale - 1", "-", lambda b: float(b["scale"]) - 1.0, ("omega",),
        (Conversion("parameter(J)", lambda p, c: p["relative_error"], "corrected J / J - 1"),)),
}

_PARAMETER_RE = re.compile(r"^parameter\((.+)\)$")


def bench_effect_of(name: str, expected: dict[str, list[str]]) -> str | None:
    """The bench effect whose patterns (``withheld.expected``) match the diagnosis effect ``name``, or None."""
    for bench_effect, patterns in expected.items():
        if any(fnmatch.fnmatchcase(name, p) for p in patterns):
            return bench_effect
    return None


def true_size(effect: str, parameters: dict[str, Any]) -> float | None:
    """The bench's size parameter of ``effect`` (``SCORING``), or None for an effect without scoring."""
    scoring = SCORING.get(effect)
    return None if scoring is None else scoring.true_value(parameters)


def effect_size(record: dict[str, Any], patterns: list[str]) -> float | None:
    """sqrt of the largest first-step ``relative_improvement`` among the candidates matching ``patterns`` over
    all examined equations (the effect's RMS share of the equation error, 0..1), or None if no candidate
    matches. A calibrated parameter error (``which.calibration``: fitted from the start, never a first-step
    candidate) counts with the share of the residual it removes entering last."""
    best = None
    for row in (record.get("which") or {}).get("calibration") or []:
        value = row.get("relative_improvement")
        if value is not None and any(fnmatch.fnmatchcase(row["effect"], p) for p in patterns):
            # entering last, a joint coefficient's refit can also lower the other equations' residual: at most 1
            value = min(float(value), 1.0)
            best = value if best is None else max(best, value)
    for equation in (record.get("which") or {}).get("equations", {}).values():
        steps = equation.get("steps") or []
        if not steps:
            continue
        for candidate in steps[0].get("candidates", []):
            if any(fnmatch.fnmatchcase(candidate["effect"], p) for p in patterns):
                value = candidate.get("relative_improvement")
                if value is not None and (best is None or value > best):
                    best = float(value)
    return None if best is None else math.sqrt(max(best, 0.0))


def _scoring_context(record: dict[str, Any], truth: dict[str, Any], parameters: dict[str, Any]) -> ScoringContext:
    inertia = (record.get("model_parameters") or {}).get("J")
    if inertia is None:
        inertia = (truth.get("nominal_parameters") or {}).get("J")
    return ScoringContext(inertia_kg_m2=float(inertia) if inertia is not None else math.nan,
                          pwm_frequency_hz=float(truth.get("pwm_frequency_hz") or math.nan),
                          true_parameters=parameters)


@dataclass(frozen=True)
class FittedSize:
    """A withheld effect's size parameter as the diagnosis estimates it (bench units).

    Attributes:
        value: from the named effect's parameters (None: no conversion applied); source: that effect and its
            equation; note: why there is no value; interval: the conversion at the ends of the parameters' 90 %
            intervals (None where they have none); with_rival: from its values with its first rival beside it
            (None where no rival moves them).
    """

    value: float | None
    source: str = ""
    note: str = ""
    interval: tuple[float, float] | None = None
    with_rival: float | None = None


def _fitted_value(effect: str, items: list[dict[str, Any]], ctx: ScoringContext) -> FittedSize:
    """The :class:`FittedSize` of the first item with a conversion (every conversion rises or falls with each of its
    parameters, so the interval's ends are the conversion at the parameters' ends)."""
    scoring = SCORING.get(effect)
    if scoring is None:
        return FittedSize(None, note="no scoring for this effect")
    notes = []
    for item in items:
        for conversion in scoring.conversions:
            if fnmatch.fnmatchcase(item["effect"], conversion.pattern):
                rows = [p for p in item["parameters"] if p.get("value") is not None]
                params = {p["name"]: p["value"] for p in rows}
                try:
                    value = float(conversion.fitted(params, ctx))
                except ScoreMismatch as err:
                    notes.append(f"{item['effect']}: {err}")
                    continue
                except KeyError as err:
                    notes.append(f"{item['effect']}: no parameter {err}")
                    continue
                return FittedSize(value, f"{item['effect']} in d{item['equation']}/dt", "",
                                  _interval(conversion, rows, ctx), _with_rival(conversion, params, item, ctx))
    return FittedSize(None, note="; ".join(notes) or "no conversion for " + ", ".join(sorted({i["effect"]
                                                                                            for i in items})))


def _with_rival(conversion: Conversion, params: dict[str, float], item: dict[str, Any], ctx: ScoringContext
                ) -> float | None:
    """``conversion`` at the named ``item``'s parameter values with its first rival beside it, or None."""
    rivals = item.get("rivals") or []
    if not rivals:
        return None
    try:
        value = float(conversion.fitted({**params, **rivals[0]["values"]}, ctx))
    except (ScoreMismatch, KeyError, ZeroDivisionError):
        return None
    return value if math.isfinite(value) else None


def _interval(conversion: Conversion, rows: list[dict[str, Any]], ctx: ScoringContext
              ) -> tuple[float, float] | None:
    """``conversion`` at the lower and the upper ends of the parameter rows' ``interval_90`` (a row without one at its
    value), ordered; None when no row has an interval or an end is not finite."""
    if not any(p.get("interval_90") for p in rows):
        return None
    ends = []
    for side in (0, 1):
        params = {p["name"]: (p["interval_90"][side] if p.get("interval_90") else p["value"]) for p in rows}
        try:
            ends.append(float(conversion.fitted(params, ctx)))
        except (ScoreMismatch, KeyError, ZeroDivisionError):
            return None
    if not all(math.isfinite(e) for e in ends):
        return None
    return min(ends), max(ends)


def _covers(interval: tuple[float, float] | None, true: float | None) -> bool | None:
    if interval is None or true is None or not math.isfinite(true):
        return None
    return interval[0] <= true <= interval[1]


def _error_pct(fitted: float | None, true: float | None) -> float | None:
    if fitted is None or true is None or not math.isfinite(fitted) or true == 0:
        return None
    return abs(fitted - true) / abs(true) * 100.0


def score_case(record: dict[str, Any], truth: dict[str, Any], draw: dict[str, Any],
               expected: dict[str, list[str]], background: dict[str, list[str]] | None = None) -> dict[str, Any]:
    """One case's scores (a row of ``summary.csv`` before formatting).

    Args:
        record: the case's ``diagnosis.json``.
        truth: one of its bench truth files (effects with their parameters, ``parameter_offsets``,
            ``nominal_parameters``, ``pwm_frequency_hz``).
        draw: its draw record (:func:`hybridfmu_bench.withheld.suite.draw_case`: kind, seed, stratum, size scales).
        expected: ``withheld.expected`` (bench effect -> diagnosis effect name patterns).
        background: ``withheld.background`` (condition present in every case -> diagnosis effect name patterns).

    Returns:
        A dict with the columns of :data:`hybridfmu_bench.withheld.report.SUMMARY_COLUMNS`; per-effect
        columns are lists in the order of ``true_effects`` (a list of bench effect names).
    """
    true_params = {e["name"]: e["parameters"] for e in truth.get("effects", [])}
    true_effects = list(true_params)
    if sorted(true_effects) != sorted(draw.get("effects", [])):
        raise ValueError(f"case {draw.get('case')!r}: the truth's effects {true_effects} differ from the draw's "
                         f"{draw.get('effects')}; regenerate the case")
    true_offsets = {k: float(v) for k, v in (truth.get("parameter_offsets") or {}).items()}
    chosen = list((record.get("which") or {}).get("chosen", []))
    named = list((record.get("which") or {}).get("found_effects", []))
    findings: dict[str, list[dict[str, Any]]] = {e: [] for e in true_effects}
    offset_items: dict[str, list[dict[str, Any]]] = {}
    found: list[str] = []
    extras: list[str] = []
    background_found: list[str] = []
    for item in chosen:  # rank order
        if not is_finding(item):  # an adjustment or unconfirmed: in the model, not named
            continue
        bench = bench_effect_of(item["effect"], expected)
        parameter = _PARAMETER_RE.match(item["effect"])
        condition = bench_effect_of(item["effect"], background or {})
        if bench not in findings and condition is not None:
            if condition not in background_found:
                background_found.append(condition)
            continue
        if bench in findings:
            findings[bench].append(item)
            label = bench
        elif parameter and parameter.group(1) in true_offsets:
            offset_items.setdefault(parameter.group(1), []).append(item)
            continue
        else:
            label = bench or item["effect"]
            if label not in extras:
                extras.append(label)
        if label not in found:
            found.append(label)
    per_effect = []
    for effect in true_effects:
        scoring = SCORING.get(effect)
        items = findings[effect]
        acting = scoring.equations if scoring else ()
        preferred = [i for i in items if _acts_on(i, acting)] + [i for i in items if not _acts_on(i, acting)]
        ctx = _scoring_context(record, truth, true_params[effect])
        true_value = true_size(effect, true_params[effect])
        size = _fitted_value(effect, preferred, ctx) if items else FittedSize(None, note="missed")
        fitted, source, note, interval = size.value, size.source, size.note, size.interval
        per_effect.append({
            "effect": effect, "detected": bool(items),
            "named_in": sorted({e for i in items for e in i.get("equations") or [i["equation"]]}),
            "where_correct": any(_acts_on(i, acting) for i in items),
            "size_scale": (draw.get("size_scales") or {}).get(effect),
            "effect_size": effect_size(record, list(expected.get(effect, []))),
            "true_value": true_value, "fitted_value": fitted, "fitted_from": source,
            "parameter_error_pct": _error_pct(fitted, true_value), "note": note, "fitted_with_rival": size.with_rival,
            "parameter_error_with_rival_pct": _error_pct(size.with_rival, true_value),
            "interval_90": list(interval) if interval else None, "interval_covers_truth": _covers(interval, true_value),
        })
    offsets_found = [p for p in true_offsets if p in offset_items]
    offset_errors = {}
    for p in offsets_found:
        params = {q["name"]: q["value"] for q in offset_items[p][0]["parameters"]}
        offset_errors[p] = _error_pct(params.get("relative_error"), true_offsets[p])
    far = record.get("how_far") or {}
    before, after = far.get("gap_before"), far.get("gap_after")
    w_before, w_after = far.get("window_gap_before"), far.get("window_gap_after")
    states = ((record.get("where") or {}).get("equations") or {}).get("states", {})
    return {
        "case": draw.get("case", record.get("case")), "seed": draw.get("seed"), "kind": draw.get("kind"),
        "stratum": draw.get("stratum"), "true_effects": true_effects,
        "size_scale": [e["size_scale"] for e in per_effect],
        "effect_size": [e["effect_size"] for e in per_effect],
        "detected": [e["detected"] for e in per_effect],
        "found_effects": found, "named_effects": named, "extra_effects": extras,
        "exact": set(found) == set(true_effects),
        "where_correct": all(e["where_correct"] for e in per_effect) if per_effect else None,
        "named_in": [",".join(e["named_in"]) or "-" for e in per_effect],
        "parameter_error_pct": [_error_token(e) for e in per_effect],
        "parameter_error_with_rival_pct": [e["parameter_error_with_rival_pct"] for e in per_effect],
        "true_size_parameters": {e["effect"]: {"parameter": SCORING[e["effect"]].size_parameter if e["effect"] in
                                               SCORING else None, "value": e["true_value"],
                                               "unit": SCORING[e["effect"]].unit if e["effect"] in SCORING else None}
                                 for e in per_effect},
        "fitted_size_parameters": {e["effect"]: {"value": e["fitted_value"], "from": e["fitted_from"],
                                                 "note": e["note"], "with_rival": e["fitted_with_rival"]}
                                   for e in per_effect},
        "true_params": true_params, "fitted_params": _fitted_parameters(record),
        "background_found": background_found,
        "offsets_true": true_offsets, "offsets_found": offsets_found,
        "offsets_missed": [p for p in true_offsets if p not in offset_items], "offset_errors_pct": offset_errors,
        "gap_before": before, "gap_after": after, "gap_shrink": _ratio(before, after),
        "window_gap_before": w_before, "window_gap_after": w_after, "shrink_factor": _ratio(w_before, w_after),
        "interval_covers_truth": _all_known([e["interval_covers_truth"] for e in per_effect]),
        "effect_shrink": far.get("effect_shrink_factor"), "window_effect_shrink": far.get("window_effect_shrink_factor"),
        "ratio_to_noise": {k: v.get("ratio_to_noise") for k, v in states.items()},
        "effects_detail": per_effect,
    }


def _all_known(values: list[bool | None]) -> bool | None:
    """Whether every judged value is True (None when none was judged)."""
    known = [v for v in values if v is not None]
    return all(known) if known else None


def _error_token(effect: dict[str, Any]) -> float | str:
    """The parameter error (%) of one effect, or why there is none: ``missed`` (not named), ``mismatch`` (named
    with another structure, e.g. cogging order), ``n/a`` (no conversion; the note says why)."""
    if effect["parameter_error_pct"] is not None:
        return effect["parameter_error_pct"]
    if not effect["detected"]:
        return "missed"
    return "mismatch" if "mismatch" in effect["note"] else "n/a"


def _acts_on(item: dict[str, Any], acting: tuple[str, ...]) -> bool:
    """Whether a named effect acts on one of the equations ``acting`` (a change of an input or a parameter is
    named with every equation it acts on, ``equations``)."""
    return any(e in acting for e in item.get("equations") or [item["equation"]])


def _ratio(before: float | None, after: float | None) -> float | None:
    if before is None or after is None or after <= 0:
        return None
    return float(before) / float(after)


def _fitted_parameters(record: dict[str, Any]) -> dict[str, dict[str, float]]:
    return {f"{item['effect']} in d{item['equation']}/dt": {p["name"]: p["value"] for p in item["parameters"]}
            for item in (record.get("which") or {}).get("chosen", [])}


def selection_thresholds(record: dict[str, Any]) -> dict[str, float]:
    """The thresholds the case's selection used: ``diagnosis.selection`` as recorded in ``diagnosis.json``
    (``method.selection``) over the selection's defaults."""
    from hybridfmu.diagnosis.selection import SelectionSettings

    settings = SelectionSettings.from_config((record.get("method") or {}).get("selection") or {})
    keys = ("min_bic_drop", "min_relative_improvement", "min_share_of_initial", "min_explained_to_noise",
            "max_effects_per_equation")
    return {k: float(getattr(settings, k)) for k in keys if hasattr(settings, k)}


def rejected_candidates(record: dict[str, Any]) -> list[dict[str, Any]]:
    """Per examined equation, the strongest candidate acting on it that the selection rejected at its last step.

    The selection runs over all examined equations at once (``which.steps``); per equation, the strongest is the
    candidate acting on it with the lowest BIC among those that are not parameter errors within the tolerance.
    Returns one dict per equation: ``equation``, ``effect`` (None when the last step accepted one), ``bic_drop``
    (BIC before minus with it), ``relative_improvement`` (of the remaining residual sum of squares of the
    equation(s) it acts on), ``explained_share`` (of their initial residual sum of squares), ``explained_to_noise``
    (explained mean square / the noise variance), ``reason`` (why it may not enter) and ``chosen_before``
    (the effects accepted before, over all equations).
    """
    which = record.get("which") or {}
    steps = [st for st in which.get("steps") or [] if st.get("kind", "forward") == "forward"]
    chosen_before = [st["chosen"] for st in steps if st.get("chosen")]
    last = steps[-1] if steps else None
    out = []
    for state in (which.get("equations") or {}):
        row = {"equation": state, "effect": None, "bic_drop": None, "relative_improvement": None,
               "explained_share": None, "explained_to_noise": None, "reason": None, "chosen_before": chosen_before}
        if last is None:
            row["reason"] = "no selection step"
        elif last.get("chosen") is not None:
            row["reason"] = f"accepted {last['chosen']} at the last step (max_effects_per_equation reached)"
        else:
            weighed = [c for c in last["candidates"] if not c.get("within_tolerance") and state in c.get("equations", [])]
            if weighed:
                best = min(weighed, key=lambda c: float(c["bic"]))
                row.update({"effect": best["effect"], "bic_drop": best.get("bic_drop"),
                            "relative_improvement": float(best["relative_improvement"]),
                            "explained_share": best.get("explained_share"),
                            "explained_to_noise": best.get("explained_to_noise")})
                row["reason"] = best.get("rejected_because") or last.get("reason")
            else:
                row["reason"] = last.get("reason")
        out.append(row)
    return out


def dumps(value: Any) -> str:
    """Compact, sorted JSON for a CSV cell."""
    return json.dumps(value, sort_keys=True, default=float)
