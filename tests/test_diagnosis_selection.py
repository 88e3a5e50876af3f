"""The diagnosis names a known effect added to a small model's derivatives, and nothing when none is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diagnosis_models import MassSpringDamper, msd_maneuvers, msd_problem
from hybridfmu.diagnosis.report import verdict
from hybridfmu.diagnosis.run import run_diagnosis


def _extra(func):
    """An additive term in the velocity equation: (N, 2) rows -> (N, 2)."""
    return lambda x, u: np.stack([np.zeros(len(x)), func(x, u)], axis=1)


def _names(result):
    return [c["effect"] for c in result.which.chosen]


def _param(result, name):
    return {p["name"]: p["value"] for p in result.which.chosen[0]["parameters"]}[name]


CASES = {
    "viscous": (_extra(lambda x, u: -0.3 * x[:, 1]), {"parameters": ["m"]}, "viscous(v)",
                ("coefficient", 0.3)),
    "coulomb": (_extra(lambda x, u: -0.4 * np.tanh(x[:, 1] / 0.005)), {}, "coulomb(v)", ("coulomb_level", 0.4)),
    "periodic": (_extra(lambda x, u: 0.6 * np.sin(2 * math.pi * 3 * x[:, 0] / 1.0)),
                 {"periodic": {"x": 1.0}, "effects": {"periodic_max_order": 5}}, "periodic(x)", ("order", 3)),
    # the orders found in the data (periodic_max_order at its default, null)
    "periodic_searched": (_extra(lambda x, u: 0.6 * np.sin(2 * math.pi * 3 * x[:, 0] / 1.0)),
                          {"periodic": {"x": 1.0}}, "periodic(x)", ("order", 3)),
    "saturation": (_extra(lambda x, u: 3.0 * np.maximum(x[:, 0] - 0.3, 0.0)), {"parameters": ["m"]},
                   "saturation_above(x)", ("threshold", 0.3)),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_known_effect_is_named_alone_with_its_parameter(case):
    extra, diagnosis, name, (parameter, value) = CASES[case]
    problem, model = msd_problem(**diagnosis)
    result = run_diagnosis(problem, model, msd_maneuvers(extra, duration_s=20.0), open_loop=False)
    assert _names(result) == [name]
    assert _param(result, parameter) == pytest.approx(value, rel=0.1, abs=0.02)
    assert result.which.chosen[0]["equation"] == "v"
    assert result.where["carrier"] == "v"


def test_a_parameter_error_is_named_with_its_relative_size():
    problem, model = msd_problem()
    measured = msd_maneuvers(None, duration_s=20.0, truth_model=MassSpringDamper(m=1.1))
    result = run_diagnosis(problem, model, measured, open_loop=False)
    assert _names(result) == ["parameter(m)"]
    # f_true = f / 1.1: the first-order fit finds -0.091 of p df/dp, which the model's own response to a mass
    # error reads as the 10 % it is
    assert _param(result, "relative_error") == pytest.approx(0.1, rel=0.02)


def test_an_input_time_offset_is_named_with_its_size():
    problem, model = msd_problem(parameters=[])
    measured = msd_maneuvers(None, duration_s=20.0, input_delay_s=0.03)
    result = run_diagnosis(problem, model, measured, open_loop=False)
    assert _names(result) == ["time_offset(F)"]
    assert _param(result, "offset_s") == pytest.approx(0.03, rel=0.01)  # measured 0.0300007 s


def test_nothing_is_named_when_the_model_is_right():
    problem, model = msd_problem()
    result = run_diagnosis(problem, model, msd_maneuvers(None, noise=(2e-4, 2e-3), duration_s=20.0))
    assert _names(result) == []
    assert result.where["states"]["v"]["ratio_to_noise"] < 1.5
    assert result.how_far.shrink_factor == pytest.approx(1.0)


def test_how_far_shrinks_the_open_loop_gap_on_the_test_maneuver():
    extra = _extra(lambda x, u: -0.4 * np.tanh(x[:, 1] / 0.005))
    problem, model = msd_problem()
    result = run_diagnosis(problem, model, msd_maneuvers(extra, duration_s=20.0))
    far = result.how_far
    assert [s["model"] for s in far.steps] == ["FMU", "+ coulomb(v) (dv/dt)"]
    for key in ("position_rmse", "position_mae", "velocity_rmse", "velocity_mae"):
        assert far.after[key] < 0.1 * far.before[key]
    assert far.shrink_factor > 10


def test_how_far_attributes_the_shrink_to_the_parameter_corrections_and_to_the_effects():
    """A mass error and a Coulomb friction: the held-out shrink splits into the corrected mass's part (the model with
    only parameter(m)) and the friction's part on top of it; their product is the whole shrink."""
    extra = _extra(lambda x, u: -0.4 * np.tanh(x[:, 1] / 0.005))
    problem, model = msd_problem(open_loop={"window_s": 1.0})
    result = run_diagnosis(problem, model, msd_maneuvers(extra, duration_s=20.0, truth_model=MassSpringDamper(m=1.1)))
    far = result.how_far
    assert sorted(_names(result)) == ["coulomb(v)", "parameter(m)"]
    only = far.parameters_only
    assert only["effects"] == ["parameter(m)"] and only["model"] == "parameter corrections only"
    assert far.parameter_shrink_factor * far.effect_shrink_factor == pytest.approx(far.shrink_factor)
    assert far.window_parameter_shrink_factor * far.window_effect_shrink_factor == pytest.approx(
        far.window_gap_before / far.window_gap_after)
    assert far.effect_shrink_factor > 3  # the friction, not the mass, closes most of the gap
    from hybridfmu.diagnosis.report import attribution_sentence, held_out_record
    assert "only its parameter errors corrected (parameter(m))" in attribution_sentence(held_out_record(far))
    assert "the effects beyond the parameter corrections ×" in verdict(result)


def test_with_nothing_but_parameter_errors_the_effects_add_nothing():
    problem, model = msd_problem()
    result = run_diagnosis(problem, model, msd_maneuvers(None, duration_s=20.0, truth_model=MassSpringDamper(m=1.1)))
    far = result.how_far
    assert _names(result) == ["parameter(m)"]
    assert far.effect_shrink_factor == 1.0 and far.parameter_shrink_factor == pytest.approx(far.shrink_factor)


def test_unmeasured_states_come_from_the_simulation_and_are_reported():
    """Velocity unmeasured: the position equation dx/dt = v depends on it; a force gain error in the
    velocity equation then shows in the position equation only through the simulated velocity."""
    from dataclasses import replace

    from diagnosis_models import msd_roles
    from hybridfmu.diagnosis.problem import build_problem, diagnosis_settings

    roles = msd_roles()
    roles = replace(roles, states={"x": "position"}, target_weights={"x": 1.0})
    model = MassSpringDamper()
    settings = diagnosis_settings({"diagnosis": {"kernel_s": 0.09, "selection": {"bootstrap_samples": 0}}})
    problem = build_problem(roles, model, settings, model.get_parameters())
    measured = msd_maneuvers(None, duration_s=10.0)
    for m in measured.values():
        m.x[:, 1] = np.nan
        m.x0_unmeasured = {"v": 0.0}
    result = run_diagnosis(problem, model, measured, open_loop=False)
    assert problem.unmeasured == [1] and problem.equations == [0]
    assert result.where["states"]["x"]["depends_on_unmeasured"] == ["v"]
    assert np.all(np.isfinite(result.prepared["train"].measured.x[:, 1]))
    assert _names(result) == []


def test_waterfall_bars_say_whether_each_step_helped():
    from hybridfmu.diagnosis.figures import FMU_COLOUR, HELPED_COLOUR, HURT_COLOUR, step_colours

    assert step_colours([0.5, 0.1, 0.2, 0.2, float("nan"), 0.05]) == [
        FMU_COLOUR, HELPED_COLOUR, HURT_COLOUR, HELPED_COLOUR, HURT_COLOUR, HELPED_COLOUR]


def test_a_parameter_error_the_data_cannot_tell_from_another_is_named_not_identifiable():
    """Two parameters that enter the equations only as a product have proportional sensitivities: the one fitted
    beside the other is reported as not identifiable with these data, not with a relative error; a parameter
    whose sensitivity differs is identifiable."""
    from types import SimpleNamespace

    from hybridfmu.diagnosis.selection import COLLINEAR_SHARE, Term, collinearity

    rng = np.random.default_rng(0)
    x, u = rng.normal(size=500), rng.normal(size=500)
    columns = {"a": -2.0 * x, "b": -3.0 * x, "c": u}  # f = -a b x + c u: d/da = -b x, d/db = -a x, d/dc = u

    class Cache:
        def target(self, equation, names):
            return -6.0 * x + u

        def design(self, effect, setting, names):
            return columns[effect.name][:, None]

    def term(name):
        return Term(SimpleNamespace(name=name), {}, np.zeros(1))

    share, carried = collinearity(Cache(), [term("a"), term("c")], term("b"), 0, ["m"])
    assert share < COLLINEAR_SHARE and carried == ["a"]
    share, carried = collinearity(Cache(), [term("a")], term("c"), 0, ["m"])
    assert share > 0.5


def test_effect_sizes_are_given_in_the_unit_the_configured_scale_makes():
    """diagnosis.report_scale: a Coulomb level in (m/s)/s times the moving mass is a force in N, a viscous
    coefficient in 1/s a damping in N*s/m; a size without a unit pint reads, or without a scale, has none."""
    from hybridfmu.diagnosis.report import scaled_size

    assert scaled_size(0.8, "(m/s)/s", "1.2 kg") == "0.96 N"
    assert scaled_size(0.5, "1/s", "1.2 kg") == "0.6 N·s/m"
    assert scaled_size(2.0, "rad/s**2", "2.5e-4 kg*m**2") == "0.0005 m·N"
    assert scaled_size(0.5, "(m/s)/s per power of the state", "1 kg") == "-"
    assert scaled_size(0.5, "1/s", None) == "-"


def _viscous_with_a_small_coulomb():
    """Viscous friction with a Coulomb friction too small to be named (it explains 0.8 % of the initial residual,
    below the 5 % asked for here) but plain in the data."""
    def extra(x, u):
        return np.stack([np.zeros(len(x)), -0.3 * x[:, 1] - 0.05 * np.tanh(x[:, 1] / 0.005)], axis=1)

    problem, model = msd_problem(parameters=["m"], candidates=["viscous(*)", "coulomb(*)", "parameter(*)"],
                                 selection={"bootstrap_samples": 20, "min_share_of_initial": 0.05})
    return problem, model, msd_maneuvers(extra, duration_s=20.0)


def test_an_estimate_that_rests_on_a_term_left_out_names_it_and_reaches_its_value(monkeypatch):
    """With no adjustment allowed: the viscous coefficient fitted alone absorbs the Coulomb part; fitted with it
    beside, it is the truth. The diagnosis names the rival and widens the interval to it."""
    import hybridfmu.diagnosis.run as run

    monkeypatch.setattr(run, "MAX_ADJUSTMENTS", 0)
    problem, model, measured = _viscous_with_a_small_coulomb()
    result = run_diagnosis(problem, model, measured, open_loop=False)
    assert _names(result) == ["viscous(v)"]
    alone = _param(result, "coefficient")
    assert alone > 0.31                                       # biased by the Coulomb part
    rivals = result.which.chosen[0]["rivals"]
    assert [r["effect"] for r in rivals] == ["coulomb(v)"]
    beside = rivals[0]["values"]["coefficient"]
    assert beside == pytest.approx(0.3, rel=0.02)
    low, high = result.which.chosen[0]["parameters"][0]["interval_90"]
    assert low <= beside + 1e-12 and high >= alone
    assert "with coulomb(v) beside it coefficient" in verdict(result)

    # without the rival in the data, none is named and the interval is the regression's own
    plain = run_diagnosis(problem, model, msd_maneuvers(_extra(lambda x, u: -0.3 * x[:, 1]), duration_s=20.0),
                          open_loop=False)
    assert _names(plain) == ["viscous(v)"] and plain.which.chosen[0]["rivals"] == []


def test_a_rival_that_moves_a_named_estimate_is_fitted_beside_it_as_an_adjustment():
    """The same data with adjustments (the default): the Coulomb friction is fitted beside the viscous one, not
    named; the viscous coefficient is the truth, and the verdict says what was fitted beside it."""
    problem, model, measured = _viscous_with_a_small_coulomb()
    result = run_diagnosis(problem, model, measured, open_loop=False)
    assert result.which.found_effects == ["viscous(v)"] and result.which.adjustments == ["coulomb(v)"]
    by_name = {c["effect"]: c for c in result.which.chosen}
    assert by_name["viscous(v)"]["role"] == "finding" and by_name["coulomb(v)"]["role"] == "adjustment"
    coefficient = {p["name"]: p["value"] for p in by_name["viscous(v)"]["parameters"]}["coefficient"]
    assert coefficient == pytest.approx(0.3, rel=0.02)
    assert by_name["viscous(v)"]["rivals"] == []
    text = verdict(result)
    assert "Unmodelled effects named (rank order): 1. viscous(v)" in text
    assert "Fitted beside them, not named" in text and "coulomb(v)" in text.split("Fitted beside them")[1]
