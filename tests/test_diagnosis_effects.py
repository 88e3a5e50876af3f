"""Candidate effects: each recovers its parameters from a synthetic residual; the three ways of
evaluating a correction (vectorised, model-based, scalar from calibrated constants) agree."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfmu.diagnosis.derivatives import hann_kernel, smooth_at
from hybridfmu.diagnosis.effects import EFFECTS, EffectInputs, candidate_effects, effect_options
from hybridfmu.diagnosis.layout import MotorLayout, calibrate_constants
from hybridfmu.diagnosis.selection import DesignCache, ManeuverFitData, SelectionSettings, Term, best_setting, \
    fit_terms
from hybridfmu.diagnosis.synthetic import PmsmReference, synthetic_trajectory

KERNEL = 41

# effect -> (nonlinear setting, true coefficients, physical parameter checked, its true value, rel. tolerance)
TRUTHS = {
    "coulomb_friction": ({"stribeck_velocity_rad_s": 8.0}, [0.05, 0.03], "breakaway_torque_nm", 0.08, 0.05),
    "viscous_friction": ({}, [2e-4], "viscous_coefficient_nm_s_rad", 2e-4, 0.05),
    "load_dependent_friction": ({"asymmetric": 1.0}, [0.06, 0.02], "coefficient_release", 0.04, 0.1),
    "cogging": ({"order": 12.0, "harmonics": 2.0}, [0.02, 0.01, 0.0, 0.005], "amplitude_12_nm", np.hypot(0.02, 0.01),
                0.1),
    "inertia_mismatch": ({}, [0.1], "inertia_kg_m2", 2e-4 / 1.1, 0.02),
    "torque_constant_error": ({}, [0.05], "torque_constant_relative_error", 0.05, 0.05),
    "resistance_error": ({}, [0.2], "resistance_relative_error", 0.2, 0.05),
    "inverter_deadtime": ({"current_scale_a": 2.0}, [0.02], "duty_error", 0.02, 0.05),
    "channel_time_offset": ({"offset_s": 3e-5}, [], "offset_s", 3e-5, 0.1),
}


def make_layout(model) -> MotorLayout:
    return MotorLayout(state_names=model.state_names, input_names=model.input_names, theta=2, omega=3, i_d=0, i_q=1,
                       duty=(0, 1, 2), u_dc=3, tau_load=4, pole_pairs=4.0, inertia_kg_m2=2e-4,
                       groups={"mechanical": [3], "electrical": [0, 1]}, dt_s=1e-4)


@pytest.fixture(scope="module")
def synthetic():
    """Effect inputs along a smooth random trajectory of the NumPy motor model."""
    rng = np.random.default_rng(5)
    model = PmsmReference()
    traj = synthetic_trajectory(rng, duration_s=3.0)
    f = model.derivatives(traj.x, traj.u)
    dfdx, dfdu = model.jacobians(traj.x, traj.u)
    layout = make_layout(model)
    grid = np.arange(len(traj.u))

    def shift(offset_s: float) -> np.ndarray:
        index = grid + offset_s / layout.dt_s
        return np.stack([np.interp(index, grid, traj.u[:, j]) for j in range(traj.u.shape[1])], axis=1)

    inputs = EffectInputs(layout, traj.x, traj.u, f=f, dfdx=dfdx, dfdu=dfdu, shift=shift,
                          context={"u_dc_mean_v": 12.0})
    return model, traj, layout, inputs


def fit_data(inputs, residual: np.ndarray, rng: np.random.Generator, noise_std: np.ndarray) -> ManeuverFitData:
    kernel = hann_kernel(KERNEL)
    centres = np.arange(KERNEL, len(residual) - KERNEL, KERNEL)
    raw = residual + rng.standard_normal(residual.shape) * noise_std * np.sqrt(KERNEL)
    return ManeuverFitData("synthetic", inputs, kernel, centres, np.arange(len(centres)) // 20,
                           smooth_at(raw, kernel, centres), noise_std)


@pytest.mark.parametrize("name", sorted(TRUTHS))
def test_effect_recovers_its_parameters(synthetic, name):
    _, _, layout, inputs = synthetic
    setting, coef, parameter, value, tolerance = TRUTHS[name]
    effect = EFFECTS[name]
    options = effect_options({"effects": {"cogging_orders": [6, 12, 24]}})
    truth = effect.correction(inputs, np.array(coef), setting, options)
    noise = np.array([500.0, 500.0, 0.0, 30.0])
    data = fit_data(inputs, truth, np.random.default_rng(1), noise)
    cache = DesignCache([data], options)
    rows = layout.groups[effect.group]
    term, rss, _ = best_setting(cache, [], effect, rows, ["synthetic"], options, layout, 30)
    fit = fit_terms(cache, [term], rows, ["synthetic"])
    term.coef = fit.coefs[0]
    params = {p["name"]: p for p in effect.physical(term.coef, fit.cov, term.setting, term.setting_se, layout,
                                                    options, inputs.context)}
    assert params[parameter]["value"] == pytest.approx(value, rel=tolerance)
    if params[parameter]["se"] is not None:
        assert 0 <= params[parameter]["se"] < abs(value)
    for key, true_value in setting.items():
        if key in term.setting and key != "harmonics":
            assert term.setting[key] == pytest.approx(true_value, rel=0.15)


def test_corrections_agree_in_all_three_forms():
    rng = np.random.default_rng(2)
    model = PmsmReference({"L_d": 50e-6, "R": 0.033})  # unequal inductances: the reluctance terms matter
    traj = synthetic_trajectory(rng, duration_s=0.3)
    layout = make_layout(model)
    f = model.derivatives(traj.x, traj.u)
    dfdx, dfdu = model.jacobians(traj.x, traj.u)
    constants = calibrate_constants(layout, traj.x, traj.u, f, dfdx, dfdu)
    assert constants["inv_l_d"] == pytest.approx(1 / 50e-6, rel=1e-6)
    assert constants["diag_d"] == pytest.approx(-0.033 / 50e-6, rel=1e-6)
    options = effect_options({})
    cases = {"inertia_mismatch": ({}, [0.1]), "torque_constant_error": ({}, [0.05]), "resistance_error": ({}, [0.2]),
             "inverter_deadtime": ({"current_scale_a": 1.0}, [0.02])}
    x, u = traj.x[:40], traj.u[:40]
    for name, (setting, coef) in cases.items():
        effect, coef = EFFECTS[name], np.array(coef)
        vectorised = effect.correction(EffectInputs(layout, x, u, model=model), coef, setting, options)
        fast = effect.fast_correction(coef, setting, options, layout, model)(x, u)
        rows = effect.scalar_rows(coef, setting, options, layout)
        scalar = np.zeros_like(x)
        for k in range(len(x)):
            for index, value in rows(x[k].tolist(), u[k].tolist()):
                scalar[k, index] += value
        scale = np.max(np.abs(vectorised))
        assert scale > 0
        np.testing.assert_allclose(fast, vectorised, atol=1e-8 * scale)
        np.testing.assert_allclose(scalar, vectorised, atol=1e-8 * scale)


def test_torque_effects_scalar_form_matches_vectorised(synthetic):
    _, traj, layout, inputs = synthetic
    options = effect_options({})
    for name in ("coulomb_friction", "viscous_friction", "load_dependent_friction", "cogging"):
        setting, coef = TRUTHS[name][0], np.array(TRUTHS[name][1])
        effect = EFFECTS[name]
        sim_inputs = EffectInputs(layout, traj.x[:50], traj.u[:50])
        vectorised = effect.correction(sim_inputs, coef, setting, options)[:, layout.omega]
        torque = effect.scalar_torque(coef, setting, options)
        scalar = np.array([torque(traj.x[k, 2], traj.x[k, 3], traj.u[k, 4]) for k in range(50)]) / 2e-4
        np.testing.assert_allclose(scalar, vectorised, rtol=1e-10, atol=1e-12)


def test_unknown_candidate_is_named(synthetic):
    _, _, layout, _ = synthetic
    with pytest.raises(ValueError, match="unknown effects \\['magic_friction'\\]"):
        candidate_effects(["coulomb_friction", "magic_friction"], layout)


def test_effects_needing_missing_quantities_are_skipped():
    layout = MotorLayout(state_names=["theta", "omega"], input_names=["torque"], theta=0, omega=1,
                         inertia_kg_m2=None, groups={"mechanical": [1]})
    usable, skipped = candidate_effects([], layout)
    assert not usable
    assert "inertia" in skipped["coulomb_friction"]
    assert "duty" in skipped["inverter_deadtime"]
    assert "dq current" in skipped["resistance_error"]


def test_terms_and_selection_settings_defaults():
    settings = SelectionSettings.from_config({"min_bic_drop": 5.0, "unrelated": 1})
    assert settings.min_bic_drop == 5.0 and settings.min_relative_improvement == 0.03
    term = Term(EFFECTS["viscous_friction"], {})
    assert term.coef.size == 0
