"""Equation error and its pieces: exact model data give a zero residual, measurement noise alone gives a
residual at the predicted noise floor, kernels and input shifts behave as documented."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfmu.diagnosis.corrected_model import shift_inputs
from hybridfmu.diagnosis.derivatives import hann_kernel, odd_window, smooth_at, smooth_same, white_noise_std
from hybridfmu.diagnosis.residual import check_uniform_grid, equation_error, noise_floor_std
from hybridfmu.diagnosis.synthetic import PmsmReference, abc_to_dq, dq_to_abc

DT = 1e-4


def exact_trajectory(model: PmsmReference, n: int = 3000, substeps: int = 6, seed: int = 0):
    """The model's own trajectory under random held duties (fine RK4 inside every sample)."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(n) * DT
    angle = 2 * np.pi * 3.0 * time_s
    duty = 0.5 + 0.08 * np.stack([np.cos(angle), np.cos(angle - 2.1), np.cos(angle + 2.1)], axis=1)
    duty += 0.01 * rng.standard_normal(duty.shape)
    u = np.column_stack([duty, np.full(n, 12.0), 0.2 + 0.1 * np.sin(2 * np.pi * 5 * time_s)])
    x = np.zeros((n, 4))
    x[0] = [0.0, 0.0, 10.0, 0.0]
    h = DT / substeps
    for k in range(n - 1):
        state = x[k][None].copy()
        for _ in range(substeps):
            k1 = model.derivatives(state, u[k][None])
            k2 = model.derivatives(state + 0.5 * h * k1, u[k][None])
            k3 = model.derivatives(state + 0.5 * h * k2, u[k][None])
            k4 = model.derivatives(state + h * k3, u[k][None])
            state = state + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[k + 1] = state[0]
    return time_s, x, u


@pytest.fixture(scope="module")
def exact():
    model = PmsmReference()
    return (model,) + exact_trajectory(model)


def test_exact_model_data_give_zero_equation_error(exact):
    model, time_s, x, u = exact
    err = equation_error(model, time_s, x, u, 41, one_step_states=[0, 1])
    residual = err.filtered_residual()
    rate = err.filtered_rate()
    for j in range(4):
        scale = np.nanstd(rate[:, j]) + 1e-9
        assert np.nanmax(np.abs(residual[:, j])) < 2e-3 * scale, err.state_names[j]


def test_a_missing_torque_appears_in_the_speed_equation_only(exact):
    model, time_s, x, u = exact
    wrong = PmsmReference({"J": 2.2e-4})  # the data come from J = 2e-4
    err = equation_error(wrong, time_s, x, u, 41, one_step_states=[0, 1])
    residual = err.filtered_residual()
    expected = err.f_model[:, 3] * (2.2 / 2.0 - 1.0)
    inside = np.isfinite(residual[:, 3])
    np.testing.assert_allclose(residual[inside, 3], smooth_same(expected, err.kernel)[inside], atol=5.0)
    # the currents' one-step prediction sees the speed evolve with the wrong inertia within a sample: tiny
    assert np.nanmax(np.abs(residual[:, 0])) < 1e-2 * np.nanstd(err.filtered_rate()[:, 0])


def test_noise_floor_predicts_the_residual_of_pure_noise(exact):
    model, time_s, x, u = exact
    rng = np.random.default_rng(4)
    noise = np.zeros_like(x)
    noise[:, :2] = 0.3 * rng.standard_normal((len(x), 2))
    noise[:, 2] = 1e-4 * rng.standard_normal(len(x))
    noise[:, 3] = np.gradient(noise[:, 2], time_s)
    err = equation_error(model, time_s, x + noise, u, 41, one_step_states=[0, 1])
    centres = np.arange(41, len(err.time_s) - 41, 41)
    observed = np.sqrt(np.mean(smooth_at(err.residual, err.kernel, centres) ** 2, axis=0))
    other = np.zeros_like(noise)
    other[:, :2] = 0.3 * np.random.default_rng(9).standard_normal((len(x), 2))
    other[:, 2] = 1e-4 * np.random.default_rng(10).standard_normal(len(x))
    other[:, 3] = np.gradient(other[:, 2], time_s)
    predicted = noise_floor_std(err, other, centres)
    for j in (0, 1, 3):
        assert 0.7 < observed[j] / predicted[j] < 1.4


def test_kernel_and_smoothing():
    kernel = hann_kernel(21)
    assert kernel.sum() == pytest.approx(1.0)
    assert np.all(kernel > 0) and kernel[10] == kernel.max()
    signal = np.random.default_rng(0).standard_normal((300, 2))
    centres = np.arange(10, 290, 13)
    np.testing.assert_allclose(smooth_at(signal, kernel, centres), smooth_same(signal, kernel)[centres])
    assert np.isnan(smooth_same(signal, kernel)[:10]).all()
    assert odd_window(0.004, 1e-4) == 41
    with pytest.raises(ValueError, match="odd"):
        hann_kernel(20)
    assert white_noise_std(np.linspace(0, 1, 5000) + 0.1 * np.random.default_rng(1).standard_normal(5000)) \
        == pytest.approx(0.1, rel=0.1)


def test_shift_inputs_interpolates_held_samples():
    u = np.arange(10.0)[:, None] * np.array([1.0, 2.0])
    np.testing.assert_allclose(shift_inputs(u, DT, DT)[:-1], u[1:])
    np.testing.assert_allclose(shift_inputs(u, 0.5 * DT, DT)[:-1, 0], u[:-1, 0] + 0.5)
    np.testing.assert_allclose(shift_inputs(u, -DT, DT)[1:], u[:-1])
    only_first = shift_inputs(u, DT, DT, columns=np.array([True, False]))
    np.testing.assert_allclose(only_first[:, 1], u[:, 1])


def test_park_transforms_are_inverse():
    rng = np.random.default_rng(3)
    i_d, i_q, theta_e = rng.standard_normal(50), rng.standard_normal(50), rng.uniform(0, 7, 50)
    back_d, back_q = abc_to_dq(dq_to_abc(i_d, i_q, theta_e), theta_e)
    np.testing.assert_allclose(back_d, i_d, atol=1e-12)
    np.testing.assert_allclose(back_q, i_q, atol=1e-12)


def test_non_uniform_grid_is_rejected_with_the_name():
    with pytest.raises(ValueError, match="test maneuver: time_s is not a uniform grid"):
        check_uniform_grid(np.array([0.0, 1e-4, 3e-4, 4e-4]), "test maneuver")
