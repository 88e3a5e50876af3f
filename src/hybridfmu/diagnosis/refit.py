"""The named effects recalibrated with the model by output error, for the held-out check ("how far").

The effects' coefficients come from the equation-error fit, against a model whose parameters were
calibrated by output error without them: on real data the calibration has absorbed part of the
missing effect (a tank that overflows makes the calibrated outflow smaller), so adding the effect to
the calibrated model double-counts it. A grey-box modeller recalibrates the model with the effect
added; :func:`refit_terms` does that, by the same criterion as the calibration
(:mod:`hybridfmu.calibration.fit`): the simulated target states against the measured ones over the
whole train maneuvers, each target normalised by its spread and weighted by its target weight.

Fitted together by the calibration's output-error fitter (:mod:`hybridfmu.output_error`: trust-region
reflective least squares, forward differences of the simulation with the step :data:`DIFF_STEP`, variables
normalised by their start values):

- the model parameters of ``config.calibration.parameters`` (bounds from there), starting from the
  calibrated values; a named parameter error of one of them is absorbed into its value;
- every other named effect's linear coefficients (bounds: ``Effect.coefficient_bounds``; equal bounds fix a
  coefficient at that value) and its
  continuously refined settings (bounds: ``Effect.refine_bounds``), starting from the equation-error fit;
- the unmeasured initial states of the train maneuvers (``config.calibration.initial_states``,
  bounds ``initial_state_bounds``), starting from the calibrated values.

Switched on by ``diagnosis.open_loop.refit``; ``refit_max_evaluations`` bounds the simulations.

API::

    refit_spec(config) -> RefitSpec | None
    refit_terms(model, helper, simulate_fn, maneuvers, terms, problem, spec, label) -> Refit
    parameters_set(instances, values)                   # context: model parameters set, restored afterwards
    simulate_corrected(model, simulate_fn, time_s, u, x0, corrected) -> (T, n_x) states
"""

from __future__ import annotations

import contextlib
import logging
import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterator

import numpy as np

from hybridfmu.diagnosis.corrected_model import CorrectedModel, simulate
from hybridfmu.diagnosis.prepare import MeasuredManeuver
from hybridfmu.diagnosis.problem import Problem
from hybridfmu.diagnosis.selection import Term
from hybridfmu.output_error import Variable as OutputErrorVariable

LOGGER = logging.getLogger("hybridfmu.diagnosis")

#: Forward-difference step relative to a normalised variable (1.1 %): a limit or overflow makes the simulated
#: trajectory kinked in the variables, and finer differences see the kinks, not the slope (on the tanks case,
#: steps of 1e-4 and 1e-6 left least_squares stalled at its start from most starting levels).
DIFF_STEP = 0.011


@dataclass(frozen=True)
class RefitSpec:
    """What the refit may change besides the effects (from the case config).

    Attributes:
        parameter_bounds: model parameter -> (min, max), the calibration's parameters.
        state_bounds: unmeasured state -> (min, max) of its fitted initial value.
        fit_initial_states: fit the unmeasured initial states of the fitted maneuvers.
        initial_states_from: maneuver -> the maneuver whose unmeasured initial states it takes.
        max_evaluations: most simulations of all fitted maneuvers (least_squares' max_nfev).
    """

    parameter_bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    state_bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    fit_initial_states: bool = False
    initial_states_from: dict[str, str] = field(default_factory=dict)
    max_evaluations: int = 160


def refit_spec(config: dict[str, Any], settings: dict[str, Any]) -> RefitSpec | None:
    """The refit's variables from ``config.calibration`` and ``settings`` (the diagnosis section with defaults),
    or None when ``diagnosis.open_loop.refit`` is off."""
    open_loop = settings.get("open_loop") or {}
    if not open_loop.get("refit"):
        return None
    calibration = config.get("calibration") or {}

    def bounds(entries: dict[str, Any]) -> dict[str, tuple[float, float]]:
        return {name: (float(e.get("min", -math.inf)), float(e.get("max", math.inf)))
                for name, e in (entries or {}).items()}

    return RefitSpec(parameter_bounds=bounds(calibration.get("parameters")),
                     state_bounds=bounds(calibration.get("initial_state_bounds")),
                     fit_initial_states=bool(calibration.get("initial_states", False)),
                     initial_states_from={name: m["initial_states_from"] for name, m in config["maneuvers"].items()
                                          if m.get("initial_states_from")},
                     max_evaluations=int(open_loop.get("refit_max_evaluations", 160)))


@dataclass
class Refit:
    """Outcome of :func:`refit_terms`.

    Attributes:
        terms: the effects with refitted coefficients and settings (parameter errors of refitted
            parameters left out: their values are in ``parameters``).
        parameters: refitted model parameter -> value.
        initial_states: fitted maneuver -> unmeasured state -> initial value.
        cost_start, cost: half the weighted mean of the squared normalised errors, before and after.
        evaluations: objective evaluations (simulations of all fitted maneuvers) at trial points; elapsed_s: wall
            time.
        variables: name -> (start, fitted) of every variable.
        above_previous: the fit ended above the cost of the variant before it (``previous`` of
            :func:`refit_terms`): the new effect cannot be switched off by zero coefficients (a limit, an overflow)
            and no start found a lower cost.
    """

    terms: list[Term]
    parameters: dict[str, float]
    initial_states: dict[str, dict[str, float]]
    cost_start: float
    cost: float
    evaluations: int
    elapsed_s: float
    variables: dict[str, tuple[float, float]]
    above_previous: bool = False

    def initial_states_of(self, maneuver: str, spec: RefitSpec) -> dict[str, float]:
        """Refitted unmeasured initial states of ``maneuver`` (own, else of its ``initial_states_from``), or {}."""
        if maneuver in self.initial_states:
            return self.initial_states[maneuver]
        return self.initial_states.get(spec.initial_states_from.get(maneuver, ""), {})


@contextlib.contextmanager
def parameters_set(instances: list[Any], values: dict[str, float]) -> Iterator[None]:
    """Within the block every model instance (``None`` skipped) has ``values``; restored afterwards."""
    touched = [m for m in instances if m is not None]
    if not values:
        yield
        return
    previous = [m.get_parameters(list(values)) for m in touched]
    for m in touched:
        m.set_parameters(values)
    try:
        yield
    finally:
        for m, old in zip(touched, previous):
            m.set_parameters(old)


@dataclass
class _Variable:
    name: str
    start: float
    low: float
    high: float
    kind: str            # "parameter", "coef", "setting", "state"
    key: Any             # parameter name, (term index, coefficient index), (term index, setting), (maneuver, state)


def _variables(terms: list[Term], spec: RefitSpec, model: Any, maneuvers: list[MeasuredManeuver],
               problem: Problem) -> tuple[list[Term], list[_Variable]]:
    """The terms the refit keeps (copies; parameter errors of refitted parameters left out, fixed coefficients
    set) and its variables in order: parameters, then per term its free coefficients and refined settings,
    then per maneuver its unmeasured initial states."""
    current = model.get_parameters(list(spec.parameter_bounds)) if spec.parameter_bounds else {}
    variables = [_Variable(f"{name}", float(current[name]), *spec.parameter_bounds[name], "parameter", name)
                 for name in spec.parameter_bounds]
    kept: list[Term] = []
    for term in terms:
        change = term.effect.parameter_change(term.coef, term.setting)
        if change is not None and change[0] in spec.parameter_bounds:
            continue  # the parameter itself is refitted
        t = len(kept)
        kept.append(replace(term, coef=np.array(term.coef, dtype=float), setting=dict(term.setting)))
        coefficient_bounds = term.effect.coefficient_bounds(term.setting)
        for c, cname in enumerate(term.effect.coefficient_names(term.setting)):
            low, high = coefficient_bounds[c]
            start = float(np.clip(term.coef[c], low, high))
            if low == high:  # fixed where the effect is added to the model
                kept[t].coef[c] = low
                continue
            variables.append(_Variable(f"{term.effect.name}.{cname}", start, low, high, "coef", (t, c)))
        for name in term.effect.continuous_parameters():
            bounds = term.effect.refine_bounds(name)
            value = term.setting.get(name)
            if bounds is None or value is None or (term.effect.log_scale and value == 0.0):
                continue
            low, high = float(min(bounds)), float(max(bounds))
            if high <= low:
                continue
            variables.append(_Variable(f"{term.effect.name}.{name}", float(np.clip(value, low, high)), low, high,
                                       "setting", (t, name)))
    if spec.fit_initial_states:
        for meas in maneuvers:
            for i in problem.unmeasured:
                state = problem.state_names[i]
                low, high = spec.state_bounds.get(state, (-math.inf, math.inf))
                start = float(np.clip(meas.x0_unmeasured.get(state, meas.x[0, i]), low, high))
                variables.append(_Variable(f"{state}@{meas.name}", start, low, high, "state", (meas.name, state)))
    return kept, variables


def refit_terms(model: Any, helper: Any, simulate_fn: Callable, maneuvers: list[MeasuredManeuver],
                terms: list[Term], problem: Problem, spec: RefitSpec, label: str = "refit",
                previous: Refit | None = None) -> Refit:
    """Recalibrate the model with ``terms`` added on ``maneuvers`` (module docstring), by the output-error fitter
    the calibration uses (:func:`hybridfmu.output_error.fit_output_error`).

    With ``previous`` (the refit of the same terms but the last), every variable it has starts at its optimum and
    the fit runs from two starts, the new effect at its equation-error fit and at zero coefficients; the lower cost
    wins. For an effect that zero coefficients switch off (an additive term, an input or parameter change) the
    second start is the previous variant itself, so the variant never ends with a higher train cost than the one
    before it, nor the first above the model alone's. An effect evaluated through the model (a limit, an overflow)
    acts at any coefficients; a fit of it that still ends above the variant before is flagged
    (``Refit.above_previous``) and logged.

    Args:
        model, helper: the simulating model instance and the helper of the terms (both get the trial parameters).
        simulate_fn: open-loop simulator (``simulate_open_loop`` or ``rk4_simulate``).
        maneuvers: the fitted maneuvers (measured states (T, n_x); unmeasured columns and ``x0_unmeasured``
            from the calibration).
        terms: the named effects with their equation-error fits, rank order.
        problem: the problem (targets and their weights).
        spec: from :func:`refit_spec`.
        label: prefix of the progress lines.
        previous: the refit of ``terms[:-1]`` (or of the model alone for a single term), or None.
    """
    from hybridfmu.fmu import FmuError
    from hybridfmu.output_error import fit_output_error, target_spread

    kept, variables = _variables(terms, spec, model, maneuvers, problem)
    targets = [problem.state_names.index(s) for s in problem.target_weights]
    weights = np.array([problem.target_weights[problem.state_names[i]] for i in targets], dtype=float)
    weights = weights / weights.sum()
    measured = [m.x[:, targets] for m in maneuvers]
    by_name = {v.name: v for v in variables}

    def unpack(values: dict[str, float]) -> tuple[dict[str, float], list[Term], dict[str, dict[str, float]]]:
        parameters: dict[str, float] = {}
        current = [replace(t, coef=np.array(t.coef, dtype=float), setting=dict(t.setting)) for t in kept]
        states: dict[str, dict[str, float]] = {}
        for name, value in values.items():
            v = by_name[name]
            if v.kind == "parameter":
                parameters[v.key] = float(value)
            elif v.kind == "coef":
                current[v.key[0]].coef[v.key[1]] = float(value)
            elif v.kind == "setting":
                current[v.key[0]].setting[v.key[1]] = float(value)
            else:
                states.setdefault(v.key[0], {})[v.key[1]] = float(value)
        return parameters, current, states

    def simulate(values: dict[str, float], m: int) -> np.ndarray:
        parameters, current, states = unpack(values)
        meas = maneuvers[m]
        with parameters_set([model, helper], parameters):  # the effects are built with the trial parameters set
            corrected = CorrectedModel(current, problem, helper) if current else None
            whole = simulate_corrected(model, simulate_fn, meas.time_s, meas.u,
                                       initial_state(meas, states.get(meas.name, {}), problem), corrected)
        return whole[:, targets]

    index = {meas.name: m for m, meas in enumerate(maneuvers)}
    fit_variables = [OutputErrorVariable(v.name, v.start, v.low, v.high,
                                         index[v.key[0]] if v.kind == "state" else None) for v in variables]
    starts = None
    if previous is not None and variables:
        warm = {v.name: previous.variables[v.name][1] if v.name in previous.variables else v.start
                for v in variables}
        quiet = {v.name: 0.0 if v.kind == "coef" and v.name not in previous.variables and v.low <= 0.0 <= v.high
                 else warm[v.name] for v in variables}
        starts = [warm, quiet]
    fit = fit_output_error(fit_variables, simulate, measured, weights, target_spread(measured),
                           relative_step=DIFF_STEP, tolerance=1e-8, max_evaluations=spec.max_evaluations,
                           label=label, starts=starts, failures=(FmuError,))
    cost = fit.cost
    above = previous is not None and cost > previous.cost * (1.0 + 1e-9)
    if above:
        LOGGER.warning("%s: ends at train cost %.6g, above the variant before it (%.6g): the new effect acts even at "
                       "zero coefficients and no start found a lower cost", label, cost, previous.cost)
    values = fit.values or {v.name: v.start for v in variables}
    parameters, current, states = unpack(values)
    return Refit(terms=current, parameters=parameters, initial_states=states, cost_start=fit.cost_start, cost=cost,
                 evaluations=fit.evaluations, elapsed_s=fit.elapsed_s,
                 variables={v.name: (v.start, float(values[v.name])) for v in variables},
                 above_previous=above)


def initial_state(meas: MeasuredManeuver, initial_states: dict[str, float], problem: Problem) -> np.ndarray:
    """(n_x,) start of a maneuver's simulation: measured states at its first sample, unmeasured ones from
    ``initial_states`` (else as filled from the calibration)."""
    x0 = np.array(meas.x[0], dtype=float)
    for i in problem.unmeasured:
        state = problem.state_names[i]
        x0[i] = float(initial_states.get(state, meas.x0_unmeasured.get(state, x0[i])))
    return x0


def simulate_corrected(model: Any, simulate_fn: Callable, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
                       corrected: CorrectedModel | None, apply_parameters: bool = True) -> np.ndarray:
    """States (T, n_x) of the (corrected) model open loop from ``x0`` (n_x,) with the logged inputs ``u`` (T, n_u).
    The model has the parameters it should have (the caller sets them); the corrected model's own parameter
    changes (unless ``apply_parameters`` is False: the caller holds them applied, ``parameters_applied``) and
    input changes are applied here."""
    if corrected is None:
        return simulate(model, simulate_fn, time_s, u, x0, None)
    dt_s = float(np.median(np.diff(time_s)))
    with corrected.parameters_applied(model) if apply_parameters else contextlib.nullcontext():
        return simulate(model, simulate_fn, time_s, corrected.inputs(u, dt_s), x0, corrected.correction())
