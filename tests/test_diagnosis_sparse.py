"""SINDy's thresholded least squares over candidate features (the forward selection's comparison)."""

import numpy as np

from hybridfmu.diagnosis.effects import Effect
from hybridfmu.diagnosis.selection import Term
from hybridfmu.diagnosis.sparse import Features, stlsq_select


class _Named(Effect):
    def __init__(self, name: str, width: int):
        super().__init__(name, 0, name, name)
        self.width = width

    def coefficient_names(self, setting):
        return [f"c{k}" for k in range(self.width)]


def _features(seed: int = 0) -> tuple[Features, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = 2000
    design = rng.standard_normal((n, 5))
    design[:, 4] = design[:, 1] + 0.3 * rng.standard_normal(n)  # a look-alike of a column of effect a
    true = np.array([0.0, 0.8, -0.5, 0.0, 0.0])  # effect a (columns 1, 2) only
    target = design @ true + rng.standard_normal(n)  # unit noise: rows in noise-floor units
    terms = [Term(_Named("p", 1), {}), Term(_Named("a", 2), {}), Term(_Named("b", 1), {}), Term(_Named("c", 1), {})]
    return Features(terms=terms, design=design, target=target, owner=np.array([0, 1, 1, 2, 3])), true


def test_stlsq_names_the_effect_with_a_surviving_coefficient_and_returns_its_coefficients():
    features, true = _features()
    fit = stlsq_select(features, threshold=10.0)
    assert [t.effect.name for t in fit.terms] == ["a"]
    assert np.allclose(fit.terms[0].coef, true[1:3], atol=0.1)


def test_stlsq_names_nothing_above_every_coefficient_and_everything_at_zero():
    features, _ = _features()
    assert stlsq_select(features, threshold=1e4).terms == []
    assert len(stlsq_select(features, threshold=0.0).terms) == 4
