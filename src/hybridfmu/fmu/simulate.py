"""Open-loop simulation of an FMU on the sample grid of its inputs.

Fixed-step classical Runge-Kutta (RK4), one step per input sample, inputs held between samples
(zero-order hold). The step loop runs in the C shim and returns to Python only when an event
needs handling:

- state events: an event indicator changes its domain (z > 0 versus z <= 0) within a step; the
  crossing is located by bisection on the step fraction (RK4 over the partial step) to
  ``event_tolerance_s``, the FMU is integrated up to just past the crossing, and the event is
  handled in the FMU's event mode (fmi2EnterEventMode, fmi2NewDiscreteStates until no new
  event, states read back if they changed, fmi2EnterContinuousTimeMode); the rest of the step
  is then integrated from the new state;
- input events: new input values at a sample move an indicator across zero;
- time events announced by the FMU (nextEventTime), and step events requested by
  fmi2CompletedIntegratorStep (called after every accepted step).

Any number of events may fall within one sample interval: they are handled one after the other in
time order (the integration stops at each time event and at each located state event, runs the
event iteration, reads the states back if the FMU changed them, and continues from there).

If the FMU asks to end the simulation (terminateSimulation from fmi2NewDiscreteStates or
fmi2CompletedIntegratorStep), the trajectory up to that time is kept: with
``allow_termination=True`` it is returned with ``terminated_at_s`` and ``termination_reason``
set; by default (callers that need the whole horizon) :class:`FmuTerminated` is raised, naming
the FMU and the time, and carrying that partial result as ``.result``.

The simulation re-initialises the FMU at ``time_s[0]`` (parameters kept) with the start values
``x0`` and ``u[0]``; afterwards the model is re-initialised again before its next batch call, so
batch evaluations never see the discrete state the simulation left behind.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from hybridfmu.fmu import shim as _shim
from hybridfmu.fmu.bridge import FmuError, FmuModel, FmuTerminated
from hybridfmu.fmu.effect_program import EffectProgram

Correction = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class SimulationResult:
    """time_s (T,) in s, states (T, n_x) (columns ``state_names``), events: (time_s, description).

    states[k] is the state at time_s[k]; where an event falls exactly on a sample, the state
    after the event is reported.

    A simulation that the FMU ended early (terminateSimulation) has ``terminated_at_s`` (s) and
    ``termination_reason`` set (None otherwise); its time_s holds the samples before
    terminated_at_s followed by terminated_at_s itself (the last row is the state when the FMU
    asked to terminate), so T may be smaller than the grid's length. ``path`` is the FMU file.
    """

    time_s: np.ndarray
    states: np.ndarray
    events: list[tuple[float, str]] = field(default_factory=list)
    state_names: list[str] = field(default_factory=list)
    terminated_at_s: float | None = None
    termination_reason: str | None = None
    path: str | None = None

    @property
    def terminated(self) -> bool:
        """True if the FMU ended the simulation before the end of the grid."""
        return self.terminated_at_s is not None

    def require_full_horizon(self) -> "SimulationResult":
        """This result if it covers the whole grid; FmuTerminated naming the FMU, the time and the
        reason if the FMU ended the simulation early."""
        if self.terminated_at_s is None:
            return self
        raise FmuTerminated(
            f"{self.path}: the simulation ended at t = {self.terminated_at_s} s, before the end of the grid "
            f"(the FMU asked to terminate: {self.termination_reason}); expected the full horizon",
            path=self.path, time_s=self.terminated_at_s, reason=self.termination_reason or "", result=self,
        )


class _TerminationRequest(Exception):
    """Internal: the FMU asked to terminate at time_s (s) with the states x (n_x,) at that time."""

    def __init__(self, time_s: float, x: np.ndarray, reason: str):
        super().__init__(reason)
        self.time_s, self.x, self.reason = float(time_s), np.array(x, dtype=np.float64), reason


def simulate_open_loop(
    model: FmuModel,
    time_s,
    u,
    x0,
    correction: Correction | None = None,
    *,
    event_tolerance_s: float = 1e-10,
    max_events_per_step: int = 100,
    allow_termination: bool = False,
) -> SimulationResult:
    """Simulate ``model`` from ``x0`` over the grid ``time_s`` with inputs ``u`` held per sample.

    time_s: (T,) strictly increasing sample times in s; u: (T, n_u) inputs (u[k] acts on
    [time_s[k], time_s[k+1]); None if the FMU has no inputs); x0: (n_x,) initial states.
    correction: optional terms added to the FMU's derivatives at every right-hand-side evaluation:
    an :class:`~hybridfmu.fmu.effect_program.EffectProgram` (evaluated by the C step loop itself) or a
    callable (x (1, n_x), u (1, n_u)) -> (1, n_x) (called from the C step loop, once per RK4 stage). event_tolerance_s: width of the bracket that locates a state event.
    max_events_per_step: the most events (time, state and step events) handled within one
    sample interval before the run is stopped as chattering.
    allow_termination: if the FMU asks to terminate, return the partial result (True) or raise
    :class:`FmuTerminated` carrying it (False, for callers that need the whole grid).
    Returns a :class:`SimulationResult`.
    """
    session = _Session(model, time_s, u, x0, correction, event_tolerance_s, max_events_per_step)
    result = session.run()
    return result if allow_termination else result.require_full_horizon()


def _crossed(z_a: np.ndarray, z_b: np.ndarray) -> np.ndarray:
    """Indices of the event indicators whose domain (z > 0 or z <= 0) differs between a and b."""
    return np.flatnonzero((z_a > 0.0) != (z_b > 0.0))


class _Session:
    """One simulation run: validated arguments, shim buffers and the event handling."""

    def __init__(self, model, time_s, u, x0, correction, event_tolerance_s, max_events_per_step):
        if not isinstance(model, FmuModel):
            raise ValueError(f"model: expected an FmuModel (from load_fmu), got {type(model).__name__}")
        model._require_open()
        self.model = model
        self.time = self._check_time(time_s)
        n_samples = self.time.size
        self.u = model._as_matrix("u", u, model.n_inputs, model.input_names, n_samples)
        x0 = np.asarray(x0) if x0 is not None else None
        if x0 is None or x0.dtype.kind not in "fiu" or x0.shape != (model.n_states,):
            got = "None" if x0 is None else f"shape {x0.shape}, dtype {x0.dtype}"
            raise ValueError(f"x0: expected a real array of shape ({model.n_states},) ({model.state_names}), got {got}")
        self.x0 = model._as_matrix("x0", x0.reshape(1, -1), model.n_states, model.state_names, 1)[0]
        if correction is not None and not callable(correction):
            raise ValueError(f"correction: expected a callable (x, u) -> dx or None, got {type(correction).__name__}")
        self.correction = correction
        if not (np.isfinite(event_tolerance_s) and event_tolerance_s > 0):
            raise ValueError(f"event_tolerance_s: expected a positive number of seconds, got {event_tolerance_s}")
        self.tol = float(event_tolerance_s)
        if int(max_events_per_step) < 1:
            raise ValueError(f"max_events_per_step: expected at least 1, got {max_events_per_step}")
        self.max_events = int(max_events_per_step)
        nx, nz = model.n_states, model.n_event_indicators
        self.work = np.empty(5 * nx + nz + 1)
        self.x_new = np.empty(nx)
        self.z_new = np.empty(max(nz, 1))
        self.flags = np.zeros(2, dtype=np.intc)
        self.result = np.zeros(2, dtype=np.int64)
        self.events: list[tuple[float, str]] = []
        self.callback_errors: list[BaseException] = []

    @staticmethod
    def _check_time(time_s) -> np.ndarray:
        t = np.asarray(time_s)
        if t.dtype.kind not in "fiu" or t.ndim != 1 or t.size < 1:
            raise ValueError(f"time_s: expected a real 1-D array of sample times in s, got shape {t.shape}, dtype {t.dtype}")
        t = np.ascontiguousarray(t, dtype=np.float64)
        if not np.isfinite(t).all():
            raise ValueError(f"time_s: non-finite time at index {int(np.flatnonzero(~np.isfinite(t))[0])}")
        steps = np.diff(t)
        if (steps <= 0).any():
            k = int(np.flatnonzero(steps <= 0)[0])
            raise ValueError(f"time_s: expected strictly increasing times, but time_s[{k + 1}] = {t[k + 1]} "
                             f"<= time_s[{k}] = {t[k]}")
        return t

    # ------------------------------------------------------------------ shim calls

    def _check(self, status: int, what: str) -> None:
        if status == 0:
            return
        if status == _shim.ERR_EFFECT_PROGRAM:
            raise ValueError(f"{what}: the C step loop found an unknown term in the effect program")
        if status == _shim.ERR_CALLBACK and self.callback_errors:
            error = self.callback_errors[0]
            raise type(error)(f"correction failed during {what}: {error}") from error
        self.model._raise_shim_error(status, what, row_label="step")

    def _rk4_step(self, t: float, h: float, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.model
        status = m._lib.hf_rk4_step(m._m, t, h, x.ctypes.data, m._data(u) or m._empty.ctypes.data,
                                    self.x_new.ctypes.data, self.z_new.ctypes.data, self.work.ctypes.data)
        self._check(status, f"an RK4 step at t = {t} s")
        return self.x_new.copy(), self.z_new[: m.n_event_indicators].copy()

    def _indicators(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Event indicators at (t, x, u); also leaves the FMU at that point."""
        m = self.model
        z = np.empty(max(m.n_event_indicators, 1))
        status = m._lib.hf_event_indicators(m._m, 1, np.array([t]).ctypes.data, 0, x.ctypes.data,
                                            m._data(u) or m._empty.ctypes.data, z.ctypes.data)
        self._check(status, f"event indicators at t = {t} s")
        return z[: m.n_event_indicators]

    def _completed_step(self, t: float) -> tuple[bool, bool]:
        m = self.model
        status = m._lib.hf_completed_step(m._m, self.flags.ctypes.data)
        self._check(status, f"fmi2CompletedIntegratorStep at t = {t} s")
        return bool(self.flags[0]), bool(self.flags[1])

    # ------------------------------------------------------------------ events

    def _handle_event(self, t: float, x: np.ndarray, u: np.ndarray, description: str | None):
        """Event mode at (t, x, u); return the states (n_x,) and event indicators after the event.

        The event is recorded under ``description``; with None it is recorded only if the FMU
        changed the states. A terminate request raises _TerminationRequest with the states then."""
        m = self.model
        self._indicators(t, x, u)  # sets time, states and inputs
        m._fmi("enterEventMode")
        update = m._event_iteration(t)
        if update.states_changed and m.n_states:
            x = self._read_states(t)
            description = (description or "event iteration") + "; states re-initialised"
        if description is not None:
            self.events.append((float(t), description))
        if update.terminate:
            raise _TerminationRequest(t, x, f"fmi2NewDiscreteStates at the {description or 'event'} at t = {t} s")
        self.next_time_event = update.next_time_event_s
        m._fmi("enterContinuousTimeMode")
        return x, self._indicators(t, x, u)

    def _read_states(self, t: float) -> np.ndarray:
        """The FMU's continuous states (n_x,) after an event at t (s); FmuError if not finite."""
        m = self.model
        x = np.empty(m.n_states)
        m._fmi("getContinuousStates", x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), m.n_states)
        if not np.isfinite(x).all():
            bad = [name for name, value in zip(m.state_names, x) if not np.isfinite(value)]
            raise FmuError(f"{m.path}: the FMU set non-finite values of the states {bad} at the event at t = {t} s "
                           "(expected finite states)", m.log_messages())
        return x

    def _accept_step(self, t: float, x: np.ndarray, u: np.ndarray, z: np.ndarray):
        """fmi2CompletedIntegratorStep at the accepted point (t, x); handle a step event if the FMU
        asks for one. Returns the states and event indicators to continue from."""
        enter, terminate = self._completed_step(t)
        if terminate:
            raise _TerminationRequest(t, x, f"fmi2CompletedIntegratorStep after the step to t = {t} s")
        if enter:
            return self._handle_event(t, x, u, "step event (fmi2CompletedIntegratorStep)")
        return x, z

    def _locate_state_event(self, t_a: float, x_a: np.ndarray, span: float, u: np.ndarray,
                            z_a: np.ndarray, x_b: np.ndarray, z_b: np.ndarray):
        """Bisection on the fraction of the step (t_a, t_a + span] for the first point where an
        event indicator has left its domain at t_a, to within the event tolerance. Returns the
        time (s), the states and event indicators just past the crossing."""
        lo, hi, x_hi, z_hi = 0.0, 1.0, x_b, z_b
        t_b = t_a + span
        tol = max(self.tol, 4.0 * np.finfo(float).eps * max(1.0, abs(t_b)))
        while (hi - lo) * span > tol:
            mid = 0.5 * (lo + hi)
            x_m, z_m = self._rk4_step(t_a, mid * span, x_a, u)
            if _crossed(z_a, z_m).size:
                hi, x_hi, z_hi = mid, x_m, z_m
            else:
                lo = mid
        t_e = t_a + hi * span if hi < 1.0 else t_b
        self._indicators(t_e, x_hi, u)  # leave the FMU at the accepted point
        return t_e, x_hi, z_hi

    def _step(self, t_a: float, x_a: np.ndarray, t_stop: float, u: np.ndarray, z_a: np.ndarray):
        """One RK4 step from (t_a, x_a) towards t_stop (s), cut short at the first state event,
        which is then handled. Returns (t, x, z, event): where the step ended, the states and event
        indicators there, and whether an event (state or step event) was handled."""
        x_b, z_b = self._rk4_step(t_a, t_stop - t_a, x_a, u)
        crossed = _crossed(z_a, z_b)
        if crossed.size == 0:
            events_before = len(self.events)
            x_b, z_b = self._accept_step(t_stop, x_b, u, z_b)
            return t_stop, x_b, z_b, len(self.events) > events_before
        t_e, x_e, z_e = self._locate_state_event(t_a, x_a, t_stop - t_a, u, z_a, x_b, z_b)
        crossed = _crossed(z_a, z_e)
        # event mode follows anyway: of fmi2CompletedIntegratorStep only a terminate request matters
        _, terminate = self._completed_step(t_e)
        if terminate:
            raise _TerminationRequest(t_e, x_e, f"fmi2CompletedIntegratorStep after the step to t = {t_e} s")
        x_e, z_e = self._handle_event(t_e, x_e, u, f"state event: event indicator(s) {crossed.tolist()} changed sign")
        return t_e, x_e, z_e, True

    def _handle_time_event(self, t: float, x: np.ndarray, u: np.ndarray):
        """The time event due at t (s); FmuError if the FMU then announces one that is not later."""
        x, z = self._handle_event(t, x, u, "time event")
        if self.next_time_event <= t:
            raise FmuError(f"{self.model.path}: the FMU announced its next time event (nextEventTime) at t = "
                           f"{self.next_time_event} s, expected a time after the current time {t} s",
                           self.model.log_messages())
        return x, z

    def _integrate_interval(self, t_a: float, x: np.ndarray, t_b: float, u: np.ndarray, z: np.ndarray):
        """Integrate from (t_a, x) to t_b (s) with the inputs u held, handling in time order every
        time event (the FMU's nextEventTime) and state event on the way, and a time event due at t_b.
        Returns the states (n_x,) and event indicators (n_z,) at t_b."""
        events = 0
        while True:
            if self.next_time_event <= t_a:
                events = self._count_event(events, t_a, t_b)
                x, z = self._handle_time_event(t_a, x, u)
                continue
            if t_b - t_a <= 4.0 * np.finfo(float).eps * max(1.0, abs(t_b)):
                return x, z
            t_a, x, z, handled = self._step(t_a, x, min(self.next_time_event, t_b), u, z)
            if handled:
                events = self._count_event(events, t_a, t_b)

    def _count_event(self, events: int, t: float, t_b: float) -> int:
        """events + 1; FmuError if that is more than max_events_per_step within the interval ending at t_b."""
        if events >= self.max_events:
            raise FmuError(f"{self.model.path}: more than {self.max_events} events within one step ending at "
                           f"t = {t_b} s (at t = {t} s; chattering? raise max_events_per_step if expected)",
                           self.model.log_messages())
        return events + 1

    # ------------------------------------------------------------------ main loop

    def _start_values(self) -> dict[str, float]:
        """Start values for the re-initialisation: the states x0 the FMU accepts as start values
        (initial exact or approx) and the inputs u[0]."""
        m = self.model
        start_values = {}
        for name, value in zip(m.state_names, self.x0):
            variable = m._variables[name]
            if variable.initial in ("exact", "approx") or (variable.initial is None and variable.start is not None):
                start_values[name] = float(value)
        for name, value in zip(m.input_names, self.u[0] if self.time.size else []):
            start_values[name] = float(value)
        return start_values

    def run(self) -> SimulationResult:
        """Simulate over the whole grid, or up to the FMU's terminate request (see the module doc)."""
        m = self.model
        states = np.empty((self.time.size, m.n_states))
        states[0] = self.x0
        try:
            try:
                m._initialise(start_time_s=float(self.time[0]), start_values=self._start_values())
            except FmuTerminated as err:
                raise _TerminationRequest(self.time[0], self.x0, err.reason) from None
            self.next_time_event = m._next_time_event_s
            self._install_correction()
            self._run_grid(states)
        except _TerminationRequest as request:
            return self._partial_result(states, request)
        finally:
            self._remove_correction()
            m._needs_reinit = True
        return SimulationResult(time_s=self.time.copy(), states=states, events=self.events,
                                state_names=list(m.state_names), path=str(m.path))

    def _partial_result(self, states: np.ndarray, request: _TerminationRequest) -> SimulationResult:
        """The result up to the terminate request: the samples before its time, then its time and states."""
        m = self.model
        m._needs_reinit = True
        self.events.append((request.time_s, f"terminate: {request.reason}"))
        k = int(np.searchsorted(self.time, request.time_s, side="left"))
        time_s = np.append(self.time[:k], request.time_s)
        kept = np.vstack([states[:k], request.x.reshape(1, -1)]) if m.n_states else np.empty((k + 1, 0))
        return SimulationResult(time_s=time_s, states=kept, events=self.events, state_names=list(m.state_names),
                                terminated_at_s=request.time_s, termination_reason=request.reason,
                                path=str(m.path))

    def _run_grid(self, states: np.ndarray) -> None:
        """Fill states (T, n_x) sample by sample: the C step loop runs until an event needs
        handling, which is done here, and then resumes."""
        m = self.model
        time, u = self.time, self.u
        n_samples, nz = time.size, m.n_event_indicators
        # the FMU initialised from its start values; settle its discrete state at x0
        x, z = self._handle_event(time[0], self.x0.copy(), u[0], None)
        states[0] = x
        z_prev = np.ascontiguousarray(z, dtype=np.float64).copy() if nz else np.empty(1)
        k = 0
        u_ptr = m._data(u) or m._empty.ctypes.data
        while k < n_samples - 1:
            status = m._lib.hf_simulate(m._m, n_samples, time.ctypes.data, u_ptr, k,
                                        self.next_time_event, states.ctypes.data, z_prev.ctypes.data,
                                        self.work.ctypes.data, self.result.ctypes.data)
            self._check(status, "simulation")
            reason, k = int(self.result[0]), int(self.result[1])
            if reason == _shim.SIM_DONE:
                break
            if reason == _shim.SIM_INPUT_EVENT:
                crossed = _crossed(z_prev[:nz], self._indicators(time[k], states[k], u[k])).tolist()
                x, z = self._handle_event(time[k], states[k].copy(), u[k],
                                          f"input event: event indicator(s) {crossed} changed sign with the new inputs")
                states[k] = x
            elif reason in (_shim.SIM_STATE_EVENT, _shim.SIM_TIME_EVENT):
                x, z = self._integrate_interval(time[k], states[k].copy(), time[k + 1], u[k], z_prev[:nz].copy())
                states[k + 1] = x
                k += 1
            elif reason == _shim.SIM_STEP_EVENT:
                x, z = self._handle_event(time[k + 1], states[k + 1].copy(), u[k],
                                          "step event (fmi2CompletedIntegratorStep)")
                states[k + 1] = x
                k += 1
            elif reason == _shim.SIM_TERMINATE:
                raise _TerminationRequest(time[k + 1], states[k + 1],
                                          f"fmi2CompletedIntegratorStep after the step to t = {time[k + 1]} s")
            else:
                raise FmuError(f"{m.path}: the simulation loop returned an unknown reason {reason}")
            if nz:
                z_prev[:nz] = z

    # ------------------------------------------------------------------ correction callback

    def _install_correction(self) -> None:
        if self.correction is None:
            return
        if isinstance(self.correction, EffectProgram):
            self._buffers = self.correction.install(self.model._shim_model)
            return
        m = self.model
        nx, nu = m.n_states, m.n_inputs
        x_buf = np.zeros((1, nx))
        u_buf = np.zeros((1, nu))
        dx_buf = np.zeros(nx)
        correction, errors = self.correction, self.callback_errors

        def call() -> int:
            try:
                out = np.asarray(correction(x_buf, u_buf), dtype=np.float64)
                if out.shape not in ((1, nx), (nx,)):
                    raise ValueError(f"correction: expected an array of shape (1, {nx}), got {out.shape}")
                dx_buf[:] = out.reshape(nx)
                return 0
            except BaseException as err:  # reported after the C loop returns
                errors.append(err)
                return 1

        self._callback = _shim.CORRECTION_FN(call)
        self._buffers = (x_buf, u_buf, dx_buf)
        sm = m._shim_model
        sm.cb_x = x_buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        sm.cb_u = (u_buf if nu else m._empty).ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        sm.cb_dx = dx_buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        sm.correction = self._callback

    def _remove_correction(self) -> None:
        self.model._shim_model.correction = _shim.CORRECTION_FN()
        EffectProgram.remove(self.model._shim_model)
