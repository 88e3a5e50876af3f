"""The chosen effects as explicit correction terms of the model, and open-loop re-simulation.

``EffectCorrection`` sums the fitted terms of the chosen effects; it is passed to
``hybridfmu.fmu.simulate_open_loop`` as ``correction`` (called with one state and input row
per Runge-Kutta stage). Terms that need model quantities (e.g. the modelled acceleration for an
inertia error) evaluate them with a second model instance, so the simulation's own instance
is never re-entered. Effects that shift the inputs in time (a channel time offset) act on the
logged inputs before the simulation.

Open-loop errors are reported two ways: over the whole maneuver from the measured initial
state (the motor is driven by logged duties computed from the measured angle, so a simulated
angle that drifts away makes the motor lose synchronism and the error explodes), and as the
mean error of short windows, each restarted from the measured state (``window_s``), which
measures how fast the model departs from the data without the loss of synchronism.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from hybridfmu.diagnosis.derivatives import odd_window, savgol_smooth
from hybridfmu.diagnosis.effects import EffectInputs
from hybridfmu.diagnosis.layout import MotorLayout
from hybridfmu.diagnosis.selection import Term

LOGGER = logging.getLogger("hybridfmu.diagnosis")


class EffectCorrection:
    """Callable (x (N, n_x), u (N, n_u)) -> (N, n_x): the sum of the fitted effect terms.

    Args:
        terms: fitted terms (effect, setting, coefficients).
        layout: motor layout.
        options: effect options.
        helper_model: model instance used for terms that need model derivatives (may be None
            when no term needs it).
    """

    def __init__(self, terms: list[Term], layout: MotorLayout, options: dict[str, Any], helper_model: Any = None):
        self.terms = [t for t in terms if t.effect.input_shift_s(t.setting) == 0.0 or len(t.coef)]
        self.layout = layout
        self.options = options
        self.helper_model = helper_model
        self._torques, self._rows, self._fast, self._general = [], [], [], []
        for term in self.terms:
            scalar = term.effect.scalar_torque(term.coef, term.setting, options)
            if scalar is not None:
                self._torques.append(scalar)
                continue
            rows = term.effect.scalar_rows(term.coef, term.setting, options, layout)
            if rows is not None:
                self._rows.append(rows)
                continue
            fast = term.effect.fast_correction(term.coef, term.setting, options, layout, helper_model) \
                if helper_model is not None else None
            if fast is not None:
                self._fast.append(fast)
            else:
                self._general.append(term)
        self._inv_inertia = 1.0 / layout.inertia_kg_m2 if layout.inertia_kg_m2 else 0.0
        self._load = layout.tau_load

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        if not self._fast and not self._general and np.size(x) == self.layout.n_x:
            return self._one_row(x, u)
        x = np.asarray(x, dtype=float).reshape(-1, self.layout.n_x)
        u = np.asarray(u, dtype=float).reshape(-1, self.layout.n_u)
        out = np.zeros_like(x)
        if self._torques:
            lay = self.layout
            if x.shape[0] == 1:  # one row per Runge-Kutta stage: plain floats are much faster
                theta, omega = float(x[0, lay.theta]), float(x[0, lay.omega])
                load = float(u[0, self._load]) if self._load is not None else 0.0
                out[0, lay.omega] = sum(f(theta, omega, load) for f in self._torques) * self._inv_inertia
            else:
                for row in range(x.shape[0]):
                    load = float(u[row, self._load]) if self._load is not None else 0.0
                    out[row, lay.omega] = sum(f(float(x[row, lay.theta]), float(x[row, lay.omega]), load)
                                              for f in self._torques) * self._inv_inertia
        if self._rows:
            for row in range(x.shape[0]):
                x_row, u_row = x[row].tolist(), u[row].tolist()
                for func in self._rows:
                    for index, value in func(x_row, u_row):
                        out[row, index] += value
        for fast in self._fast:
            out += fast(x, u)
        if self._general:
            inputs = EffectInputs(self.layout, x, u, model=self.helper_model)
            for term in self._general:
                out += term.effect.correction(inputs, term.coef, term.setting, self.options)
        return out

    def _one_row(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``__call__`` for one state row (the simulation loop's calls), in plain floats: (1, n_x)."""
        lay = self.layout
        x_row = np.ravel(x).tolist()
        u_row = np.ravel(u).tolist()
        out = [0.0] * lay.n_x
        if self._torques:
            theta, omega = x_row[lay.theta], x_row[lay.omega]
            load = u_row[self._load] if self._load is not None else 0.0
            out[lay.omega] = sum(f(theta, omega, load) for f in self._torques) * self._inv_inertia
        for func in self._rows:
            for index, value in func(x_row, u_row):
                out[index] += value
        return np.array([out])

    def batch(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The same sum for many rows at once, vectorised over the rows: (N, n_x), (N, n_u) -> (N, n_x).

        Every term is evaluated by its array form (``fast_correction`` with the helper model, else
        ``correction`` in simulation mode) instead of the per-row scalar forms that ``__call__``
        uses for the one-row calls of the simulation loop.
        """
        x = np.asarray(x, dtype=float).reshape(-1, self.layout.n_x)
        u = np.asarray(u, dtype=float).reshape(-1, self.layout.n_u)
        out = np.zeros_like(x)
        inputs = EffectInputs(self.layout, x, u, model=self.helper_model)
        for term in self.terms:
            fast = term.effect.fast_correction(term.coef, term.setting, self.options, self.layout,
                                               self.helper_model) if self.helper_model is not None else None
            if fast is not None:
                out += fast(x, u)
            else:
                out += term.effect.correction(inputs, term.coef, term.setting, self.options)
        return out


def input_shift_s(terms: list[Term]) -> float:
    """Total time (s) by which the chosen terms shift the inputs."""
    return float(sum(t.effect.input_shift_s(t.setting) for t in terms))


def shift_inputs(u: np.ndarray, offset_s: float, dt_s: float, columns: np.ndarray | None = None) -> np.ndarray:
    """Inputs seen ``offset_s`` later, held per sample: u(t + offset) averaged over each step.

    ``u`` (N, n_u) -> (N, n_u); ``columns`` (n_u,) bool selects the shifted inputs (default all).
    Beyond the ends the first/last sample is held.
    """
    if offset_s == 0.0:
        return np.array(u, dtype=float)
    index = np.arange(len(u)) + offset_s / dt_s
    base = np.floor(index)
    frac = (index - base)[:, None]
    lower = np.clip(base.astype(int), 0, len(u) - 1)
    upper = np.clip(lower + 1, 0, len(u) - 1)
    shifted = (1.0 - frac) * u[lower] + frac * u[upper]
    if columns is not None:
        shifted[:, ~columns] = u[:, ~columns]
    return shifted


@dataclass
class OpenLoopErrors:
    """Open-loop errors against the measurements (angle in rad, speed in rad/s)."""

    angle_mae_rad: float
    angle_mse_rad2: float
    speed_mae_rad_s: float
    speed_mse_rad2_s2: float
    window_angle_mae_rad: float
    window_speed_mae_rad_s: float
    n_windows: int

    def as_dict(self) -> dict[str, float]:
        return dict(self.__dict__)


def measured_initial_states(x: np.ndarray, layout: MotorLayout, dt_s: float, smoothing_s: float) -> np.ndarray:
    """Low-noise measured states (N, n_x) to start simulations from (speed and currents smoothed)."""
    states = np.array(x, dtype=float)
    window = odd_window(smoothing_s, dt_s, minimum=5)
    smooth_columns = [layout.omega] + [i for i in (layout.i_d, layout.i_q) if i is not None]
    states[:, smooth_columns] = savgol_smooth(states[:, smooth_columns], window)
    return states


def simulate(model: Any, simulate_fn: Callable, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
             correction: Callable | None) -> np.ndarray:
    """States (T, n_x) of one open-loop simulation; NaN rows after a failure (logged)."""
    try:
        result = simulate_fn(model, time_s, u, x0, correction=correction)
        return np.asarray(result.states, dtype=float)
    except Exception as err:  # a diverging or failing simulation is a result, not a crash
        LOGGER.warning("open-loop simulation failed: %s", err)
        return np.full((len(time_s), len(x0)), np.nan)


def simulate_windows(model: Any, simulate_fn: Callable, time_s: np.ndarray, u: np.ndarray, x0: np.ndarray,
                     first: np.ndarray, n_steps: int, correction: Callable | None) -> np.ndarray:
    """Open-loop simulations of many windows side by side: (W, n_steps + 1, n_x) states.

    Window w starts at sample ``first[w]`` from ``x0[w]`` (n_x,) and runs ``n_steps`` samples
    of the grid ``time_s`` (T,) with the inputs ``u`` (T, n_u) held per sample. All windows
    take the same fixed-step RK4 as ``simulate_fn`` (one step per sample, the correction added
    at every stage) as one batch of vectorised model evaluations. Only windows whose event
    indicators stay positive throughout (free motion between the end stops, no mode switch) and
    whose states stay finite keep the batch result; every other window (starting at or reaching
    an end stop, ...) is simulated again on its own with ``simulate_fn``, which handles the events.
    """
    first = np.asarray(first, dtype=int)
    n_w, n_x = len(first), len(x0[0]) if len(first) else 0
    out = np.empty((n_w, n_steps + 1, n_x))
    if n_w == 0:
        return out
    x = np.array(x0, dtype=float)
    out[:, 0] = x
    n_z = int(getattr(model, "n_event_indicators", 0))
    clean = np.ones(n_w, dtype=bool)
    z0 = np.asarray(model.event_indicators(x, u[first]), dtype=float) > 0.0 if n_z else None
    if n_z:  # a window starting on an indicator's boundary or beyond (e.g. at an end stop) needs the
        clean &= np.all(z0, axis=1)  # simulator's initial event iteration (discrete mode)

    batch = getattr(correction, "batch", correction)  # a plain callable takes (N, n_x), (N, n_u) rows

    def rhs(states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        f = np.asarray(model.derivatives(states, inputs), dtype=float)
        return f + np.asarray(batch(states, inputs), dtype=float) if batch is not None else f

    with np.errstate(all="ignore"):
        for j in range(n_steps):
            k = first + j
            u_k = u[k]
            h = (time_s[k + 1] - time_s[k])[:, None]
            k1 = rhs(x, u_k)
            k2 = rhs(x + 0.5 * h * k1, u_k)
            k3 = rhs(x + 0.5 * h * k2, u_k)
            k4 = rhs(x + h * k3, u_k)
            x = x + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
            finite = np.all(np.isfinite(x), axis=1)
            clean &= finite
            x[~finite] = x0[~finite]  # keeps the batch finite; the window is redone on its own
            if n_z:  # sign changes along the step or with the next sample's inputs
                clean &= np.all((np.asarray(model.event_indicators(x, u_k), dtype=float) > 0.0) == z0, axis=1)
                clean &= np.all((np.asarray(model.event_indicators(x, u[k + 1]), dtype=float) > 0.0) == z0, axis=1)
            out[:, j + 1] = x
    for w in np.flatnonzero(~clean):
        piece = slice(int(first[w]), int(first[w]) + n_steps + 1)
        out[w] = simulate(model, simulate_fn, time_s[piece], u[piece], np.asarray(x0[w]), correction)
    LOGGER.debug("%d of %d windows simulated side by side, %d on their own", int(clean.sum()), n_w,
                 int((~clean).sum()))
    return out


def open_loop_errors(model: Any, simulate_fn: Callable, time_s: np.ndarray, x_meas: np.ndarray, u: np.ndarray,
                     layout: MotorLayout, correction: Callable | None, window_s: float, smoothing_s: float,
                     windows_mask: np.ndarray | None = None) -> tuple[OpenLoopErrors, np.ndarray]:
    """Whole-maneuver and windowed open-loop errors of the (corrected) model.

    Args:
        model, simulate_fn: model instance and ``simulate_open_loop``.
        time_s: (T,) grid; x_meas: (T, n_x) measured states; u: (T, n_u) inputs (already shifted).
        correction: callable or None.
        window_s: length of the restarted windows (s).
        smoothing_s: smoothing of the measured start states (s).
        windows_mask: (T,) bool; windows whose start lies in it are used (default all).
    Returns:
        (errors, simulated states of the whole maneuver (T, n_x)).
    """
    dt_s = float(np.median(np.diff(time_s)))
    starts = measured_initial_states(x_meas, layout, dt_s, smoothing_s)
    whole = simulate(model, simulate_fn, time_s, u, starts[0], correction)
    angle_err = whole[:, layout.theta] - x_meas[:, layout.theta]
    speed_err = whole[:, layout.omega] - starts[:, layout.omega]
    n_win = max(int(round(window_s / dt_s)), 2)
    first = np.array([start for start in range(0, len(time_s) - n_win, n_win)
                      if windows_mask is None or windows_mask[start]], dtype=int)
    windows = simulate_windows(model, simulate_fn, time_s, u, starts[first], first, n_win, correction)
    angle_abs, speed_abs = [], []
    for w, start in enumerate(first):
        piece = slice(start, start + n_win + 1)
        states = windows[w]
        angle_abs.append(np.mean(np.abs(states[:, layout.theta] - x_meas[piece, layout.theta])))
        speed_abs.append(np.mean(np.abs(states[:, layout.omega] - starts[piece, layout.omega])))

    def finite_mean(values) -> float:
        values = np.asarray(values, dtype=float)
        return float(np.mean(values)) if values.size and np.all(np.isfinite(values)) else float("nan")

    errors = OpenLoopErrors(
        angle_mae_rad=finite_mean(np.abs(angle_err)), angle_mse_rad2=finite_mean(angle_err ** 2),
        speed_mae_rad_s=finite_mean(np.abs(speed_err)), speed_mse_rad2_s2=finite_mean(speed_err ** 2),
        window_angle_mae_rad=finite_mean(angle_abs), window_speed_mae_rad_s=finite_mean(speed_abs),
        n_windows=len(angle_abs),
    )
    return errors, whole
