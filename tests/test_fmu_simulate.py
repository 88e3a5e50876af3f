"""Open-loop simulation: end-stop events, agreement with fmpy.simulate_fmu, the correction hook."""

from __future__ import annotations

import fmpy
import numpy as np
import pytest
from scipy.optimize import brentq

from hybridfmu.fmu import load_fmu, simulate_open_loop

DT_S = 1e-4


@pytest.fixture()
def motor(ipbmotor_fmu):
    model = load_fmu(ipbmotor_fmu)
    yield model
    model.close()


def mechanics_only(model, theta_max=2.0):
    """psi = 0 and equal duties: no currents, no electrical torque; the rotor obeys
    J domega/dt = -b omega - tau_load, which has a closed-form solution."""
    model.set_parameters({"psi": 0.0, "theta_min": 0.0, "theta_max": theta_max})
    return model.get_parameters()


def free_motion(t, theta0, tau_load, J, b):
    """Angle and speed from rest under a constant load torque (closed form)."""
    decay = np.exp(-b * t / J)
    omega = -(tau_load / b) * (1.0 - decay)
    theta = theta0 - (tau_load / b) * (t - (J / b) * (1.0 - decay))
    return theta, omega


def test_end_stop_events_match_the_closed_form(motor):
    par = mechanics_only(motor, theta_max=2.0)
    J, b, theta_max, theta_min = par["J"], par["b"], par["theta_max"], par["theta_min"]
    t = np.arange(8001) * DT_S  # 0 .. 0.8 s
    tau_load = np.where(t < 0.4, -0.01, 0.01)  # push towards theta_max, then back
    u = np.column_stack([np.full((t.size, 3), 0.5), np.full(t.size, 12.0), tau_load])
    result = simulate_open_loop(motor, t, u, np.array([0.0, 0.0, 0.5, 0.0]))

    assert result.states.shape == (t.size, 4) and result.time_s.shape == (t.size,)
    np.testing.assert_array_equal(result.states[:, :2], 0.0)
    hit_max = brentq(lambda s: free_motion(s, 0.5, -0.01, J, b)[0] - theta_max, 0.0, 0.4)
    hit_min = 0.4 + brentq(lambda s: free_motion(s, theta_max, 0.01, J, b)[0] - theta_min, 0.0, 0.4)
    times = [time_s for time_s, _ in result.events]
    descriptions = [d for _, d in result.events]
    assert all(isinstance(d, str) for d in descriptions)
    # reaching theta_max: located within the tolerance, the rotor held (omega = 0, angle clamped)
    assert times[0] == pytest.approx(hit_max, abs=1e-8)
    assert "indicator(s) [1]" in descriptions[0] and "states re-initialised" in descriptions[0]
    held = (t > hit_max + DT_S) & (t < 0.4)
    np.testing.assert_array_equal(result.states[held, 2], theta_max)
    np.testing.assert_array_equal(result.states[held, 3], 0.0)
    # the load reverses at the 0.4 s sample: released by an input event at exactly that time
    assert any(time_s == pytest.approx(0.4, abs=1e-12) and "input event" in d for time_s, d in result.events)
    # back across the stroke into theta_min, held there to the end
    assert any(time_s == pytest.approx(hit_min, abs=1e-8) and "[0]" in d for time_s, d in result.events)
    np.testing.assert_array_equal(result.states[t > hit_min + DT_S, 2], theta_min)

    # between the events the trajectory is the closed-form one
    before = t < hit_max
    theta, omega = free_motion(t[before], 0.5, -0.01, J, b)
    np.testing.assert_allclose(result.states[before, 2], theta, atol=1e-10)
    np.testing.assert_allclose(result.states[before, 3], omega, atol=1e-9)
    after = (t >= 0.4) & (t < hit_min)
    theta, omega = free_motion(t[after] - 0.4, theta_max, 0.01, J, b)
    np.testing.assert_allclose(result.states[after, 2], theta, atol=1e-10)
    np.testing.assert_allclose(result.states[after, 3], omega, atol=1e-9)


def zoh_input_signal(names, t_blocks, u_blocks, t_end):
    """FMPy input with steps at the block times (a repeated time stamp marks a discontinuity)."""
    rows = []
    for k, t_k in enumerate(t_blocks):
        if k:
            rows.append((t_k, *u_blocks[k - 1]))
        rows.append((t_k, *u_blocks[k]))
    rows.append((t_end, *u_blocks[-1]))
    return np.array(rows, dtype=[("time", float)] + [(n, float) for n in names])


def test_motor_agrees_with_fmpy_simulate_fmu(ipbmotor_fmu, motor):
    """Rotating duties and a load step, including an end-stop contact, against CVode in FMPy."""
    parameters = {"theta_max": 1.5}
    motor.set_parameters(parameters)
    t = np.arange(2001) * DT_S  # 0.2 s
    hold = 10  # inputs change every 1 ms (steps of 0.1 ms)
    t_blocks = t[::hold]
    phase = 2.0 * np.pi * 40.0 * t_blocks
    duty = 0.5 + 0.1 * np.column_stack([np.cos(phase), np.cos(phase - 2 * np.pi / 3), np.cos(phase + 2 * np.pi / 3)])
    u_blocks = np.column_stack([duty, np.full(t_blocks.size, 12.0), np.where(t_blocks < 0.1, -0.02, 0.03)])
    u = np.repeat(u_blocks, hold, axis=0)[: t.size]
    x0 = np.array([0.0, 0.0, 0.5, 0.0])
    result = simulate_open_loop(motor, t, u, x0)
    assert any("[1]" in d and "re-initialised" in d for _, d in result.events), result.events

    reference = fmpy.simulate_fmu(
        str(ipbmotor_fmu), start_time=0.0, stop_time=t[-1], solver="CVode", relative_tolerance=1e-10,
        output_interval=DT_S, input=zoh_input_signal(motor.input_names, t_blocks, u_blocks, t[-1]),
        output=motor.state_names, start_values={**dict(zip(motor.state_names, x0)), **parameters},
    )
    expected = np.column_stack([np.interp(t, reference["time"], reference[n]) for n in motor.state_names])
    scale = np.abs(expected).max(axis=0)
    assert (np.abs(result.states - expected).max(axis=0) / scale).max() < 1e-6


def test_oscillator_agrees_with_fmpy_simulate_fmu(oscillator_fmu):
    with load_fmu(oscillator_fmu, parameters={"mu": 0.5}) as model:
        t = np.arange(5001) * 1e-3  # 5 s
        x0 = np.array([1.5, 0.0])
        result = simulate_open_loop(model, t, None, x0)
        reference = fmpy.simulate_fmu(str(oscillator_fmu), stop_time=t[-1], relative_tolerance=1e-11,
                                      output_interval=1e-3, output=["x", "v"],
                                      start_values={"x": 1.5, "v": 0.0, "mu": 0.5})
        expected = np.column_stack([np.interp(t, reference["time"], reference[n]) for n in ("x", "v")])
        np.testing.assert_allclose(result.states, expected, atol=1e-7)
        assert result.events == []


def test_correction_is_added_to_the_derivatives(motor):
    """A constant correction c on domega/dt equals a load torque lowered by J c."""
    par = motor.get_parameters()
    t = np.arange(3001) * DT_S
    rng = np.random.default_rng(0)
    u = np.column_stack([rng.uniform(0.45, 0.55, (t.size, 3)), np.full(t.size, 12.0), np.full(t.size, 0.01)])
    x0 = np.array([1.0, -2.0, 10.0, 5.0])
    c = np.array([[0.0, 0.0, 0.0, 40.0]])
    seen = []

    def correction(x, u_row):
        seen.append(x.shape + u_row.shape)
        return c

    corrected = simulate_open_loop(motor, t, u, x0, correction=correction)
    shifted = u.copy()
    shifted[:, 4] -= par["J"] * 40.0
    reference = simulate_open_loop(motor, t, shifted, x0)
    np.testing.assert_allclose(corrected.states, reference.states, rtol=1e-9, atol=1e-9)
    assert seen[0] == (1, 4, 1, 5) and len(seen) == 4 * (t.size - 1)


def test_batch_evaluation_after_a_simulation_is_unaffected(motor):
    """A simulation that ends held at a stop leaves no discrete state behind for batch calls."""
    mechanics_only(motor, theta_max=1.0)
    x = np.array([[0.0, 0.0, 0.5, 3.0], [1.0, 2.0, 0.9, -3.0]])
    u = np.array([[0.5, 0.5, 0.5, 12.0, -0.01], [0.6, 0.4, 0.5, 12.0, 0.02]])
    before = motor.derivatives(x, u)
    t = np.arange(3001) * DT_S
    u_sim = np.tile([0.5, 0.5, 0.5, 12.0, -0.05], (t.size, 1))
    result = simulate_open_loop(motor, t, u_sim, np.array([0.0, 0.0, 0.5, 0.0]))
    assert result.states[-1, 2] == 1.0 and result.states[-1, 3] == 0.0  # held at theta_max
    np.testing.assert_array_equal(motor.derivatives(x, u), before)


def test_start_beyond_a_stop_and_at_a_later_time(motor):
    mechanics_only(motor, theta_max=2.0)
    t = 5.0 + np.arange(101) * DT_S
    u = np.tile([0.5, 0.5, 0.5, 12.0, -0.01], (t.size, 1))
    result = simulate_open_loop(motor, t, u, np.array([0.0, 0.0, 2.5, 1.0]))
    assert result.events and result.events[0][0] == 5.0 and "re-initialised" in result.events[0][1]
    np.testing.assert_array_equal(result.states[:, 2], 2.0)
    np.testing.assert_array_equal(result.states[:, 3], 0.0)
    np.testing.assert_array_equal(result.time_s, t)


def test_single_sample(motor):
    result = simulate_open_loop(motor, np.array([0.0]), np.array([[0.5, 0.5, 0.5, 12.0, 0.0]]),
                                np.array([1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_array_equal(result.states, [[1.0, 2.0, 3.0, 4.0]])
