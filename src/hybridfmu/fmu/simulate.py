"""Open-loop simulation of an FMU on the sample grid of its inputs.

Fixed-step classical Runge-Kutta (RK4), one step per input sample, inputs held between samples
(zero-order hold). The whole grid runs in the C shim (``hf_run_grid``), events included (an exported
model steps with the same functions), and returns to Python only to hand over its event log or when
the run ends:

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
from hybridfmu.fmu.bridge import MAX_EVENT_ITERATIONS, FmuError, FmuModel, FmuTerminated
from hybridfmu.fmu.effect_program import EffectProgram

Correction = Callable[[np.ndarray, np.ndarray], np.ndarray]

#: hf_settle's return code when it stopped with an outcome (HF_STOP in shim.c)
_STOP = -10


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

    # ------------------------------------------------------------------ events (in C: shim.c, hf_run_grid)

    def _event_record(self) -> _shim.ShimEvents:
        """The C loop's event settings, log buffers and outcome."""
        m = self.model
        nz = max(m.n_event_indicators, 1)
        capacity = max(256, 4 * (self.max_events + 2))
        self.log_time = np.zeros(capacity)
        self.log_kind = np.zeros(capacity, dtype=np.intc)
        self.log_reinit = np.zeros(capacity, dtype=np.intc)
        self.log_crossed = np.zeros((capacity, nz), dtype=np.uint8)
        self.outcome_x = np.zeros(max(m.n_states, 1))
        ev = _shim.ShimEvents()
        ev.tolerance_s, ev.max_events, ev.max_iterations = self.tol, self.max_events, MAX_EVENT_ITERATIONS
        ev.next_time_event = float(self.next_time_event)
        ev.capacity, ev.count = capacity, 0
        ev.log_time, ev.log_kind = self.log_time.ctypes.data, self.log_kind.ctypes.data
        ev.log_reinit, ev.log_crossed = self.log_reinit.ctypes.data, self.log_crossed.ctypes.data
        ev.outcome_x = self.outcome_x.ctypes.data
        return ev

    def _description(self, kind: int, reinit: bool, crossed: np.ndarray) -> str | None:
        """The words of one logged event (None: the start's event iteration without a change of the states)."""
        indicators = np.flatnonzero(crossed[: self.model.n_event_indicators]).tolist()
        text = {_shim.EV_SETTLE: None,
                _shim.EV_INPUT: f"input event: event indicator(s) {indicators} changed sign with the new inputs",
                _shim.EV_STATE: f"state event: event indicator(s) {indicators} changed sign",
                _shim.EV_TIME: "time event",
                _shim.EV_STEP: "step event (fmi2CompletedIntegratorStep)"}[kind]
        if reinit:
            text = (text or "event iteration") + "; states re-initialised"
        return text

    def _drain(self, ev: _shim.ShimEvents) -> str | None:
        """Move the C loop's log into ``events``; the description of the last entry logged (or None)."""
        last = None
        for i in range(int(ev.count)):
            last = self._description(int(self.log_kind[i]), bool(self.log_reinit[i]), self.log_crossed[i])
            if last is not None:
                self.events.append((float(self.log_time[i]), last))
        ev.count = 0
        return last

    def _finish(self, ev: _shim.ShimEvents, last: str | None) -> None:
        """Raise what ended the C loop early: a terminate request (with the states then) or an error."""
        m, t = self.model, float(ev.outcome_time)
        outcome = int(ev.outcome)
        if outcome == _shim.OUT_TERMINATE:
            x = self.outcome_x[: m.n_states].copy()
            if ev.terminate_source == _shim.TERM_COMPLETED_STEP:
                raise _TerminationRequest(t, x, f"fmi2CompletedIntegratorStep after the step to t = {t} s")
            raise _TerminationRequest(t, x, f"fmi2NewDiscreteStates at the {last or 'event'} at t = {t} s")
        if outcome == _shim.OUT_TOO_MANY_EVENTS:
            raise FmuError(f"{m.path}: more than {self.max_events} events within one step ending at "
                           f"t = {float(ev.outcome_value)} s (at t = {t} s; chattering? raise max_events_per_step "
                           "if expected)", m.log_messages())
        if outcome == _shim.OUT_TIME_EVENT_PAST:
            raise FmuError(f"{m.path}: the FMU announced its next time event (nextEventTime) at t = "
                           f"{float(ev.outcome_value)} s, expected a time after the current time {t} s",
                           m.log_messages())
        if outcome == _shim.OUT_NONFINITE_STATES:
            bad = [name for name, value in zip(m.state_names, self.outcome_x) if not np.isfinite(value)]
            raise FmuError(f"{m.path}: the FMU set non-finite values of the states {bad} at the event at t = {t} s "
                           "(expected finite states)", m.log_messages())
        if outcome == _shim.OUT_NO_CONVERGENCE:
            raise FmuError(f"{m.path}: event iteration at t = {t} s did not converge in {MAX_EVENT_ITERATIONS} "
                           "iterations (newDiscreteStatesNeeded stayed true)", m.log_messages())
        if outcome != _shim.OUT_DONE:
            raise FmuError(f"{m.path}: the simulation loop ended with an unknown outcome {outcome}")

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
        """Fill states (T, n_x) sample by sample in the C loop (events handled there), reading its event log
        whenever it fills up."""
        m = self.model
        time, u = self.time, self.u
        nz = m.n_event_indicators
        ev = self._event_record()
        u_ptr = m._data(u) or m._empty.ctypes.data
        z_prev = np.zeros(max(nz, 1))
        # the FMU initialised from its start values; settle its discrete state at x0
        x = self.x0.copy()
        status = m._lib.hf_settle(m._m, ctypes.addressof(ev), float(time[0]), x.ctypes.data, u_ptr,
                                  z_prev.ctypes.data)
        if status != _STOP:
            self._check(status, f"the event iteration at t = {time[0]} s")
        last = self._drain(ev)
        if status == _STOP:
            self._finish(ev, last)
        states[0] = x
        work = np.empty(16 * m.n_states + 6 * nz + 1)
        k_out = np.zeros(1, dtype=np.int64)
        k = 0
        while True:
            status = m._lib.hf_run_grid(m._m, ctypes.addressof(ev), time.size, time.ctypes.data, u_ptr, k,
                                        states.ctypes.data, z_prev.ctypes.data, work.ctypes.data, k_out.ctypes.data)
            last = self._drain(ev)
            self._check(status, "simulation")
            if ev.outcome == _shim.OUT_PAUSE:
                k = int(k_out[0])
                continue
            self.next_time_event = float(ev.next_time_event)
            self._finish(ev, last)
            return

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
