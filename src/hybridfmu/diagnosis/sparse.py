"""Sparse regression over the candidate library: SINDy's sequentially thresholded least squares (pysindy's
``STLSQ``), the alternative to the forward selection with BIC that ``benchmarks/sparse_selection.py`` compares
side by side on the withheld-effect suite.

Features: every candidate effect (model-wide ones joined over their equations) at the nonlinear setting it
takes when fitted alone beside the calibrated parameter errors (:func:`hybridfmu.diagnosis.selection.best_setting`:
grid, then refined), and every parameter error, stacked over the examined equations with each row divided by
its maneuver's noise floor (:class:`hybridfmu.diagnosis.joint.StackedCache`). The columns are normalised to
unit length, so the threshold is in noise-floor units: a coefficient below it would explain less than its
square in noise variances. An effect is named when any of its coefficients survives the thresholding.

API::

    candidate_features(stacked, candidates, calibrate, names, iterations) -> Features
    stlsq_select(features, threshold, alpha=1e-6) -> SparseFit
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybridfmu.diagnosis.joint import JOINT, StackedCache
from hybridfmu.diagnosis.selection import Term, best_setting


@dataclass
class Features:
    """The sparse regression's inputs.

    Attributes:
        terms: one term per candidate (its setting fitted alone), parameter errors first.
        design: (n_rows, n_columns) weighted regressors of all terms side by side.
        target: (n_rows,) weighted equation errors.
        owner: (n_columns,) index into ``terms`` of each column.
    """

    terms: list[Term]
    design: np.ndarray
    target: np.ndarray
    owner: np.ndarray


@dataclass
class SparseFit:
    """Result of :func:`stlsq_select`: the named ``terms`` (with their coefficients) and the threshold."""

    terms: list[Term]
    threshold: float


def candidate_features(stacked: StackedCache, candidates: list, calibrate: list, names: list[str],
                       iterations: int) -> Features:
    """Columns of every parameter error (``calibrate``) and every candidate at its best setting fitted alone
    beside the parameter errors, on the maneuvers ``names``."""
    base = [Term(e, dict(e.grid()[0])) for e in calibrate]
    terms = list(base)
    for effect in candidates:
        term, _, _ = best_setting(stacked, base, effect, JOINT, names, iterations)
        terms.append(term)
    columns, owner = [], []
    for k, term in enumerate(terms):
        block = stacked.design(term.effect, term.setting, names)
        columns.append(block)
        owner += [k] * block.shape[1]
    target = stacked.target(JOINT, names)
    design = np.concatenate(columns, axis=1) if columns else np.zeros((len(target), 0))
    return Features(terms=terms, design=design, target=target, owner=np.array(owner, dtype=int))


def stlsq_select(features: Features, threshold: float, alpha: float = 1e-6) -> SparseFit:
    """Sequentially thresholded least squares on unit-length columns (``threshold`` in noise-floor units,
    ``alpha`` the ridge weight); the terms with a surviving coefficient, coefficients in the columns' units."""
    import pysindy as ps

    design = np.nan_to_num(features.design)
    norms = np.linalg.norm(design, axis=0)
    usable = norms > 0
    scaled = design[:, usable] / norms[usable]
    optimizer = ps.STLSQ(threshold=float(threshold), alpha=float(alpha), normalize_columns=False, max_iter=50)
    optimizer.fit(scaled, features.target)
    coef = np.zeros(design.shape[1])
    coef[usable] = np.asarray(optimizer.coef_).reshape(-1) / norms[usable]
    named = []
    for k, term in enumerate(features.terms):
        values = coef[features.owner == k]
        if np.any(values != 0.0):
            named.append(Term(term.effect, dict(term.setting), np.array(values, dtype=float), dict(term.setting_se)))
    return SparseFit(terms=named, threshold=float(threshold))
