"""The effect library over roles: names, regressors, the forms used in the corrected simulation,
config errors, and the motor plugin loaded only when configured."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from diagnosis_models import MassSpringDamper, msd_maneuvers, msd_problem
from hybridfmu.config import ConfigError
from hybridfmu.diagnosis.corrected_model import CorrectedModel
from hybridfmu.diagnosis.library import build_library
from hybridfmu.diagnosis.prepare import prepare_maneuver
from hybridfmu.diagnosis.problem import set_data_statistics
from hybridfmu.diagnosis.selection import Term


@pytest.fixture(scope="module")
def library():
    problem, model = msd_problem(equations=["x", "v"], periodic={"x": 1.0}, effects={"periodic_max_order": 12})
    measured = msd_maneuvers(None, duration_s=5.0)
    set_data_statistics(problem, [measured["train"].x], 0.01)
    prepared = prepare_maneuver(measured["train"], model, problem)
    effects, skipped = build_library(problem, prepared.inputs, model)
    return problem, model, prepared, effects, skipped


def test_names_carry_their_variables_and_input_effects_need_a_sensitivity(library):
    problem, _, _, effects, skipped = library
    names_v = {e.name for e in effects[1]}
    assert {"viscous(v)", "viscous(x)", "coulomb(v)", "periodic(x)", "saturation_above(x)", "input_gain(F)",
            "time_offset(F)", "parameter(m)", "parameter(k)", "parameter(c)", "coulomb(v)*|F|"} <= names_v
    names_x = {e.name for e in effects[0]}
    assert "input_gain(F)" not in names_x and "parameter(m)" not in names_x  # dx/dt = v depends on neither
    assert "periodic(v)" not in names_v  # only the states of diagnosis.periodic
    assert any("input effects of F in dx/dt" in k for k in skipped)


def test_parameter_sensitivity_matches_the_analytic_derivative(library):
    _, model, prepared, _, _ = library
    sens = prepared.inputs.sensitivity("c")
    np.testing.assert_allclose(sens[:, 1], -0.4 * prepared.inputs.x[:, 1] / 1.0, rtol=1e-5, atol=1e-9)
    assert model.get_parameters(["c"])["c"] == 0.4  # restored


def test_row_functions_equal_the_regressors(library):
    """The plain-float form used in the simulation equals the fitted regressors times the coefficients."""
    problem, _, prepared, effects, _ = library
    inputs = prepared.inputs
    rows = np.arange(0, inputs.n, 37)
    checked = 0
    for effect in effects[1]:
        grid = effect.grid()
        for setting in (grid[0], grid[len(grid) // 2], grid[-1]):  # e.g. with and without a Stribeck term
            coef = np.linspace(0.5, 1.5, len(effect.coefficient_names(setting)))
            func = effect.row_function(coef, setting)
            if func is None:
                continue
            states = inputs.x if effect.kind in ("viscous", "periodic") else inputs.x_smooth
            values = [func(states[r].tolist(), inputs.u[r].tolist()) for r in rows]
            np.testing.assert_allclose(values, effect.regressors(inputs, setting)[rows] @ coef, rtol=1e-9,
                                       atol=1e-12, err_msg=f"{effect.name} at {setting}")
            checked += 1
    assert checked >= 30


def test_corrected_model_applies_each_kind_of_change(library):
    problem, _, _, effects, _ = library
    by_name = {e.name: e for e in effects[1]}
    terms = [Term(by_name["viscous(v)"], {}, np.array([0.2])),
             # dv/dt is proportional to 1 / m: a first-order coefficient 0.1 / 1.1 is a mass 10 % larger
             Term(by_name["parameter(m)"], {}, np.array([0.1 / 1.1])),
             Term(by_name["input_gain(F)"], {}, np.array([0.05]))]
    corrected = CorrectedModel(terms, problem)
    assert corrected.parameters == {"m": pytest.approx(1.1, rel=1e-4)}
    np.testing.assert_allclose(corrected(np.array([[0.0, 2.0]]), np.array([[1.0]])), [[0.0, -0.4]])
    np.testing.assert_allclose(corrected.inputs(np.ones((3, 1)), 0.01), 1.05)
    model = MassSpringDamper()
    with corrected.parameters_applied(model):
        assert model.values["m"] == pytest.approx(1.1, rel=1e-4)
    assert model.values["m"] == 1.0


def test_config_errors_name_the_field():
    with pytest.raises(ConfigError, match="config.diagnosis.equations"):
        msd_problem(equations=["nope"])
    with pytest.raises(ConfigError, match="config.diagnosis.periodic"):
        msd_problem(periodic={"x": -1.0})
    problem, model = msd_problem(plugins=["hybridfmu.no_such_plugin"])
    measured = msd_maneuvers(None, duration_s=2.0)
    set_data_statistics(problem, [measured["train"].x], 0.01)
    with pytest.raises(ConfigError, match="config.diagnosis.plugins"):
        build_library(problem, prepare_maneuver(measured["train"], model, problem).inputs, model)


def test_the_core_never_imports_the_motor_plugin():
    code = ("import sys, hybridfmu.diagnosis.run, hybridfmu.diagnosis.report, hybridfmu_bench.withheld.suite; "
            "print(any('motor' in m for m in sys.modules if m.startswith('hybridfmu.diagnosis')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"


def test_the_motor_plugin_adds_dead_time_to_the_current_equations_only():
    from hybridfmu.diagnosis import effects_motor

    class Stub:
        state_names = ["i_d", "i_q", "theta", "omega"]
        input_names = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
        parameter_values = {"p": 4.0}

    options = {"duty_inputs": ["d_a", "d_b", "d_c"], "current_states": ["i_d", "i_q"], "angle_state": "theta",
               "pole_pairs_parameter": "p", "pwm_frequency_hz": 20000, "current_scales_a": [1.0, 3.0]}
    assert [e.name for e in effects_motor.plugin_effects(Stub(), 0, options, None)] == ["deadtime(d_a,d_b,d_c)"]
    assert effects_motor.plugin_effects(Stub(), 3, options, None) == []
    with pytest.raises(ConfigError, match="effects_motor"):
        effects_motor.plugin_effects(Stub(), 0, {"duty_inputs": ["d_a"]}, None)
    phases = effects_motor.dq_to_abc(np.array([0.0]), np.array([1.0]), np.array([0.0]))
    assert phases.sum() == pytest.approx(0.0) and phases[0, 0] == pytest.approx(0.0)


def test_every_effect_states_sizes_that_its_physical_parameters_carry(library):
    """The confirmation of an effect (:func:`hybridfmu.diagnosis.identification.confirmed`) reads its sizes among its
    physical parameters: each effect of the library names at least one that is there, none of them a setting."""
    from hybridfmu.diagnosis.identification import parameter_matches

    _, _, _, effects, _ = library
    kinds = set()
    for effect in effects[0] + effects[1]:
        grid = effect.grid()
        for setting in (grid[0], grid[-1]):
            n = len(effect.coefficient_names(setting))
            rows = effect.physical(np.linspace(0.5, 1.5, n), np.eye(n) * 1e-4, setting, {})
            names = [r["name"] for r in rows]
            sizes = effect.size_parameters(setting)
            matched = [r for r in names if parameter_matches(r, sizes)]
            assert matched, f"{effect.name} {setting}: sizes {sizes} among none of {names}"
            assert not set(matched) & set(setting) - {"half_width"}, f"{effect.name}: a searched shape as a size"
        kinds.add(effect.kind)
    assert {"viscous", "quadratic", "polynomial", "coulomb", "scaled_coulomb", "periodic", "saturation_above",
            "limit_above", "input_gain", "input_offset", "time_offset", "input_lag", "input_deadzone",
            "input_saturation_above", "parameter"} <= kinds
