"""An unmeasured state that overflows into a measured one: named from the data, recalibrated by output error.

Two tanks in cascade (Torricelli outflows), only the lower level measured; the 'real' upper tank
overflows at a level and half of what spills reaches the lower tank. The model lacks the overflow.
"""

from __future__ import annotations

import numpy as np
import pytest

from hybridfmu.data.roles import CaseRoles, Signal
from hybridfmu.diagnosis.corrected_model import rk4_simulate
from hybridfmu.diagnosis.library import Overflow
from hybridfmu.diagnosis.prepare import MeasuredManeuver, fill_unmeasured
from hybridfmu.diagnosis.problem import build_problem, diagnosis_settings, set_data_statistics
from hybridfmu.diagnosis.refit import RefitSpec, refit_terms
from hybridfmu.diagnosis.run import run_diagnosis
from hybridfmu.diagnosis.selection import Term
from diagnosis_models import ParameterStore, simulate_truth

TRUE_LEVEL = 12.0     # upper level where the real tank overflows
TRUE_SHARE = 0.5      # share of the overflow that reaches the lower tank


class TwoTanks(ParameterStore):
    """dx1/dt = -k1 sqrt(x1) + k4 u, dx2/dt = k2 sqrt(x1) - k3 sqrt(x2); states (V), input u (V)."""

    state_names = ["x1", "x2"]
    input_names = ["u"]
    parameter_names = ["k1", "k2", "k3", "k4"]

    def __init__(self, **values):
        self.values = {"k1": 0.05, "k2": 0.05, "k3": 0.05, "k4": 0.06, **values}

    def derivatives(self, x, u=None):
        x = np.atleast_2d(np.asarray(x, dtype=float))
        u = np.atleast_2d(np.asarray(u, dtype=float)).reshape(len(x), -1)
        v = self.values
        r1, r2 = np.sqrt(np.maximum(x[:, 0], 0.0)), np.sqrt(np.maximum(x[:, 1], 0.0))
        return np.stack([-v["k1"] * r1 + v["k4"] * u[:, 0], v["k2"] * r1 - v["k3"] * r2], axis=1)

    def jacobians(self, x, u=None):
        x = np.atleast_2d(np.asarray(x, dtype=float))
        v = self.values
        h1 = 0.5 / np.sqrt(np.maximum(x[:, 0], 1e-6))
        h2 = 0.5 / np.sqrt(np.maximum(x[:, 1], 1e-6))
        dfdx = np.zeros((len(x), 2, 2))
        dfdx[:, 0, 0] = -v["k1"] * h1
        dfdx[:, 1, 0] = v["k2"] * h1
        dfdx[:, 1, 1] = -v["k3"] * h2
        dfdu = np.zeros((len(x), 2, 1))
        dfdu[:, 0, 0] = v["k4"]
        return dfdx, dfdu


def overflow_truth(model: TwoTanks):
    """The real system's extra rates: the upper tank cannot pass TRUE_LEVEL, TRUE_SHARE of the spill arrives below."""
    def extra(x, u):
        f = model.derivatives(x, u)
        spill = np.where(x[:, 0] >= TRUE_LEVEL, np.maximum(f[:, 0], 0.0), 0.0)
        return np.stack([-spill, TRUE_SHARE * spill], axis=1)
    return extra


def tank_roles() -> CaseRoles:
    signals = {"level": Signal("level", "V", "V", "lower level"), "pump": Signal("pump", "V", "V", "pump voltage")}
    return CaseRoles(signals=signals, transforms=[], state_names=["x1", "x2"], input_names=["u"],
                     inputs={"u": "pump"}, states={"x2": "level"}, target_weights={"x2": 1.0})


def tank_maneuvers(overflow: bool, duration_s: float = 3000.0, dt: float = 2.0) -> dict[str, MeasuredManeuver]:
    """Train, validation, test: pump steps (held 60-200 s) that fill the upper tank past the level now and then."""
    model = TwoTanks()
    extra = overflow_truth(model) if overflow else None
    time_s = np.arange(0.0, duration_s, dt)
    out = {}
    for seed, role in enumerate(("train", "validation", "test")):
        rng = np.random.default_rng(seed)
        levels, u = [], []
        while len(u) < len(time_s):
            hold = int(rng.uniform(60.0, 200.0) / dt)
            u += [rng.uniform(0.5, 4.5)] * hold
        u = np.array(u[:len(time_s)])[:, None]
        x = simulate_truth(model, extra, time_s, u, [4.0, 4.0])
        x[:, 1] += np.random.default_rng(10 + seed).standard_normal(len(time_s)) * 0.005
        measured = np.array(x)
        measured[:, 0] = np.nan
        out[role] = MeasuredManeuver(name=role, role=role, time_s=time_s, x=measured, u=u,
                                     spans_s=[[0.0, float(time_s[-1])]], x0_unmeasured={"x1": 4.0})
    return out


def tank_problem(model: TwoTanks):
    settings = diagnosis_settings({"seed": 5, "diagnosis": {"kernel_s": 20.0, "selection": {"bootstrap_samples": 10},
                                                            "open_loop": {"window_s": 400.0}}})
    return build_problem(tank_roles(), model, settings, model.get_parameters())


def test_overflow_of_an_unmeasured_state_is_named_first_and_its_share_and_level_found():
    model, helper = TwoTanks(), TwoTanks()
    problem = tank_problem(model)
    result = run_diagnosis(problem, model, tank_maneuvers(overflow=True), helper=helper)
    named = [c for c in result.which.chosen if c["kind"] != "parameter"]
    assert named and named[0]["effect"] == "overflow(x1->x2)", [c["effect"] for c in result.which.chosen]
    values = {p["name"]: p["value"] for p in named[0]["parameters"]}
    assert values["share"] == pytest.approx(TRUE_SHARE, abs=0.15)
    assert values["level"] == pytest.approx(TRUE_LEVEL, rel=0.15)
    far = result.how_far
    assert far.after["level_rmse"] < 0.5 * far.before["level_rmse"]


def test_no_overflow_in_the_data_names_none():
    model, helper = TwoTanks(), TwoTanks()
    problem = tank_problem(model)
    result = run_diagnosis(problem, model, tank_maneuvers(overflow=False), helper=helper, open_loop=False)
    assert [c["effect"] for c in result.which.chosen] == []


def miscalibrated_tanks():
    """(model, helper, problem, train maneuver) of the overflowing tanks with k2 and k3 off by +20 % (what a
    calibration without the overflow does), the train maneuver's unmeasured level from that model."""
    measured = tank_maneuvers(overflow=True)
    model, helper = TwoTanks(k2=0.06, k3=0.06), TwoTanks(k2=0.06, k3=0.06)
    problem = tank_problem(model)
    train = measured["train"]
    fill_unmeasured(train, problem, model, rk4_simulate)
    set_data_statistics(problem, [train.x], 2.0)
    return model, helper, problem, train


def test_refit_recovers_a_parameter_absorbed_by_the_calibration_and_the_overflow_share():
    """Start: k2 and k3 off by +20 % (what a calibration without the overflow does), the overflow at the
    wrong share and level; the output-error refit of k2, k3 and the effect restores them."""
    model, helper, problem, train = miscalibrated_tanks()
    term = Term(Overflow(problem, 1, 0, {"overflow_quantiles": [0.5, 0.9]}), {"level": 13.0}, np.array([1.0, 0.3]))
    spec = RefitSpec(parameter_bounds={"k2": (0.01, 0.2), "k3": (0.01, 0.2)}, max_evaluations=100)
    fitted = refit_terms(model, helper, rk4_simulate, [train], [term], problem, spec)
    assert fitted.cost < 0.05 * fitted.cost_start
    assert fitted.parameters["k2"] == pytest.approx(0.05, rel=0.05)
    assert fitted.parameters["k3"] == pytest.approx(0.05, rel=0.05)
    assert fitted.terms[0].coef[1] == pytest.approx(TRUE_SHARE, abs=0.05)
    assert fitted.terms[0].setting["level"] == pytest.approx(TRUE_LEVEL, rel=0.05)
    assert model.get_parameters(["k2"]) == {"k2": 0.06}  # restored after the fit


def test_a_variant_never_ends_above_the_variant_before_it():
    """The recalibrating check refits each variant from the one before. An additive effect with a poor start and a
    fit cut short at its first simulation still ends no higher than the model alone (its start at zero is the
    model alone at its optimum); an overflow, which acts at any coefficients, is flagged when it ends above."""
    from hybridfmu.diagnosis.library import Viscous

    model, helper, problem, train = miscalibrated_tanks()
    spec = RefitSpec(parameter_bounds={"k2": (0.01, 0.2), "k3": (0.01, 0.2)}, max_evaluations=30)
    alone = refit_terms(model, helper, rk4_simulate, [train], [], problem, spec)
    short = RefitSpec(parameter_bounds=spec.parameter_bounds, max_evaluations=1)
    poor = Term(Viscous(problem, 1, 1), {}, np.array([0.5]))  # a strong damping of the lower level
    cold = refit_terms(model, helper, rk4_simulate, [train], [poor], problem, short)
    warm = refit_terms(model, helper, rk4_simulate, [train], [poor], problem, short, previous=alone)
    assert cold.cost > alone.cost  # from its own start alone, the variant ends worse than the model alone
    assert warm.cost <= alone.cost * (1 + 1e-9) and not warm.above_previous
    overflow = Term(Overflow(problem, 1, 0, {"overflow_quantiles": [0.5, 0.9]}), {"level": 2.0}, np.array([1.0, 1.0]))
    flagged = refit_terms(model, helper, rk4_simulate, [train], [overflow], problem, short, previous=alone)
    assert flagged.above_previous == (flagged.cost > alone.cost * (1 + 1e-9))
