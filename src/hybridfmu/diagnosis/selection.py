"""Fitting candidate effects to the equation error, sparse selection, uncertainty, stability.

Per examined state equation the kernel-averaged equation error ``y`` is sampled at centres one kernel length apart (so
the noise of neighbouring samples is nearly independent) inside the informative segments.
Every effect's term is averaged with the same kernel at the same centres. The selection runs on one equation
(:class:`DesignCache`) or on all examined equations stacked (:class:`hybridfmu.diagnosis.joint.StackedCache`,
each block of rows in units of its noise floor). Effects enter by stepwise forward selection: at each step
every remaining candidate is fitted together with those already chosen (linear least squares in its
coefficients; its nonlinear settings searched on a grid, the ``refine_candidates`` best refined by bounded
minimisation, and settings with different numbers of coefficients compared by BIC, the sum over blocks of
their Gaussian log-likelihoods) and the one with the lowest BIC among those passing every threshold enters.
A candidate passes if it lowers the BIC by ``min_bic_drop``, removes at least ``min_relative_improvement`` of
the remaining residual sum of squares of the equation(s) it acts on, explains a mean square of at least
``min_explained_to_noise`` times their noise floor's variance and at least ``min_share_of_initial`` of their
initial residual energy (an effect much weaker than the measurement noise, or than the gap it is part of, is
of no practical consequence even when a long record makes it statistically significant), and their remaining
residual is still above the noise floor. Parameter errors below ``parameter_tolerance`` never enter.
Parameter errors may be calibrated instead (fitted from the start, kept only while they would pass the
thresholds entering last); after the forward steps a chosen term is exchanged for a candidate that lowers
the BIC and passes the thresholds in its place, provided the replaced term would not enter again, and the
forward steps resume.
Standard errors come from the regression and from a bootstrap over segments; the
chosen set is refitted on every fitting maneuver alone to show its stability.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Callable

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from hybridfmu.config import ConfigError
from hybridfmu.diagnosis.derivatives import smooth_at
from hybridfmu.diagnosis.effects import Effect, EffectInputs
from hybridfmu.diagnosis.joint import Block, JointEffect, effect_equations, effect_key
from hybridfmu.diagnosis.memo import LruMemo, setting_key

LOGGER = logging.getLogger("hybridfmu.diagnosis")


@dataclass
class ManeuverFitData:
    """One maneuver prepared for fitting.

    Attributes:
        name: maneuver name.
        inputs: effect inputs along the measured trajectory (data mode), M samples.
        kernel: (W,) smoothing kernel.
        centres: (K,) sample indices at which the kernel-averaged quantities are fitted.
        span_id: (K,) index of the segment each centre lies in (for the bootstrap).
        target: (K, n_x) kernel-averaged equation error at the centres.
        noise_std: (n_x,) predicted noise std of the kernel-averaged equation error.
    """

    name: str
    inputs: EffectInputs
    kernel: np.ndarray
    centres: np.ndarray
    span_id: np.ndarray
    target: np.ndarray
    noise_std: np.ndarray


@dataclass
class SelectionSettings:
    """Thresholds of the forward selection (config ``diagnosis.selection``)."""

    min_bic_drop: float = 10.0
    min_relative_improvement: float = 0.03
    min_explained_to_noise: float = 1.0
    min_share_of_initial: float = 0.001
    parameter_tolerance: float = 0.005
    noise_margin: float = 0.10
    max_effects_per_equation: int = 6
    bootstrap_samples: int = 200
    refine_iterations: int = 30
    refine_candidates: int = 8
    calibrate_parameters: bool = True
    max_exchange_rounds: int = 4
    max_parameter_overlap: float = 0.9

    @classmethod
    def from_config(cls, section: dict[str, Any] | None) -> "SelectionSettings":
        """The settings of ``diagnosis.selection`` (missing keys take the defaults above).

        Raises:
            ConfigError: an unknown key, or a value that is no number (``config.diagnosis.selection.<key>``).
        """
        section = dict(section or {})
        if "max_effects_per_group" in section:  # the name before equations were examined one by one
            section.setdefault("max_effects_per_equation", section.pop("max_effects_per_group"))
        unknown = sorted(k for k in section if k not in cls.__dataclass_fields__)
        if unknown:
            raise ConfigError(f"config.diagnosis.selection: unknown {unknown}; expected some of "
                              f"{sorted(cls.__dataclass_fields__)}")
        for key, value in section.items():
            if key == "calibrate_parameters":
                if not isinstance(value, bool):
                    raise ConfigError(f"config.diagnosis.selection.{key}: expected true or false, got {value!r}")
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
                raise ConfigError(f"config.diagnosis.selection.{key}: expected a number >= 0, got {value!r}")
        return cls(**section)


class DesignCache:
    """Kernel-averaged effect regressors at the fitting centres, cached per (effect, setting, maneuver)."""

    def __init__(self, maneuvers: list[ManeuverFitData]) -> None:
        self.maneuvers = {m.name: m for m in maneuvers}
        self._cache: dict[tuple, np.ndarray] = {}
        #: the latest fits of :func:`fit_terms`
        self.fits = LruMemo()

    def _one(self, effect: Effect, setting: dict[str, float], name: str) -> np.ndarray:
        key = (effect.name, effect.equation, setting_key(setting), name)
        if key not in self._cache:
            data = self.maneuvers[name]
            regressors = np.asarray(effect.regressors(data.inputs, setting), dtype=float)
            if regressors.ndim != 2 or regressors.shape[0] != data.inputs.n:
                raise ValueError(f"{effect.name}: regressors of shape {regressors.shape}, expected "
                                 f"({data.inputs.n}, n_coef)")
            design = smooth_at(regressors, data.kernel, data.centres) if len(data.centres) else \
                np.zeros((0, regressors.shape[1]))
            design[~np.isfinite(design)] = 0.0
            design.setflags(write=False)
            self._cache[key] = design
        return self._cache[key]

    def design(self, effect: Effect, setting: dict[str, float], names: list[str]) -> np.ndarray:
        """Stacked (n, n_coef) kernel-averaged regressors over the maneuvers ``names`` (read-only)."""
        if len(names) == 1:
            return self._one(effect, setting, names[0])
        return np.concatenate([self._one(effect, setting, name) for name in names], axis=0)

    def target(self, equation: int, names: list[str]) -> np.ndarray:
        """(n,) kernel-averaged equation error of state ``equation`` at the centres of ``names``."""
        return np.concatenate([self.maneuvers[n].target[:, equation] for n in names])

    def groups_of_rows(self, names: list[str]) -> np.ndarray:
        """Bootstrap group (maneuver, segment block) of every stacked row."""
        return np.concatenate([self.maneuvers[n].span_id + 100000 * j for j, n in enumerate(names)])

    def noise_variance(self, equation: int, names: list[str]) -> float:
        """Mean predicted noise variance per stacked row."""
        values = [self.maneuvers[n].noise_std[equation] ** 2 * len(self.maneuvers[n].centres) for n in names]
        count = sum(len(self.maneuvers[n].centres) for n in names)
        return float(sum(values) / max(count, 1))

    def accepts(self, effect: Effect, equation: int) -> bool:
        """Whether ``effect`` is a candidate of the selection in ``equation`` (its own equation's)."""
        return effect.equation == equation

    def blocks(self, equation: int, names: list[str]) -> list[Block]:
        """The rows of ``equation``: a single block (see :class:`hybridfmu.diagnosis.joint.StackedCache`)."""
        count = sum(len(self.maneuvers[n].centres) for n in names)
        return [Block(equation, slice(0, count), self.noise_variance(equation, names))]


@dataclass
class Term:
    """An effect with its nonlinear setting (and, once fitted, coefficients)."""

    effect: Effect
    setting: dict[str, float]
    coef: np.ndarray = field(default_factory=lambda: np.zeros(0))
    setting_se: dict[str, float] = field(default_factory=dict)


def terms_in_equation(terms: list[Term], equation: int) -> list[Term]:
    """The chosen terms acting on ``equation``, a joint term as its member there (same setting and
    coefficients): what a consumer that works equation by equation (a figure, a comparison) needs."""
    out = []
    for term in terms:
        if isinstance(term.effect, JointEffect):
            member = term.effect.member(equation)
            if member is not None:
                out.append(Term(member, dict(term.setting), term.coef, dict(term.setting_se)))
        elif term.effect.equation == equation:
            out.append(term)
    return out


def count_parameters(term: Term, grid_size: int) -> int:
    """Parameters of a term for the information criterion: its coefficients plus its searched settings
    (each continuous setting in use, else one for a grid of several settings)."""
    effect = term.effect
    n = len(effect.coefficient_names(term.setting))
    refined = [p for p in effect.continuous_parameters() if effect.refine_bounds(p) is not None
               and not (effect.log_scale and term.setting.get(p, 0.0) == 0.0)]
    if refined:
        n += len(refined)
    elif grid_size > 1:
        n += 1
    return n


class LinearFit:
    """Least-squares fit of a set of terms: ``coefs`` per term, ``rss``, ``n`` fitted rows, ``residual`` (n,); ``cov``
    of all coefficients, computed when first read (most fits of a selection compare residuals only)."""

    def __init__(self, coefs: list[np.ndarray], rss: float, n: int, residual: np.ndarray,
                 covariance: Callable[[], np.ndarray] | None = None) -> None:
        self.coefs = coefs
        self.rss = rss
        self.n = n
        self.residual = residual
        self._covariance = covariance

    @cached_property
    def cov(self) -> np.ndarray:
        """(n_coef, n_coef) covariance of the coefficients (:func:`coefficient_covariance`)."""
        return self._covariance() if self._covariance is not None else np.zeros((0, 0))


def coefficient_covariance(scaled: np.ndarray, scale: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """sigma^2 (D^T D)^+ of the column-scaled design D (n, k) over the scales' (k,) outer product, sigma^2 the
    residual variance (rss over the n - k degrees of freedom): the covariance (k, k) of a least-squares fit."""
    if scaled.shape[1] == 0:
        return np.zeros((0, 0))
    sigma2 = float(residual @ residual) / max(len(residual) - scaled.shape[1], 1)
    # a general product of two arrays, as ever: NumPy takes a symmetric kernel for D^T D, which rounds otherwise
    gram = scaled.T @ scaled.copy()
    return sigma2 * np.linalg.pinv(gram) / np.outer(scale, scale)


def stacked_design(cache: DesignCache, terms: list[Term], equation: int,
                   names: list[str]) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """The equation error (n,), the terms' design columns side by side (n, sum of sizes), and the
    number of columns of each term."""
    y = cache.target(equation, names)
    designs, sizes = [], []
    for term in terms:
        design = cache.design(term.effect, term.setting, names)
        designs.append(design)
        sizes.append(design.shape[1])
    design = np.concatenate(designs, axis=1) if designs else np.zeros((len(y), 0))
    return y, design, sizes


def fit_terms(cache: DesignCache, terms: list[Term], equation: int, names: list[str],
              row_mask: np.ndarray | None = None) -> LinearFit:
    """Fit the coefficients of ``terms`` (settings fixed) to the equation error of state ``equation``.

    A fit of all rows is kept by the cache's ``fits`` memo (where it has one) and given again, with new coefficient
    arrays, when the same terms at the same settings are fitted on the same maneuvers (the selection refits the
    best setting it has just found)."""
    memo = getattr(cache, "fits", None) if row_mask is None else None
    if memo is None:
        return _solve(cache, terms, equation, names, row_mask)
    key = (tuple((effect_key(t.effect), setting_key(t.setting)) for t in terms), equation, tuple(names))
    kept = memo.get(key)
    if kept is not None:
        coefs, rss, n, residual = kept
        frozen = [Term(t.effect, dict(t.setting)) for t in terms]
        return LinearFit([c.copy() for c in coefs], rss, n, residual,
                         covariance=lambda: _solve(cache, frozen, equation, names, None).cov)
    fit = _solve(cache, terms, equation, names, row_mask)
    fit.residual.setflags(write=False)
    memo.put(key, (tuple(c.copy() for c in fit.coefs), fit.rss, fit.n, fit.residual))
    return fit


def _solve(cache: DesignCache, terms: list[Term], equation: int, names: list[str],
           row_mask: np.ndarray | None) -> LinearFit:
    """The least-squares fit of :func:`fit_terms` (columns scaled to unit norm for the solve)."""
    y, design, sizes = stacked_design(cache, terms, equation, names)
    if row_mask is not None:
        y, design = y[row_mask], design[row_mask]
    covariance = None
    if design.shape[1]:
        scale = np.sqrt(np.sum(design ** 2, axis=0))
        scale[scale == 0] = 1.0
        scaled = design / scale
        coef_scaled, *_ = np.linalg.lstsq(scaled, y, rcond=None)
        coef = coef_scaled / scale
        residual = y - design @ coef

        def covariance() -> np.ndarray:
            return coefficient_covariance(scaled, scale, residual)
    else:
        coef = np.zeros(0)
        residual = np.array(y, dtype=float)
    splits = np.cumsum(sizes)[:-1] if sizes else []
    return LinearFit(coefs=list(np.split(coef, splits)) if sizes else [], rss=float(residual @ residual),
                     n=len(y), residual=residual, covariance=covariance)


#: A candidate whose design columns the other terms' reproduce up to this share of their energy (1 - R^2) cannot be
#: told apart from them with these data: its fitted value is reported as not identifiable.
COLLINEAR_SHARE = 1e-6


def collinearity(cache: DesignCache, others: list[Term], term: Term, equation: int,
                 names: list[str]) -> tuple[float, list[str]]:
    """How much of ``term``'s design columns the ``others``' columns leave unexplained (1 - R^2 of a least-squares fit
    of the unit-norm columns; 0: a combination of theirs, 1: orthogonal to them), and the names of the others whose
    columns carry that fit (weight above 1 % of the largest)."""
    if not others:
        return 1.0, []
    _, design, sizes = stacked_design(cache, others + [term], equation, names)
    scale = np.sqrt(np.sum(design ** 2, axis=0))
    scale[scale == 0] = 1.0
    unit = design / scale
    own, rest = unit[:, -sizes[-1]:], unit[:, :-sizes[-1]]
    weights, *_ = np.linalg.lstsq(rest, own, rcond=None)
    left = own - rest @ weights
    share = float(np.sum(left ** 2) / max(float(np.sum(own ** 2)), 1e-300))
    per_term = [float(np.max(np.abs(part))) if part.size else 0.0
                for part in np.split(weights, np.cumsum(sizes[:-1])[:-1], axis=0)]
    top = max(per_term, default=0.0)
    carried = [t.effect.name for t, w in zip(others, per_term) if top > 0 and w >= 0.01 * top]
    return share, carried


def bic(rss: float, n: int, k: int) -> float:
    """Bayesian information criterion of a Gaussian least-squares fit."""
    return n * math.log(max(rss, 1e-300) / max(n, 1)) + k * math.log(max(n, 2))


def block_bic(residual: np.ndarray, blocks: list[Block], k: int) -> float:
    """Bayesian information criterion of a least-squares fit whose rows fall into blocks of their own variance
    (the equations of a stacked selection): sum over blocks of n_b log(rss_b / n_b), plus k log n. One block
    gives :func:`bic`."""
    value = 0.0
    for block in blocks:
        part = residual[block.rows]
        if len(part):
            value += len(part) * math.log(max(float(part @ part), 1e-300) / len(part))
    return value + k * math.log(max(len(residual), 2))


def block_rss(residual: np.ndarray, blocks: list[Block]) -> list[float]:
    """Residual sum of squares of each block."""
    return [float(residual[b.rows] @ residual[b.rows]) for b in blocks]


def _identity(value: float) -> float:
    return value


def _refine(cache: DesignCache, active: list[Term], effect: Effect, best: dict[str, float], best_rss: float,
            grid: list[dict[str, float]], equation: int, names: list[str],
            iterations: int) -> tuple[dict[str, float], float | None, dict[str, float]]:
    """Refine the continuous settings of ``effect`` (added to ``active``) from the best grid setting ``best``.

    Each continuous setting in turn is varied between its neighbouring grid values (or the effect's
    ``refine_bounds`` beyond the ends) by a bounded scalar minimisation of the residual sum of squares,
    the others held; several settings are then refined jointly (bounded Powell search within the same
    brackets, as they are often correlated). On a log scale where ``effect.log_scale`` (a setting at 0
    means "absent" there and is left alone). Standard errors from
    the curvature of the RSS in the refinement coordinates z (the log of the setting on a log scale),
    the linear coefficients refitted at every point: cov(z) = 2 (rss / n) H^-1 with H the Hessian of the
    RSS (finite differences, steps 0.02 in log, 2 % of the bracketing grid interval otherwise).

    Returns:
        (setting, its RSS or None when nothing was refined, {setting name: standard error in its unit}).
    """
    log = effect.log_scale
    forward, inverse = (math.log, math.exp) if log else (_identity, _identity)
    params: list[str] = []
    brackets: dict[str, tuple[float, float]] = {}
    for name in effect.continuous_parameters():
        bounds = effect.refine_bounds(name)
        if name not in best or bounds is None or not bounds[0] < bounds[1] or (log and not best[name] > 0):
            continue
        params.append(name)
        brackets[name] = (float(bounds[0]), float(bounds[1]))
    if not params:
        return best, None, {}

    def rss_of(setting: dict[str, float]) -> float:
        return fit_terms(cache, active + [Term(effect, setting)], equation, names).rss

    def bracket(name: str, centre: float) -> tuple[float, float]:
        values = sorted({float(g[name]) for g in grid if name in g and (not log or g[name] > 0)})
        low, high = brackets[name]
        return (max(max((v for v in values if v < centre), default=low), low),
                min(min((v for v in values if v > centre), default=high), high))

    setting, rss_cur = dict(best), float(best_rss)
    for name in params:  # one coordinate-wise pass
        lower, upper = bracket(name, setting[name])
        if not lower < upper or (log and not lower > 0):
            continue

        def rss_at(z: float, name: str = name) -> float:
            trial = dict(setting)
            trial[name] = float(inverse(z))
            return rss_of(trial)

        result = minimize_scalar(rss_at, bounds=(forward(lower), forward(upper)), method="bounded",
                                 options={"maxiter": iterations,
                                          "xatol": 1e-4 if log else 1e-4 * (upper - lower)})
        if float(result.fun) < rss_cur:
            setting[name] = float(inverse(float(result.x)))
            rss_cur = float(result.fun)
    if len(params) > 1:  # then jointly (the settings are often correlated), within the grid brackets of the best
        boxes = [bracket(name, best[name]) for name in params]
        boxes = [(min(lo, setting[n]), max(hi, setting[n])) for n, (lo, hi) in zip(params, boxes)]
        if all(lo < hi and (not log or lo > 0) for lo, hi in boxes):
            def rss_joint(z: np.ndarray) -> float:
                trial = dict(setting)
                for name, value in zip(params, z):
                    trial[name] = float(inverse(float(value)))
                return rss_of(trial)

            result = minimize(rss_joint, np.array([forward(setting[n]) for n in params]), method="Powell",
                              bounds=[(forward(lo), forward(hi)) for lo, hi in boxes],
                              options={"maxiter": iterations, "xtol": 1e-4, "ftol": 1e-10})
            if float(result.fun) < rss_cur:
                for name, value in zip(params, result.x):
                    setting[name] = float(inverse(float(value)))
                rss_cur = float(result.fun)
    # curvature of the RSS at the refined setting
    z0 = np.array([forward(setting[p]) for p in params])
    steps = []
    for name in params:
        lower, upper = bracket(name, setting[name])
        steps.append(0.02 if log else max(0.02 * (upper - lower), 1e-12))
    steps = np.array(steps)

    def rss_z(z: np.ndarray) -> float:
        trial = dict(setting)
        for name, value in zip(params, z):
            trial[name] = float(inverse(float(value)))
        return rss_of(trial)

    k = len(params)
    hessian = np.zeros((k, k))
    unit = np.eye(k)
    for i in range(k):
        step = steps[i] * unit[i]
        hessian[i, i] = (rss_z(z0 + step) - 2.0 * rss_cur + rss_z(z0 - step)) / steps[i] ** 2
        for j in range(i):
            di, dj = steps[i] * unit[i], steps[j] * unit[j]
            hessian[i, j] = hessian[j, i] = (rss_z(z0 + di + dj) - rss_z(z0 + di - dj) - rss_z(z0 - di + dj)
                                             + rss_z(z0 - di - dj)) / (4.0 * steps[i] * steps[j])
    n = len(cache.target(equation, names))
    scale = 2.0 * rss_cur / max(n, 1)
    variances = np.full(k, np.nan)
    if np.all(np.isfinite(hessian)):
        if k > 1 and np.all(np.linalg.eigvalsh(hessian) > 0):
            variances = scale * np.diag(np.linalg.inv(hessian))
        else:  # not positive definite: the curvature of each setting alone where it is positive
            diagonal = np.diag(hessian)
            variances = np.where(diagonal > 0, scale / np.where(diagonal > 0, diagonal, 1.0), np.nan)
    se = {}
    for name, variance in zip(params, variances):
        if np.isfinite(variance) and variance >= 0:
            z_se = math.sqrt(variance)
            se[name] = z_se * setting[name] if log else z_se
    return setting, rss_cur, se


def _structure(effect: Effect, setting: dict[str, float]) -> tuple:
    """What a setting fixes beyond its continuous values: coefficient names, discrete settings, and the
    log-scale settings at 0 ("absent", e.g. no Stribeck term)."""
    continuous = set(effect.continuous_parameters())
    discrete = tuple(sorted((k, round(float(v), 12)) for k, v in setting.items() if k not in continuous))
    absent = tuple(sorted(p for p in continuous if effect.log_scale and not setting.get(p, 0.0) > 0))
    return tuple(effect.coefficient_names(setting)), discrete, absent


def best_setting(cache: DesignCache, active: list[Term], effect: Effect, equation: int, names: list[str],
                      iterations: int, refine: bool = True) -> tuple[Term, float, list[dict[str, Any]]]:
    """Best nonlinear setting of ``effect`` added to ``active``: (term, rss, profile over the grid).

    Settings are compared by BIC (:func:`block_bic`: n log(rss / n) + n_coef log n for one equation, n fitted
    rows, n_coef the effect's coefficients at that setting): a setting with more coefficients (a Stribeck term,
    more harmonics, an asymmetry) must earn them. The grid's best setting of each structure (:func:`_structure`:
    the same coefficients and discrete settings, differing only in continuous values) is refined
    (:func:`_refine`, unless ``refine`` is False) before the structures are compared, so a structure is not
    preferred for making up for a coarse grid; a setting whose fit the effect does not find admissible
    (:meth:`Effect.admissible`, e.g. a negative Stribeck peak) is not chosen, refined or not. The profile lists
    every grid setting's ``rss``, ``bic`` and ``admissible``.
    """
    grid = effect.grid()
    blocks = cache.blocks(equation, names)
    profile = []
    per_structure: dict[tuple, tuple[float, float, dict[str, float]]] = {}
    inadmissible: dict[tuple, tuple[float, float, dict[str, float]]] = {}
    for setting in grid:
        fit = fit_terms(cache, active + [Term(effect, setting)], equation, names)
        score = block_bic(fit.residual, blocks, len(effect.coefficient_names(setting)))
        admissible = effect.admissible(fit.coefs[-1], setting)
        profile.append({"setting": dict(setting), "rss": fit.rss, "bic": score, "admissible": admissible})
        key = _structure(effect, setting)
        store = per_structure if admissible else inadmissible
        if key not in store or score < store[key][0]:
            store[key] = (score, fit.rss, setting)
    fallback = not per_structure  # no setting fits admissibly: the best fits are all there is
    if fallback:
        per_structure = inadmissible
    best_score, best_rss, best, best_se = math.inf, math.inf, grid[0], {}
    for score, rss, setting in per_structure.values():
        setting_se: dict[str, float] = {}
        if refine and effect.continuous_parameters():
            refined, refined_rss, refined_se = _refine(cache, active, effect, setting, rss, grid, equation, names,
                                                       iterations)
            if refined_rss is not None and refined_rss <= rss:
                fit = fit_terms(cache, active + [Term(effect, refined)], equation, names)
                if fallback or effect.admissible(fit.coefs[-1], refined):
                    setting, rss, setting_se = refined, refined_rss, refined_se
                    score = block_bic(fit.residual, blocks, len(effect.coefficient_names(setting)))
        if score < best_score:
            best_score, best_rss, best, best_se = score, rss, setting, setting_se
    return Term(effect, dict(best), setting_se=best_se), best_rss, profile


@dataclass
class SelectionStep:
    """One forward step: every candidate's best fit and whether the best one entered."""

    candidates: list[dict[str, Any]]
    chosen: str | None
    reason: str
    kind: str = "forward"  # or "exchange": ``chosen`` replaced a term (``reason`` names it)


#: Most rivals (:class:`Rival`) kept per selection, the lowest BIC first.
MAX_RIVALS = 3


@dataclass
class Rival:
    """A candidate left out of the final selection that the data still support beside it: fitted together with the
    chosen terms it lowers the BIC by at least ``min_bic_drop``, yet it failed a threshold of practical size
    (``rejected_because``; None where it would pass now). Where it takes over part of a chosen term's work, leaving it
    out biases that term's estimate, so the estimate rests on a choice the data do not make.

    Attributes:
        effect: its name; setting: its settings in the joint fit; bic_drop: how far it lowers the BIC.
        coefs: the chosen terms' coefficients in the joint fit (one array per term, in the order of
            ``EquationSelection.terms``).
    """

    effect: str
    setting: dict[str, float]
    bic_drop: float
    rejected_because: str | None
    coefs: list[np.ndarray]
    term: Term | None = None


@dataclass
class EquationSelection:
    """Result of the selection in one state equation (``rivals``: :class:`Rival`, where asked for; ``adjustments``:
    the names of the terms fitted beside the chosen ones by :func:`with_adjustment`, the last of ``terms``)."""

    equation: int
    terms: list[Term]
    fit: LinearFit
    rss_none: float
    n: int
    noise_variance: float
    steps: list[SelectionStep]
    calibration: list[dict[str, Any]] = field(default_factory=list)
    rivals: list[Rival] = field(default_factory=list)
    adjustments: list[str] = field(default_factory=list)


def _fit_state(cache, terms: list[Term], equation: int, names: list[str], blocks: list[Block],
               grid_sizes: dict[tuple, int]) -> tuple[list[float], float]:
    """Residual sum of squares per block and block BIC of ``terms`` fitted together."""
    fit = fit_terms(cache, terms, equation, names)
    k = sum(count_parameters(t, grid_sizes[effect_key(t.effect)]) for t in terms)
    return block_rss(fit.residual, blocks), block_bic(fit.residual, blocks, k)


def _effects_per_equation(terms: list[Term]) -> dict[int, int]:
    """Equation index -> number of ``terms`` acting on it (for ``max_effects_per_equation``)."""
    counts: dict[int, int] = {}
    for term in terms:
        for eq in effect_equations(term.effect):
            counts[eq] = counts.get(eq, 0) + 1
    return counts


def _candidate_row(cache, active: list[Term], term: Term, equation: int, names: list[str],
                   blocks: list[Block], rss_cur_blocks: list[float], rss_none_blocks: list[float], bic_cur: float,
                   grid_sizes: dict[tuple, int], settings: SelectionSettings) -> dict[str, Any]:
    """One candidate of a forward step, measured on the blocks (equations) it acts on."""
    effect = term.effect
    k = sum(count_parameters(t, grid_sizes[effect_key(t.effect)]) for t in active + [term])
    fit = fit_terms(cache, active + [term], equation, names)
    acting = set(effect_equations(effect))
    own = [j for j, b in enumerate(blocks) if b.equation in acting or b.equation == equation]
    own_cur = sum(rss_cur_blocks[j] for j in own)
    own_none = sum(rss_none_blocks[j] for j in own)
    own_rows = sum(blocks[j].rows.stop - blocks[j].rows.start for j in own)
    own_noise = sum((blocks[j].rows.stop - blocks[j].rows.start) * blocks[j].noise_variance for j in own)
    explained = sum(rss_cur_blocks) - fit.rss
    score = block_bic(fit.residual, blocks, k)
    error = effect.relative_error(fit.coefs[-1]) if fit.coefs and len(fit.coefs[-1]) else None
    return {"effect": effect.name, "equations": sorted(acting), "setting": term.setting, "rss": fit.rss,
            "relative_improvement": explained / own_cur if own_cur > 0 else 0.0,
            "explained_share": explained / own_none if own_none > 0 else 0.0,
            "explained_to_noise": explained / own_noise if own_noise > 0 else math.inf,
            "at_noise": own_rows > 0 and own_cur <= own_noise * (1.0 + settings.noise_margin),
            "bic": score, "bic_drop": bic_cur - score, "relative_parameter_error": error,
            "within_tolerance": error is not None and abs(error) < settings.parameter_tolerance,
            "term": term, "rss_blocks": block_rss(fit.residual, blocks)}


def _candidate_rows(cache, active: list[Term], pool: list[Effect], equation: int, names: list[str],
                    blocks: list[Block], rss_cur_blocks: list[float], rss_none_blocks: list[float], bic_cur: float,
                    grid_sizes: dict[tuple, int], settings: SelectionSettings, counts: dict[int, int]
                    ) -> list[dict[str, Any]]:
    """Every effect of ``pool`` not in ``active``, fitted beside it (:func:`_candidate_row`; the
    ``refine_candidates`` best by BIC with their continuous settings refined), sorted by BIC, each with the
    ``rejected_because`` of :func:`_rejection` (None: it may enter)."""
    chosen_keys = {effect_key(t.effect) for t in active}
    remaining = [e for e in pool if effect_key(e) not in chosen_keys]

    def row_of(effect: Effect, refine: bool) -> dict[str, Any]:
        term, _, _ = best_setting(cache, active, effect, equation, names, settings.refine_iterations, refine)
        return _candidate_row(cache, active, term, equation, names, blocks, rss_cur_blocks, rss_none_blocks,
                              bic_cur, grid_sizes, settings)

    rows = sorted((row_of(e, False) for e in remaining), key=lambda r: r["bic"])
    top = max(int(settings.refine_candidates), 1)
    for j, row in enumerate(rows[:top]):
        if row["term"].effect.continuous_parameters():
            rows[j] = row_of(row["term"].effect, True)
    rows.sort(key=lambda r: r["bic"])
    for r in rows:
        r["rejected_because"] = "parameter error within the tolerance" if r["within_tolerance"] else \
            _rejection(r, settings, counts)
    return rows


def _rejection(row: dict[str, Any], settings: SelectionSettings, counts: dict[int, int]) -> str | None:
    """Why a candidate may not enter (None: it may)."""
    full = [eq for eq in row["equations"] if counts.get(eq, 0) >= settings.max_effects_per_equation]
    if full:
        return f"{settings.max_effects_per_equation} effects already chosen in the equation(s) {full}"
    if row["bic_drop"] < settings.min_bic_drop:
        return f"BIC drop {row['bic_drop']:.1f} below {settings.min_bic_drop}"
    if row["relative_improvement"] < settings.min_relative_improvement:
        return f"relative improvement {row['relative_improvement']:.3f} below {settings.min_relative_improvement}"
    if row["explained_share"] < settings.min_share_of_initial:
        return (f"explains {100 * row['explained_share']:.2f} % of the initial residual, below "
                f"{100 * settings.min_share_of_initial:g} %")
    if row["explained_to_noise"] < settings.min_explained_to_noise:
        return (f"explains a mean square of {row['explained_to_noise']:.3g} noise variances, below "
                f"{settings.min_explained_to_noise}")
    if row["at_noise"]:
        return "the residual of its equation(s) is at the noise floor"
    return None


def _eliminate(cache, active: list[Term], base: list[Term], equation: int, names: list[str], blocks: list[Block],
               rss_none_blocks: list[float], grid_sizes: dict[tuple, int], settings: SelectionSettings,
               label: str, earlier: dict[tuple, dict[str, Any]] | None = None
               ) -> tuple[list[Term], dict[tuple, dict[str, Any]]]:
    """Backward elimination of the calibrated terms ``base`` (parameter errors) from ``active``: while one of them
    would not pass the thresholds if it entered last, the one whose removal raises the BIC least is dropped.
    Returns the remaining active terms and the records of ``earlier`` rounds updated: per calibrated term (by
    :func:`hybridfmu.diagnosis.joint.effect_key`) ``kept`` or why it was dropped."""
    records: dict[tuple, dict[str, Any]] = dict(earlier or {})
    while True:
        candidates = [t for t in active if any(t is b for b in base)]
        if not candidates:
            break
        rows = []
        for term in candidates:
            others = [t for t in active if t is not term]
            rss_blocks, bic_others = _fit_state(cache, others, equation, names, blocks, grid_sizes)
            row = _candidate_row(cache, others, term, equation, names, blocks, rss_blocks, rss_none_blocks,
                                 bic_others, grid_sizes, settings)
            row["rejected_because"] = "parameter error within the tolerance" if row["within_tolerance"] else \
                _rejection(row, settings, {})
            rows.append(row)
        failing = [r for r in rows if r["rejected_because"] is not None]

        def recorded(row: dict[str, Any], outcome: str) -> dict[str, Any]:
            """The row's record, with the terms beside it whose sensitivities reproduce its own (if any)."""
            others = [t for t in active if t is not row["term"]]
            share, carried = collinearity(cache, others, row["term"], equation, names)
            return _calibration_record({**row, "not_identifiable_with": carried if share < COLLINEAR_SHARE else []},
                                       outcome)

        if not failing:
            for row in rows:
                records[effect_key(row["term"].effect)] = recorded(row, "kept")
            break
        dropped = min(failing, key=lambda r: r["bic_drop"])
        records[effect_key(dropped["term"].effect)] = recorded(dropped, "dropped: " + dropped["rejected_because"])
        LOGGER.info("selection %s: calibrated %s dropped (%s)", label or equation, dropped["effect"],
                    dropped["rejected_because"])
        active = [t for t in active if t is not dropped["term"]]
    return active, records


def parameter_overlap(cache, term: Term, parameters: list[Effect], equation: int, names: list[str]) -> float:
    """Share (R^2, 0..1) of a term's regressors that the model's parameter sensitivities reproduce: 1 when the term
    is a combination of parameter errors (a supply-voltage gain against a resistance and an inductance error),
    which no data can tell from them."""
    if not parameters:
        return 0.0
    design = cache.design(term.effect, term.setting, names)
    basis = np.concatenate([cache.design(p, {}, names) for p in parameters], axis=1)
    total = float(np.sum(design ** 2))
    if total <= 0 or basis.shape[1] == 0:
        return 0.0
    coef, *_ = np.linalg.lstsq(basis, design, rcond=None)
    return float(1.0 - np.sum((design - basis @ coef) ** 2) / total)


def _best_exchange(cache, active: list[Term], pool: list[Effect], equation: int, names: list[str],
                   blocks: list[Block], rss_none_blocks: list[float], grid_sizes: dict[tuple, int],
                   settings: SelectionSettings, parameters: list[Effect] | None = None
                   ) -> tuple[Term, dict[str, Any]] | None:
    """The best exchange of one active term for one candidate not in use: the pair whose exchange lowers the BIC
    most, by at least ``min_bic_drop``, the candidate passing every threshold as if it entered last in the place of
    the term (a forward step can commit early to a term that merely resembles what is there, e.g. a damping for a
    lagging load signal). A model-wide term (an input or a parameter change) is exchanged only for another
    model-wide one, and only when the term it replaces would not enter again beside it (:func:`_would_not_return`).
    A calibrated parameter error (``parameters``) is not exchanged for a candidate that its fellow parameters
    reproduce to more than ``max_parameter_overlap`` (:func:`parameter_overlap`). None if there is no such
    exchange. The candidate's continuous settings are refined for
    the ``refine_candidates`` best by BIC at their grid settings."""
    if not active:
        return None
    _, bic_all = _fit_state(cache, active, equation, names, blocks, grid_sizes)
    in_use = {effect_key(t.effect) for t in active}
    best: tuple[Term, dict[str, Any]] | None = None
    for out in active:
        others = [t for t in active if t is not out]
        rss_blocks, bic_others = _fit_state(cache, others, equation, names, blocks, grid_sizes)

        def row_of(effect: Effect, refine: bool) -> dict[str, Any]:
            term, _, _ = best_setting(cache, others, effect, equation, names, settings.refine_iterations, refine)
            return _candidate_row(cache, others, term, equation, names, blocks, rss_blocks, rss_none_blocks,
                                  bic_others, grid_sizes, settings)

        # a change of the whole model is exchanged only for another one: a local term in its place would stand
        # in for it in one equation (the surrogates the joint selection exists to avoid)
        allowed = [e for e in pool if effect_key(e) not in in_use
                   and (e.model_wide or not getattr(out.effect, "model_wide", False))]
        rows = sorted((row_of(e, False) for e in allowed), key=lambda r: r["bic"])
        rows = rows[:max(int(settings.refine_candidates), 1)]
        rows = sorted((row_of(r["term"].effect, True) if r["term"].effect.continuous_parameters() else r
                       for r in rows), key=lambda r: r["bic"])
        counts = _effects_per_equation(others)
        calibrated = any(out.effect is p for p in parameters or [])
        for row in rows:
            gain = bic_all - row["bic"]
            if row["within_tolerance"] or gain < settings.min_bic_drop:
                break
            if calibrated and row["term"].effect.kind != "parameter":
                row["parameter_overlap"] = parameter_overlap(cache, row["term"], list(parameters or []), equation,
                                                             names)
                LOGGER.info("exchange %s -> %s: overlap with the parameter errors %.3f", out.effect.name,
                            row["effect"], row["parameter_overlap"])
                if row["parameter_overlap"] > settings.max_parameter_overlap:
                    continue
            if _rejection(row, settings, counts) is None and _would_not_return(
                    cache, others + [row["term"]], out, equation, names, blocks, rss_none_blocks, grid_sizes,
                    settings):
                if best is None or gain > best[1]["bic_gain"]:
                    row["bic_gain"] = gain
                    best = (out, row)
                break
    return best


def _would_not_return(cache, active: list[Term], out: Term, equation: int, names: list[str], blocks: list[Block],
                      rss_none_blocks: list[float], grid_sizes: dict[tuple, int], settings: SelectionSettings) -> bool:
    """Whether the term ``out`` is no longer significant beside ``active`` (after an exchange): its BIC drop as a
    candidate there is below ``min_bic_drop`` (or it is a parameter error within the tolerance). Else the
    newcomer explains only part of what ``out`` does, and both belong to the model (a damping beside a lagging
    load signal): the exchange is refused and ``out`` stays."""
    rss_blocks, bic_active = _fit_state(cache, active, equation, names, blocks, grid_sizes)
    term, _, _ = best_setting(cache, active, out.effect, equation, names, settings.refine_iterations)
    row = _candidate_row(cache, active, term, equation, names, blocks, rss_blocks, rss_none_blocks, bic_active,
                         grid_sizes, settings)
    return row["within_tolerance"] or row["bic_drop"] < settings.min_bic_drop


def _calibration_record(row: dict[str, Any], outcome: str) -> dict[str, Any]:
    return {"effect": row["effect"], "equations": row["equations"], "relative_parameter_error":
            row["relative_parameter_error"], "not_identifiable_with": row.get("not_identifiable_with") or [],
            "bic_drop": row["bic_drop"], "relative_improvement":
            row["relative_improvement"], "explained_share": row["explained_share"],
            "explained_to_noise": row["explained_to_noise"], "outcome": outcome}


def select_equation(cache: DesignCache, equation: int, effects: list[Effect], names: list[str],
                    settings: SelectionSettings, label: str = "", calibrate: list[Effect] | None = None,
                    rivals: bool = False) -> EquationSelection:
    """Stepwise forward selection among ``effects`` (those the cache accepts for ``equation``) on the maneuvers
    ``names``.

    ``cache`` is a :class:`DesignCache` (one equation) or a :class:`hybridfmu.diagnosis.joint.StackedCache`
    (all examined equations, ``equation`` = ``JOINT``). At each step every remaining candidate is fitted with
    those already chosen at its grid settings; the ``refine_candidates`` best by BIC have their continuous
    settings refined. A candidate may enter when it passes every threshold of ``settings``, measured on the
    blocks (equations) it acts on; the one with the lowest BIC among those enters. The selection stops when
    none may; the step records why the best one (lowest BIC, not a parameter error within tolerance) may not.

    ``calibrate``: linear effects (the model's parameter errors) fitted from the start and refitted with every
    candidate, a calibration in equation-error form, so a combination of parameter errors is not named as one
    surrogate effect; after the forward steps each is kept only if it would pass the thresholds entering last
    (:func:`_eliminate`; the outcome per effect in ``EquationSelection.calibration``).

    ``rivals``: also find the candidates the data support beside the final choice (:class:`Rival`, one more pass
    over the candidates).
    """
    effects = [e for e in effects if cache.accepts(e, equation)]
    base = [Term(e, dict(e.grid()[0])) for e in (calibrate or []) if cache.accepts(e, equation)]
    parameters = [t.effect for t in base]
    y = cache.target(equation, names)
    n = len(y)
    blocks = cache.blocks(equation, names)
    noise_var = cache.noise_variance(equation, names)
    active: list[Term] = list(base)
    grid_sizes = {effect_key(e): len(e.grid()) for e in effects + [t.effect for t in base]}
    rss_none = float(y @ y)
    rss_none_blocks = block_rss(y, blocks)
    rss_cur_blocks, bic_cur = _fit_state(cache, active, equation, names, blocks, grid_sizes)
    counts: dict[int, int] = {}
    steps: list[SelectionStep] = []
    limit = settings.max_effects_per_equation * max(len(blocks), 1) + len(base)
    pool = effects + [t.effect for t in base]

    def restate(terms: list[Term]) -> tuple[list[float], float, dict[int, int]]:
        """Residual per block, BIC and chosen (not calibrated) effects per equation of the active ``terms``."""
        rss_blocks, bic_terms = _fit_state(cache, terms, equation, names, blocks, grid_sizes)
        return rss_blocks, bic_terms, _effects_per_equation([t for t in terms if not any(t is b for b in base)])

    def forward() -> None:
        """Forward steps from the active set until no candidate may enter."""
        nonlocal active, rss_cur_blocks, bic_cur, counts
        while len(active) < limit and n > 0:
            rows_info = _candidate_rows(cache, active, pool, equation, names, blocks, rss_cur_blocks,
                                        rss_none_blocks, bic_cur, grid_sizes, settings, counts)
            if not rows_info:
                break
            eligible = [r for r in rows_info if not r["within_tolerance"]]
            record = [{k: v for k, v in r.items() if k not in ("term", "rss_blocks")} for r in rows_info]
            if not eligible:
                steps.append(SelectionStep(candidates=record, chosen=None,
                                           reason="the remaining candidates are parameter errors within the "
                                                  f"tolerance of {settings.parameter_tolerance:g}"))
                break
            passing = [r for r in eligible if r["rejected_because"] is None]
            best = passing[0] if passing else eligible[0]
            reason = "accepted" if passing else eligible[0]["rejected_because"]
            steps.append(SelectionStep(candidates=record, chosen=best["effect"] if passing else None, reason=reason))
            LOGGER.info("selection %s step %d: best %s (rel. improvement %.3f, BIC %.1f -> %.1f): %s",
                        label or equation, len(steps), best["effect"], best["relative_improvement"], bic_cur,
                        best["bic"], reason)
            if not passing:
                break
            active = active + [best["term"]]
            for eq in best["equations"]:
                counts[eq] = counts.get(eq, 0) + 1
            bic_cur, rss_cur_blocks = best["bic"], best["rss_blocks"]

    calibration: dict[tuple, dict[str, Any]] = {}
    for _ in range(int(settings.max_exchange_rounds) + 1):
        forward()
        if base:
            active, calibration = _eliminate(cache, active, base, equation, names, blocks, rss_none_blocks,
                                             grid_sizes, settings, label, calibration)
        exchange = _best_exchange(cache, active, pool, equation, names, blocks, rss_none_blocks, grid_sizes,
                                  settings, parameters) if settings.max_exchange_rounds > 0 else None
        if exchange is None:
            break
        out, row = exchange
        LOGGER.info("selection %s: %s exchanged for %s (BIC %.1f lower)", label or equation, out.effect.name,
                    row["effect"], row["bic_gain"])
        steps.append(SelectionStep(candidates=[{k: v for k, v in row.items() if k not in ("term", "rss_blocks")}],
                                   chosen=row["effect"], reason=f"exchanged for {out.effect.name}",
                                   kind="exchange"))
        active = [t for t in active if t is not out] + [row["term"]]
        if any(t is out for t in base):
            calibration[effect_key(out.effect)] = {
                "effect": out.effect.name, "equations": effect_equations(out.effect), "relative_parameter_error": None,
                "bic_drop": None, "relative_improvement": None, "explained_share": None, "explained_to_noise": None,
                "outcome": f"exchanged for {row['effect']}"}
            base = [t for t in base if t is not out]
        rss_cur_blocks, bic_cur, counts = restate(active)
    for term in active:  # a dropped parameter error that entered again in a forward step
        record = calibration.get(effect_key(term.effect))
        if record is not None and not any(term is b for b in base) and record["outcome"] != "kept":
            record["outcome"] = f"{record['outcome']}; entered again in a forward step"
    active = _polish(cache, active, equation, names, settings)
    fit = fit_terms(cache, active, equation, names)
    for term, coef in zip(active, fit.coefs):
        term.coef = coef
    found = []
    if rivals and active and n > 0:
        rss_cur_blocks, bic_cur, counts = restate(active)
        found = _rivals(cache, active, pool, equation, names, blocks, rss_cur_blocks, rss_none_blocks, bic_cur,
                        grid_sizes, settings, counts)
        for rival in found:
            LOGGER.info("selection %s: %s left out, though it lowers the BIC by %.1f beside the chosen terms (%s)",
                        label or equation, rival.effect, rival.bic_drop, rival.rejected_because or "it would pass")
    return EquationSelection(equation=equation, terms=active, fit=fit, rss_none=rss_none, n=n,
                             noise_variance=noise_var, steps=steps,
                             calibration=[calibration[effect_key(e)] for e in parameters if effect_key(e) in calibration],
                             rivals=found)


def _rivals(cache, active: list[Term], pool: list[Effect], equation: int, names: list[str], blocks: list[Block],
            rss_cur_blocks: list[float], rss_none_blocks: list[float], bic_cur: float, grid_sizes: dict[tuple, int],
            settings: SelectionSettings, counts: dict[int, int]) -> list[Rival]:
    """The :data:`MAX_RIVALS` candidates with the lowest BIC beside the final ``active`` terms among those that lower
    it by at least ``min_bic_drop`` (parameter errors within the tolerance aside), each with the active terms'
    coefficients in the joint fit."""
    found = []
    for row in _candidate_rows(cache, active, pool, equation, names, blocks, rss_cur_blocks, rss_none_blocks,
                               bic_cur, grid_sizes, settings, counts):
        if row["within_tolerance"] or row["bic_drop"] < settings.min_bic_drop:
            continue
        joint = fit_terms(cache, active + [row["term"]], equation, names)
        found.append(Rival(effect=row["effect"], setting=dict(row["term"].setting), bic_drop=float(row["bic_drop"]),
                           rejected_because=row["rejected_because"],
                           coefs=[np.array(c, dtype=float) for c in joint.coefs[:len(active)]],
                           term=Term(row["term"].effect, dict(row["term"].setting),
                                     setting_se=dict(row["term"].setting_se))))
        if len(found) >= MAX_RIVALS:
            break
    return found


def with_adjustment(cache, selection: EquationSelection, rival: Rival, effects: list[Effect], names: list[str],
                    settings: SelectionSettings) -> EquationSelection:
    """``selection`` with ``rival`` fitted beside its terms as an adjustment: a term the data support that is too
    small to be named but whose omission would bias a named estimate (the caller judges that). Every term is
    refitted with it (settings kept), and the rivals are found anew among ``effects`` (the selection's candidates
    and calibrated parameter errors) beside the enlarged set. Returns a new selection; ``selection`` is unchanged."""
    if rival.term is None:
        raise ValueError(f"rival {rival.effect}: no term to fit (rivals are found with their terms)")
    equation = selection.equation
    pool = [e for e in effects if cache.accepts(e, equation)]
    terms = [Term(t.effect, dict(t.setting), setting_se=dict(t.setting_se)) for t in selection.terms]
    terms.append(Term(rival.term.effect, dict(rival.term.setting), setting_se=dict(rival.term.setting_se)))
    fit = fit_terms(cache, terms, equation, names)
    for term, coef in zip(terms, fit.coefs):
        term.coef = coef
    blocks = cache.blocks(equation, names)
    grid_sizes = {effect_key(e): len(e.grid()) for e in pool + [t.effect for t in terms]}
    rss_blocks, bic_now = _fit_state(cache, terms, equation, names, blocks, grid_sizes)
    counts = _effects_per_equation([t for t in terms if t.effect.kind != "parameter"])
    rivals = _rivals(cache, terms, pool, equation, names, blocks, rss_blocks,
                     block_rss(cache.target(equation, names), blocks), bic_now, grid_sizes, settings, counts)
    return EquationSelection(equation=equation, terms=terms, fit=fit, rss_none=selection.rss_none, n=selection.n,
                             noise_variance=selection.noise_variance, steps=selection.steps,
                             calibration=selection.calibration, rivals=rivals,
                             adjustments=selection.adjustments + [rival.effect])


def _polish(cache, active: list[Term], equation: int, names, settings) -> list[Term]:
    """Re-optimise each term's nonlinear setting with the others present (one pass)."""
    if len(active) < 2:
        return active
    polished = list(active)
    for j, term in enumerate(polished):
        if len(term.effect.grid()) <= 1 and not term.effect.continuous:
            continue
        others = polished[:j] + polished[j + 1:]
        new_term, _, _ = best_setting(cache, others, term.effect, equation, names, settings.refine_iterations)
        polished[j] = new_term
    return polished


def drop_one_scores(cache: DesignCache, selection: EquationSelection, names: list[str]) -> dict[str, float]:
    """Increase of the RSS when each chosen term is dropped, in units of the final residual variance, keyed by
    :func:`hybridfmu.diagnosis.joint.effect_key`."""
    scores = {}
    final = selection.fit
    variance = final.rss / max(final.n - sum(len(c) for c in final.coefs), 1)
    for j, term in enumerate(selection.terms):
        others = selection.terms[:j] + selection.terms[j + 1:]
        rss = fit_terms(cache, others, selection.equation, names).rss
        scores[effect_key(term.effect)] = (rss - final.rss) / max(variance, 1e-300)
    return scores


def bootstrap_coefficients(cache: DesignCache, terms: list[Term], equation: int, names: list[str],
                           samples: int, seed: int) -> list[np.ndarray]:
    """Coefficients of ``terms`` refitted on bootstrap resamples of the segments: (samples, n_coef) per term."""
    if not terms or samples <= 0:
        return [np.zeros((0, len(t.coef))) for t in terms]
    groups = cache.groups_of_rows(names)
    unique = np.unique(groups)
    members = {g: np.flatnonzero(groups == g) for g in unique}
    rng = np.random.default_rng(seed)
    draws = [[] for _ in terms]
    for _ in range(samples):
        chosen = rng.choice(unique, size=len(unique), replace=True)
        index = np.concatenate([members[g] for g in chosen])
        # Rows of segments drawn several times count several times (weights = counts).
        counts = np.bincount(index, minlength=len(groups))
        for j, coef in enumerate(_fit_weighted(cache, terms, equation, names, counts)):
            draws[j].append(coef)
    return [np.array(d) for d in draws]


def _fit_weighted(cache: DesignCache, terms: list[Term], equation: int, names, counts: np.ndarray) -> list[np.ndarray]:
    y, design, sizes = stacked_design(cache, terms, equation, names)
    weights = np.sqrt(counts.astype(float))
    if design.shape[1] == 0:
        return [np.zeros(0) for _ in terms]
    coef, *_ = np.linalg.lstsq(design * weights[:, None], y * weights, rcond=None)
    return list(np.split(coef, np.cumsum(sizes)[:-1]))
