"""The diagnosis' open-loop check: how far the gap shrinks on held-out maneuvers, and where the error grows.

``how_far`` simulates the model open loop on the test maneuvers (whole records and windows restarted from the
measured state), alone and after each chosen effect in rank order, each variant recalibrated with its effects
when ``diagnosis.open_loop.refit`` is on, and ends with the diagnosed model (FMU + effects). ``error_growth``
gives, per maneuver and target, when the model's normalised open-loop error first exceeds a threshold.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any, Callable

import numpy as np

from hybridfmu.diagnosis.corrected_model import CorrectedModel, open_loop_errors, simulate, simulate_windows
from hybridfmu.diagnosis.export import DiagnosedModel
from hybridfmu.diagnosis.joint import effect_equations
from hybridfmu.diagnosis.prepare import MeasuredManeuver, PreparedManeuver
from hybridfmu.diagnosis.problem import Problem
from hybridfmu.diagnosis.refit import Refit, RefitSpec, parameters_set, refit_terms, simulate_corrected
from hybridfmu.diagnosis.result import HeldOutCheck
from hybridfmu.diagnosis.selection import Term
from hybridfmu.diagnosis.standstill_hold import StandstillHold, choose_hold, friction_rows

LOGGER = logging.getLogger("hybridfmu.diagnosis")


def reference_states(meas: MeasuredManeuver, starts: np.ndarray, problem: Problem) -> np.ndarray:
    """Measured states to compare with: as logged, differentiated states smoothed like the start states."""
    ref = np.array(meas.x, dtype=float)
    for state in problem.settings.get("state_from_derivative") or {}:
        i = problem.state_names.index(state)
        ref[:, i] = starts[:, i]
    return ref


def equation_label(effect: Any, problem: Problem) -> str:
    """``d<state>/dt`` of the equation(s) an effect acts on, joined by commas."""
    return ", ".join(f"d{problem.state_names[eq]}/dt" for eq in effect_equations(effect))


def mean_errors(per: dict[str, dict[str, float]]) -> dict[str, float]:
    """Mean over maneuvers of each error of ``per`` (maneuver -> error name -> value), window counts left out."""
    keys = next(iter(per.values())).keys()
    return {k: float(np.mean([v[k] for v in per.values()])) for k in keys if k != "n_windows"}


def _refit_record(refit: Refit) -> dict[str, Any]:
    return {"cost_start": refit.cost_start, "cost": refit.cost, "evaluations": refit.evaluations,
            "elapsed_s": round(refit.elapsed_s, 2), "parameters": refit.parameters,
            "initial_states": refit.initial_states,
            "variables": {name: {"start": a, "fitted": b} for name, (a, b) in refit.variables.items()},
            "above_previous": refit.above_previous}


def how_far(model: Any, helper: Any, simulate_fn: Callable, prepared: dict[str, PreparedManeuver],
            test_names: list[str], terms: list[Term], problem: Problem,
            refit: RefitSpec | None = None, refit_names: list[str] | None = None,
            fit_names: list[str] | None = None) -> HeldOutCheck:
    """Open-loop errors on the test maneuvers: the model, and after each chosen effect (cumulative, rank order)
    (:class:`hybridfmu.diagnosis.result.HeldOutCheck`).

    With ``refit`` (:func:`hybridfmu.diagnosis.refit.refit_spec`), every variant, the model alone among them,
    is first recalibrated with its effects by output error on the maneuvers ``refit_names``, each variant from the
    optimum of the one before it (its train cost never rises where the new effect can be switched off)
    (:mod:`hybridfmu.diagnosis.refit`); each step then carries its ``refit`` record.

    The shrink is also attributed: ``parameters_only`` is the model with the chosen parameter errors corrected and
    no other effect (recalibrated from the model alone's optimum with ``refit``); ``parameter_shrink_factor`` is the
    gap of the model alone over its gap, ``effect_shrink_factor`` its gap over the diagnosed model's (what the named
    effects add on top of the parameter corrections; 1 when every chosen term is a parameter error), and the same
    with ``window_`` over the restarted windows.

    With a configured standstill (``diagnosis.standstill``) and ``fit_names``, the diagnosed model may hold that
    state at rest by its friction: the band is chosen on the whole fitting maneuvers (:func:`standstill_hold`), and
    when one is, the check ends with one more variant, the diagnosed model with it (``standstill_hold`` records the
    choice)."""
    window = window_setting(model, simulate_fn, prepared, fit_names, problem)
    window_s = window["window_s"] if window else None
    steps = []
    trajectories: dict[str, dict[str, np.ndarray]] = {name: {} for name in test_names}
    variants = [("FMU", [])] + [(f"+ {t.effect.name} ({equation_label(t.effect, problem)})", terms[:k + 1])
                                for k, t in enumerate(terms)]
    notes: list[str] = []
    fitted = alone = None
    for label, active in variants:
        if refit is not None:
            absorbed = active and _refitted_parameter(active[-1], refit)
            if not (absorbed and fitted is not None):  # an absorbed parameter error leaves the variant as it was
                fitted = refit_terms(model, helper, simulate_fn, [prepared[n].measured for n in refit_names or []],
                                     active, problem, refit, label=f"refit {label}", previous=fitted)
            alone = alone or fitted
        step, corrected, whole = _variant(model, helper, simulate_fn, prepared, test_names, label, active, fitted,
                                          problem, refit, window_s)
        if corrected is not None:
            notes = corrected.notes
        for name in test_names:
            trajectories[name][label] = whole[name]
        steps.append(step)
    active = fitted.terms if fitted is not None else terms
    diagnosed = DiagnosedModel(list(active), dict(fitted.parameters) if fitted is not None else {}, problem,
                               [t.effect.name for t in terms],
                               {name: dict(fitted.initial_states_of(name, refit)) for name in prepared
                                if fitted.initial_states_of(name, refit)} if fitted is not None else {})
    hold_record = None
    if fit_names and problem.settings.get("standstill"):
        diagnosed, hold_record = standstill_hold(model, helper, simulate_fn, prepared, fit_names, diagnosed,
                                                 problem)
        if diagnosed.hold is not None:
            label = f"+ {diagnosed.hold.describe(problem.unit(diagnosed.hold.state))}"
            step, corrected, whole = _variant(model, helper, simulate_fn, prepared, test_names, label, terms,
                                              fitted, problem, refit, window_s, diagnosed.hold)
            for name in test_names:
                trajectories[name][label] = whole[name]
            steps.append(step)
    before, after = steps[0], steps[-1]
    keys = [k for k in before if k not in ("model", "effects", "per_maneuver")]
    return HeldOutCheck(
        steps=steps, before={k: before[k] for k in keys}, after={k: after[k] for k in keys},
        gap_before=before["gap"], gap_after=after["gap"],
        shrink_factor=before["gap"] / after["gap"] if after["gap"] and after["gap"] > 0 else float("inf"),
        notes=notes, trajectories=trajectories, diagnosed=diagnosed,
        window_gap_before=before.get("window_gap"), window_gap_after=after.get("window_gap"),
        window=window, standstill_hold=hold_record,
        **_attributed(model, helper, simulate_fn, prepared, test_names, terms, steps, alone, problem, refit,
                      refit_names, window_s))


def _variant(model: Any, helper: Any, simulate_fn: Callable, prepared: dict[str, PreparedManeuver],
             test_names: list[str], label: str, active: list[Term], fitted: Refit | None, problem: Problem,
             refit: RefitSpec | None, window_s: float | None, hold: StandstillHold | None = None
             ) -> tuple[dict[str, Any], CorrectedModel | None, dict[str, np.ndarray]]:
    """One variant of the held-out check open loop on every test maneuver: its step record (errors per maneuver and
    their means, the refit record), its corrected model and its whole-maneuver states (maneuver -> (T, n_x))."""
    names = [t.effect.name for t in active]
    if fitted is not None:
        active = fitted.terms
    corrected = CorrectedModel(active, problem, helper, hold=hold) if active else None
    per, whole = {}, {}
    with parameters_set([model, helper], fitted.parameters if fitted is not None else {}):
        for name in test_names:
            meas = prepared[name].measured
            starts = prepared[name].starts
            if fitted is not None:
                starts = _refit_starts(model, simulate_fn, meas, starts, corrected,
                                       fitted.initial_states_of(name, refit), problem)
            started = time.perf_counter()
            errors, whole[name] = open_loop_errors(model, simulate_fn, meas.time_s,
                                                   reference_states(meas, starts, problem), meas.u, starts, problem,
                                                   corrected, window_s)
            LOGGER.info("open loop %s on %s: normalised gap %.4g (%.1f s)", label, name, errors["gap"],
                        time.perf_counter() - started)
            per[name] = errors
    step = {"model": label, "effects": names, "per_maneuver": per, **mean_errors(per)}
    if fitted is not None:
        step["refit"] = _refit_record(fitted)
    return step, corrected, whole


def _shrink(before: float | None, after: float | None) -> float | None:
    """before / after of two gaps (inf for an after of 0, None when either is missing or not finite)."""
    if before is None or after is None or not (np.isfinite(before) and np.isfinite(after)):
        return None
    return before / after if after > 0 else float("inf")


def _attributed(model: Any, helper: Any, simulate_fn: Callable, prepared: dict[str, PreparedManeuver],
                test_names: list[str], terms: list[Term], steps: list[dict[str, Any]], alone: Refit | None,
                problem: Problem, refit: RefitSpec | None, refit_names: list[str] | None,
                window_s: float | None) -> dict[str, Any]:
    """The shrink attributed to the parameter corrections and to the other effects (:func:`how_far`)."""
    parameters = [t for t in terms if t.effect.parameter_change(t.coef, t.setting) is not None]
    if len(parameters) == len(terms):  # nothing but parameter errors (or nothing): the last step is the variant
        only = steps[-1]
    elif not parameters or (refit is not None and all(_refitted_parameter(t, refit) for t in parameters)):
        only = steps[0]  # no parameter error, or only those the recalibration of the model alone fits anyway
    else:
        fitted = None
        if refit is not None:
            fitted = refit_terms(model, helper, simulate_fn, [prepared[n].measured for n in refit_names or []],
                                 parameters, problem, refit, label="refit parameter corrections", previous=alone)
        only, _, _ = _variant(model, helper, simulate_fn, prepared, test_names, "parameter corrections only",
                              parameters, fitted, problem, refit, window_s)
    before, after = steps[0], steps[-1]
    out = {"parameters_only": {**only, "model": "parameter corrections only",
                               "effects": [t.effect.name for t in parameters]},
           "parameter_shrink_factor": _shrink(before["gap"], only["gap"]),
           "effect_shrink_factor": _shrink(only["gap"], after["gap"])}
    if "window_gap" in before:
        out["window_parameter_shrink_factor"] = _shrink(before["window_gap"], only["window_gap"])
        out["window_effect_shrink_factor"] = _shrink(only["window_gap"], after["window_gap"])
    return out


def standstill_hold(model: Any, helper: Any, simulate_fn: Callable, prepared: dict[str, PreparedManeuver],
                    fit_names: list[str], diagnosed: DiagnosedModel, problem: Problem
                    ) -> tuple[DiagnosedModel, dict[str, Any]]:
    """The diagnosed model with the standstill hold whose open-loop gap over the whole fitting maneuvers
    ``fit_names`` is the smallest (:func:`hybridfmu.diagnosis.standstill_hold.choose_hold`; unchanged when no hold
    beats none), and the record of the choice: ``state``, ``threshold`` (``diagnosis.standstill.below``),
    ``band`` (None: no hold), ``candidates`` (``band``, ``gap``), ``maneuvers``."""
    setting = problem.settings["standstill"]
    state, threshold = str(setting["state"]), float(setting["below"])
    record: dict[str, Any] = {"state": state, "threshold": threshold, "band": None, "candidates": [],
                              "maneuvers": list(fit_names)}
    if not friction_rows(diagnosed.corrected(helper).row_terms, problem.state_names.index(state)):
        record["note"] = f"no friction of {state} was named in its equation: nothing to hold it at rest"
        return diagnosed, record

    def gap_of(hold: StandstillHold | None) -> float:
        candidate = dataclasses.replace(diagnosed, hold=hold)
        gaps = []
        with parameters_set([model, helper], candidate.parameters):
            corrected = candidate.corrected(helper)
            for name in fit_names:
                meas = prepared[name].measured
                starts = prepared[name].starts
                if candidate.initial_states.get(name):
                    starts = _refit_starts(model, simulate_fn, meas, starts, corrected, candidate.initial_states[name],
                                           problem)
                errors, _ = open_loop_errors(model, simulate_fn, meas.time_s, reference_states(meas, starts, problem),
                                             meas.u, starts, problem, corrected, None)
                gaps.append(errors["gap"])
        return float(np.mean(gaps)) if gaps else float("nan")

    hold, record["candidates"] = choose_hold(state, threshold, problem.dt_s, gap_of)
    record["band"] = None if hold is None else hold.band
    return dataclasses.replace(diagnosed, hold=hold), record


def _refitted_parameter(term: Term, refit: RefitSpec) -> bool:
    """Whether ``term`` is an error of a parameter the refit fits anyway (it adds nothing to the variant)."""
    change = term.effect.parameter_change(term.coef, term.setting)
    return change is not None and change[0] in refit.parameter_bounds


def _refit_starts(model: Any, simulate_fn: Callable, meas: MeasuredManeuver, starts: np.ndarray,
                  corrected: CorrectedModel | None, initial_states: dict[str, float], problem: Problem) -> np.ndarray:
    """Start states (T, n_x) of a recalibrated variant: its unmeasured initial states, and the unmeasured states
    along its own open-loop simulation (the windows restart from them)."""
    if not problem.unmeasured:
        return starts
    out = np.array(starts, dtype=float)
    for i in problem.unmeasured:
        out[0, i] = float(initial_states.get(problem.state_names[i], out[0, i]))
    whole = simulate_corrected(model, simulate_fn, meas.time_s, meas.u, out[0], corrected)
    out[:, problem.unmeasured] = whole[:, problem.unmeasured]
    return out


def error_growth(model: Any, simulate_fn: Callable, prepared: dict[str, PreparedManeuver],
                 problem: Problem) -> list[dict[str, Any]]:
    """Where the model's open-loop error grows: per maneuver and target, the normalised |error| over time and
    the first time it exceeds ``open_loop.growth_threshold_relative`` (of the target's spread)."""
    threshold = float(problem.settings["open_loop"].get("growth_threshold_relative", 0.1))
    out = []
    for name, p in prepared.items():
        meas = p.measured
        starts = p.starts
        whole = simulate(model, simulate_fn, meas.time_s, meas.u, starts[0], None)
        ref = reference_states(meas, starts, problem)
        item = {"maneuver": name, "role": meas.role, "threshold_relative": threshold, "targets": {},
                "normalised_error": {}}
        for state in problem.target_weights:
            i = problem.state_names.index(state)
            err = np.abs(whole[:, i] - ref[:, i]) / (float(np.std(ref[:, i])) or 1.0)
            exceeded = np.flatnonzero(~(err <= threshold))
            item["targets"][problem.state_signal[state]] = {
                "exceeds_threshold_at_s": float(meas.time_s[exceeded[0]]) if len(exceeded) else None,
                "final_normalised_error": float(err[-1]) if np.isfinite(err[-1]) else None}
            item["normalised_error"][problem.state_signal[state]] = err
        out.append(item)
    return out


#: Restarted simulations per fitting maneuver that measure how long the model alone stays near the data.
TAKE_OFF_STARTS = 32
#: The longest window: this share of the shortest fitting maneuver.
LONGEST_WINDOW_SHARE = 1.0 / 3.0


def take_off_times(model: Any, simulate_fn: Callable, meas: MeasuredManeuver, starts: np.ndarray, problem: Problem,
                   horizon: int, count: int = TAKE_OFF_STARTS) -> np.ndarray:
    """How long the model alone, restarted from the measured state, stays near the data: (count,) times (s) until
    the first target's |error| exceeds ``open_loop.growth_threshold_relative`` of that target's spread along the
    maneuver (the threshold :func:`error_growth` uses), from ``count`` starts spread evenly over the maneuver, each
    run ``horizon`` samples at most (a window that stays near the data for all of them gives its full length)."""
    threshold = float(problem.settings["open_loop"].get("growth_threshold_relative", 0.1))
    n = len(meas.time_s)
    horizon = int(min(horizon, n - 1))
    first = np.unique(np.linspace(0, n - 1 - horizon, count).astype(int))
    ref = reference_states(meas, starts, problem)
    windows = simulate_windows(model, simulate_fn, meas.time_s, meas.u, starts[first], first, horizon, None)
    exceeded = np.zeros((len(first), horizon + 1), dtype=bool)
    for state in problem.target_weights:
        i = problem.state_names.index(state)
        spread = float(np.std(ref[:, i])) or 1.0
        measured = np.stack([ref[s:s + horizon + 1, i] for s in first])
        exceeded |= ~(np.abs(windows[:, :, i] - measured) <= threshold * spread)
    dt_s = float(np.median(np.diff(meas.time_s)))
    steps = np.where(exceeded.any(axis=1), exceeded.argmax(axis=1), horizon)
    return steps * dt_s


def window_from_data(model: Any, simulate_fn: Callable, prepared: dict[str, PreparedManeuver], fit_names: list[str],
                     problem: Problem) -> dict[str, Any]:
    """The length of the held-out check's restarted windows, chosen on the fitting maneuvers (``open_loop.window_s``
    absent or ``auto``): the median time the model alone stays near the data (:func:`take_off_times` over every
    fitting maneuver), at most :data:`LONGEST_WINDOW_SHARE` of the shortest of them and at least two samples. Windows
    of that length measure the model where its own error is still local: a shorter one sees little of an effect, a
    longer one mostly the drift the model has once it left the data.

    Returns ``window_s`` and how it was found (``take_off_s``: median per maneuver, ``longest_s``, ``starts``)."""
    dt_s = float(problem.dt_s)
    lengths = [len(prepared[n].measured.time_s) for n in fit_names]
    horizon = max(int(LONGEST_WINDOW_SHARE * min(lengths)), 2)
    started = time.perf_counter()
    times = {n: take_off_times(model, simulate_fn, prepared[n].measured, prepared[n].starts, problem, horizon)
             for n in fit_names}
    window_s = max(float(np.median(np.concatenate(list(times.values())))), 2 * dt_s)
    LOGGER.info("open-loop windows of %.4g s: the median time the model alone stays within the growth threshold on "
                "%s (%.1f s)", window_s, ", ".join(fit_names), time.perf_counter() - started)
    return {"window_s": window_s, "take_off_s": {n: float(np.median(t)) for n, t in times.items()},
            "longest_s": horizon * dt_s, "starts": int(sum(len(t) for t in times.values()))}


def window_setting(model: Any, simulate_fn: Callable, prepared: dict[str, PreparedManeuver],
                   fit_names: list[str] | None, problem: Problem) -> dict[str, Any] | None:
    """The restarted windows of the held-out check from ``open_loop.window_s``: a number fixes their length (s),
    null means none, absent or ``auto`` chooses it on the fitting maneuvers (:func:`window_from_data`; none without
    them). Returns ``window_s`` with ``chosen`` (``config`` or ``data``, and how), or None."""
    setting = problem.settings["open_loop"].get("window_s", "auto")
    if setting is None:
        return None
    if setting != "auto":
        return {"window_s": float(setting), "chosen": "config"}
    if not fit_names:
        return None
    return {**window_from_data(model, simulate_fn, prepared, fit_names, problem), "chosen": "data"}


def how_far_not_run(test_names: list[str], open_loop: bool = True) -> str | None:
    """Why the held-out check ("how far") is not run, in words for the report, or None when it runs."""
    if not test_names:
        from hybridfmu.data.roles import NO_TEST_MANEUVER

        return f"There is no test maneuver: {NO_TEST_MANEUVER}."
    if not open_loop:
        return "The open-loop simulation was switched off, so the held-out check on the test maneuver(s) was not run."
    return None
