"""The chosen effects added to the model, and open-loop re-simulation against the measurements.

A :class:`CorrectedModel` gathers the fitted terms by the way each adds itself to the model
(:mod:`hybridfmu.diagnosis.effects`): additive derivative terms (the ``correction`` given to
``simulate_open_loop``: for an FMU an effect program its C step loop evaluates at every Runge-Kutta stage,
:mod:`hybridfmu.fmu.effect_program`, else a callable called with the stage's state and input rows), modified
logged inputs (time shift, first-order lag, static nonlinearities such as a dead zone or a saturation,
gain, offset; changes of different kinds to one input compose, in that order; where several
equations chose an effect of the same kind on the same input, the higher-ranked one is applied), and
corrected model parameters (set on the simulating instance
for the simulation, restored afterwards). In Python, terms that need model derivatives evaluate them with a
second model instance (``helper``), so the simulation's own instance is never re-entered; in C, the
simulating instance evaluates them within the stage.

Open-loop errors are reported per target signal over the whole maneuver (from the measured initial
state, unmeasured states from the calibration) and, when ``window_s`` is set, as the mean error of
short windows each restarted from the measured state.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import numpy as np

from hybridfmu.diagnosis.effects import HELD_UNCHANGED_FORMS, EffectInputs, input_derivative
from hybridfmu.diagnosis.problem import Problem
from hybridfmu.diagnosis.selection import Term
from hybridfmu.diagnosis.standstill_hold import StandstillHold, friction_rows, held_rate
from hybridfmu.fmu.bridge import FmuModel
from hybridfmu.fmu.simulate import simulate_open_loop
from hybridfmu.fmu.effect_program import EffectProgram, EffectTerm
from hybridfmu.runge_kutta import RK4, numpy_axpy

LOGGER = logging.getLogger("hybridfmu.diagnosis")


@dataclass
class RK4Result:
    """Result of :func:`rk4_simulate`: ``states`` (T, n_x)."""

    states: np.ndarray


def rk4_simulate(model: Any, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
                 correction: Callable | None = None) -> RK4Result:
    """Fixed-step RK4 (one step per sample, inputs held) for models that are no FMU (no events).

    ``model.derivatives(x (1, n_x), u (1, n_u)) -> (1, n_x)``; ``correction`` as for ``simulate_open_loop``.
    """
    time_s = np.asarray(time_s, dtype=float)
    u = np.asarray(u, dtype=float).reshape(len(time_s), -1)
    states = np.empty((len(time_s), len(x0)))
    x = np.asarray(x0, dtype=float).reshape(1, -1)
    states[0] = x

    def rhs(xs: np.ndarray, us: np.ndarray) -> np.ndarray:
        f = np.asarray(model.derivatives(xs, us), dtype=float).reshape(1, -1)
        return f + np.asarray(correction(xs, us), dtype=float).reshape(1, -1) if correction is not None else f

    for k in range(len(time_s) - 1):
        h, uk = time_s[k + 1] - time_s[k], u[k:k + 1]
        x = RK4.plan(h).step(x, lambda state, _stage, held=uk: rhs(state, held), numpy_axpy)
        states[k + 1] = x
    return RK4Result(states)


def simulator_for(model: Any) -> Callable:
    """``hybridfmu.fmu.simulate_open_loop`` for an FMU, :func:`rk4_simulate` for any other model."""
    return simulate_open_loop if isinstance(model, FmuModel) else rk4_simulate


def simulate(model: Any, simulate_fn: Callable, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
             correction: Callable | None) -> np.ndarray:
    """States (T, n_x) of one open-loop simulation; NaN rows after a failure (logged)."""
    try:
        result = simulate_fn(model, time_s, u, x0, correction=correction)
        return np.asarray(result.states, dtype=float)
    except Exception as err:  # a diverging or failing simulation is a result, not a crash
        LOGGER.warning("open-loop simulation failed: %s", err)
        return np.full((len(time_s), len(x0)), np.nan)


def shift_inputs(u: np.ndarray, offset_s: float, dt_s: float, columns: list[int] | None = None) -> np.ndarray:
    """Inputs seen ``offset_s`` later, held per sample (linear interpolation between samples).

    ``u`` (N, n_u) -> (N, n_u); ``columns`` selects the shifted inputs (default all). Beyond the
    ends the first/last sample is held.
    """
    u = np.array(u, dtype=float)
    if offset_s == 0.0:
        return u
    index = np.arange(len(u)) + offset_s / dt_s
    base = np.floor(index)
    frac = (index - base)[:, None]
    lower = np.clip(base.astype(int), 0, len(u) - 1)
    upper = np.clip(lower + 1, 0, len(u) - 1)
    shifted = (1.0 - frac) * u[lower] + frac * u[upper]
    out = u.copy()
    cols = list(range(u.shape[1])) if columns is None else list(columns)
    out[:, cols] = shifted[:, cols]
    return out


def _gains_then_offsets(values: np.ndarray, changes: list[tuple[str, dict[str, Any]]]) -> np.ndarray:
    """``values`` of one input through its changes' gains ((1 + g) v), then their offsets (v + o): the last steps
    of :meth:`CorrectedModel.inputs` and :meth:`CorrectedModel.held_inputs`."""
    for _, change in changes:
        values = (1.0 + change.get("gain", 0.0)) * values
    for _, change in changes:
        values = values + change.get("offset", 0.0)
    return values


class CorrectedModel:
    """The chosen terms as changes of the model (module docstring).

    Args:
        terms: fitted terms in rank order.
        problem: the problem (state and input counts; ``diagnosis.effects.lag_derivative_window_s``, the
            window of the input rate of fitted input lags).
        helper: a second model instance for terms with a ``batch_function`` (may be None otherwise).
        joint_batches: evaluate a joint effect whose members offer ``joint_batch_function`` (e.g. one
            actuator dead time acting in several equations) once for all its equations; False evaluates each member on its
            own (same values; ``benchmarks/physics_layer.py`` times both).
        hold: hold a state at rest by the friction terms of its own equation
            (:mod:`hybridfmu.diagnosis.standstill_hold`; it needs ``helper`` for the model's derivatives), or None.
            Without such friction terms among ``terms`` nothing is held.
    """

    def __init__(self, terms: list[Term], problem: Problem, helper: Any = None, joint_batches: bool = True,
                 hold: StandstillHold | None = None) -> None:
        self.n_x, self.n_u = problem.n_x, problem.n_u
        self.helper = helper
        self.rows: list[tuple[int, Callable]] = []
        #: the row terms' (equation, effect, coefficients, setting), for :meth:`additive_batch`; the members of
        #: one joint effect share one coefficient array (a hybrid trains them in place, ``model.physics``)
        self.row_terms: list[tuple[int, Any, np.ndarray, dict[str, float]]] = []
        #: (effect name, coefficient array) of each term with row terms, in rank order (the arrays of row_terms)
        self.row_coefficients: list[tuple[str, np.ndarray]] = []
        #: (equation, or a joint effect's equations, batch function returning (N,) or (N, k)) of the terms the
        #: model evaluates (:meth:`additive_batch`)
        self.batches: list[tuple[int | list[int], Callable]] = []
        #: the terms of ``batches`` (in their order) as the C step loop evaluates them (None for one without a C
        #: form), for :meth:`effect_program` (which makes those of ``rows`` from ``row_terms`` when called)
        self.batch_stage_terms: list[EffectTerm | None] = []
        self.parameters: dict[str, float] = {}
        #: input column -> [(effect kind, change)] in rank order (see ``Effect.input_change``)
        self.input_changes: dict[int, list[tuple[str, dict[str, Any]]]] = {}
        self.lag_window_s = ((problem.settings or {}).get("effects") or {}).get("lag_derivative_window_s")
        self.notes: list[str] = []
        for term in terms:
            effect, coef, setting = term.effect, term.coef, term.setting
            change = effect.parameter_change(coef, setting)
            if change is not None:
                name, value = change
                if name in self.parameters:
                    self.notes.append(f"{effect.name}: parameter {name} already "
                                      "corrected by a higher-ranked term; not applied")
                else:
                    self.parameters[name] = value
                continue
            change = effect.input_change(coef, setting)
            if change is not None:
                columns = change["input"] if isinstance(change["input"], list) else [change["input"]]
                if any(kind == effect.kind for c in columns for kind, _ in self.input_changes.get(c, [])):
                    self.notes.append(f"{effect.name}: input(s) already changed by a higher-ranked {effect.kind} "
                                      "term; not applied")
                    continue
                for c in columns:
                    self.input_changes.setdefault(c, []).append((effect.kind, change))
                continue
            coefficients = np.array(coef, dtype=float)  # one array per term, shared by a joint effect's members
            members = list(getattr(effect, "members", [effect]))
            joint = getattr(members[0], "joint_batch_function", None)
            if joint_batches and len(members) > 1 and callable(joint) and all(m.row_function(coef, setting) is None for m in members):
                # a joint effect whose members evaluate the model alike: all its equations from one evaluation
                batch = joint(members, coef, setting, helper)
                if batch is None:
                    raise ValueError(f"{effect.name}: the effect needs a helper model instance")
                self.batches.append(([m.equation for m in members], batch))
                joint_stage = getattr(members[0], "joint_stage_term", None)
                self.batch_stage_terms.append(joint_stage(members, coef, setting) if callable(joint_stage) else None)
                continue
            for member in members:  # a joint effect in each of its equations
                row = member.row_function(coef, setting)
                if row is not None:
                    self.rows.append((member.equation, row))
                    self.row_terms.append((member.equation, member, coefficients, dict(setting)))
                    if not any(array is coefficients for _, array in self.row_coefficients):
                        self.row_coefficients.append((effect.name, coefficients))
                    continue
                batch = member.batch_function(coef, setting, helper)
                if batch is None:
                    raise ValueError(f"{effect.name}: the effect offers no way to be added to the model")
                self.batches.append((member.equation, batch))
                self.batch_stage_terms.append(member.stage_term(coef, setting))
                source = getattr(member, "source_batch_function", None)
                if source is not None:  # an overflow also limits the unmeasured state it comes from
                    limited = source(setting, helper)
                    if limited is None:
                        raise ValueError(f"{effect.name}: the effect needs a helper model instance")
                    self.batches.append(limited)
                    source_stage = getattr(member, "source_stage_term", None)
                    self.batch_stage_terms.append(source_stage(setting) if callable(source_stage) else None)

        #: the hold, its state and its friction terms (indices into rows / row_terms), when it holds anything
        self.hold: StandstillHold | None = None
        self.hold_state, self.hold_friction = -1, []
        if hold is not None:
            if hold.state not in list(problem.state_names):
                raise ValueError(f"standstill hold: {hold.state!r} is not a state of the model; expected one of "
                                 f"{list(problem.state_names)}")
            state = list(problem.state_names).index(hold.state)
            friction = friction_rows(self.row_terms, state)
            if friction:
                if helper is None:
                    raise ValueError(f"the standstill hold of {hold.state} needs a helper model instance")
                self.hold, self.hold_state, self.hold_friction = hold, state, friction

    @property
    def has_correction(self) -> bool:
        return bool(self.rows or self.batches)

    def _held_rows(self, x: np.ndarray, u: np.ndarray, out: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The rows (indices) within the hold's band, their rate with the hold, whether the friction holds them,
        and their states with the held state at the band's edge the push points to; None if no row is within.
        ``out`` (N, n_x): the other terms' sum at (x, u)."""
        j, hold = self.hold_state, self.hold
        rows = np.flatnonzero(np.abs(x[:, j]) < hold.band)
        if not rows.size:
            return None
        xs, us = x[rows], u[rows]
        before = np.asarray(self.helper.derivatives(xs, us), dtype=float).reshape(len(rows), -1)[:, j] + out[rows, j]
        friction = self._friction(xs, us)
        edge_states = xs.copy()
        edge_states[:, j] = np.where(before - friction >= 0.0, hold.band, -hold.band)
        rate, held = held_rate(before, friction, self._friction(edge_states, us), xs[:, j], hold.rate_per_s)
        return rows, rate - before, held, edge_states

    def _friction(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(N,) the hold's friction terms summed in order at (x, u), with their coefficients as they are now
        (row by row, the operations of the C step loop)."""
        functions = [effect.row_function(coef, setting)
                     for _, effect, coef, setting in (self.row_terms[n] for n in self.hold_friction)]
        total = np.zeros(x.shape[0])
        for r in range(x.shape[0]):
            x_row, u_row, value = x[r].tolist(), u[r].tolist(), 0.0
            for function in functions:
                value += function(x_row, u_row)
            total[r] = value
        return total

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Additive derivative terms: (N, n_x), (N, n_u) -> (N, n_x) (one row per RK stage in a simulation)."""
        x = np.asarray(x, dtype=float).reshape(-1, self.n_x)
        u = np.asarray(u, dtype=float).reshape(-1, self.n_u)
        out = np.zeros_like(x)
        if self.rows:
            for r in range(x.shape[0]):
                x_row, u_row = x[r].tolist(), u[r].tolist()
                for equation, func in self.rows:
                    out[r, equation] += func(x_row, u_row)
        for equation, batch in self.batches:
            out[:, equation] += batch(x, u)
        return self._with_hold(x, u, out)

    def _with_hold(self, x: np.ndarray, u: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out`` (N, n_x), the terms' sum at (x, u), with the hold's change added (in place)."""
        if self.hold is not None:
            held = self._held_rows(x, u, out)
            if held is not None:
                out[held[0], self.hold_state] += held[1]
        return out

    def additive_batch(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The additive derivative terms vectorised over rows, the hold included: (N, n_x), (N, n_u) -> (N, n_x)
        (same values as :meth:`__call__`; :meth:`_terms_batch` without the hold)."""
        x = np.asarray(x, dtype=float).reshape(-1, self.n_x)
        u = np.asarray(u, dtype=float).reshape(-1, self.n_u)
        return self._with_hold(x, u, self._terms_batch(x, u))

    def _terms_batch(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The additive terms without the hold, vectorised over rows: (N, n_x), (N, n_u) -> (N, n_x). A row term
        is its effect's regressors at (x, u) times its coefficients (the row functions are the regressors'
        plain-float form), so many rows cost one array evaluation."""
        out = np.zeros_like(x)
        if self.row_terms:
            inputs = EffectInputs(x, u, model=self.helper)
            for equation, effect, coef, setting in self.row_terms:
                out[:, equation] += np.asarray(effect.regressors(inputs, setting), dtype=float) @ coef
        for equation, batch in self.batches:
            out[:, equation] += batch(x, u)
        return out

    def coefficient_regressors(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """d(additive terms)/d(row coefficients): (N, n_x), (N, n_u) -> (N, n_x, n_c), the coefficients in the
        order of :attr:`row_coefficients` (each term's array in turn). The row terms are linear in their
        coefficients, so this is their regressors, placed in the rows of their equations."""
        x = np.asarray(x, dtype=float).reshape(-1, self.n_x)
        u = np.asarray(u, dtype=float).reshape(-1, self.n_u)
        starts, n_c = {}, 0
        for _, array in self.row_coefficients:
            starts[id(array)] = n_c
            n_c += array.size
        out = np.zeros((x.shape[0], self.n_x, n_c))
        if self.row_terms:
            inputs = EffectInputs(x, u, model=self.helper)
            for equation, effect, coef, setting in self.row_terms:
                start = starts[id(coef)]
                regressors = np.asarray(effect.regressors(inputs, setting), dtype=float).reshape(x.shape[0], -1)
                out[:, equation, start:start + coef.size] += regressors
        if self.hold is not None and self.row_terms:
            self._hold_regressors(x, u, out, starts)
        return out

    def _hold_regressors(self, x: np.ndarray, u: np.ndarray, out: np.ndarray, starts: dict[int, int]) -> None:
        """The hold's rows of :meth:`coefficient_regressors` (in place): a held row's rate depends on no
        coefficient; a sliding row's friction acts as at the band's edge."""
        j = self.hold_state
        held = self._held_rows(x, u, self._terms_batch(x, u))
        if held is None:
            return
        rows, _, holding, edge_states = held
        out[rows[holding], j, :] = 0.0
        sliding = rows[~holding]
        if not sliding.size:
            return
        at_state = EffectInputs(x[sliding], u[sliding], model=self.helper)
        at_edge = EffectInputs(edge_states[~holding], u[sliding], model=self.helper)
        for n in self.hold_friction:
            _, effect, coef, setting = self.row_terms[n]
            start = starts[id(coef)]
            change = (np.asarray(effect.regressors(at_edge, setting), dtype=float)
                      - np.asarray(effect.regressors(at_state, setting), dtype=float)).reshape(sliding.size, -1)
            out[sliding, j, start:start + coef.size] += change

    def effect_program(self) -> EffectProgram | None:
        """The additive terms as an :class:`~hybridfmu.fmu.effect_program.EffectProgram` (rows, then batches,
        the order :meth:`__call__` sums them in; same values), the row terms with their coefficients as they are
        at the call (a hybrid trains them in place, :attr:`row_terms`); None when some term has no C form or
        there is no term."""
        rows = [member.stage_term(coefficients, setting) for _, member, coefficients, setting in self.row_terms]
        terms = rows + self.batch_stage_terms
        if not terms or any(term is None for term in terms):
            return None
        if self.hold is not None:  # rows come first: a friction row's index is its term number
            terms.append(EffectTerm("hold", (self.hold_state,), (self.hold_state, *self.hold_friction),
                                    (float(self.hold.band), float(self.hold.rate_per_s))))
        return EffectProgram(terms, self.n_x, self.n_u, python=self)

    def correction(self) -> Callable | None:
        """The additive terms to simulate with: the :meth:`effect_program` (evaluated by an FMU's C step loop,
        called as this model elsewhere) when every term has a C form, else this model; None without terms."""
        if not self.has_correction:
            return None
        return self.effect_program() or self

    def inputs(self, u: np.ndarray, dt_s: float) -> np.ndarray:
        """The logged inputs (N, n_u) as the corrected model sees them (``dt_s``: sampling interval, s).

        Per changed input v (N,): the time shifts (v(t + s)), then the first-order lags (v + T dv/dt, dv/dt
        by :func:`hybridfmu.diagnosis.effects.input_derivative` with ``diagnosis.effects.lag_derivative_window_s``,
        the filter of the fitted regressors), the transforms (``transform(v, dt_s)``: dead zones, saturations,
        slow actuators; in rank order), the gains ((1 + g) v) and the offsets (v + o).
        """
        u = np.asarray(u, dtype=float)
        out = np.array(u, dtype=float)
        for column, changes in sorted(self.input_changes.items()):
            values = u[:, column]
            for _, change in changes:
                if change.get("shift_s", 0.0):
                    values = shift_inputs(values[:, None], change["shift_s"], dt_s)[:, 0]
            for _, change in changes:
                if change.get("lag_s", 0.0):
                    values = values + change["lag_s"] * input_derivative(values, dt_s, self.lag_window_s)
            for _, change in changes:
                if change.get("transform") is not None:
                    values = np.asarray(change["transform"](values, dt_s), dtype=float)
            out[:, column] = _gains_then_offsets(values, changes)
        return out

    def held_inputs(self, u: np.ndarray, dt_s: float) -> np.ndarray:
        """Inputs held constant, as the corrected model sees them: ``u`` (B, n_u), each row its own held inputs ->
        (B, n_u); ``dt_s`` the sampling interval (s). What :meth:`inputs` makes of a constant sequence of each row,
        all rows at once: time shifts and lags leave a held value as it is, and so do the transforms of
        :data:`~hybridfmu.diagnosis.effects.HELD_UNCHANGED_FORMS`; the static transforms, gains and offsets change
        it as any sample. A transform without a stated form is applied to a constant sequence of each row."""
        u = np.asarray(u, dtype=float)
        out = np.array(u, dtype=float)
        for column, changes in sorted(self.input_changes.items()):
            values = np.array(u[:, column], dtype=float)
            for _, change in changes:
                transform, form = change.get("transform"), change.get("form")
                if transform is None or (form is not None and form[0] in HELD_UNCHANGED_FORMS):
                    continue
                if form is not None:  # a static form: each sample on its own
                    values = np.asarray(transform(values, dt_s), dtype=float)
                else:
                    values = np.array([np.asarray(transform(np.full(3, v), dt_s), dtype=float)[1] for v in values])
            out[:, column] = _gains_then_offsets(values, changes)
        return out

    @contextlib.contextmanager
    def parameters_applied(self, model: Any) -> Iterator[None]:
        """Within the block, ``model`` and the helper (whose derivatives terms such as a limit use) have the
        corrected parameters; restored afterwards."""
        if not self.parameters:
            yield
            return
        instances = [model] + ([self.helper] if self.helper is not None and self.helper is not model else [])
        previous = [m.get_parameters(list(self.parameters)) for m in instances]
        for m in instances:
            m.set_parameters(self.parameters)
        try:
            yield
        finally:
            for m, values in zip(instances, previous):
                m.set_parameters(values)


def _steps_in_c(model: Any, correction: Callable | None) -> bool:
    """Whether a simulation of ``model`` with ``correction`` runs its solver stages in C only: an FMU (its C step
    loop) with no correction or an effect program."""
    return isinstance(model, FmuModel) and (correction is None or isinstance(correction, EffectProgram))


def simulate_windows(model: Any, simulate_fn: Callable, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
                     first: np.ndarray, n_steps: int, correction: Callable | None) -> np.ndarray:
    """Open-loop simulations of many windows: (W, n_steps + 1, n_x) states.

    Window w starts at sample ``first[w]`` from ``x0[w]`` (n_x,) and runs ``n_steps`` samples of the
    grid ``time_s`` (T,) with the inputs ``u`` (T, n_u) held per sample. An FMU whose correction its C step
    loop evaluates (none, or an :class:`~hybridfmu.fmu.effect_program.EffectProgram`) simulates each window
    on its own with ``simulate_fn`` (no Python per solver stage). Otherwise the windows run side by side, by
    the same fixed-step RK4 as ``simulate_fn``, as one batch of vectorised model evaluations; windows whose
    event indicators change sign (end stops, mode switches) or whose states become non-finite are then
    simulated again on their own with ``simulate_fn``, which handles the events. Both ways give the same
    states to the bit.
    """
    first = np.asarray(first, dtype=int)
    n_w, n_x = len(first), len(x0[0]) if len(first) else 0
    out = np.empty((n_w, n_steps + 1, n_x))
    if n_w == 0:
        return out
    if _steps_in_c(model, correction):
        for w, start in enumerate(first):
            piece = slice(int(start), int(start) + n_steps + 1)
            out[w] = simulate(model, simulate_fn, time_s[piece], u[piece], np.asarray(x0[w]), correction)
        return out
    x = np.array(x0, dtype=float)
    out[:, 0] = x
    n_z = int(getattr(model, "n_event_indicators", 0))
    clean = np.ones(n_w, dtype=bool)
    z0 = np.asarray(model.event_indicators(x, u[first]), dtype=float) > 0.0 if n_z else None
    if n_z:
        clean &= np.all(z0, axis=1)

    def rhs(states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        f = np.asarray(model.derivatives(states, inputs), dtype=float)
        return f + np.asarray(correction(states, inputs), dtype=float) if correction is not None else f

    with np.errstate(all="ignore"):
        for j in range(n_steps):
            k = first + j
            u_k = u[k]
            h = (time_s[k + 1] - time_s[k])[:, None]
            x = RK4.plan(h).step(x, lambda state, _stage, held=u_k: rhs(state, held), numpy_axpy)
            finite = np.all(np.isfinite(x), axis=1)
            clean &= finite
            x[~finite] = x0[~finite]
            if n_z:
                clean &= np.all((np.asarray(model.event_indicators(x, u_k), dtype=float) > 0.0) == z0, axis=1)
                clean &= np.all((np.asarray(model.event_indicators(x, u[k + 1]), dtype=float) > 0.0) == z0, axis=1)
            out[:, j + 1] = x
    for w in np.flatnonzero(~clean):
        piece = slice(int(first[w]), int(first[w]) + n_steps + 1)
        out[w] = simulate(model, simulate_fn, time_s[piece], u[piece], np.asarray(x0[w]), correction)
    return out


def target_errors(states: np.ndarray, x_meas: np.ndarray, problem: Problem) -> dict[str, float]:
    """``<signal>_rmse`` and ``<signal>_mae`` (signal units) per target, and the normalised ``gap``:
    the target-weighted MAE / std of the measured target."""
    out: dict[str, float] = {}
    gap = 0.0
    for state, weight in problem.target_weights.items():
        i = problem.state_names.index(state)
        signal = problem.state_signal[state]
        err = states[:, i] - x_meas[:, i]
        finite = bool(np.all(np.isfinite(err)))
        mae = float(np.mean(np.abs(err))) if finite else float("nan")
        out[f"{signal}_rmse"] = float(np.sqrt(np.mean(err ** 2))) if finite else float("nan")
        out[f"{signal}_mae"] = mae
        scale = float(np.std(x_meas[:, i])) or 1.0
        gap += weight * mae / scale
    out["gap"] = gap
    return out


def open_loop_errors(model: Any, simulate_fn: Callable, time_s: np.ndarray, x_meas: np.ndarray, u: np.ndarray,
                     starts: np.ndarray, problem: Problem, corrected: CorrectedModel | None,
                     window_s: float | None) -> tuple[dict[str, float], np.ndarray]:
    """Whole-maneuver (and windowed) open-loop errors of the (corrected) model.

    Args:
        model, simulate_fn: the simulating instance and its simulator.
        time_s: (T,) grid; x_meas: (T, n_x) measured states (unmeasured columns ignored); u: (T, n_u) logged inputs.
        starts: (T, n_x) low-noise states to start from (unmeasured ones from the reference simulation).
        corrected: the chosen effects, or None for the plain model.
        window_s: length of the restarted windows (s), or None for none.
    Returns:
        (errors: ``<signal>_rmse``, ``<signal>_mae``, ``gap``, and ``window_<signal>_mae``, ``window_gap``
        when windowed; simulated states of the whole maneuver (T, n_x)).
    """
    dt_s = float(np.median(np.diff(time_s)))
    correction = corrected.correction() if corrected is not None else None
    u_model = corrected.inputs(u, dt_s) if corrected is not None else u
    context = corrected.parameters_applied(model) if corrected is not None else contextlib.nullcontext()
    with context:
        whole = simulate(model, simulate_fn, time_s, u_model, starts[0], correction)
        errors = target_errors(whole, x_meas, problem)
        if window_s:
            n_win = max(int(round(window_s / dt_s)), 2)
            first = np.arange(0, len(time_s) - n_win, n_win)
            windows = simulate_windows(model, simulate_fn, time_s, u_model, starts[first], first, n_win, correction)
            gap = 0.0
            for state, weight in problem.target_weights.items():
                i = problem.state_names.index(state)
                values = [np.mean(np.abs(windows[w, :, i] - x_meas[s:s + n_win + 1, i])) for w, s in enumerate(first)]
                mae = float(np.mean(values)) if values and np.all(np.isfinite(values)) else float("nan")
                errors[f"window_{problem.state_signal[state]}_mae"] = mae
                gap += weight * mae / (float(np.std(x_meas[:, i])) or 1.0)
            errors["window_gap"] = gap
            errors["n_windows"] = len(first)
    return errors, whole
