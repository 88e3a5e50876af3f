"""Equation error, noise floor, kernels and input shifts on a small model (no FMU)."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_models import MassSpringDamper, force_profile, simulate_truth
from hybridfmu.diagnosis.corrected_model import shift_inputs
from hybridfmu.diagnosis.derivatives import hann_kernel, odd_window, smooth_at, smooth_same
from hybridfmu.diagnosis.residual import check_uniform_grid, equation_error, noise_floor_std


@pytest.fixture(scope="module")
def exact():
    model = MassSpringDamper()
    time_s = np.arange(0.0, 10.0, 0.01)
    u = force_profile(time_s, 0)[:, None]
    return model, time_s, u, simulate_truth(model, None, time_s, u, [0.0, 0.0], substeps=8)


def test_exact_model_data_give_zero_equation_error(exact):
    model, time_s, u, x = exact
    err = equation_error(model, time_s, x, u, 9)
    residual = err.filtered_residual()
    assert np.nanmax(np.abs(residual)) < 1e-3 * np.max(np.abs(err.rate_meas))


def test_a_missing_force_appears_in_the_velocity_equation_only(exact):
    model, time_s, u, _ = exact
    x = simulate_truth(model, lambda xs, us: np.array([[0.0, -0.5]]), time_s, u, [0.0, 0.0], substeps=8)
    residual = equation_error(model, time_s, x, u, 9).filtered_residual()
    assert np.nanmean(residual[:, 1]) == pytest.approx(-0.5, rel=0.02)
    assert np.nanmax(np.abs(residual[:, 0])) < 1e-2


def test_noise_floor_predicts_the_residual_of_pure_noise(exact):
    model, time_s, u, x = exact
    rng = np.random.default_rng(1)
    noise = rng.standard_normal(x.shape) * [1e-3, 1e-2]
    err = equation_error(model, time_s, x + noise, u, 9)
    predicted = noise_floor_std(err, rng.standard_normal(x.shape) * [1e-3, 1e-2])
    centres = np.arange(4, len(err.time_s) - 4, 9)
    observed = np.sqrt(np.mean(err.filtered_residual()[centres] ** 2, axis=0))
    np.testing.assert_allclose(observed, predicted, rtol=0.25)


def test_kernel_and_smoothing():
    kernel = hann_kernel(9)
    assert kernel.sum() == pytest.approx(1.0) and np.all(kernel > 0)
    assert odd_window(0.004, 1e-4) == 41
    signal = np.arange(50, dtype=float)
    same = smooth_same(signal, kernel)
    np.testing.assert_allclose(smooth_at(signal, kernel, np.array([10, 20])), same[[10, 20]])
    assert np.isnan(same[:4]).all()


def test_shift_inputs_interpolates_held_samples():
    u = np.arange(6, dtype=float)[:, None]
    np.testing.assert_allclose(shift_inputs(u, 0.5, 1.0)[:, 0], [0.5, 1.5, 2.5, 3.5, 4.5, 5.0])
    np.testing.assert_allclose(shift_inputs(u, 0.0, 1.0), u)


def test_non_uniform_grid_is_rejected_with_the_name():
    with pytest.raises(ValueError, match="maneuver_x"):
        check_uniform_grid(np.array([0.0, 0.1, 0.3, 0.4]), "maneuver_x")
