"""One selection over all examined equations (hybridfmu.diagnosis.joint): a change of the whole model takes one
value in every equation it acts on, parameter errors are calibrated first and eliminated when they are not
needed, and a term chosen early for a look-alike is exchanged for the one that explains the data."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfmu.diagnosis.effects import Effect, EffectInputs
from hybridfmu.diagnosis.joint import JOINT, JointEffect, StackedCache, joint_candidates
from hybridfmu.diagnosis.selection import terms_in_equation
from hybridfmu.diagnosis.selection import DesignCache, ManeuverFitData, SelectionSettings, select_equation

M = 3000
NOISE = 0.01


class Column(Effect):
    """A test effect: c times one column of the states, in one equation."""

    def __init__(self, name: str, equation: int, column: int, kind: str = "local", model_wide: bool = False):
        super().__init__(name, equation, f"column {column}", "c * x_k")
        self.column, self.kind, self.model_wide = column, kind, model_wide

    def regressors(self, inputs, setting):
        return inputs.x[:, [self.column]]

    def relative_error(self, coef):
        return float(coef[0]) if self.kind == "parameter" else None


def signals(seed: int = 0) -> np.ndarray:
    """(M, 4) independent smooth signals of unit spread."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 30.0, M)
    cols = [sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 6)) for f in rng.uniform(0.2, 3.0, size=3)) for _ in range(4)]
    x = np.stack(cols, axis=1)
    return x / x.std(axis=0)


def caches(x: np.ndarray, truth: list[np.ndarray], noise: list[float], seed: int = 1) -> tuple[DesignCache, StackedCache]:
    """Two examined equations (0, 1) whose errors are ``truth`` (M,) each plus white noise of std ``noise``."""
    centres = np.arange(0, M, 3)
    rng = np.random.default_rng(seed)
    target = np.stack([truth[i][centres] + noise[i] * rng.standard_normal(len(centres)) for i in range(2)]
                      + [np.zeros(len(centres))] * 2, axis=1)
    inputs = EffectInputs(x, np.zeros((M, 1)))
    data = ManeuverFitData(name="m", inputs=inputs, kernel=np.array([1.0]), centres=centres,
                           span_id=np.arange(len(centres)) // 50, target=target,
                           noise_std=np.array(noise + [1.0, 1.0]))
    base = DesignCache([data])
    return base, StackedCache(base, [0, 1])


def parameter(name: str, columns: tuple[int, int]) -> list[Effect]:
    """A parameter error with a sensitivity in each equation (columns of the states)."""
    return [Column(name, eq, col, kind="parameter", model_wide=True) for eq, col in zip((0, 1), columns)]


SETTINGS = SelectionSettings(bootstrap_samples=0)


def test_a_parameter_acting_on_two_equations_is_named_once_with_one_value():
    x = signals()
    r = 0.05
    _, stacked = caches(x, [r * x[:, 0] * 10, r * x[:, 1] * 10], [NOISE, NOISE])
    library = {0: parameter("parameter(p)", (0, 1)) + [Column("local(a)", 0, 0)],
               1: [Column("local(b)", 1, 1)] + [e for e in parameter("parameter(p)", (0, 1)) if e.equation == 1]}
    library[0] = [e for e in library[0] if not (e.kind == "parameter" and e.equation == 1)]
    candidates = joint_candidates(library, [0, 1])
    assert [type(c).__name__ for c in candidates] == ["JointEffect", "Column", "Column"]
    for calibrate in (True, False):
        settings = SelectionSettings(bootstrap_samples=0, calibrate_parameters=calibrate)
        joint = [c for c in candidates if c.kind == "parameter"]
        selection = select_equation(stacked, JOINT, [c for c in candidates if c not in joint] if calibrate
                                    else candidates, ["m"], settings, calibrate=joint if calibrate else None)
        assert [t.effect.name for t in selection.terms] == ["parameter(p)"], calibrate
        assert float(selection.terms[0].coef[0]) == pytest.approx(10 * r, rel=0.01)
    # equation by equation, the same data is two local terms (or a parameter with two values)
    base, _ = caches(x, [r * x[:, 0] * 10, r * x[:, 1] * 10], [NOISE, NOISE])
    per_equation = [select_equation(base, eq, library[eq], ["m"], SETTINGS) for eq in (0, 1)]
    assert all(len(s.terms) == 1 for s in per_equation)


def test_a_calibrated_parameter_that_is_not_needed_is_eliminated_and_the_local_effect_named():
    x = signals()
    _, stacked = caches(x, [np.zeros(M), 0.2 * x[:, 2]], [NOISE, NOISE])
    joint = JointEffect(parameter("parameter(p)", (0, 1)))
    local = Column("local(c)", 1, 2)
    selection = select_equation(stacked, JOINT, [local], ["m"], SETTINGS, calibrate=[joint])
    assert [t.effect.name for t in selection.terms] == ["local(c)"]
    assert float(selection.terms[0].coef[0]) == pytest.approx(0.2, rel=0.02)
    (record,) = selection.calibration
    assert record["effect"] == "parameter(p)" and record["outcome"].startswith("dropped")


def test_a_calibrated_look_alike_is_exchanged_for_the_change_that_explains_the_data():
    """The error is a weak model-wide change E whose signal a parameter's sensitivity P reproduces to 70 %: the
    calibration takes P first, after which E adds too little to enter (the remainder is below the noise
    threshold); the exchange puts E in P's place. Where E is a combination of the parameters' sensitivities
    (reproduced to more than ``max_parameter_overlap``), no data can tell it from them and P stays."""
    x = signals()
    e_signal = x[:, 1] + 0.65 * x[:, 2]
    x = np.column_stack([x[:, 0], x[:, 1], x[:, 2], e_signal])
    c = 0.012
    _, stacked = caches(x, [np.zeros(M), c * e_signal], [NOISE, NOISE])
    p = JointEffect([Column("parameter(p)", 1, 1, kind="parameter", model_wide=True)])
    e = JointEffect([Column("change(e)", 1, 3, kind="input_gain", model_wide=True)])
    no_exchange = select_equation(stacked, JOINT, [e], ["m"], SelectionSettings(bootstrap_samples=0,
                                                                                 max_exchange_rounds=0), calibrate=[p])
    assert [t.effect.name for t in no_exchange.terms] == ["parameter(p)"]
    selection = select_equation(stacked, JOINT, [e], ["m"], SETTINGS, calibrate=[p])
    assert [t.effect.name for t in selection.terms] == ["change(e)"]
    assert float(selection.terms[0].coef[0]) == pytest.approx(c, rel=0.1)
    (exchange,) = [step for step in selection.steps if step.kind == "exchange"]
    assert exchange.chosen == "change(e)" and "parameter(p)" in exchange.reason
    assert exchange.candidates[0]["parameter_overlap"] == pytest.approx(1 / (1 + 0.65 ** 2), abs=0.05)
    assert selection.steps[-1].kind == "forward" and selection.steps[-1].chosen is None  # forward again after it
    assert selection.calibration[-1]["outcome"] == "exchanged for change(e)"
    strict = select_equation(stacked, JOINT, [e], ["m"], SelectionSettings(bootstrap_samples=0,
                                                                           max_parameter_overlap=0.6), calibrate=[p])
    assert [t.effect.name for t in strict.terms] == ["parameter(p)"]


def test_a_model_wide_change_is_not_exchanged_for_a_local_stand_in():
    """A parameter acts on equation 1 (where the data wants it, 0.3) and weakly on equation 0 (where the data
    wants the opposite sign: a disturbance there). A local term with the parameter's column in equation 1 would
    fit better in its place, dropping the disturbance's pull; such an exchange would trade the model-wide
    change for its stand-in in one equation, and is not made."""
    x = signals()
    a = 0.01
    x = np.column_stack([a * x[:, 0], x[:, 1], x[:, 2], x[:, 1]])
    _, stacked = caches(x, [-0.3 * x[:, 0], 0.3 * x[:, 1]], [NOISE, NOISE])
    p = JointEffect(parameter("parameter(p)", (0, 1)))
    local = Column("local(l)", 1, 3)
    selection = select_equation(stacked, JOINT, [local], ["m"], SETTINGS, calibrate=[p])
    assert [t.effect.name for t in selection.terms] == ["parameter(p)"]
    assert not any(s.kind == "exchange" for s in selection.steps)


def test_terms_in_equation_gives_a_joint_term_as_its_member_with_the_same_coefficients():
    x = signals()
    _, stacked = caches(x, [0.5 * x[:, 0], 0.5 * x[:, 1]], [NOISE, NOISE])
    joint = JointEffect(parameter("parameter(p)", (0, 1)))
    selection = select_equation(stacked, JOINT, [joint], ["m"], SelectionSettings(bootstrap_samples=0,
                                                                                  calibrate_parameters=False))
    (term,) = selection.terms
    for eq in (0, 1):
        (member,) = terms_in_equation(selection.terms, eq)
        assert member.effect.equation == eq and np.array_equal(member.coef, term.coef)
    assert terms_in_equation(selection.terms, 2) == []


def test_a_level_the_state_cannot_pass_is_found_with_its_level():
    """Limit: the measured state stops at a level (an overflow); the model keeps rising there. The equation error
    is minus the model's positive derivative at and above the level; the fitted level and stop fraction match."""
    from diagnosis_models import msd_problem
    from hybridfmu.diagnosis.library import Limit

    t = np.linspace(0.0, 60.0, M)
    v = 1.2 * np.sin(2 * np.pi * 0.05 * t) + 0.3 * np.sin(2 * np.pi * 0.31 * t)
    v = np.minimum(v, 1.0)  # the measured level never passes 1.0
    f = 0.8 * np.cos(2 * np.pi * 0.05 * t) + 0.5 * np.sin(2 * np.pi * 0.17 * t)  # the model's derivative
    x = np.column_stack([np.cumsum(v) * (t[1] - t[0]), v])
    inputs = EffectInputs(x, np.zeros((M, 1)), f=np.column_stack([v, f]))
    truth = -np.where(v >= 1.0, np.maximum(f, 0.0), 0.0)
    centres = np.arange(0, M, 2)
    rng = np.random.default_rng(4)
    target = np.column_stack([np.zeros(len(centres)), truth[centres] + NOISE * rng.standard_normal(len(centres))])
    cache = DesignCache([ManeuverFitData("m", inputs, np.array([1.0]), centres, np.arange(len(centres)) // 50,
                                         target, np.array([1.0, NOISE]))])
    problem, _ = msd_problem()
    problem.quantiles = {"x": np.quantile(x[:, 0], np.linspace(0, 1, 101)),
                         "v": np.quantile(v, np.linspace(0, 1, 101))}
    options = {"limit_quantiles": [0.8, 0.9, 0.95, 0.98, 0.99]}
    above, below = Limit(problem, 1, "above", options), Limit(problem, 1, "below", options)
    selection = select_equation(cache, 1, [below, above], ["m"], SETTINGS)
    (term,) = selection.terms
    assert term.effect.name == "limit_above(v)"
    report = {p["name"]: p["value"] for p in above.physical(term.coef, selection.fit.cov, term.setting, {})}
    assert report["stop_fraction"] == pytest.approx(1.0, abs=0.03)
    assert report["level"] == pytest.approx(1.0, abs=0.02)
    assert len(below.grid()) == 5 and all(g["level"] < 0 for g in below.grid())


def test_an_exchange_is_refused_when_the_replaced_term_would_enter_again():
    """A candidate G that mixes two parameters' sensitivities (x1 + x2) can lower the BIC in the place of one of
    them, yet the replaced parameter still explains what G cannot: it is still significant beside G, so G only
    stands in for part of it. Where the data is G itself, the parameter has nothing left to explain and the
    exchange stands."""
    from hybridfmu.diagnosis.joint import Block
    from hybridfmu.diagnosis.selection import Term, _would_not_return

    x = signals()
    g_signal = x[:, 1] + x[:, 2]
    x = np.column_stack([x[:, 0], x[:, 1], x[:, 2], g_signal])
    p = JointEffect([Column("parameter(p)", 1, 1, kind="parameter", model_wide=True)])
    g = JointEffect([Column("gain(g)", 1, 3, kind="input_gain", model_wide=True)])
    # third: the parameter's own share is below the practical thresholds (0.36 noise variances) but significant:
    # both belong to the model, and the exchange is refused
    for truth, returns in ((0.3 * x[:, 1] + 0.1 * x[:, 2], True), (0.2 * g_signal, False),
                           (0.2 * g_signal + 0.006 * x[:, 1], True)):
        _, stacked = caches(x, [np.zeros(M), truth], [NOISE, NOISE])
        blocks = stacked.blocks(JOINT, ["m"])
        assert all(isinstance(b, Block) for b in blocks)
        y = stacked.target(JOINT, ["m"])
        rss_none = [float(y[b.rows] @ y[b.rows]) for b in blocks]
        sizes = {("parameter(p)", JOINT): 1, ("gain(g)", JOINT): 1}
        assert _would_not_return(stacked, [Term(g, {})], Term(p, {}), JOINT, ["m"], blocks, rss_none, sizes,
                                 SETTINGS) is (not returns)
