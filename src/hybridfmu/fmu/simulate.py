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
- time events announced by the FMU, and step events requested by fmi2CompletedIntegratorStep
  (called after every accepted step).

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
from hybridfmu.fmu.bridge import FmuError, FmuModel

Correction = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class SimulationResult:
    """time_s (T,) in s, states (T, n_x) (columns ``state_names``), events: (time_s, description).

    states[k] is the state at time_s[k]; where an event falls exactly on a sample, the state
    after the event is reported.
    """

    time_s: np.ndarray
    states: np.ndarray
    events: list[tuple[float, str]] = field(default_factory=list)
    state_names: list[str] = field(default_factory=list)


def simulate_open_loop(
    model: FmuModel,
    time_s,
    u,
    x0,
    correction: Correction | None = None,
    *,
    event_tolerance_s: float = 1e-10,
    max_events_per_step: int = 100,
) -> SimulationResult:
    """Simulate ``model`` from ``x0`` over the grid ``time_s`` with inputs ``u`` held per sample.

    time_s: (T,) strictly increasing sample times in s; u: (T, n_u) inputs (u[k] acts on
    [time_s[k], time_s[k+1]); None if the FMU has no inputs); x0: (n_x,) initial states.
    correction: optional callable (x (1, n_x), u (1, n_u)) -> (1, n_x) added to the FMU's
    derivatives at every right-hand-side evaluation (it is called from the C step loop, once
    per RK4 stage). event_tolerance_s: width of the bracket that locates a state event.
    Returns a :class:`SimulationResult`.
    """
    session = _Session(model, time_s, u, x0, correction, event_tolerance_s, max_events_per_step)
    return session.run()


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
        """Event mode at (t, x, u); return the states and event indicators after the event.

        The event is recorded under ``description``; with None it is recorded only if the FMU
        changed the states."""
        m = self.model
        self._indicators(t, x, u)  # sets time, states and inputs
        m._fmi("enterEventMode")
        self.next_time_event, changed = m._event_iteration(t)
        m._fmi("enterContinuousTimeMode")
        if changed and m.n_states:
            x = np.empty(m.n_states)
            m._fmi("getContinuousStates", x.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), m.n_states)
            if not np.isfinite(x).all():
                raise FmuError(f"{m.path}: the FMU set non-finite states at the event at t = {t} s", m.log_messages())
            description = (description or "event iteration") + "; states re-initialised"
        if description is not None:
            self.events.append((float(t), description))
        return x, self._indicators(t, x, u)

    def _advance(self, t_a: float, x_a: np.ndarray, t_b: float, u: np.ndarray, z_a: np.ndarray):
        """Integrate from (t_a, x_a) to t_b with one RK4 step, locating and handling every state
        event on the way; return the states and event indicators at t_b."""
        for _ in range(self.max_events):
            span = t_b - t_a
            if span <= 4.0 * np.finfo(float).eps * max(1.0, abs(t_b)):
                return x_a, z_a
            x_b, z_b = self._rk4_step(t_a, span, x_a, u)
            crossed = _crossed(z_a, z_b)
            if crossed.size == 0:
                enter, terminate = self._completed_step(t_b)
                self._check_terminate(terminate, t_b)
                if enter:
                    x_b, z_b = self._handle_event(t_b, x_b, u, "step event (fmi2CompletedIntegratorStep)")
                return x_b, z_b
            lo, hi, x_hi, z_hi = 0.0, 1.0, x_b, z_b
            tol = max(self.tol, 4.0 * np.finfo(float).eps * max(1.0, abs(t_b)))
            while (hi - lo) * span > tol:
                mid = 0.5 * (lo + hi)
                x_m, z_m = self._rk4_step(t_a, mid * span, x_a, u)
                if _crossed(z_a, z_m).size:
                    hi, x_hi, z_hi = mid, x_m, z_m
                else:
                    lo = mid
            t_e = t_a + hi * span if hi < 1.0 else t_b
            crossed = _crossed(z_a, z_hi)
            self._indicators(t_e, x_hi, u)  # leave the FMU at the accepted point
            _, terminate = self._completed_step(t_e)
            self._check_terminate(terminate, t_e)
            x_e, z_e = self._handle_event(
                t_e, x_hi, u, f"state event: event indicator(s) {crossed.tolist()} changed sign")
            t_a, x_a, z_a = t_e, x_e, z_e
        raise FmuError(f"{self.model.path}: more than {self.max_events} events within one step ending at "
                       f"t = {t_b} s (chattering?)", self.model.log_messages())

    def _check_terminate(self, terminate: bool, t: float) -> None:
        if terminate:
            raise FmuError(f"{self.model.path}: the FMU asked to terminate the simulation at t = {t} s",
                           self.model.log_messages())

    # ------------------------------------------------------------------ main loop

    def run(self) -> SimulationResult:
        m = self.model
        time, u = self.time, self.u
        n_samples, nx, nz = time.size, m.n_states, m.n_event_indicators
        start_values = {}
        for name, value in zip(m.state_names, self.x0):
            variable = m._variables[name]
            if variable.initial in ("exact", "approx") or (variable.initial is None and variable.start is not None):
                start_values[name] = float(value)
        for name, value in zip(m.input_names, u[0] if n_samples else []):
            start_values[name] = float(value)
        states = np.empty((n_samples, nx))
        states[0] = self.x0
        try:
            m._initialise(start_time_s=float(time[0]), start_values=start_values)
            self.next_time_event = m._next_time_event_s
            self._install_correction()
            u0 = u[0]
            # the FMU initialised from its start values; settle its discrete state at x0
            x, z = self._handle_event(time[0], self.x0.copy(), u0, None)
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
                    x, z = self._handle_event(time[k], states[k].copy(), u[k], "input event: event indicator(s) "
                                              f"{_crossed(z_prev[:nz], self._indicators(time[k], states[k], u[k])).tolist()} "
                                              "changed sign with the new inputs")
                    states[k] = x
                elif reason == _shim.SIM_STATE_EVENT:
                    x, z = self._advance(time[k], states[k].copy(), time[k + 1], u[k], z_prev[:nz].copy())
                    states[k + 1] = x
                    k += 1
                elif reason == _shim.SIM_TIME_EVENT:
                    t_event = self.next_time_event
                    if t_event <= time[k]:
                        x, z = self._handle_event(time[k], states[k].copy(), u[k], "time event")
                        states[k] = x
                        if self.next_time_event <= time[k]:
                            raise FmuError(f"{m.path}: the FMU announced a time event at t = "
                                           f"{self.next_time_event} s, not after the current time {time[k]} s")
                    else:
                        x, z = self._advance(time[k], states[k].copy(), t_event, u[k], z_prev[:nz].copy())
                        x, z = self._handle_event(t_event, x, u[k], "time event")
                        x, z = self._advance(t_event, x, time[k + 1], u[k], z)
                        states[k + 1] = x
                        k += 1
                elif reason == _shim.SIM_STEP_EVENT:
                    x, z = self._handle_event(time[k + 1], states[k + 1].copy(), u[k],
                                              "step event (fmi2CompletedIntegratorStep)")
                    states[k + 1] = x
                    k += 1
                elif reason == _shim.SIM_TERMINATE:
                    self._check_terminate(True, time[k + 1])
                else:
                    raise FmuError(f"{m.path}: the simulation loop returned an unknown reason {reason}")
                if nz:
                    z_prev[:nz] = z
        finally:
            self._remove_correction()
            m._needs_reinit = True
        return SimulationResult(time_s=time.copy(), states=states, events=self.events,
                                state_names=list(m.state_names))

    # ------------------------------------------------------------------ correction callback

    def _install_correction(self) -> None:
        if self.correction is None:
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
