"""Input effects whose shape is fitted to the data: a first-order lag (sensor or slow actuator), a dead zone
and saturations of an input; their input changes in the corrected model equal the fitted regressors."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_models import msd_input_maneuvers, msd_maneuvers, msd_problem
from hybridfmu.diagnosis.corrected_model import CorrectedModel
from hybridfmu.diagnosis.effects import first_order_lag, input_derivative, shift_samples
from hybridfmu.diagnosis.library import build_library
from hybridfmu.diagnosis.prepare import prepare_maneuver
from hybridfmu.diagnosis.problem import set_data_statistics
from hybridfmu.diagnosis.run import run_diagnosis
from hybridfmu.diagnosis.selection import Term


def _chosen(result):
    return [c["effect"] for c in result.which.chosen]


def _params(result, index=0):
    return {p["name"]: p for p in result.which.chosen[index]["parameters"]}


# ----------------------------------------------------------------------------- helpers of the input changes

def test_input_derivative_is_the_interval_rate_of_the_smoothed_samples():
    dt = 0.01
    t = np.arange(0.0, 1.0, dt)
    quadratic = 3.0 * t ** 2 + t  # a quadratic passes the Savitzky-Golay smoothing unchanged
    rate = input_derivative(quadratic, dt)
    np.testing.assert_allclose(rate[:-1], (quadratic[1:] - quadratic[:-1]) / dt, rtol=1e-9)
    assert rate[-1] == rate[-2]
    step = (t >= 0.5).astype(float)
    raw = input_derivative(step, dt, window_s=0.03)  # 3 samples: no smoothing
    assert raw[49] == pytest.approx(100.0) and np.count_nonzero(raw) == 1
    smoothed = input_derivative(step, dt)  # default 5 samples: the jump is spread
    assert np.count_nonzero(np.abs(smoothed) > 1e-9) > 1
    assert smoothed[:-1].sum() * dt == pytest.approx(1.0)  # the rate still integrates to the jump
    np.testing.assert_allclose(input_derivative(np.stack([t, 2 * t], axis=1), dt), [[1.0, 2.0]] * len(t), rtol=1e-9)


def test_first_order_lag_is_exact_for_held_inputs():
    dt, tau = 0.01, 0.05
    u = np.zeros(100)
    u[20:] = 2.0
    lagged = first_order_lag(u, tau, dt)
    assert np.all(lagged[:20] == 0.0)
    for k in (20, 25, 60):  # mean of 2 (1 - exp(-t / tau)) over [t_k, t_k+1]
        t0 = (k - 20) * dt
        exact = 2.0 * (1.0 - tau / dt * (np.exp(-t0 / tau) - np.exp(-(t0 + dt) / tau)))
        assert lagged[k] == pytest.approx(exact, rel=1e-12)
    np.testing.assert_allclose(first_order_lag(np.ones((5, 2)), tau, dt), 1.0)
    with pytest.raises(ValueError, match="positive"):
        first_order_lag(u, 0.0, dt)


def test_shift_samples_interpolates_and_holds_the_ends():
    values = np.arange(6, dtype=float)
    np.testing.assert_allclose(shift_samples(values, 0.015, 0.01), [1.5, 2.5, 3.5, 4.5, 5.0, 5.0])
    np.testing.assert_allclose(shift_samples(values, -0.01, 0.01), [0.0, 0.0, 1.0, 2.0, 3.0, 4.0])


# ----------------------------------------------------------------------------- the corrected model: what was fitted

@pytest.fixture(scope="module")
def library():
    problem, model = msd_problem(effects={"lag_derivative_window_s": 0.07})
    measured = msd_maneuvers(None, duration_s=5.0)
    set_data_statistics(problem, [measured["train"].x], 0.01)
    prepared = prepare_maneuver(measured["train"], model, problem)
    effects, _ = build_library(problem, prepared.inputs, model)
    return problem, prepared, {e.name: e for e in effects[1]}


def test_every_input_effect_is_built_where_the_input_acts(library):
    _, _, by_name = library
    for name in ("input_lag(F)", "input_deadzone(F)", "input_saturation_above(F)", "input_saturation_below(F)"):
        assert name in by_name
        assert by_name[name].grid()
    assert by_name["input_lag(F)"].grid()[0] == {"actuator_lag_s": 0.0}  # the first-order form first


@pytest.mark.parametrize("name, coef", [("input_gain(F)", 0.07), ("input_offset(F)", 0.3), ("input_lag(F)", 0.04),
                                        ("input_lag(F)", 0.8), ("input_deadzone(F)", 0.9),
                                        ("input_saturation_above(F)", 1.0), ("input_saturation_below(F)", 0.6),
                                        ("time_offset(F)", 1.7)])
def test_the_input_change_equals_the_fitted_regressors(library, name, coef):
    """dfdu times the change the corrected model makes to the logged input = regressors @ coef (the model is
    linear in its input), for every grid setting kind, including the smoothing window of the lag's du/dt."""
    problem, prepared, by_name = library
    effect = by_name[name]
    inputs = prepared.inputs
    grid = effect.grid()
    settings = [grid[0], grid[len(grid) // 2]] if len(grid) > 1 else grid
    for setting in settings:
        corrected = CorrectedModel([Term(effect, setting, np.array([coef]))], problem)
        u_model = corrected.inputs(inputs.u_samples, inputs.dt_s)
        change = inputs.dfdu[:, 1, 0] * (u_model[:-1, 0] - inputs.u[:, 0])
        np.testing.assert_allclose(change, effect.regressors(inputs, setting)[:, 0] * coef, rtol=1e-9, atol=1e-12,
                                   err_msg=f"{name} at {setting}")


def test_input_changes_of_different_kinds_compose_and_a_second_of_one_kind_is_not_applied(library):
    problem, prepared, by_name = library
    u = prepared.inputs.u_samples
    dt = prepared.inputs.dt_s
    dead = Term(by_name["input_deadzone(F)"], {"half_width": 0.5}, np.array([1.0]))
    gain = Term(by_name["input_gain(F)"], {}, np.array([0.1]))
    lag = Term(by_name["input_lag(F)"], {"actuator_lag_s": 0.0}, np.array([0.02]))
    again = Term(by_name["input_gain(F)"], {}, np.array([0.5]))
    corrected = CorrectedModel([dead, gain, lag, again], problem)
    lagged = u[:, 0] + 0.02 * input_derivative(u[:, 0], dt, 0.07)
    expected = 1.1 * (lagged - np.clip(lagged, -0.5, 0.5))  # lag, then the dead zone, then the gain
    np.testing.assert_allclose(corrected.inputs(u, dt)[:, 0], expected, rtol=1e-12)
    assert any("input_gain(F)" in note and "not applied" in note for note in corrected.notes)


@pytest.mark.parametrize("terms", [
    [("time_offset(F)", 1, 0.9), ("input_deadzone(F)", 1, 0.8), ("input_gain(F)", 0, 0.1)],
    [("input_lag(F)", 0, 0.3), ("input_saturation_above(F)", 1, 0.7), ("input_offset(F)", 0, 0.2)],
    [("input_lag(F)", -1, 0.9), ("input_saturation_below(F)", -1, 0.6)],
])
def test_held_inputs_are_what_the_corrected_model_makes_of_constant_sequences(library, terms):
    """Each row of a batch held on its own (a closed loop's step): time shifts and lags (the rate form and a slow
    actuator's filter) leave it as it is, dead zones, saturations, gains and offsets change it; the same values as
    the sequence form on a constant sequence of each row, all rows in one call."""
    problem, prepared, by_name = library
    dt = prepared.inputs.dt_s
    chosen = []
    for name, index, coef in terms:
        grid = by_name[name].grid()
        chosen.append(Term(by_name[name], grid[index], np.array([coef])))
    corrected = CorrectedModel(chosen, problem)
    assert not corrected.notes
    rows = np.linspace(-3.0, 3.0, 13)[:, None]
    held = corrected.held_inputs(rows, dt)
    sequences = np.stack([corrected.inputs(np.repeat(row[None], 3, axis=0), dt)[1] for row in rows])
    np.testing.assert_allclose(held, sequences, rtol=1e-13, atol=1e-13)
    assert np.ptp(held - rows) > 0.01  # the static changes acted


def test_a_held_input_through_a_transform_without_a_stated_form_is_its_constant_sequences_middle(library):
    from hybridfmu.diagnosis.effects import make_input_change

    problem, prepared, _ = library
    corrected = CorrectedModel([], problem)
    cumulative = make_input_change(0, transform=lambda v, dt_s: np.cumsum(v) * dt_s)  # depends on the samples before
    corrected.input_changes = {0: [("custom", cumulative)]}
    rows = np.array([[1.0], [-2.0]])
    np.testing.assert_allclose(corrected.held_inputs(rows, 0.01), [[0.02], [-0.04]], rtol=1e-14)


# ----------------------------------------------------------------------------- found from the data

def test_a_sensor_lag_is_found_with_its_time_constant_and_undone_in_the_simulation():
    """The logged force lags the true one by a first-order lag of 50 ms (and carries sensor noise). For an input
    held per sample the fitted lag includes half a sampling interval (the hold's own delay)."""
    problem, model = msd_problem(parameters=[])
    result = run_diagnosis(problem, model, msd_input_maneuvers(lag_s=0.05, sensor=True, input_noise=0.02))
    assert _chosen(result) == ["input_lag(F)"]
    lag = _params(result)["lag_s"]
    assert lag["value"] == pytest.approx(0.05 + 0.005, rel=0.03)
    assert 0 < lag["se"] < 0.01 * lag["value"]
    far = result.how_far
    assert far.gap_after < 0.05 * far.gap_before


def test_a_slow_actuator_is_found_as_a_negative_lag_with_its_exact_shape():
    """The plant feels the logged force through a 50 ms lag: the exact form (a lag filter of the held input)
    is chosen over the first-order one and over a time offset, and the corrected model applies it."""
    problem, model = msd_problem(parameters=[])
    result = run_diagnosis(problem, model, msd_input_maneuvers(lag_s=0.05, sensor=False))
    assert _chosen(result) == ["input_lag(F)"]
    params = _params(result)
    assert params["lag_s"]["value"] == pytest.approx(-0.05, rel=0.01)
    assert params["lag_s"]["se"] is not None and params["lag_s"]["se"] < 0.001
    assert params["scale"]["value"] == pytest.approx(1.0, abs=0.01)
    steps = result.which.equations["v"]["steps"][0]["candidates"]
    assert steps[0]["effect"] == "input_lag(F)" and steps[0]["setting"]["actuator_lag_s"] > 0
    far = result.how_far
    assert far.gap_after < 0.01 * far.gap_before


@pytest.mark.parametrize("case", ["deadzone", "above", "below"])
def test_an_input_dead_zone_or_saturation_is_found_with_its_level(case):
    plant_input, name, key, value = {
        "deadzone": (lambda f: f - np.clip(f, -0.8, 0.8), "input_deadzone(F)", "half_width", 0.8),
        "above": (lambda f: np.minimum(f, 3.5), "input_saturation_above(F)", "level", 3.5),
        "below": (lambda f: np.maximum(f, -2.5), "input_saturation_below(F)", "level", -2.5)}[case]
    problem, model = msd_problem(parameters=[])
    result = run_diagnosis(problem, model, msd_input_maneuvers(plant_input=plant_input))
    assert _chosen(result) == [name]
    params = _params(result)
    assert params[key]["value"] == pytest.approx(value, rel=0.01)
    assert params[key]["se"] is not None and params[key]["se"] < 0.01 * abs(value)
    assert params["scale"]["value"] == pytest.approx(1.0, abs=0.01)
    far = result.how_far
    assert far.gap_after < 0.01 * far.gap_before
