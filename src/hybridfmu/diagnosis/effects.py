"""Candidate effects: each a term with physical meaning in ONE state equation, linear in its coefficients.

An effect in the equation of state i contributes ``A(x, u; s) @ c`` to dx_i/dt: regressors ``A``
(M, n_coef) computed along the data, coefficients ``c`` fitted by least squares, an optional
setting ``s`` of nonlinear parameters searched on a grid and then refined continuously (one or more
``continuous`` parameters, e.g. a Stribeck velocity and the smoothing of a friction sign, or a
threshold). The shape of an effect is thus fitted to the data, not assumed. Effect names carry the
variables they use (``viscous(v)``, ``periodic(angle)``, ``input_gain(F)``, ``parameter(m)``).

For "how far" an effect adds itself to the model in one of four ways (the corrected model of
:mod:`hybridfmu.diagnosis.corrected_model` collects them):

- ``row_function``: a plain-float function (x row, u row) -> term value (fast, called per RK stage);
- ``batch_function``: an array function using a helper model instance (x (N, n_x), u (N, n_u)) -> (N,);
- ``input_change``: the logged input is modified (time shift, first-order lag, a static nonlinearity
  such as a dead zone or a saturation, gain, offset) before the simulation;
- ``parameter_change``: a model parameter is set to a corrected value.

The library over roles lives in :mod:`hybridfmu.diagnosis.library`; case plugins add effects that
need machine knowledge (e.g. :mod:`hybridfmu.diagnosis.effects_motor`).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Callable

import numpy as np

from hybridfmu.diagnosis.derivatives import odd_window, savgol_smooth
from hybridfmu.fmu.effect_program import EffectTerm

#: Samples of the input derivative's Savitzky-Golay window when no window is configured.
DEFAULT_LAG_DERIVATIVE_SAMPLES = 5

#: Shifted inputs an :class:`EffectInputs` keeps (:meth:`EffectInputs.shifted_inputs`).
SHIFTED_INPUTS_KEPT = 16


def input_derivative(u: np.ndarray, dt_s: float, window_s: float | None = None) -> np.ndarray:
    """Rate of change of logged input samples over the interval each sample starts, per column.

    Row k is the difference quotient (v[k+1] - v[k]) / dt of the Savitzky-Golay smoothed samples v
    (quadratic, odd window): the rate over the interval [t_k, t_k+1] over which u[k] is held (the last row
    repeats the one before). For held inputs this is the discrete inverse of a first-order lag; a window
    of 3 samples does not smooth (a quadratic through 3 points is exact).

    Args:
        u: (N, n_u) or (N,) input samples on a uniform grid (input units).
        dt_s: sampling interval (s).
        window_s: smoothing window (s), rounded to an odd number of samples (at least 3); None: 5 samples
            (``diagnosis.effects.lag_derivative_window_s``).

    Returns:
        Same shape as ``u``, in input units per s (zeros for fewer than 2 samples; a record no longer than the
        window is not smoothed).
    """
    u = np.asarray(u, dtype=float)
    if dt_s <= 0:
        raise ValueError(f"input_derivative: the sampling interval must be positive, got {dt_s}")
    window = DEFAULT_LAG_DERIVATIVE_SAMPLES if window_s is None else odd_window(float(window_s), dt_s, minimum=3)
    out = np.zeros_like(u)
    if u.shape[0] < 2:
        return out
    smooth = savgol_smooth(u, window) if window > 3 else u
    out[:-1] = (smooth[1:] - smooth[:-1]) / dt_s
    out[-1] = out[-2]
    return out


def shift_samples(values: np.ndarray, offset_s: float, dt_s: float) -> np.ndarray:
    """Samples seen ``offset_s`` later: linear interpolation at the fractional index k + offset / dt, the end
    samples held beyond the ends. ``values`` (N, ...) -> (N, ...)."""
    values = np.asarray(values, dtype=float)
    if values.shape[0] == 0 or offset_s == 0.0:
        return values.copy()
    last = values.shape[0] - 1
    index = np.arange(values.shape[0]) + offset_s / dt_s
    floor = np.floor(index)
    lower = np.minimum(np.maximum(floor.astype(int), 0), last)  # np.clip's values, without its per-call checks
    upper = np.minimum(lower + 1, last)
    frac = (index - floor).reshape((-1,) + (1,) * (values.ndim - 1))
    return (1.0 - frac) * values[lower] + frac * values[upper]


def first_order_lag(u: np.ndarray, lag_s: float, dt_s: float) -> np.ndarray:
    """What a first-order lag (time constant ``lag_s``) makes of inputs held per sample, per interval.

    The lag's output z (T dz/dt = u - z, starting at rest at u[0]) is exact for held inputs; row k is
    its mean over the interval [t_k, t_k+1] (what a model holding one value per sample should see).

    Args:
        u: (N, n_u) or (N,) input samples (input units), held over each sampling interval.
        lag_s: time constant (s), > 0.
        dt_s: sampling interval (s), > 0.

    Returns:
        Same shape as ``u`` (input units).
    """
    from scipy.signal import lfilter

    u = np.asarray(u, dtype=float)
    if not lag_s > 0 or not dt_s > 0:
        raise ValueError(f"first_order_lag: time constant and sampling interval must be positive, got {lag_s}, {dt_s}")
    if u.shape[0] == 0:
        return u.copy()
    a = math.exp(-dt_s / lag_s)
    z, _ = lfilter([0.0, 1.0 - a], [1.0, -a], u, axis=0, zi=u[:1])
    return u + (z - u) * (lag_s / dt_s) * (1.0 - a)


class EffectInputs:
    """What the effects' regressors are computed from, along M sampling intervals of one maneuver.

    Args:
        x: (M, n_x) interval means of the states (unmeasured ones from the open-loop simulation).
        u: (M, n_u) inputs held over each interval.
        x_smooth: (M, n_x) low-noise states for nonlinear regressors (default ``x``).
        f: (M, n_x) the model's derivatives at (x, u).
        dfdx: (M, n_x, n_x), dfdu: (M, n_x, n_u) model Jacobians at (x, u).
        du_dt: (M, n_u) centred rates of the held inputs (input units per s).
        du_dt_smooth: (M, n_u) rate of the Savitzky-Golay smoothed input samples over each interval
            (:func:`input_derivative`; input units per s), for input lags; None if not provided.
        model: the model (parameter sensitivities by finite differences; plugins' input responses).
        parameter_step: relative step of the parameter finite differences.
        u_samples: (M + 1, n_u) the logged input samples (for inputs shifted in time), with ``dt_s``.
    """

    def __init__(self, x: np.ndarray, u: np.ndarray, *, x_smooth: np.ndarray | None = None,
                 f: np.ndarray | None = None, dfdx: np.ndarray | None = None, dfdu: np.ndarray | None = None,
                 du_dt: np.ndarray | None = None, du_dt_smooth: np.ndarray | None = None, model: Any = None,
                 parameter_step: float = 1e-5, u_samples: np.ndarray | None = None, dt_s: float = 0.0) -> None:
        self.x = np.asarray(x, dtype=float)
        self.u = np.asarray(u, dtype=float).reshape(self.x.shape[0], -1)
        self.x_smooth = self.x if x_smooth is None else np.asarray(x_smooth, dtype=float)
        self._f = f
        self.dfdx = dfdx
        self.dfdu = dfdu
        self.du_dt = du_dt if du_dt is not None else np.zeros_like(self.u)
        self.du_dt_smooth = None if du_dt_smooth is None else \
            np.asarray(du_dt_smooth, dtype=float).reshape(self.u.shape)
        self.model = model
        self.parameter_step = float(parameter_step)
        self._sensitivities: dict[str, np.ndarray | None] = {}
        self._responses: dict[str, ParameterResponse | None] = {}
        self.u_samples = u_samples
        self.dt_s = float(dt_s)
        self._shifted: OrderedDict[tuple, np.ndarray] = OrderedDict()

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @cached_property
    def f(self) -> np.ndarray:
        if self._f is not None:
            return np.asarray(self._f, dtype=float)
        return np.asarray(self.model.derivatives(self.x, self.u), dtype=float)

    def input_response(self, delta_u: np.ndarray) -> np.ndarray:
        """Change of the derivatives (M, n_x) for an input change ``delta_u`` (M, n_u), to first order."""
        if self.dfdu is not None:
            return np.einsum("mij,mj->mi", self.dfdu, delta_u)
        eps = 1e-3 / max(float(np.max(np.abs(delta_u))), 1e-12)
        return (np.asarray(self.model.derivatives(self.x, self.u + eps * delta_u)) - self.f) / eps

    def shifted_inputs(self, offset_s: float, columns: list[int] | None = None) -> np.ndarray:
        """Inputs seen ``offset_s`` later (M, n_u), or only the input ``columns`` (M, len(columns)): the held
        signal's mean over each shifted interval, i.e. linear interpolation of the samples at the fractional index
        k + offset / dt (ends held). The last few are kept (read-only): the members of a time offset acting on
        several equations ask for the same shift one after another."""
        if self.u_samples is None or self.dt_s <= 0:
            raise RuntimeError("shifted inputs need the logged input samples and the sampling interval")
        key = (float(offset_s), None if columns is None else tuple(columns))
        if key in self._shifted:
            self._shifted.move_to_end(key)
            return self._shifted[key]
        samples = self.u_samples if columns is None else self.u_samples[:, columns]
        shifted = shift_samples(samples, offset_s, self.dt_s)[:self.n]
        shifted.setflags(write=False)
        self._shifted[key] = shifted
        if len(self._shifted) > SHIFTED_INPUTS_KEPT:
            self._shifted.popitem(last=False)
        return shifted

    def response(self, parameter: str) -> ParameterResponse | None:
        """The model's response to finite errors of ``parameter`` along these rows (:func:`parameter_response`),
        or None when it has no sensitivity or the model rejects the changed values."""
        if parameter not in self._responses:
            sensitivity = self.sensitivity(parameter)
            self._responses[parameter] = None if sensitivity is None else \
                parameter_response(self.model, self.x, self.u, parameter, sensitivity)
        return self._responses[parameter]

    def sensitivity(self, parameter: str) -> np.ndarray | None:
        """p * df/dp (M, n_x) by central finite differences of the model's derivatives, or None when the
        parameter cannot be perturbed (e.g. an integer parameter, or a value the model rejects)."""
        if parameter not in self._sensitivities:
            self._sensitivities[parameter] = parameter_sensitivity(self.model, self.x, self.u, parameter,
                                                                   self.parameter_step)
        return self._sensitivities[parameter]


def parameter_sensitivity(model: Any, x: np.ndarray, u: np.ndarray, parameter: str,
                          relative_step: float = 1e-5) -> np.ndarray | None:
    """p * df/dp (M, n_x) at the rows (x (M, n_x), u (M, n_u)); the parameter is restored afterwards.

    A parameter at 0 is perturbed by an absolute step ``relative_step``, and the result is df/dp
    (reported as such by the parameter effect). Returns None if the model rejects the perturbed values.
    """
    if model is None or not hasattr(model, "set_parameters"):
        return None
    value = float(model.get_parameters([parameter])[parameter])
    step = abs(value) * relative_step if value != 0.0 else relative_step
    try:
        model.set_parameters({parameter: value + step})
        upper = np.asarray(model.derivatives(x, u), dtype=float)
        model.set_parameters({parameter: value - step})
        lower = np.asarray(model.derivatives(x, u), dtype=float)
    except (ValueError, RuntimeError):
        return None
    finally:
        try:
            model.set_parameters({parameter: value})
        except (ValueError, RuntimeError):
            pass
    derivative = (upper - lower) / (2.0 * step)
    return derivative * value if value != 0.0 else derivative


#: relative parameter errors r at which :func:`parameter_response` evaluates the model: 1 + r log-spaced from
#: x1/4 to x4 (and r = 0), the range over which a fitted first-order error is mapped to the model's own response
RESPONSE_FACTORS = np.unique(np.concatenate([np.geomspace(0.25, 4.0, 41), [1.0]]))
#: rows :func:`parameter_response` evaluates at most (evenly spread over the fitting maneuver's): the response is
#: an average over the operating points, which a few thousand of them describe
RESPONSE_ROWS = 4000


@dataclass(frozen=True)
class ParameterResponse:
    """How a model's derivatives respond to finite relative errors r of one parameter, projected on its
    first-order regressor s_i = p df_i/dp in each equation i (least squares along the rows):
    ``numerator[k, i] = <f_i(p (1 + r_k)) - f_i(p), s_i>``, ``denominator[i] = <s_i, s_i>``.

    Attributes:
        relative: (K,) the relative errors r_k (one of them 0).
        numerator: (K, n_x) and denominator: (n_x,) as above (equation units squared).
    """

    relative: np.ndarray
    numerator: np.ndarray
    denominator: np.ndarray

    def coefficients(self, weights: np.ndarray) -> np.ndarray:
        """(K,) the first-order coefficient c(r_k) that a fit of the equations with row weights ``weights`` (n_x,)
        (0: an equation not fitted) finds for the error r_k: c = sum_i w_i numerator_i / sum_i w_i denominator_i
        (r for a model linear in p; r / (1 + r) for a derivative proportional to 1 / p, such as an inertia's or an
        inductance's). NaN when the weighted equations have no sensitivity."""
        weights = np.asarray(weights, dtype=float)
        total = float(np.sum(weights * self.denominator))
        if not total > 0.0:
            return np.full(self.relative.shape, np.nan)
        return (self.numerator * weights).sum(axis=1) / total


def parameter_response(model: Any, x: np.ndarray, u: np.ndarray, parameter: str,
                       sensitivity: np.ndarray) -> ParameterResponse | None:
    """The model's response to finite errors of ``parameter`` (:class:`ParameterResponse`) at the rows (x, u) (at
    most :data:`RESPONSE_ROWS` of them, evenly spread), for every r of :data:`RESPONSE_FACTORS` - 1 the model
    accepts; the parameter is restored afterwards.

    Args:
        model: the model (``get_parameters``, ``set_parameters``, ``derivatives``).
        x: (M, n_x) states and u: (M, n_u) inputs of the rows.
        parameter: the parameter's name.
        sensitivity: (M, n_x) its first-order regressor p df/dp at the rows (:func:`parameter_sensitivity`).

    Returns:
        The response, or None when the parameter is zero (its regressor is df/dp, not a relative error) or the
        model rejects every changed value.
    """
    if model is None or not hasattr(model, "set_parameters"):
        return None
    value = float(model.get_parameters([parameter])[parameter])
    if value == 0.0:
        return None
    rows = np.flatnonzero(np.all(np.isfinite(sensitivity), axis=1) & np.all(np.isfinite(x), axis=1)
                          & np.all(np.isfinite(u), axis=1))
    rows = rows[::max(1, -(-rows.size // RESPONSE_ROWS))]  # evenly spread, at most RESPONSE_ROWS of them
    column = np.asarray(sensitivity, dtype=float)[rows]
    base = np.asarray(model.derivatives(x[rows], u[rows]), dtype=float)
    relative, numerator = [], []
    try:
        for factor in RESPONSE_FACTORS:
            try:
                model.set_parameters({parameter: value * float(factor)})
                changed = np.asarray(model.derivatives(x[rows], u[rows]), dtype=float)
            except (ValueError, RuntimeError):
                continue
            if not np.all(np.isfinite(changed)):
                continue
            relative.append(float(factor) - 1.0)
            numerator.append(np.sum((changed - base) * column, axis=0))
    finally:
        try:
            model.set_parameters({parameter: value})
        except (ValueError, RuntimeError):
            pass
    if not relative:
        return None
    return ParameterResponse(np.asarray(relative), np.asarray(numerator), np.sum(column ** 2, axis=0))


def make_input_change(input_index: int | list[int], *, gain: float = 0.0, offset: float = 0.0,
                      shift_s: float = 0.0, lag_s: float = 0.0,
                      transform: Callable[[np.ndarray, float], np.ndarray] | None = None,
                      form: tuple[str, float, float] | None = None) -> dict[str, Any]:
    """A change of logged input(s) for :meth:`Effect.input_change`.

    Args:
        input_index: the changed input column(s).
        gain: relative gain error g (-): the model should see (1 + g) times the input.
        offset: offset o (input units) added last.
        shift_s: time shift s (s): the model sees u(t + s).
        lag_s: first-order lag T (s): the model sees v + T dv/dt (T > 0: the logged channel lags the true
            input, like a sensor; T < 0: the plant sees a lagged version, like a slow actuator).
        transform: a change h of the input's samples, ``h(values (N,), dt_s) -> (N,)`` (a static
            nonlinearity such as a dead zone or a saturation, or a dynamic one such as a slow actuator), or None.
        form: what ``transform`` computes, as ``(kind, a, b)`` with one of the kinds of
            :data:`TRANSFORM_FORMS` (an exported model evaluates it in C); None: a transform without one.
    """
    if form is not None and form[0] not in TRANSFORM_FORMS:
        raise ValueError(f"make_input_change: form {form[0]!r}: expected one of {sorted(TRANSFORM_FORMS)}")
    return {"input": input_index, "gain": float(gain), "offset": float(offset), "shift_s": float(shift_s),
            "lag_s": float(lag_s), "transform": transform,
            "form": None if form is None else (str(form[0]), float(form[1]), float(form[2]))}


#: The transforms of an input change that have a stated form (``make_input_change(form=(kind, a, b))``), with
#: what they make of the samples v of one input (dt: the sampling interval):
#: ``shift_mix`` v + a (shift_samples(v, b, dt) - v); ``actuator_lag`` v + a (first_order_lag(v, b, dt) - v);
#: ``deadzone`` v - a clip(v, -b, b); ``saturation_above`` v + a (-max(v - b, 0));
#: ``saturation_below`` v + a max(b - v, 0).
TRANSFORM_FORMS = ("shift_mix", "actuator_lag", "deadzone", "saturation_above", "saturation_below")
#: The forms that leave a held (constant) input unchanged: a constant shifted in time, or lagged from its own value,
#: is itself. The others are static (each sample changed on its own), so a held value changes as any sample does.
HELD_UNCHANGED_FORMS = ("shift_mix", "actuator_lag")


def smooth_sign(value: np.ndarray, scale: float) -> np.ndarray:
    """tanh(value / scale): a sign continuous through zero (friction-like terms)."""
    return np.tanh(np.asarray(value, dtype=float) / scale) if scale > 0 else np.sign(value)


def linear_estimate(coef: np.ndarray, cov: np.ndarray, weights: list[float] | np.ndarray) -> tuple[float, float]:
    """Value and standard error of ``weights @ coef``."""
    weights = np.asarray(weights, dtype=float)
    value = float(weights @ coef)
    var = float(weights @ cov @ weights) if cov.size else 0.0
    return value, float(np.sqrt(max(var, 0.0)))


def param(name: str, value: float, se: float | None, unit: str, description: str) -> dict[str, Any]:
    """One physical parameter of a fitted effect (a row of the report)."""
    return {"name": name, "value": float(value), "se": None if se is None else float(se), "unit": unit,
            "description": description}


class Effect:
    """A candidate effect in the equation of one state (module docstring).

    Attributes:
        name: name with the variables it uses, e.g. ``coulomb(v)``.
        kind: the library entry it comes from (``coulomb``, ``parameter``, ...).
        equation: index of the state whose equation it acts on.
        description: one line for the report.
        formula: the term as a formula.
        continuous: the nonlinear setting refined continuously after the grid (a name), several of them
            (a tuple of names, refined coordinate-wise), or None.
        log_scale: refine the ``continuous`` settings on a logarithmic scale (a setting at 0 then means
            "absent" and is not refined).
        coefficient_unit: unit of the linear coefficients (for the report).
        model_wide: a change of an input or a model parameter, which acts on every equation the input or
            parameter enters with one value (selected jointly over the equations,
            :mod:`hybridfmu.diagnosis.joint`); False for a term local to its equation.
    """

    kind: str = ""
    continuous: str | tuple[str, ...] | None = None
    log_scale: bool = False
    model_wide: bool = False

    def __init__(self, name: str, equation: int, description: str, formula: str, coefficient_unit: str = ""):
        self.name = name
        self.equation = equation
        self.description = description
        self.formula = formula
        self.coefficient_unit = coefficient_unit

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, equation={self.equation})"

    def grid(self) -> list[dict[str, float]]:
        """Settings of the nonlinear parameters to try ([{}] for a purely linear effect)."""
        return [{}]

    def bounds(self) -> tuple[float, float] | None:
        """Search interval of ``continuous`` (a single continuous setting)."""
        return None

    def continuous_parameters(self) -> list[str]:
        """Names of the settings refined continuously after the grid ([] for none)."""
        if not self.continuous:
            return []
        return [self.continuous] if isinstance(self.continuous, str) else list(self.continuous)

    def refine_bounds(self, name: str) -> tuple[float, float] | None:
        """Search interval of the continuous setting ``name`` (default: ``bounds()``)."""
        return self.bounds()

    def coefficient_names(self, setting: dict[str, float]) -> list[str]:
        return ["coefficient"]

    def size_parameters(self, setting: dict[str, float]) -> list[str]:
        """Names of the physical parameters (:meth:`physical`) that say how large the effect is, each zero when the
        effect is absent (a friction level, an amplitude, a time offset, a relative parameter error); a name
        ending in ``_`` stands for every parameter it begins (``amplitude_``). Not its shape (a smoothing, a
        Stribeck velocity) nor its location (a threshold). The effect is confirmed by the data when one of them is
        identified (:func:`hybridfmu.diagnosis.identification.confirmed`). Default: the coefficient names."""
        return self.coefficient_names(setting)

    def coefficient_bounds(self, setting: dict[str, float]) -> list[tuple[float, float]]:
        """(min, max) of each linear coefficient where it is refitted by output error (default: unbounded)."""
        return [(-math.inf, math.inf)] * len(self.coefficient_names(setting))

    def regressors(self, inputs: EffectInputs, setting: dict[str, float]) -> np.ndarray:
        """(M, n_coef) regressors of the effect's equation."""
        raise NotImplementedError

    def physical(self, coef: np.ndarray, cov: np.ndarray, setting: dict[str, float],
                 setting_se: dict[str, float]) -> list[dict[str, Any]]:
        """Physical parameters with standard errors (default: the coefficients and the setting)."""
        out = []
        for j, name in enumerate(self.coefficient_names(setting)):
            weights = np.zeros(len(coef))
            weights[j] = 1.0
            out.append(param(name, *linear_estimate(coef, cov, weights), self.coefficient_unit,
                             f"coefficient of {self.formula}"))
        for key, value in setting.items():
            out.append(param(key, value, setting_se.get(key), "", "nonlinear setting (searched)"))
        return out

    def admissible(self, coef: np.ndarray, setting: dict[str, float]) -> bool:
        """Whether fitted coefficients describe the effect physically (e.g. a Stribeck peak adds to the Coulomb
        level); settings whose fit is not admissible are not chosen. Default: always."""
        return True

    def relative_error(self, coef: np.ndarray) -> float | None:
        """For a parameter error: the relative error implied by ``coef``; None for other effects."""
        return None

    def row_function(self, coef: np.ndarray, setting: dict[str, float]) -> Callable[[list, list], float] | None:
        """Plain-float version (x row, u row) -> term value, or None."""
        return None

    def batch_function(self, coef: np.ndarray, setting: dict[str, float],
                       helper: Any) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
        """Array version (x (N, n_x), u (N, n_u)) -> (N,) using a helper model instance, or None."""
        return None

    def stage_term(self, coef: np.ndarray, setting: dict[str, float]) -> EffectTerm | None:
        """The term of :meth:`row_function` or :meth:`batch_function` in the form an FMU's C step loop evaluates
        at every solver stage (same values), or None for an effect without one (it is then called from Python)."""
        return None

    def input_change(self, coef: np.ndarray, setting: dict[str, float]) -> dict[str, Any] | None:
        """How the logged input(s) change in the corrected simulation, or None for other effects:
        ``{"input": index or [indices], "gain": g, "offset": o, "shift_s": s, "lag_s": T, "transform": h}``
        (see :func:`make_input_change`); the input then becomes ``(1 + g) h(v + T dv/dt, dt) + o`` with
        ``v = u(t + s)`` and ``dv/dt`` by :func:`input_derivative`."""
        return None

    def parameter_change(self, coef: np.ndarray, setting: dict[str, float]) -> tuple[str, float] | None:
        """(parameter, corrected value) for a parameter error; None for other effects."""
        return None
