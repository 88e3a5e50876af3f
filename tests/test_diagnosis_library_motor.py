"""The motor plugin's dead-time effect: its current scale searched relative to the phase currents along the
data and refined, an explicit grid in A still accepted, config errors named, and the term of the corrected
simulation evaluated with one batch of the helper model per stage."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybridfmu.config import ConfigError
from hybridfmu.diagnosis import effects_motor
from hybridfmu.diagnosis.derivatives import hann_kernel, smooth_at
from hybridfmu.diagnosis.effects import EffectInputs
from hybridfmu.diagnosis.selection import DesignCache, ManeuverFitData, best_setting, fit_terms

OPTIONS = {"duty_inputs": ["d_a", "d_b", "d_c"], "current_states": ["i_d", "i_q"], "angle_state": "theta",
           "pole_pairs_parameter": "p"}
WHERE = "config.diagnosis.plugin_options.hybridfmu.diagnosis.effects_motor"


class Stub:
    state_names = ["i_d", "i_q", "theta", "omega"]
    input_names = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
    parameter_values = {"p": 4.0}


def motor_inputs(m: int = 20000, amplitude_a: float = 20.0, seed: int = 0) -> EffectInputs:
    """States with a q current of varying amplitude and a turning rotor; the input Jacobian of a toy machine
    whose d and q voltages are the Park transform of the phase duties at 12 V over 1 mH."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2.0, m)
    x = np.zeros((m, 4))
    x[:, 0] = 2.0 * np.sin(2 * math.pi * 1.3 * t)
    x[:, 1] = amplitude_a * np.sin(2 * math.pi * 0.7 * t + rng.uniform(0, 6))
    x[:, 2] = 30.0 * t + 2.0 * np.sin(3.0 * t)
    x[:, 3] = 30.0 + 6.0 * np.cos(3.0 * t)
    u = np.full((m, 5), 0.5)
    u[:, 3] = 12.0
    theta_e = 4.0 * x[:, 2]
    dfdu = np.zeros((m, 4, 5))
    for k in range(3):
        shift = 2.0 * math.pi * k / 3.0
        dfdu[:, 0, k] = (2.0 / 3.0) * 12.0 / 1e-3 * np.cos(theta_e - shift)
        dfdu[:, 1, k] = -(2.0 / 3.0) * 12.0 / 1e-3 * np.sin(theta_e - shift)
    return EffectInputs(x, u, x_smooth=x, f=np.zeros((m, 4)), dfdx=np.zeros((m, 4, 4)), dfdu=dfdu)


def test_the_current_scale_grid_is_relative_to_the_rms_phase_current():
    inputs = motor_inputs(amplitude_a=0.0)
    inputs.x_smooth[:, 0], inputs.x_smooth[:, 1] = 0.0, 10.0  # a constant q current: phase amplitude 10 A
    rms = effects_motor.phase_current_rms(inputs.x_smooth, (0, 1), 2, 4.0)
    assert rms == pytest.approx(10.0 / math.sqrt(2.0), rel=1e-3)
    (effect,) = effects_motor.plugin_effects(Stub(), 1, OPTIONS, inputs)
    expected = [r * rms for r in effects_motor.DEFAULT_CURRENT_SCALE_RELATIVE]
    assert [g["current_scale_a"] for g in effect.grid()] == pytest.approx(expected)
    (effect,) = effects_motor.plugin_effects(Stub(), 1, {**OPTIONS, "current_scale_relative": [0.1, 0.2]}, inputs)
    assert [g["current_scale_a"] for g in effect.grid()] == pytest.approx([0.1 * rms, 0.2 * rms])
    (effect,) = effects_motor.plugin_effects(Stub(), 1, {**OPTIONS, "current_scales_a": [4.0, 1.0]}, None)
    assert [g["current_scale_a"] for g in effect.grid()] == [1.0, 4.0]  # the explicit grid in A, no data needed
    inputs.x_smooth[:, :2] = 0.0
    (effect,) = effects_motor.plugin_effects(Stub(), 1, OPTIONS, inputs)
    assert effect.grid() == []  # no current along the data: left out by the library ("empty grid")


@pytest.mark.parametrize("options, field", [
    ({"current_scale_relative": [-0.1]}, "current_scale_relative"),
    ({"current_scale_relative": []}, "current_scale_relative"),
    ({"current_scales_a": [0.0]}, "current_scales_a"),
    ({"current_scales_a": [1.0], "current_scale_relative": [0.1]}, "not both"),
    ({"pwm_frequency_hz": -5.0}, "pwm_frequency_hz"),
])
def test_bad_plugin_options_name_the_field(options, field):
    with pytest.raises(ConfigError, match=rf"{WHERE}.*{field}"):
        effects_motor.plugin_effects(Stub(), 0, {**OPTIONS, **options}, motor_inputs(m=200))


def test_the_current_scale_is_refined_off_the_grid_with_a_standard_error():
    inputs = motor_inputs()
    (effect,) = effects_motor.plugin_effects(Stub(), 1, OPTIONS, inputs)
    assert effect.continuous == "current_scale_a" and effect.log_scale
    true_scale, true_loss = 1.7, 0.004  # 1.7 A lies between the grid values
    assert true_scale not in [g["current_scale_a"] for g in effect.grid()]
    term_values = true_loss * effect.regressors(inputs, {"current_scale_a": true_scale})[:, 0]
    kernel = hann_kernel(9)
    centres = np.arange(4, inputs.n - 4, 9)
    rng = np.random.default_rng(1)
    target = np.zeros((len(centres), 4))
    target[:, 1] = smooth_at(term_values, kernel, centres) + 2.0 * rng.standard_normal(len(centres))
    cache = DesignCache([ManeuverFitData("synthetic", inputs, kernel, centres, np.arange(len(centres)) // 40,
                                         target, np.array([0.0, 2.0, 0.0, 0.0]))])
    term, _, _ = best_setting(cache, [], effect, 1, ["synthetic"], 40)
    scale = term.setting["current_scale_a"]
    assert scale == pytest.approx(true_scale, rel=0.05)
    se = term.setting_se["current_scale_a"]
    assert 0 < se < 0.1 * true_scale and abs(scale - true_scale) < 5 * se
    fit = fit_terms(cache, [term], 1, ["synthetic"])
    params = {p["name"]: p for p in effect.physical(fit.coefs[0], fit.cov, term.setting, term.setting_se)}
    assert params["duty_error"]["value"] == pytest.approx(true_loss, rel=0.03)
    assert params["current_scale_a"]["se"] == se
    assert "dead_time_s" not in params  # no PWM frequency configured: the duty loss is reported alone
    (with_pwm,) = effects_motor.plugin_effects(Stub(), 1, {**OPTIONS, "pwm_frequency_hz": 20000.0}, inputs)
    rows = {p["name"]: p["value"] for p in with_pwm.physical(fit.coefs[0], fit.cov, term.setting, {})}
    assert rows["dead_time_s"] == pytest.approx(rows["duty_error"] / 20000.0)


class CountingHelper:
    """A helper model, nonlinear in its inputs, that counts its calls and rows."""

    def __init__(self):
        self.calls, self.rows = 0, 0

    def derivatives(self, x, u):
        x, u = np.asarray(x, dtype=float), np.asarray(u, dtype=float)
        self.calls += 1
        self.rows += len(x)
        return np.stack([x[:, 0] * u[:, 0] ** 2 + u[:, 1] * u[:, 3], np.sin(u[:, 2]) * u[:, 3] - x[:, 1],
                         x[:, 3], u[:, 4] * x[:, 0]], axis=1)


def test_the_simulation_term_evaluates_both_inputs_in_one_batch_and_equals_their_difference():
    effect = effects_motor.plugin_effects(Stub(), 1, {**OPTIONS, "current_scales_a": [2.0]}, None)[0]
    helper = CountingHelper()
    term = effect.batch_function(np.array([0.03]), {"current_scale_a": 2.0}, helper)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(7, 4)) * [5.0, 5.0, 3.0, 20.0]
    u = np.column_stack([rng.uniform(0.2, 0.8, (7, 3)), np.full(7, 12.0), rng.normal(size=7)])
    values = term(x, u)
    assert helper.calls == 1 and helper.rows == 14
    changed = u + 0.03 * effect.duty_change(x, u, 2.0)
    expected = helper.derivatives(x, changed)[:, 1] - helper.derivatives(x, u)[:, 1]
    np.testing.assert_array_equal(values, expected)  # exactly the two separate evaluations
    helper.calls = helper.rows = 0
    one_row = term(x[:1], u[:1])  # one RK stage: the duty change in plain floats
    assert helper.calls == 1 and helper.rows == 2
    np.testing.assert_allclose(one_row, expected[:1], rtol=1e-12, atol=1e-12)
    assert effect.batch_function(np.array([0.03]), {"current_scale_a": 2.0}, None) is None


class KernelHelper(CountingHelper):
    """A helper with a fixed-size kernel (like an FMU): the kernel is made once per batch size and used."""

    def __init__(self):
        super().__init__()
        self.kernels = []

    def derivatives_kernel(self, n):
        self.kernels.append(n)
        return lambda x, u: self.derivatives(x, u)


def test_the_simulation_term_uses_the_helpers_kernel_once_per_batch_size():
    effect = effects_motor.plugin_effects(Stub(), 0, {**OPTIONS, "current_scales_a": [2.0]}, None)[0]
    helper = KernelHelper()
    term = effect.batch_function(np.array([0.05]), {"current_scale_a": 2.0}, helper)
    x = np.array([[1.0, 12.0, 0.4, 30.0]])
    u = np.array([[0.5, 0.6, 0.4, 12.0, 0.1]])
    first, second = term(x, u), term(x, u)
    assert helper.kernels == [2] and helper.calls == 2
    changed = u + 0.05 * effect.duty_change(x, u, 2.0)
    np.testing.assert_allclose(first, helper.derivatives(x, changed)[:, 0] - helper.derivatives(x, u)[:, 0],
                               rtol=1e-12)
    np.testing.assert_array_equal(first, second)


def test_a_joint_dead_time_term_evaluates_the_helper_once_for_both_equations():
    """The dead time acts on both current equations with one coefficient: the corrected model evaluates both
    members from one helper call per batch (not one each) and gets the members' own values."""
    from hybridfmu.diagnosis.corrected_model import CorrectedModel
    from hybridfmu.diagnosis.joint import JointEffect
    from hybridfmu.diagnosis.selection import Term

    options = {**OPTIONS, "current_scales_a": [2.0]}
    members = [effects_motor.plugin_effects(Stub(), eq, options, None)[0] for eq in (0, 1)]
    coef, setting = np.array([0.04]), {"current_scale_a": 2.0}

    class Problem:
        n_x, n_u, settings = 4, 5, {}

    helper = CountingHelper()
    corrected = CorrectedModel([Term(JointEffect(members), setting, coef)], Problem(), helper)
    rng = np.random.default_rng(2)
    x = rng.normal(size=(6, 4)) * [5.0, 5.0, 3.0, 20.0]
    u = np.column_stack([rng.uniform(0.2, 0.8, (6, 3)), np.full(6, 12.0), rng.normal(size=6)])
    values = corrected.additive_batch(x, u)
    assert helper.calls == 1 and helper.rows == 12
    separate = CountingHelper()
    for member in members:
        np.testing.assert_array_equal(values[:, member.equation],
                                      member.batch_function(coef, setting, separate)(x, u))
    assert separate.calls == 2
    assert np.all(values[:, 2:] == 0.0)
    np.testing.assert_allclose(corrected(x[:1], u[:1]), values[:1], rtol=1e-12, atol=1e-12)
