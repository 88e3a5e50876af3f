"""The library of candidate effects over roles, built from the case config for each examined equation.

For the equation of state i (x = a measured state, u = an input, p = a model parameter; every
coefficient c is in the equation's unit per regressor unit). The nonlinear settings are searched on
a grid and refined continuously (log scale for scales, with a standard error from the curvature of
the residual sum of squares), so the shape of an effect is fitted to the data, not assumed:

=============================  =========================================================  ==========================
name                           term in dx_i/dt                                            nonlinear setting
=============================  =========================================================  ==========================
``viscous(x)``                 -c x  (linear damping / stiffness)                         -
``quadratic(x)``               -c x|x|                                                     -
``polynomial(x)``              c_2 x^2 (+ c_3 x^3)                                         degree
``coulomb(x)``                 -(c + c_s exp(-(x/v_s)^2)) tanh(x/eps)                      eps and v_s (grid, refined)
``coulomb(x)*|u|``             -(c + c_a s) |u| s, s = tanh(x/eps)                         eps (refined), asymmetric
``periodic(x)``                sum_{m<=h} a_m sin(m k 2 pi x/P) + b_m cos(m k 2 pi x/P)   order k, harmonics h
``saturation_above(x)``        c max(0, x - x_c)                                          x_c (grid, refined)
``saturation_below(x)``        c max(0, x_c - x)                                          x_c (grid, refined)
``limit_above(x_i)``           -c 1[x_i >= x_c] max(f_i, 0)  (x_i cannot rise past x_c)   x_c (grid, refined)
``limit_below(x_i)``           c 1[x_i <= x_c] max(-f_i, 0)  (x_i cannot fall past x_c)   x_c (grid, refined)
``overflow(x_j->x_i)``         c_l [f_i(x_j limited) - f_i] + s 1[x_j >= x_c] max(f_j, 0)  x_c (grid, refined)
                               (x_j not measured: integrated with the limit; the share s
                               of its overflow reaches x_i)
``input_gain(u)``              g (df_i/du) u                                              -
``input_offset(u)``            o (df_i/du)                                                -
``time_offset(u)``             c [f_i(x, u(t + s)) - f_i(x, u)]  (offset c s)              s (grid, refined)
``time_offset(u1,u2,..)``      the same with all inputs shifted together                  s (grid, refined)
``input_lag(u)``               T (df_i/du) du/dt  (the model should see u + T du/dt)      first-order or actuator
                               or c (df_i/du) [L_tau(u) - u]  (plant sees u lagged by tau)  tau (grid, refined)
``input_deadzone(u)``          -c (df_i/du) clip(u, -d, d)  (dead band of half width d)    d (grid, refined)
``input_saturation_above(u)``  -c (df_i/du) max(u - u_c, 0)  (the model sees min(u, u_c))  u_c (grid, refined)
``input_saturation_below(u)``  c (df_i/du) max(u_c - u, 0)  (the model sees max(u, u_c))   u_c (grid, refined)
``parameter(p)``               c p (df_i/dp), read as the error r with the model's own    -
                               response c(r) to p (1 + r) (relative parameter error r)
=============================  =========================================================  ==========================

eps (the Coulomb smoothing) and the Stribeck velocity are searched jointly on grids relative to the
state's spread (``diagnosis.effects.coulomb_smoothing_relative``, ``stribeck_relative``; a single
smoothing value fixes it). Periodic terms exist for the states of ``diagnosis.periodic``
({state: period}); their grid holds every order k in 1..``periodic_max_order`` with 1..``periodic_harmonics``
harmonics (settings with different numbers of coefficients are compared by BIC, so a term of order
12 alone is order 12 with one harmonic); with ``periodic_max_order`` null (the default) the orders are the
strongest peaks of the equation error's spectrum over the position (:mod:`hybridfmu.diagnosis.periodic_orders`).
State saturation thresholds are searched over quantiles of
the state (``saturation_quantiles``); input dead zones over quantiles of |u| and input saturation
levels over upper/lower quantiles of u (``input_quantiles``, taken along the fitting maneuver the
library is built on). The input lag's du/dt is the rate of the Savitzky-Golay smoothed logged input
over each interval (``lag_derivative_window_s``); its exact slow-actuator form L_tau (a first-order lag of
the held input) searches tau over ``actuator_lag_samples`` sampling intervals. Input effects exist
where df_i/du is nonzero along the data, parameter effects where p df_i/dp is (candidates: ``diagnosis.parameters`` or every model parameter). Case
plugins (``diagnosis.plugins``: module names) add effects through their
``plugin_effects(problem, equation, options, inputs)`` function.
"""

from __future__ import annotations

import fnmatch
import importlib
import logging
import math
import re
from typing import Any, Callable

import numpy as np

from hybridfmu.config import ConfigError
from hybridfmu.diagnosis.effects import (Effect, EffectInputs, ParameterResponse, first_order_lag, linear_estimate,
                                         make_input_change, param, shift_samples, smooth_sign)
from hybridfmu.diagnosis.problem import Problem, positive_grid, quantile_grid
from hybridfmu.fmu.effect_program import EffectTerm
from hybridfmu.runge_kutta import RK4, numpy_axpy

LOGGER = logging.getLogger("hybridfmu.diagnosis")

WHERE = "config.diagnosis.effects"


def _per(a: str, b: str) -> str:
    if not b or b in ("1", "dimensionless"):
        return a
    return f"{a}/({b})" if " " in b or "/" in b else f"{a}/{b}"


def log_grid_bounds(values: list[float]) -> tuple[float, float] | None:
    """Refinement interval of a positive grid refined on a log scale: one grid ratio beyond each end.

    ``values``: the grid (positive, any order). None for fewer than two distinct values (a single value is fixed).
    """
    grid = sorted({float(v) for v in values if v > 0})
    if len(grid) < 2:
        return None
    return grid[0] ** 2 / grid[1], grid[-1] ** 2 / grid[-2]


def _linear_bounds(values: list[float], low: float, high: float) -> tuple[float, float] | None:
    """Refinement interval of a grid refined on a linear scale: one grid step beyond each end, within [low, high]."""
    grid = sorted({float(v) for v in values})
    if len(grid) < 2:
        return None
    return max(grid[0] - (grid[1] - grid[0]), low), min(grid[-1] + (grid[-1] - grid[-2]), high)


def state_levels(problem: Problem, state: str, quantiles: list[float]) -> list[float]:
    """Sorted distinct values of ``state`` at ``quantiles`` (in (0, 1)) along the fitting maneuvers ([] before the
    problem's data statistics are set)."""
    levels = problem.quantiles.get(state)
    if levels is None or not len(levels):
        return []
    return sorted({float(np.interp(float(q), np.linspace(0, 1, len(levels)), levels)) for q in quantiles})


# ----------------------------------------------------------------------------- state functions

class StateEffect(Effect):
    """An effect that is a function of one measured state ``variable`` (index)."""

    def __init__(self, problem: Problem, equation: int, variable: int, kind: str, description: str, formula: str,
                 coefficient_unit: str):
        self.variable = variable
        self.problem = problem
        self.kind = kind
        var = problem.state_names[variable]
        # the state is "x" in the formula; "x" inside a word (exp, max) stays
        formula = re.sub(r"(?<![A-Za-z])x(?![A-Za-z])", var, formula)
        super().__init__(f"{kind}({var})", equation, description, formula, coefficient_unit)


class Viscous(StateEffect):
    def __init__(self, problem, equation, variable):
        var = problem.state_names[variable]
        super().__init__(problem, equation, variable, "viscous", f"linear damping / stiffness in {var}", "-c * x",
                         _per(problem.rate_unit(equation), problem.unit(var)))

    def regressors(self, inputs, setting):
        return -inputs.x[:, [self.variable]]

    def row_function(self, coef, setting):
        c, j = float(coef[0]), self.variable
        return lambda x, u: -c * x[j]

    def stage_term(self, coef, setting):
        return EffectTerm("viscous", (self.equation,), (self.variable,), (float(coef[0]),))


class Quadratic(StateEffect):
    def __init__(self, problem, equation, variable):
        var = problem.state_names[variable]
        super().__init__(problem, equation, variable, "quadratic", f"quadratic damping in {var}", "-c * x|x|",
                         _per(problem.rate_unit(equation), f"({problem.unit(var) or '1'})^2"))

    def regressors(self, inputs, setting):
        v = inputs.x_smooth[:, self.variable]
        return (-v * np.abs(v))[:, None]

    def row_function(self, coef, setting):
        c, j = float(coef[0]), self.variable
        return lambda x, u: -c * x[j] * abs(x[j])

    def stage_term(self, coef, setting):
        return EffectTerm("quadratic", (self.equation,), (self.variable,), (float(coef[0]),))


class Polynomial(StateEffect):
    def __init__(self, problem, equation, variable, degrees):
        var = problem.state_names[variable]
        super().__init__(problem, equation, variable, "polynomial", f"polynomial (stiffness) terms of {var}",
                         "c_2 x^2 + c_3 x^3", problem.rate_unit(equation) + " per power of the state")
        self.degrees = [int(d) for d in degrees]

    def grid(self):
        return [{"degree": float(d)} for d in self.degrees]

    def coefficient_names(self, setting):
        return [f"c_{k}" for k in range(2, int(setting["degree"]) + 1)]

    def regressors(self, inputs, setting):
        v = inputs.x_smooth[:, self.variable]
        return np.stack([v ** k for k in range(2, int(setting["degree"]) + 1)], axis=1)

    def row_function(self, coef, setting):
        cs, j = [float(c) for c in coef], self.variable
        return lambda x, u: sum(c * x[j] ** (k + 2) for k, c in enumerate(cs))

    def stage_term(self, coef, setting):
        return EffectTerm("polynomial", (self.equation,), (self.variable,), tuple(float(c) for c in coef))


def smoothing_grid(problem: Problem, variable: int, options: dict[str, Any]) -> list[float]:
    """The tanh smoothings (state units) searched for friction signs of state ``variable``: the grid
    ``coulomb_smoothing_relative`` (a number or a list) times the state's spread."""
    spread = float(problem.spread[variable]) if len(problem.spread) else 0.0
    relative = positive_grid(options["coulomb_smoothing_relative"], f"{WHERE}.coulomb_smoothing_relative")
    return [r * (spread or 1.0) for r in relative]


class Coulomb(StateEffect):
    """Coulomb friction with a Stribeck peak; the sign's smoothing eps and the Stribeck velocity v_s are
    searched jointly (v_s = 0: no Stribeck term) and refined coordinate-wise on a log scale."""

    continuous = ("smoothing", "stribeck_velocity")
    log_scale = True

    def __init__(self, problem, equation, variable, options):
        var = problem.state_names[variable]
        super().__init__(problem, equation, variable, "coulomb",
                         f"Coulomb friction in {var} with a Stribeck peak near {var} = 0 (smoothing of the sign "
                         "and Stribeck velocity fitted)",
                         "-(c + c_s exp(-(x/v_s)^2)) tanh(x/eps)", problem.rate_unit(equation))
        spread = float(problem.spread[variable]) if len(problem.spread) else 0.0
        self.smoothings = smoothing_grid(problem, variable, options)
        self.velocities = [r * (spread or 1.0) for r in positive_grid(
            options["stribeck_relative"], f"{WHERE}.stribeck_relative", allow_empty=True)]
        self.state_unit = problem.unit(var)

    def grid(self):
        return [{"smoothing": eps, "stribeck_velocity": v} for eps in self.smoothings
                for v in [0.0] + self.velocities]

    def refine_bounds(self, name):
        return log_grid_bounds(self.smoothings if name == "smoothing" else self.velocities)

    def bounds(self):
        return self.refine_bounds("stribeck_velocity")

    def coefficient_names(self, setting):
        return ["coulomb_level", "stribeck_excess"] if setting.get("stribeck_velocity", 0.0) > 0 else ["coulomb_level"]

    def size_parameters(self, setting):
        return ["coulomb_level", "breakaway_level"]

    def regressors(self, inputs, setting):
        v = inputs.x_smooth[:, self.variable]
        sign = smooth_sign(v, setting["smoothing"])
        columns = [-sign]
        v_s = setting.get("stribeck_velocity", 0.0)
        if v_s > 0:
            columns.append(-sign * np.exp(-(v / v_s) ** 2))
        return np.stack(columns, axis=1)

    def admissible(self, coef, setting):
        """A Stribeck peak adds to the Coulomb level (breakaway above the sliding friction): c c_s >= 0. A
        negative peak would be friction rising with speed, which a damping term describes."""
        return len(coef) < 2 or float(coef[0]) * float(coef[1]) >= 0.0

    def row_function(self, coef, setting):
        j, eps = self.variable, float(setting["smoothing"])
        c = float(coef[0])
        c_s = float(coef[1]) if len(coef) > 1 else 0.0
        v_s = setting.get("stribeck_velocity", 0.0)
        inv = 1.0 / v_s if v_s > 0 else 0.0
        return lambda x, u: -(c + c_s * math.exp(-(x[j] * inv) ** 2)) * math.tanh(x[j] / eps)

    def stage_term(self, coef, setting):
        v_s = setting.get("stribeck_velocity", 0.0)
        return EffectTerm("coulomb", (self.equation,), (self.variable,),
                          (float(coef[0]), float(coef[1]) if len(coef) > 1 else 0.0, 1.0 / v_s if v_s > 0 else 0.0,
                           float(setting["smoothing"])))

    def physical(self, coef, cov, setting, setting_se):
        unit = self.coefficient_unit
        out = [param("coulomb_level", *linear_estimate(coef, cov, [1.0] + [0.0] * (len(coef) - 1)), unit,
                     "Coulomb friction level (in the equation's unit)")]
        if len(coef) > 1:
            out.append(param("breakaway_level", *linear_estimate(coef, cov, [1.0, 1.0]), unit,
                             "friction level at zero (Coulomb + Stribeck peak)"))
            out.append(param("stribeck_velocity", setting["stribeck_velocity"], setting_se.get("stribeck_velocity"),
                             self.state_unit, "Stribeck velocity (searched on a grid, refined)"))
        fixed = len(self.smoothings) < 2
        out.append(param("smoothing", setting["smoothing"], setting_se.get("smoothing"), self.state_unit,
                         "tanh smoothing of the sign" + (" (fixed)" if fixed else " (searched on a grid, refined)")))
        return out


class ScaledCoulomb(Effect):
    """Coulomb friction of a state proportional to an input's magnitude (e.g. load-dependent friction); the
    sign's smoothing is searched on the Coulomb smoothing grid and refined on a log scale."""

    kind = "scaled_coulomb"
    continuous = "smoothing"
    log_scale = True

    def __init__(self, problem, equation, variable, input_index, options):
        var, inp = problem.state_names[variable], problem.input_names[input_index]
        super().__init__(f"coulomb({var})*|{inp}|", equation,
                         f"friction in {var} proportional to |{inp}| (optionally different for {var} > 0 and < 0)",
                         f"-(c + c_a s) |{inp}| s, s = tanh({var}/eps)",
                         _per(problem.rate_unit(equation), problem.unit(inp)))
        self.variable, self.input = variable, input_index
        self.smoothings = smoothing_grid(problem, variable, options)
        self.state_unit = problem.unit(var)

    def grid(self):
        return [{"asymmetric": a, "smoothing": eps} for a in (0.0, 1.0) for eps in self.smoothings]

    def bounds(self):
        return log_grid_bounds(self.smoothings)

    def coefficient_names(self, setting):
        return ["coefficient", "asymmetry"] if setting.get("asymmetric") else ["coefficient"]

    def size_parameters(self, setting):
        return ["coefficient", "coefficient_positive", "coefficient_negative"]

    def regressors(self, inputs, setting):
        s = smooth_sign(inputs.x_smooth[:, self.variable], setting["smoothing"])
        load = np.abs(inputs.u[:, self.input])
        columns = [-load * s] + ([-load * s * s] if setting.get("asymmetric") else [])
        return np.stack(columns, axis=1)

    def row_function(self, coef, setting):
        j, k, eps = self.variable, self.input, float(setting["smoothing"])
        c = float(coef[0])
        c_a = float(coef[1]) if len(coef) > 1 else 0.0

        def term(x, u):
            s = math.tanh(x[j] / eps)
            return -(c + c_a * s) * abs(u[k]) * s
        return term

    def stage_term(self, coef, setting):
        return EffectTerm("scaled_coulomb", (self.equation,), (self.variable, self.input),
                          (float(coef[0]), float(coef[1]) if len(coef) > 1 else 0.0, float(setting["smoothing"])))

    def physical(self, coef, cov, setting, setting_se):
        unit = self.coefficient_unit
        fixed = len(self.smoothings) < 2
        smoothing = param("smoothing", setting["smoothing"], setting_se.get("smoothing"), self.state_unit,
                          "tanh smoothing of the sign" + (" (fixed)" if fixed else " (searched on a grid, refined)"))
        if len(coef) == 1:
            return [param("coefficient", *linear_estimate(coef, cov, [1.0]), unit, "friction per unit of |input|"),
                    smoothing]
        return [param("coefficient_positive", *linear_estimate(coef, cov, [1.0, 1.0]), unit,
                      "friction per unit of |input| while the state is positive"),
                param("coefficient_negative", *linear_estimate(coef, cov, [1.0, -1.0]), unit,
                      "friction per unit of |input| while the state is negative"), smoothing]


class Periodic(StateEffect):
    """A term periodic in a state: order k (periods per configured period P) with h harmonics (orders
    k, 2k, .., hk), each a sine and a cosine; (k, h) searched over ``orders`` x 1..harmonics.

    ``orders`` is 1..``periodic_max_order`` when that is configured; with it null the orders are found in the
    data before the selection (:func:`hybridfmu.diagnosis.periodic_orders.narrow_periodic_orders`), and until
    then ``orders`` is None and the effect has no grid."""

    def __init__(self, problem, equation, variable, period, options):
        var = problem.state_names[variable]
        super().__init__(problem, equation, variable, "periodic",
                         f"term periodic in {var} (period {period:g} {problem.unit(var)} / order, with harmonics)",
                         "sum_m a_m sin(m k 2 pi x / P) + b_m cos(m k 2 pi x / P), m = 1..h",
                         problem.rate_unit(equation))
        self.period = float(period)
        max_order = options.get("periodic_max_order")
        self.orders: list[int] | None = list(range(1, int(max_order) + 1)) if max_order is not None else None
        self.harmonics = int(options["periodic_harmonics"])

    def grid(self):
        if self.orders is None:
            raise RuntimeError(f"{self.name}: its orders are searched in the data (periodic_max_order null) and "
                               "have not been (hybridfmu.diagnosis.periodic_orders.narrow_periodic_orders)")
        return [{"order": float(k), "harmonics": float(h)} for k in self.orders for h in range(1, self.harmonics + 1)]

    def _count(self, setting) -> int:
        return int(setting.get("harmonics", self.harmonics))

    def coefficient_names(self, setting):
        k = int(setting["order"])
        return [f"{f}_{m * k}" for m in range(1, self._count(setting) + 1) for f in ("sin", "cos")]

    def size_parameters(self, setting):
        return ["amplitude_"]

    def _phases(self, values: np.ndarray, setting) -> list[np.ndarray]:
        k = int(setting["order"])
        return [2.0 * math.pi * m * k * values / self.period for m in range(1, self._count(setting) + 1)]

    def regressors(self, inputs, setting):
        columns = []
        for phase in self._phases(inputs.x[:, self.variable], setting):
            columns += [np.sin(phase), np.cos(phase)]
        return np.stack(columns, axis=1)

    def row_function(self, coef, setting):
        j, k, scale = self.variable, int(setting["order"]), 2.0 * math.pi / self.period
        pairs = [(m * k * scale, float(coef[2 * (m - 1)]), float(coef[2 * (m - 1) + 1]))
                 for m in range(1, self._count(setting) + 1)]
        return lambda x, u: sum(a * math.sin(w * x[j]) + b * math.cos(w * x[j]) for w, a, b in pairs)

    def stage_term(self, coef, setting):
        k, scale = int(setting["order"]), 2.0 * math.pi / self.period
        reals = []
        for m in range(1, self._count(setting) + 1):
            reals += [m * k * scale, float(coef[2 * (m - 1)]), float(coef[2 * (m - 1) + 1])]
        return EffectTerm("periodic", (self.equation,), (self.variable,), tuple(reals))

    def physical(self, coef, cov, setting, setting_se):
        k, h = int(setting["order"]), self._count(setting)
        unit = self.problem.unit(self.problem.state_names[self.variable])
        out = [param("order", k, None, "-", f"periods per {self.period:g} {unit}"),
               param("harmonics", h, None, "-",
                     f"harmonics fitted (orders {', '.join(str(m * k) for m in range(1, h + 1))})")]
        for m in range(1, h + 1):
            a, b = float(coef[2 * (m - 1)]), float(coef[2 * (m - 1) + 1])
            amplitude = math.hypot(a, b)
            block = cov[2 * (m - 1):2 * m, 2 * (m - 1):2 * m] if cov.size else np.zeros((2, 2))
            grad = np.array([a, b]) / amplitude if amplitude > 0 else np.zeros(2)
            se = float(np.sqrt(max(grad @ block @ grad, 0.0)))
            out.append(param(f"amplitude_{m * k}", amplitude, se, self.coefficient_unit,
                             f"amplitude of the harmonic of order {m * k}"))
            out.append(param(f"phase_{m * k}", math.atan2(b, a), None, "rad", "phase (sin reference)"))
        return out


class Saturation(StateEffect):
    continuous = "threshold"

    def __init__(self, problem, equation, variable, side, options):
        var = problem.state_names[variable]
        formula = "c max(0, x - x_c)" if side == "above" else "c max(0, x_c - x)"
        super().__init__(problem, equation, variable, f"saturation_{side}",
                         f"term that sets in when {var} is {side} a threshold (saturation, dead zone)", formula,
                         _per(problem.rate_unit(equation), problem.unit(var)))
        self.side = side
        self.thresholds = state_levels(problem, var, options["saturation_quantiles"])
        self.state_unit = problem.unit(var)

    def size_parameters(self, setting):
        return ["slope"]

    def grid(self):
        return [{"threshold": t} for t in self.thresholds]

    def bounds(self):
        return (self.thresholds[0], self.thresholds[-1]) if self.thresholds else None

    def regressors(self, inputs, setting):
        v = inputs.x_smooth[:, self.variable]
        c = setting["threshold"]
        return (np.maximum(v - c, 0.0) if self.side == "above" else np.maximum(c - v, 0.0))[:, None]

    def row_function(self, coef, setting):
        c0, j, t = float(coef[0]), self.variable, setting["threshold"]
        if self.side == "above":
            return lambda x, u: c0 * max(x[j] - t, 0.0)
        return lambda x, u: c0 * max(t - x[j], 0.0)

    def stage_term(self, coef, setting):
        return EffectTerm(f"saturation_{self.side}", (self.equation,), (self.variable,),
                          (float(coef[0]), float(setting["threshold"])))

    def physical(self, coef, cov, setting, setting_se):
        return [param("slope", *linear_estimate(coef, cov, [1.0]), self.coefficient_unit, "slope beyond the threshold"),
                param("threshold", setting["threshold"], setting_se.get("threshold"), self.state_unit,
                      f"threshold ({self.side})")]


class Limit(StateEffect):
    """A level the state cannot pass (an overflow, an end stop, a full tank): at or beyond the level the model's
    derivative towards it is cancelled, ``-c 1[x >= x_c] max(f_i, 0)`` above (``c 1[x <= x_c] max(-f_i, 0)``
    below), c = 1 for a hard limit; x_c searched over the quantiles ``limit_quantiles`` of the state (their
    complements below) and refined. Only in
    the state's own equation."""

    continuous = "level"

    def __init__(self, problem, equation, side, options):
        var = problem.state_names[equation]
        formula = "-c 1[x >= x_c] max(f, 0)" if side == "above" else "c 1[x <= x_c] max(-f, 0)"
        super().__init__(problem, equation, equation, f"limit_{side}",
                         f"{var} cannot pass a level ({'upper' if side == 'above' else 'lower'} limit: an overflow, "
                         "an end stop)", formula, "-")
        self.side = side
        qs = [float(q) for q in options["limit_quantiles"]]
        self.levels = state_levels(problem, var, qs if side == "above" else [1.0 - q for q in qs])
        self.state_unit = problem.unit(var)

    def grid(self):
        return [{"level": v} for v in self.levels]

    def bounds(self):
        return (self.levels[0], self.levels[-1]) if self.levels else None

    def coefficient_names(self, setting):
        return ["stop_fraction"]

    def coefficient_bounds(self, setting):
        return [(0.0, 1.0)]

    def _term(self, x_i: np.ndarray, f_i: np.ndarray, level: float) -> np.ndarray:
        if self.side == "above":
            return -np.where(x_i >= level, np.maximum(f_i, 0.0), 0.0)
        return np.where(x_i <= level, np.maximum(-f_i, 0.0), 0.0)

    def regressors(self, inputs, setting):
        return self._term(inputs.x_smooth[:, self.variable], inputs.f[:, self.equation], setting["level"])[:, None]

    def batch_function(self, coef, setting, helper):
        if helper is None:
            return None
        c, level, i = float(coef[0]), float(setting["level"]), self.equation

        def term(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            f = np.asarray(helper.derivatives(np.asarray(x, dtype=float), np.asarray(u, dtype=float)))
            return c * self._term(np.asarray(x, dtype=float)[:, i], f[:, i], level)

        return term

    def stage_term(self, coef, setting):
        return EffectTerm(f"limit_{self.side}", (self.equation,), (self.equation,),
                          (float(coef[0]), float(setting["level"])))

    def physical(self, coef, cov, setting, setting_se):
        return [param("stop_fraction", *linear_estimate(coef, cov, [1.0]), "-",
                      "share of the model's derivative towards the level that is cancelled there (1: a hard limit)"),
                param("level", setting["level"], setting_se.get("level"), self.state_unit, f"limit ({self.side})")]


class Overflow(Effect):
    """A state that no measurement shows spills over at a level, and a share of what spills reaches the examined
    equation (an upper tank overflowing into a lower one, a pressure-relief valve venting into a second volume).

    x_j (unmeasured) cannot rise past x_c: its own rate loses ``1[x_j >= x_c] max(f_j, 0)`` (a hard limit), and
    the examined equation i sees the limited x_j and gains the share ``s`` of what spills::

        c_l [f_i(x with the limited x_j) - f_i(x)] + s 1[x_j >= x_c] max(f_j, 0)      (0 <= s <= 1)

    The limited x_j is integrated along the maneuver (RK4 per sampling interval, the other states and the
    inputs held as logged) from the unmeasured state's start; c_l (1 in theory: the model's own coupling) is
    fitted and reported as a check, the corrected model uses the limited state itself. x_c is searched over the
    ``overflow_quantiles`` of x_j along the fitting maneuvers and refined: x_j there is the simulation of the
    model without the overflow, which rises past the real level, so the grid reaches far below its top.
    """

    kind = "overflow"
    continuous = "level"

    def __init__(self, problem, equation, variable, options):
        source, target = problem.state_names[variable], problem.state_names[equation]
        super().__init__(f"overflow({source}->{target})", equation,
                         f"{source} (not measured) overflows at a level; a share of the overflow reaches {target}",
                         f"c_l [f_{target}({source} limited) - f_{target}] + s 1[{source} >= x_c] max(f_{source}, 0)",
                         "-")
        self.variable = variable
        self.levels = state_levels(problem, source, options["overflow_quantiles"])
        self.state_unit = problem.unit(source)
        self.source = source

    def grid(self):
        return [{"level": v} for v in self.levels]

    def bounds(self):
        return (self.levels[0], self.levels[-1]) if self.levels else None

    def coefficient_names(self, setting):
        return ["level_coupling", "share"]

    def coefficient_bounds(self, setting):
        return [(1.0, 1.0), (0.0, 1.0)]  # the corrected model couples through the limited state itself

    @staticmethod
    def spill(x_j: np.ndarray, f_j: np.ndarray, level: float) -> np.ndarray:
        """What overflows (state units per s), (N,): the rate of x_j towards and beyond its level."""
        return np.where(x_j >= level, np.maximum(f_j, 0.0), 0.0)

    def limited_states(self, inputs: EffectInputs, level: float) -> np.ndarray:
        """(M, n_x) the interval states with x_j integrated under the limit (RK4 per interval of ``inputs.dt_s``,
        the other states and the inputs held at their interval values; x_j starts at its first interval value)."""
        x = np.array(inputs.x, dtype=float)
        j, dt_s, model = self.variable, inputs.dt_s, inputs.model
        if model is None or dt_s <= 0:
            raise RuntimeError(f"{self.name}: the effect inputs carry no model or sampling interval")

        def rate(row: np.ndarray, u_row: np.ndarray) -> float:
            f_j = float(np.asarray(model.derivatives(row[None, :], u_row[None, :]))[0, j])
            return f_j - (max(f_j, 0.0) if row[j] >= level else 0.0)

        plan = RK4.plan(dt_s)
        value = float(x[0, j])
        for k in range(len(x)):
            row, u_row = x[k].copy(), inputs.u[k]
            x[k, j] = value

            def rate_at(x_j: float, _stage: int, row=row, u_row=u_row) -> float:
                row[j] = x_j
                return rate(row, u_row)

            value = plan.step(value, rate_at, numpy_axpy)
        return x

    def regressors(self, inputs, setting):
        level = float(setting["level"])
        limited = self.limited_states(inputs, level)
        f_limited = np.asarray(inputs.model.derivatives(limited, inputs.u), dtype=float)
        coupling = f_limited[:, self.equation] - inputs.f[:, self.equation]
        return np.stack([coupling, self.spill(limited[:, self.variable], f_limited[:, self.variable], level)], axis=1)

    def admissible(self, coef, setting):
        return 0.0 <= float(coef[1]) <= 1.0 and float(coef[0]) > 0.0

    def batch_function(self, coef, setting, helper):
        if helper is None:
            return None
        share, level, j = float(coef[1]), float(setting["level"]), self.variable

        def term(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            x = np.asarray(x, dtype=float)
            f = np.asarray(helper.derivatives(x, np.asarray(u, dtype=float)))
            return share * self.spill(x[:, j], f[:, j], level)

        return term

    def stage_term(self, coef, setting):
        return EffectTerm("spill", (self.equation,), (self.variable,), (float(coef[1]), float(setting["level"])))

    def source_stage_term(self, setting) -> EffectTerm:
        """:meth:`source_batch_function` as a :meth:`stage_term`."""
        return EffectTerm("spill", (self.variable,), (self.variable,), (-1.0, float(setting["level"])))

    def source_batch_function(self, setting, helper) -> tuple[int, Callable] | None:
        """The hard limit in the unmeasured state's own equation: (its index, (x, u) -> (N,) rate change)."""
        if helper is None:
            return None
        level, j = float(setting["level"]), self.variable

        def limit(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            x = np.asarray(x, dtype=float)
            f = np.asarray(helper.derivatives(x, np.asarray(u, dtype=float)))
            return -self.spill(x[:, j], f[:, j], level)

        return j, limit

    def physical(self, coef, cov, setting, setting_se):
        return [param("share", *linear_estimate(coef, cov, [0.0, 1.0]), "-",
                      "share of the overflow that reaches the examined equation's state"),
                param("level_coupling", *linear_estimate(coef, cov, [1.0, 0.0]), "-",
                      "scale of the model's coupling to the limited state (1 expected; a check)"),
                param("level", setting["level"], setting_se.get("level"), self.state_unit,
                      f"overflow level of {self.source}")]


# ----------------------------------------------------------------------------- inputs

class InputEffect(Effect):
    model_wide = True

    def __init__(self, problem, equation, input_index, kind, description, formula, unit):
        self.input = input_index
        self.kind = kind
        super().__init__(f"{kind}({problem.input_names[input_index]})", equation, description, formula, unit)

    def _column(self, inputs: EffectInputs) -> np.ndarray:
        if inputs.dfdu is None:
            raise RuntimeError(f"{self.name}: the input Jacobian along the data is missing")
        return inputs.dfdu[:, self.equation, self.input]


class InputGain(InputEffect):
    def __init__(self, problem, equation, input_index):
        name = problem.input_names[input_index]
        super().__init__(problem, equation, input_index, "input_gain", f"gain error of input {name}",
                         f"g * (df/d{name}) * {name}; the model should see (1 + g) {name}", "-")

    def coefficient_names(self, setting):
        return ["relative_gain_error"]

    def regressors(self, inputs, setting):
        return (self._column(inputs) * inputs.u[:, self.input])[:, None]

    def input_change(self, coef, setting):
        return make_input_change(self.input, gain=float(coef[0]))


class InputOffset(InputEffect):
    def __init__(self, problem, equation, input_index):
        name = problem.input_names[input_index]
        super().__init__(problem, equation, input_index, "input_offset", f"constant offset of input {name}",
                         f"o * (df/d{name}); the model should see {name} + o", problem.unit(name))

    def coefficient_names(self, setting):
        return ["offset"]

    def regressors(self, inputs, setting):
        return self._column(inputs)[:, None]

    def input_change(self, coef, setting):
        return make_input_change(self.input, offset=float(coef[0]))


class TimeOffset(InputEffect):
    """Inputs offset in time: the response of the equation to u(t + s) - u(t), s searched on a grid and
    refined, times a scale c (c = 1 at the true offset; for small s the term is linear in c s)."""

    continuous = "shift_s"

    def __init__(self, problem, equation, input_index, max_offset_s, columns=None, name=None):
        label = problem.input_names[input_index] if columns is None else ",".join(problem.input_names)
        super().__init__(problem, equation, input_index, "time_offset",
                         f"input(s) {label} offset in time against the states",
                         "c * [f(x, u(t + s)) - f(x, u(t))]; the model should see u + c [u(t + s) - u] "
                         "(about u(t + c s))", "-")
        if name:
            self.name = name
        self.columns = [input_index] if columns is None else list(columns)
        self.max_offset_s = float(max_offset_s)

    def grid(self):
        steps = [self.max_offset_s * k / 6.0 for k in range(1, 7)]
        return [{"shift_s": v} for v in sorted([-s for s in steps] + steps)]

    def bounds(self):
        return (-self.max_offset_s, self.max_offset_s)

    def coefficient_names(self, setting):
        return ["scale"]

    def size_parameters(self, setting):
        return ["offset_s"]

    def regressors(self, inputs, setting):
        delta = np.zeros_like(inputs.u)
        delta[:, self.columns] = inputs.shifted_inputs(setting["shift_s"], self.columns) - inputs.u[:, self.columns]
        return np.einsum("mj,mj->m", inputs.dfdu[:, self.equation, :], delta)[:, None]

    def physical(self, coef, cov, setting, setting_se):
        shift = float(setting["shift_s"])
        c, se = linear_estimate(coef, cov, [1.0])
        return [param("offset_s", c * shift, abs(shift) * se, "s",
                      "time by which the inputs lead: the model should see u(t + offset)"),
                param("scale", c, se, "-", f"scale of the shifted response (1 at the true offset; searched shift "
                                           f"{shift:.4g} s)")]

    def input_change(self, coef, setting):
        """The fitted form itself: the model sees u + c [u(t + s) - u] (= u(t + s) at c = 1; for c far from 1 the
        scaled difference is what the data asked for, not a shift by c s)."""
        c, shift = float(coef[0]), float(setting["shift_s"])
        return make_input_change(self.columns if len(self.columns) > 1 else self.columns[0],
                                 transform=lambda v, dt_s: v + c * (shift_samples(v, shift, dt_s) - v),
                                 form=("shift_mix", c, shift))


def time_offset_all(problem, equation, max_offset_s):
    """``time_offset(u1,u2,...)``: all inputs offset together."""
    return TimeOffset(problem, equation, 0, max_offset_s, columns=list(range(problem.n_u)),
                      name=f"time_offset({','.join(problem.input_names)})")


class InputLag(InputEffect):
    """A first-order lag between the logged input and what the model should see.

    Setting ``actuator_lag_s`` = 0 (the first-order form, linear in T): the model should see u + T du/dt,
    regressor (df_i/du) du/dt with du/dt the rate of the smoothed logged samples
    (:attr:`EffectInputs.du_dt_smooth`; the corrected model applies the same filter). T > 0: the
    logged channel lags the true input (a sensor with a first-order lag; exact for held inputs);
    T < 0: the plant sees a lagged version (a slow actuator; to first order in T).
    Setting ``actuator_lag_s`` = tau > 0 (the exact slow-actuator form): the plant sees the logged input
    through a first-order lag of time constant tau, regressor (df_i/du) [L_tau(u) - u] with scale c (1 at
    the truth; :func:`hybridfmu.diagnosis.effects.first_order_lag`); tau searched on ``lags_s`` and refined
    on a log scale. Both forms have one coefficient; the grid compares them by BIC.

    Args (besides the problem, equation and input index): ``lags_s`` the grid of tau (s); empty: the
    first-order form only.
    """

    continuous = "actuator_lag_s"
    log_scale = True

    def __init__(self, problem, equation, input_index, lags_s):
        name = problem.input_names[input_index]
        super().__init__(problem, equation, input_index, "input_lag",
                         f"first-order lag between the logged {name} and what the model should see "
                         "(a sensor lag if positive, a slow actuator if negative)",
                         f"T * (df/d{name}) * d{name}/dt; the model should see {name} + T d{name}/dt (for T < 0 "
                         f"also exactly: {name} through a lag of time constant -T)", "s")
        self.lags_s = sorted(float(t) for t in lags_s if t > 0)

    def grid(self):
        return [{"actuator_lag_s": 0.0}] + [{"actuator_lag_s": t} for t in self.lags_s]

    def bounds(self):
        return log_grid_bounds(self.lags_s)

    def coefficient_names(self, setting):
        return ["scale"] if setting.get("actuator_lag_s", 0.0) > 0 else ["lag_s"]

    def regressors(self, inputs, setting):
        tau = float(setting.get("actuator_lag_s", 0.0))
        if tau > 0:
            if inputs.u_samples is None or inputs.dt_s <= 0:
                raise RuntimeError(f"{self.name}: the logged input samples and the sampling interval are missing")
            lagged = first_order_lag(np.asarray(inputs.u_samples, dtype=float)[:, self.input], tau, inputs.dt_s)
            return (self._column(inputs) * (lagged[:inputs.n] - inputs.u[:, self.input]))[:, None]
        if inputs.du_dt_smooth is None:
            raise RuntimeError(f"{self.name}: the smoothed input derivative along the data is missing")
        return (self._column(inputs) * inputs.du_dt_smooth[:, self.input])[:, None]

    def physical(self, coef, cov, setting, setting_se):
        tau = float(setting.get("actuator_lag_s", 0.0))
        if tau > 0:
            se = setting_se.get("actuator_lag_s")
            return [param("lag_s", -tau, se, "s", "first-order lag T < 0: the plant sees the input through a lag "
                                                  "of time constant -T (a slow actuator; searched, refined)"),
                    param("scale", *linear_estimate(coef, cov, [1.0]), "-",
                          "scale of the lag's effect (1 at the true time constant)")]
        return [param("lag_s", *linear_estimate(coef, cov, [1.0]), "s",
                      "first-order lag T: the model should see u + T du/dt (T > 0: the logged channel lags the "
                      "true input; T < 0: the plant sees a lagged input)")]

    def input_change(self, coef, setting):
        tau = float(setting.get("actuator_lag_s", 0.0))
        if tau > 0:
            c = float(coef[0])
            return make_input_change(self.input, transform=lambda v, dt_s: v + c * (first_order_lag(v, tau, dt_s) - v),
                                     form=("actuator_lag", c, tau))
        return make_input_change(self.input, lag_s=float(coef[0]))


def _input_levels(values: np.ndarray, quantiles: list[float]) -> list[float]:
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if not values.size or float(np.ptp(values)) == 0.0:
        return []
    return sorted({float(np.quantile(values, q)) for q in quantiles})


class InputDeadzone(InputEffect):
    """A dead band of half width d around zero: the model should see u - clip(u, -d, d).

    Term: -c (df_i/du) clip(u, -d, d) with c = 1 at the truth; d searched over quantiles of |u| and
    refined on a log scale.

    Args (besides the problem, equation and input index): ``values`` (M,) the input along a fitting
    maneuver (input units), ``quantiles`` the quantiles of |u| giving the grid of d.
    """

    continuous = "half_width"
    log_scale = True

    def __init__(self, problem, equation, input_index, values, quantiles):
        name = problem.input_names[input_index]
        super().__init__(problem, equation, input_index, "input_deadzone",
                         f"dead zone of input {name} around zero",
                         f"-c * (df/d{name}) * clip({name}, -d, d); the model should see "
                         f"{name} - c clip({name}, -d, d)", "-")
        self.input_unit = problem.unit(name)
        self.half_widths = [d for d in _input_levels(np.abs(values), quantiles) if d > 0]

    def grid(self):
        return [{"half_width": d} for d in self.half_widths]

    def bounds(self):
        return log_grid_bounds(self.half_widths)

    def coefficient_names(self, setting):
        return ["scale"]

    def size_parameters(self, setting):
        return ["half_width", "scale"]

    def regressors(self, inputs, setting):
        d = float(setting["half_width"])
        return (-self._column(inputs) * np.clip(inputs.u[:, self.input], -d, d))[:, None]

    def physical(self, coef, cov, setting, setting_se):
        return [param("half_width", setting["half_width"], setting_se.get("half_width"), self.input_unit,
                      "half width d of the dead band around zero"),
                param("scale", *linear_estimate(coef, cov, [1.0]), "-",
                      "share of the dead band the model should see (1: a full dead zone)")]

    def input_change(self, coef, setting):
        c, d = float(coef[0]), float(setting["half_width"])
        return make_input_change(self.input, transform=lambda v, dt_s: v - c * np.clip(v, -d, d), form=("deadzone", c, d))


class InputSaturation(InputEffect):
    """The model should see the input clipped at a level u_c: above, min(u, u_c) (change -max(u - u_c, 0));
    below, max(u, u_c) (change max(u_c - u, 0)). Term: c (df_i/du) times that change (c = 1 at the truth);
    u_c searched over upper (above) or lower (below) quantiles of u and refined (linear scale, at most one
    grid step beyond the grid and within the data's range).

    Args (besides the problem, equation and input index): ``side`` "above" or "below", ``values`` (M,)
    the input along a fitting maneuver (input units), ``quantiles`` q giving the levels at the (1 - q)-
    (above) or q-quantiles (below) of u.
    """

    continuous = "level"

    def __init__(self, problem, equation, input_index, side, values, quantiles):
        name = problem.input_names[input_index]
        change = f"-max({name} - u_c, 0)" if side == "above" else f"max(u_c - {name}, 0)"
        super().__init__(problem, equation, input_index, f"input_saturation_{side}",
                         f"input {name} saturates {side} a level", f"c * (df/d{name}) * {change}; the model should see "
                         f"{'min' if side == 'above' else 'max'}({name}, u_c)", "-")
        self.side = side
        self.input_unit = problem.unit(name)
        values = np.asarray(values, dtype=float)
        qs = [1.0 - q for q in quantiles] if side == "above" else list(quantiles)
        self.levels = _input_levels(values, qs)
        finite = values[np.isfinite(values)]
        self.range = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)

    def grid(self):
        return [{"level": v} for v in self.levels]

    def bounds(self):
        return _linear_bounds(self.levels, *self.range)

    def coefficient_names(self, setting):
        return ["scale"]

    def _change(self, values: np.ndarray, level: float) -> np.ndarray:
        if self.side == "above":
            return -np.maximum(values - level, 0.0)
        return np.maximum(level - values, 0.0)

    def regressors(self, inputs, setting):
        return (self._column(inputs) * self._change(inputs.u[:, self.input], float(setting["level"])))[:, None]

    def physical(self, coef, cov, setting, setting_se):
        return [param("level", setting["level"], setting_se.get("level"), self.input_unit,
                      f"level u_c the input saturates at ({self.side})"),
                param("scale", *linear_estimate(coef, cov, [1.0]), "-", "share of the clipping the model should see "
                                                                      "(1: a full saturation)")]

    def input_change(self, coef, setting):
        c, level = float(coef[0]), float(setting["level"])
        return make_input_change(self.input, transform=lambda v, dt_s: v + c * self._change(v, level),
                                 form=(f"saturation_{self.side}", c, level))


# ----------------------------------------------------------------------------- parameters

class ResponseMap:
    """The relative parameter error r that a first-order coefficient c of ``parameter(p)`` stands for.

    The regressor of a parameter error is its first-order sensitivity p df/dp, so the fitted coefficient c is the
    error only where the model is linear in p. The model's own response to finite errors, c(r)
    (:func:`hybridfmu.diagnosis.effects.parameter_response`; c(r) = r / (1 + r) for a derivative proportional to
    1 / p), is inverted on the branch through r = 0 where it rises with r (monotone cubic interpolation). A
    coefficient beyond the evaluated range is continued with the slope at its end. Without a response (none
    given, or too few points) the map is the identity: the first-order reading.
    """

    def __init__(self, relative: np.ndarray | None = None, response: np.ndarray | None = None) -> None:
        self._inverse = None
        if relative is None or response is None:
            return
        relative, response = np.asarray(relative, dtype=float), np.asarray(response, dtype=float)
        keep = np.isfinite(response)
        relative, response = relative[keep], response[keep]
        if relative.size < 3 or not np.any(relative == 0.0):
            return
        zero = int(np.flatnonzero(relative == 0.0)[0])
        low, high = zero, zero
        while low > 0 and response[low - 1] < response[low]:
            low -= 1
        while high < relative.size - 1 and response[high + 1] > response[high]:
            high += 1
        if high - low < 2:
            return
        from scipy.interpolate import PchipInterpolator

        self._inverse = PchipInterpolator(response[low:high + 1], relative[low:high + 1], extrapolate=False)
        self._derivative = self._inverse.derivative()
        self._ends = (float(response[low]), float(response[high]))

    @classmethod
    def of(cls, response: ParameterResponse | None, weights: np.ndarray) -> "ResponseMap":
        """The map of a fit of the equations with row weights ``weights`` (n_x,) (None: the identity)."""
        if response is None:
            return cls()
        return cls(response.relative, response.coefficients(weights))

    @property
    def is_identity(self) -> bool:
        return self._inverse is None

    def _clamped(self, coefficient: float) -> float:
        return min(max(coefficient, self._ends[0]), self._ends[1])

    def slope(self, coefficient: float) -> float:
        """dr/dc at ``coefficient`` (1 for the identity)."""
        if self._inverse is None:
            return 1.0
        return float(self._derivative(self._clamped(float(coefficient))))

    def __call__(self, coefficient: float) -> float:
        """The relative error r with c(r) = ``coefficient``."""
        coefficient = float(coefficient)
        if self._inverse is None or not math.isfinite(coefficient):
            return coefficient
        end = self._clamped(coefficient)
        return float(self._inverse(end)) + (coefficient - end) * self.slope(end)


class ParameterError(Effect):
    kind = "parameter"
    model_wide = True
    #: the first-order reading, for an instance pickled before the response existed
    response: ParameterResponse | None = None
    response_map = ResponseMap()

    def __init__(self, problem, equation, parameter, response: ParameterResponse | None = None):
        """``response``: the model's response to finite errors of the parameter along the fitting rows
        (:meth:`EffectInputs.response`; None: the first-order reading, :class:`ResponseMap`). Alone, the effect reads
        its coefficient by its own equation's response; fitted jointly over equations, by theirs
        (:func:`share_response_map`)."""
        self.parameter = parameter
        self.value = float(problem.parameter_values.get(parameter, 0.0))
        self.response = response if self.value != 0.0 else None
        self.response_map = ResponseMap.of(self.response, np.eye(problem.n_x)[equation])
        super().__init__(f"parameter({parameter})", equation, f"model parameter {parameter} differs from its value",
                         f"f({parameter} (1 + r)) - f({parameter}) ~ c {parameter} df/d{parameter}", "-")

    def coefficient_names(self, setting):
        return ["relative_error"]

    def regressors(self, inputs, setting):
        sens = inputs.sensitivity(self.parameter)
        if sens is None:
            return np.zeros((inputs.n, 1))
        return sens[:, [self.equation]]

    def relative_error(self, coef):
        return self.response_map(float(coef[0]))

    def physical(self, coef, cov, setting, setting_se):
        c, se_c = linear_estimate(coef, cov, [1.0])
        r = self.response_map(c)
        se = abs(self.response_map.slope(c)) * se_c
        return [param("relative_error", r, se, "-", f"({self.parameter}_true - {self.parameter}) / {self.parameter}"),
                param("corrected_value", self.value * (1.0 + r), abs(self.value) * se, "",
                      f"{self.parameter} implied by the fit (model value {self.value:g})")]

    def parameter_change(self, coef, setting):
        return self.parameter, self.value * (1.0 + self.relative_error(coef))


def share_response_map(members: list[Effect], weights: dict[int, float]) -> None:
    """Give the members of one model-wide parameter error (the same ``parameter(p)`` in several equations, fitted
    with one coefficient over their stacked rows) the response map of that joint fit: each equation's response
    weighted by its rows' weight ``weights[equation]`` (the inverse noise variance of the stacked design,
    :class:`hybridfmu.diagnosis.joint.StackedCache`). Members of another kind are left alone."""
    errors = [m for m in members if isinstance(m, ParameterError)]
    if not errors or errors[0].response is None:
        return
    n_x = errors[0].response.denominator.shape[0]
    vector = np.zeros(n_x)
    for member in errors:
        vector[member.equation] = float(weights.get(member.equation, 0.0))
    shared = ResponseMap.of(errors[0].response, vector)
    for member in errors:
        member.response_map = shared


# ----------------------------------------------------------------------------- building the library

def _nonzero(values: np.ndarray | None, reference: float) -> bool:
    if values is None:
        return False
    values = values[np.isfinite(values)]
    return bool(values.size) and float(np.max(np.abs(values))) > 1e-9 * max(reference, 1e-300)


def _matches(name: str, patterns: list[str]) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)


def load_plugins(settings: dict[str, Any]) -> list[tuple[Any, dict[str, Any]]]:
    """The case plugins (``diagnosis.plugins``) with their options (``diagnosis.plugin_options[module]``).

    Raises:
        ConfigError: a plugin cannot be imported or has no ``plugin_effects`` function.
    """
    out = []
    for name in settings.get("plugins") or []:
        try:
            module = importlib.import_module(name)
        except ImportError as err:
            raise ConfigError(f"config.diagnosis.plugins: cannot import {name!r}: {err}") from None
        if not hasattr(module, "plugin_effects"):
            raise ConfigError(f"config.diagnosis.plugins: {name!r} has no function plugin_effects(problem, equation, "
                              "options, inputs)")
        out.append((module, dict((settings.get("plugin_options") or {}).get(name) or {})))
    return out


def build_library(problem: Problem, inputs: EffectInputs, model: Any) -> tuple[dict[int, list[Effect]], dict[str, str]]:
    """Candidate effects for each examined equation, and why candidates were left out.

    Args:
        problem: the problem (spreads and quantiles set).
        inputs: effect inputs along one fitting maneuver (to find nonzero input/parameter sensitivities).
        model: the model (its parameter names).

    Returns:
        ({equation index: [effects]}, {"<effect> in d<state>/dt": reason}).
    """
    settings = problem.settings
    options = settings["effects"]
    kinds = set(options.get("kinds") or [])
    input_quantiles = quantile_grid(options["input_quantiles"], f"{WHERE}.input_quantiles")
    actuator_lags_s = [n * problem.dt_s for n in positive_grid(options["actuator_lag_samples"],
                                                               f"{WHERE}.actuator_lag_samples", allow_empty=True)] \
        if problem.dt_s > 0 else []
    unknown = kinds - set(DEFAULT_KINDS)
    if unknown:
        raise ConfigError(f"{WHERE}.kinds: unknown {sorted(unknown)}; expected some of {DEFAULT_KINDS}")
    include = list(settings.get("candidates") or [])
    exclude = list(settings.get("exclude") or [])
    parameters = settings.get("parameters")
    model_parameters = list(getattr(model, "parameter_names", []))
    if parameters is not None:
        missing = [p for p in parameters if p not in model_parameters]
        if missing:
            raise ConfigError(f"config.diagnosis.parameters: {missing} are not parameters of the model "
                              f"{model_parameters}")
    else:
        parameters = model_parameters
    plugins = load_plugins(settings)
    from hybridfmu.diagnosis.prepare import kernel_samples

    # largest input time offset searched: config, else one kernel length
    max_offset_s = float(options.get("max_time_offset_s") or kernel_samples(problem, problem.dt_s) * problem.dt_s)
    library: dict[int, list[Effect]] = {}
    skipped: dict[str, str] = {}
    rate_scale = np.max(np.abs(inputs.f), axis=0) if inputs.n else np.ones(problem.n_x)
    for eq in problem.equations:
        effects: list[Effect] = []
        for j in problem.measured:
            if "viscous" in kinds:
                effects.append(Viscous(problem, eq, j))
            if "quadratic" in kinds:
                effects.append(Quadratic(problem, eq, j))
            if "polynomial" in kinds and options.get("polynomial_degrees"):
                effects.append(Polynomial(problem, eq, j, options["polynomial_degrees"]))
            if "coulomb" in kinds:
                effects.append(Coulomb(problem, eq, j, options))
            if "saturation" in kinds:
                effects += [Saturation(problem, eq, j, "above", options), Saturation(problem, eq, j, "below", options)]
            if "limit" in kinds and j == eq:
                effects += [Limit(problem, eq, "above", options), Limit(problem, eq, "below", options)]
            if "periodic" in kinds and j in problem.periodic:
                effects.append(Periodic(problem, eq, j, problem.periodic[j], options))
            if "scaled_coulomb" in kinds:
                effects += [ScaledCoulomb(problem, eq, j, k, options) for k in range(problem.n_u)]
        if "overflow" in kinds:
            effects += [Overflow(problem, eq, j, options) for j in problem.unmeasured
                        if inputs.n and _nonzero(inputs.f[:, j], float(rate_scale[j]))]
        active_inputs = []
        for k, name in enumerate(problem.input_names):
            column = inputs.dfdu[:, eq, k] if inputs.dfdu is not None else None
            if not _nonzero(column * np.maximum(np.abs(inputs.u[:, k]), 1.0) if column is not None else None,
                            float(rate_scale[eq])):
                skipped[f"input effects of {name} in d{problem.state_names[eq]}/dt"] = \
                    f"d(d{problem.state_names[eq]}/dt)/d{name} is zero along the data"
                continue
            active_inputs.append(k)
            if "input_gain" in kinds:
                effects.append(InputGain(problem, eq, k))
            if "input_offset" in kinds:
                effects.append(InputOffset(problem, eq, k))
            if "time_offset" in kinds:
                effects.append(TimeOffset(problem, eq, k, max_offset_s))
            if "input_lag" in kinds:
                effects.append(InputLag(problem, eq, k, actuator_lags_s))
            if "input_deadzone" in kinds:
                effects.append(InputDeadzone(problem, eq, k, inputs.u[:, k], input_quantiles))
            if "input_saturation" in kinds:
                effects += [InputSaturation(problem, eq, k, side, inputs.u[:, k], input_quantiles)
                            for side in ("above", "below")]
        # all inputs offset together: a member in every equation some input acts on (one offset for all of them)
        if "time_offset" in kinds and problem.n_u > 1 and active_inputs:
            effects.append(time_offset_all(problem, eq, max_offset_s))
        if "parameter" in kinds:
            for name in parameters:
                sens = inputs.sensitivity(name)
                if sens is None or not _nonzero(sens[:, eq], float(rate_scale[eq])):
                    skipped[f"parameter({name}) in d{problem.state_names[eq]}/dt"] = \
                        "no sensitivity along the data" if sens is not None else "the model rejects a perturbed value"
                    continue
                effects.append(ParameterError(problem, eq, name, inputs.response(name)))
        for module, plugin_options in plugins:
            effects += list(module.plugin_effects(problem, eq, plugin_options, inputs))
        kept = []
        for effect in effects:
            if include and not _matches(effect.name, include):
                continue
            if _matches(effect.name, exclude) or _matches(f"{problem.state_names[eq]}:{effect.name}", exclude):
                skipped[f"{effect.name} in d{problem.state_names[eq]}/dt"] = "excluded by config.diagnosis.exclude"
                continue
            searched_later = isinstance(effect, Periodic) and effect.orders is None  # orders found in the data
            if not searched_later and not effect.grid():
                skipped[f"{effect.name} in d{problem.state_names[eq]}/dt"] = "empty grid of settings"
                continue
            kept.append(effect)
        library[eq] = kept
        LOGGER.info("equation d%s/dt: %d candidate effects", problem.state_names[eq], len(kept))
    return library, skipped


DEFAULT_KINDS = ["viscous", "quadratic", "polynomial", "coulomb", "scaled_coulomb", "periodic", "saturation", "limit",
                 "overflow", "input_gain", "input_offset", "time_offset", "input_lag", "input_deadzone", "input_saturation",
                 "parameter"]
