"""Output-error least squares over whole maneuvers: the one fitter of the calibration
(:mod:`hybridfmu.calibration.fit`) and of the diagnosis' recalibration with the named effects
(:mod:`hybridfmu.diagnosis.refit`).

Objective. Each maneuver ``m`` is simulated open loop over its whole length by the caller's ``simulate(values, m)``
(values: variable name -> value), which returns its target states (T_m, n_t). The residual of target ``t`` at
sample ``k`` of maneuver ``m`` is::

    r = sqrt(w_t) * (y_sim[k, t] - y_meas[k, t]) / s_t / sqrt(N)

with ``w_t`` the target weights, ``s_t`` the targets' spreads (given by the caller: the calibration's validation
phase uses those of its train maneuvers) and ``N`` the number of samples of all fitted maneuvers, so the cost
``0.5 * sum r^2`` is half the weighted mean of the normalised squared errors. A simulation that raises one of
the caller's ``failures`` or returns non-finite values gives every sample of its maneuver the residual
``FAILED_RESIDUAL / sqrt(N)`` (logged once): a bad point, not an abort.

Optimiser: ``scipy.optimize.least_squares``, trust-region reflective (``trf``) within the variables' bounds, in
variables normalised by their start values (|start|, 1 where it is 0). Sensitivities: forward differences of the
simulation with the steps scipy's own ``jac="2-point"`` takes (:func:`forward_step`), column by column, so that a
variable that belongs to one maneuver (its initial state) re-simulates that maneuver only, where scipy would
re-simulate every maneuver for every column. From several starts (e.g. a warm start and a cold one) the fit runs once each; the lowest final
cost wins (the first start on a tie).

API::

    Variable(name, start, low, high, maneuver=None)
    target_spread(measured) -> (n_t,)
    fit_output_error(variables, simulate, measured, weights, spread, ...) -> OutputErrorFit
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

LOG = logging.getLogger(__name__)

#: Residual of a sample whose simulation failed or diverged (normalised units, before the 1/sqrt(N) scaling).
FAILED_RESIDUAL = 1e6


@dataclass(frozen=True)
class Variable:
    """One fitted quantity.

    Attributes:
        name: its name in ``simulate``'s values and in the result.
        start: start value; low, high: bounds (low <= start <= high; inf allowed).
        maneuver: index of the only maneuver it acts on (an initial state), or None (every maneuver).
    """

    name: str
    start: float
    low: float
    high: float
    maneuver: int | None = None


@dataclass
class OutputErrorFit:
    """Outcome of :func:`fit_output_error`.

    Attributes:
        values: variable name -> fitted value (the start values when there is nothing to fit).
        cost_start, cost: objective at the first start and at the chosen optimum.
        start_costs: final cost of each start, in order.
        iterations: Jacobian evaluations over all starts; evaluations: objective evaluations (all maneuvers)
            at trial points; simulations: simulations of one maneuver, finite differences included.
        status, message: of least_squares at the chosen optimum (0 and "" when nothing is fitted).
        elapsed_s: wall time.
    """

    values: dict[str, float]
    cost_start: float
    cost: float
    start_costs: list[float] = field(default_factory=list)
    iterations: int = 0
    evaluations: int = 0
    simulations: int = 0
    status: int = 0
    message: str = ""
    elapsed_s: float = 0.0


def target_spread(measured: Sequence[np.ndarray]) -> np.ndarray:
    """(n_t,) standard deviation of each measured target pooled over the maneuvers ((T_m, n_t) each; 1 where 0)."""
    pooled = np.concatenate([np.asarray(m, dtype=float) for m in measured], axis=0)
    spread = pooled.std(axis=0)
    return np.where(spread > 0, spread, 1.0)


def forward_step(z: float, relative_step: float, lower: float, upper: float) -> float:
    """The forward-difference step of a normalised variable at z within [lower, upper], as scipy's
    ``least_squares`` takes it for ``jac="2-point"`` with ``diff_step``: ``relative_step * |z|`` in the direction of
    z's sign (+ at 0), the machine-precision step sqrt(eps) * max(1, |z|) where that one vanishes, reversed where
    it would leave the bounds and fits the other way, else up to the farther bound."""
    sign = 1.0 if z >= 0 else -1.0
    step = relative_step * sign * abs(z)
    if (z + step) - z == 0:
        step = math.sqrt(np.finfo(float).eps) * sign * max(1.0, abs(z))
    if math.isinf(lower) and math.isinf(upper):
        return step
    if z + step < lower or z + step > upper:
        below, above = z - lower, upper - z
        if abs(step) <= max(below, above):
            step = -step
        else:
            step = above if above >= below else -below
    return step


class _Objective:
    """Scaled residuals of the maneuvers as a function of the normalised variables z (value = z * scale)."""

    def __init__(self, variables: list[Variable], simulate: Callable[[dict[str, float], int], np.ndarray],
                 measured: list[np.ndarray], factor: np.ndarray, failures: tuple[type[BaseException], ...],
                 label: str, names: Sequence[str] | None = None) -> None:
        self.variables = variables
        self.simulate = simulate
        self.measured = measured
        self.factor = factor
        self.failures = failures
        self.label = label
        self.names = list(names or [])
        n_samples = sum(m.shape[0] for m in measured)
        self.failed_value = FAILED_RESIDUAL / math.sqrt(n_samples)
        start = np.array([v.start for v in variables], dtype=float)
        self.scale = np.where(np.abs(start) > 0, np.abs(start), 1.0)
        self.lower = np.array([v.low for v in variables], dtype=float) / self.scale
        self.upper = np.array([v.high for v in variables], dtype=float) / self.scale
        self.evaluations = self.iterations = self.simulations = 0
        self.started = time.perf_counter()
        self._cache: tuple[np.ndarray, list[np.ndarray]] | None = None
        self._warned = False

    def values(self, z: np.ndarray) -> dict[str, float]:
        return {v.name: float(value) for v, value in zip(self.variables, np.asarray(z, float) * self.scale)}

    def block(self, z: np.ndarray, m: int) -> np.ndarray:
        """Scaled residuals of maneuver m, (T_m * n_t,)."""
        values = self.values(z)
        self.simulations += 1
        try:
            simulated = np.asarray(self.simulate(values, m), dtype=float)
            if not np.isfinite(simulated).all():
                raise FloatingPointError("non-finite simulated states")
        except (FloatingPointError, *self.failures) as err:
            if not self._warned:
                LOG.warning("%s: simulation of maneuver %d failed at %s (%s); treated as a bad point", self.label,
                            m, values, str(err).splitlines()[0])
                self._warned = True
            return np.full(self.measured[m].size, self.failed_value)
        return ((simulated - self.measured[m]) * self.factor).ravel()

    def blocks(self, z: np.ndarray) -> list[np.ndarray]:
        z = np.asarray(z, float)
        if self._cache is not None and np.array_equal(self._cache[0], z):
            return self._cache[1]
        blocks = [self.block(z, m) for m in range(len(self.measured))]
        self.evaluations += 1
        self._cache = (z.copy(), blocks)
        return blocks

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return np.concatenate(self.blocks(z))

    def cost(self, z: np.ndarray) -> float:
        return 0.5 * float(np.sum(self(z) ** 2))

    def jacobian(self, z: np.ndarray, relative_step: float) -> np.ndarray:
        """(n_residuals, n_z) forward differences (module docstring); logs one progress line."""
        z = np.asarray(z, float)
        base = self.blocks(z)
        offsets = np.cumsum([0] + [b.size for b in base])
        columns = np.zeros((z.size, offsets[-1]))  # one row per variable: the Jacobian's memory layout is scipy's
        for j, variable in enumerate(self.variables):
            shifted = z.copy()
            shifted[j] = z[j] + forward_step(z[j], relative_step, self.lower[j], self.upper[j])
            step = shifted[j] - z[j]  # exactly representable
            targets = range(len(self.measured)) if variable.maneuver is None else [variable.maneuver]
            for m in targets:
                columns[j, offsets[m]:offsets[m + 1]] = (self.block(shifted, m) - base[m]) / step
        self.iterations += 1
        values = self.values(z)
        shown = ", ".join(f"{name}={values[name]:.6g}" for name in self.names)
        LOG.info("%s: iteration %d, cost %.6g, %d evaluations, %d simulations, %.1f s elapsed%s", self.label,
                 self.iterations, 0.5 * float(sum(np.sum(b ** 2) for b in base)), self.evaluations,
                 self.simulations, time.perf_counter() - self.started, f" ({shown})" if shown else "")
        return columns.T


def fit_output_error(variables: Sequence[Variable], simulate: Callable[[dict[str, float], int], np.ndarray],
                     measured: Sequence[np.ndarray], weights: np.ndarray, spread: np.ndarray, *,
                     relative_step: float, tolerance: float, max_evaluations: int, label: str,
                     starts: Sequence[dict[str, float]] | None = None,
                     failures: tuple[type[BaseException], ...] = (), shown: Sequence[str] | None = None
                     ) -> OutputErrorFit:
    """Fit the variables so that the simulated targets follow the measured ones (module docstring).

    Args:
        variables: the fitted quantities (bounds hold their starts).
        simulate: ``(values, m) -> (T_m, n_t)`` simulated targets of maneuver m with the variables at ``values``
            (name -> value).
        measured: the measured targets of each maneuver, (T_m, n_t) each.
        weights: (n_t,) target weights; spread: (n_t,) the targets' spreads (:func:`target_spread`).
        relative_step: forward-difference step relative to |z| of a normalised variable z (:func:`forward_step`).
        tolerance: least_squares' xtol, ftol and gtol.
        max_evaluations: most objective evaluations at trial points per start (least_squares' max_nfev).
        label: prefix of the progress lines.
        starts: start values (name -> value, a missing name at its ``Variable.start``, clipped to the bounds);
            None: the variables' starts.
        failures: exception types of a failed simulation (a bad point; anything else propagates).
        shown: variable names shown in each progress line.
    """
    from scipy.optimize import least_squares

    variables = list(variables)
    measured = [np.asarray(m, dtype=float) for m in measured]
    n_samples = sum(m.shape[0] for m in measured)
    factor = np.sqrt(np.asarray(weights, dtype=float)) / np.asarray(spread, dtype=float) / math.sqrt(n_samples)
    objective = _Objective(variables, simulate, measured, factor, tuple(failures), label, shown)
    z0 = np.array([v.start for v in variables], dtype=float) / objective.scale
    cost_start = objective.cost(z0)
    LOG.info("%s: %d variables (%s), %d maneuvers, start cost %.6g", label, len(variables),
             ", ".join(v.name for v in variables), len(measured), cost_start)
    if not variables:
        return OutputErrorFit(values={}, cost_start=cost_start, cost=cost_start, start_costs=[cost_start],
                              evaluations=objective.evaluations, simulations=objective.simulations,
                              elapsed_s=time.perf_counter() - objective.started)
    start_points = [z0] if not starts else [
        np.clip(np.array([float(start.get(v.name, v.start)) for v in variables]) / objective.scale,
                objective.lower, objective.upper) for start in starts]
    best, start_costs = None, []
    for index, z_start in enumerate(start_points):
        result = least_squares(objective, z_start, jac=lambda z: objective.jacobian(z, relative_step),
                               bounds=(objective.lower, objective.upper), method="trf", x_scale=1.0,
                               max_nfev=max_evaluations, xtol=tolerance, ftol=tolerance, gtol=tolerance)
        start_costs.append(float(result.cost))
        if len(start_points) > 1:
            LOG.info("%s: start %d of %d ends at cost %.6g", label, index + 1, len(start_points), float(result.cost))
        if best is None or float(result.cost) < float(best.cost):
            best = result
    elapsed = time.perf_counter() - objective.started
    LOG.info("%s: done after %d iterations, %d evaluations, %d simulations, %.1f s: cost %.6g -> %.6g (%s)", label,
             objective.iterations, objective.evaluations, objective.simulations, elapsed, cost_start,
             float(best.cost), best.message)
    return OutputErrorFit(values=objective.values(best.x), cost_start=cost_start, cost=float(best.cost),
                          start_costs=start_costs, iterations=objective.iterations,
                          evaluations=objective.evaluations, simulations=objective.simulations,
                          status=int(best.status), message=str(best.message), elapsed_s=elapsed)

