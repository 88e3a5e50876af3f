"""Error measures, improvement factors and zoom choice, against values computed by hand."""

import math

import numpy as np
import pytest

from hybridfmu.evaluation.metrics import (improvement_factors, interval_mask, mae, metric_keys, mse,
                                          trajectory_errors)
from hybridfmu.evaluation.zoom import (choose_zoom_intervals, largest_error_growth, largest_mean_square,
                                       window_samples)


def test_mae_mse_by_hand():
    sim = np.array([1.0, 2.0, 4.0, -1.0])
    data = np.array([0.0, 2.0, 1.0, 1.0])
    # differences 1, 0, 3, -2 -> |.| sum 6, squares 1+0+9+4 = 14
    assert mae(sim, data) == pytest.approx(6 / 4)
    assert mse(sim, data) == pytest.approx(14 / 4)


def test_trajectory_errors_keys_and_values():
    angle_data = np.array([0.0, 0.5, 1.0])
    angle_sim = np.array([0.1, 0.3, 1.0])       # diffs 0.1, -0.2, 0
    speed_data = np.array([10.0, 20.0, 30.0])
    speed_sim = np.array([13.0, 16.0, 30.0])    # diffs 3, -4, 0
    errors = trajectory_errors(np.column_stack([angle_sim, speed_sim]), np.column_stack([angle_data, speed_data]),
                               ["angle", "speed"])
    assert list(errors) == metric_keys(["angle", "speed"]) == [
        "angle_mae", "angle_mse", "angle_rmse", "speed_mae", "speed_mse", "speed_rmse"]
    assert errors["speed_rmse"] == pytest.approx((25 / 3) ** 0.5)
    with pytest.raises(ValueError, match="3 signals"):
        trajectory_errors(np.zeros((3, 2)), np.zeros((3, 2)), ["a", "b", "c"])
    assert errors["angle_mae"] == pytest.approx(0.3 / 3)
    assert errors["angle_mse"] == pytest.approx(0.05 / 3)
    assert errors["speed_mae"] == pytest.approx(7 / 3)
    assert errors["speed_mse"] == pytest.approx(25 / 3)


def test_improvement_is_reference_over_candidate():
    fmu = {"angle_mae": 4.6, "angle_mse": 61.0, "speed_mae": 2.0, "speed_mse": 0.0}
    neural = {"angle_mae": 1.0, "angle_mse": 1.0, "speed_mae": 0.0, "speed_mse": 0.0}
    factors = improvement_factors(fmu, neural)
    assert factors["angle_mae"] == pytest.approx(4.6)
    assert factors["angle_mse"] == pytest.approx(61.0)
    assert factors["speed_mae"] is None          # unbounded: candidate error zero
    assert factors["speed_mse"] == 1.0           # both zero: no improvement


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="shape"):
        mae(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="NaN"):
        mse(np.array([math.nan]), np.array([0.0]))
    with pytest.raises(ValueError, match="holds no sample"):
        interval_mask(np.linspace(0, 1, 11), 2.0, 3.0)


def test_interval_mask_inclusive():
    t = np.linspace(0.0, 1.0, 11)
    assert interval_mask(t, 0.2, 0.4).sum() == 3


def test_zoom_on_largest_angle_error_growth():
    t = np.arange(0, 10.0001, 0.01)
    error = np.zeros_like(t)
    # error ramps from 0 to 5 between 6 s and 7 s, then stays: the 1 s window starting at 6 s grows most
    error[(t >= 6) & (t <= 7)] = np.linspace(0, 5, int(((t >= 6) & (t <= 7)).sum()))
    error[t > 7] = 5
    start, end = largest_error_growth(t, -error, 1.0)   # sign must not matter
    assert start == pytest.approx(6.0) and end == pytest.approx(7.0)


def test_zoom_on_largest_speed_mse():
    t = np.arange(0, 5.0001, 0.001)
    error = np.zeros_like(t)
    error[(t > 3.2) & (t < 3.3)] = 50.0            # oscillation burst
    start, end = largest_mean_square(t, error, 0.1)
    assert start <= 3.2 + 1e-9 and end >= 3.3 - 1e-3
    assert window_samples(t, 100.0) == t.size - 1   # longer than the maneuver: whole maneuver


def test_configured_intervals_replace_auto_and_are_checked():
    t = np.linspace(0, 2, 201)
    zero = np.zeros_like(t)
    errors, lengths = {"angle": zero, "speed": zero}, {"angle": 0.5, "speed": 0.2}
    criteria = {"angle": "growth", "speed": "mse"}
    auto = choose_zoom_intervals(t, errors, lengths, criteria)
    assert [(z.signal, z.criterion) for z in auto] == [("angle", "growth"), ("speed", "mse")]
    assert auto[0].t_end_s - auto[0].t_start_s == pytest.approx(0.5)
    chosen = choose_zoom_intervals(t, errors, lengths, criteria,
                                   configured=[{"t_start_s": 0.1, "t_end_s": 0.3, "signal": "speed"}])
    assert [(z.t_start_s, z.t_end_s, z.signal, z.source) for z in chosen] == [
        (auto[0].t_start_s, auto[0].t_end_s, "angle", "auto"), (0.1, 0.3, "speed", "config")]
    with pytest.raises(ValueError, match="does not overlap"):
        choose_zoom_intervals(t, errors, lengths, criteria, configured=[{"t_start_s": 5, "t_end_s": 6}])
    with pytest.raises(ValueError, match="target signals"):
        choose_zoom_intervals(t, errors, lengths, criteria, configured=[{"t_start_s": 0, "t_end_s": 1,
                                                                          "signal": "torque"}])
    bump = np.exp(-((t - 1.0) / 0.05) ** 2)  # growth and mse pick different windows of the same error
    growth = choose_zoom_intervals(t, {"x": bump}, {"x": 0.5}, {"x": "growth"})[0]
    square = choose_zoom_intervals(t, {"x": bump}, {"x": 0.5}, {"x": "mse"})[0]
    assert growth.t_end_s == pytest.approx(1.0)                                   # ends at the peak
    assert square.t_start_s < 1.0 < square.t_end_s and square.t_start_s > 0.5    # holds the peak inside


def test_time_offset_window_and_input_shift():
    from hybridfmu.evaluation.offset import estimate_input_delay_s, shift_inputs, steepest_window

    t = np.arange(0, 1.0, 1e-4)
    speed = 100 * np.tanh((t - 0.6) * 200)
    start, end = steepest_window(t, speed, 0.01)
    assert start < 0.6 < end
    # two targets: each change counts relative to its spread, so the small but sudden step wins
    other = 1e-3 * (t > 0.3) + 1e-4 * np.sin(t)
    start, end = steepest_window(t, np.column_stack([speed, other]), 0.01)
    assert start < 0.3 < end
    u = np.column_stack([np.arange(6.0), 10 * np.arange(6.0)])
    np.testing.assert_array_equal(shift_inputs(u, 0.0, 0.1), u)
    np.testing.assert_allclose(shift_inputs(u, 0.2, 0.1)[:, 0], [2, 3, 4, 5, 5, 5])      # two steps ahead, held
    np.testing.assert_allclose(shift_inputs(u, -0.05, 0.1)[:, 0], [0, 0.5, 1.5, 2.5, 3.5, 4.5])
    measured = np.sin(np.arange(50) * 0.1 + 0.3)
    best, fit = estimate_input_delay_s(lambda d: np.sin(np.arange(50) * 0.1 + d), measured,
                                       np.linspace(-1, 1, 201))
    assert best == pytest.approx(0.3) and np.allclose(fit, measured)
    both = np.column_stack([measured, 1e3 * measured])
    best, _ = estimate_input_delay_s(lambda d: np.column_stack([np.sin(np.arange(50) * 0.1 + d),
                                                                1e3 * np.sin(np.arange(50) * 0.1 + d + 0.2)]),
                                     both, np.linspace(-1, 1, 201), scales=np.array([1.0, 1e3]))
    assert best == pytest.approx(0.2, abs=0.011)  # the normalised compromise between 0.3 and 0.1
