"""FMU arrays from an ingested frame: inputs in the FMU's order, measured states, i_d/i_q through Park."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from hybridfmu.data.errors import DataError
from hybridfmu.data.signals import clarke_park, currents_dq, input_array, state_array, time_array

POLE_PAIRS = 4


def frame_with_currents(i_d_a, i_q_a, n=500, seed=1):
    """Phase currents that an inverse Park/Clarke of known (i_d, i_q) gives at a moving angle."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(n) * 1e-4
    theta = 5.0 + 30.0 * time_s + 0.1 * np.sin(50 * time_s)
    angle_e = POLE_PAIRS * theta
    alpha = i_d_a * np.cos(angle_e) - i_q_a * np.sin(angle_e)
    beta = i_d_a * np.sin(angle_e) + i_q_a * np.cos(angle_e)
    return pd.DataFrame({
        "time_s": time_s,
        "duty_a": rng.uniform(0, 1, n), "duty_b": rng.uniform(0, 1, n), "duty_c": rng.uniform(0, 1, n),
        "u_dc_v": np.full(n, 12.0), "tau_load_nm": np.linspace(0, 1, n),
        "theta_rad": theta, "omega_rad_s": np.gradient(theta, time_s),
        "i_a_a": alpha,
        "i_b_a": -0.5 * alpha + math.sqrt(3) / 2 * beta,
        "i_c_a": -0.5 * alpha - math.sqrt(3) / 2 * beta,
    })


def test_inputs_in_the_fmus_order():
    frame = frame_with_currents(0.0, 10.0)
    u = input_array(frame, {})
    assert u.shape == (len(frame), 5)
    np.testing.assert_array_equal(u[:, 3], frame["u_dc_v"])
    reordered = input_array(frame, {}, input_names=["tau_load", "d_c", "d_b", "d_a", "u_dc"])
    np.testing.assert_array_equal(reordered[:, 0], frame["tau_load_nm"])
    np.testing.assert_array_equal(reordered[:, 1], frame["duty_c"])
    with pytest.raises(DataError, match=r"no column for FMU input\(s\) \['v_bat'\]"):
        input_array(frame, {}, input_names=["d_a", "v_bat"])


def test_park_with_the_measured_angle_recovers_dq():
    i_d_true = np.linspace(-3.0, 3.0, 500)
    i_q_true = 20.0 + 5.0 * np.sin(np.arange(500) / 40.0)
    frame = frame_with_currents(i_d_true, i_q_true)
    i_d, i_q = currents_dq(frame, {"pole_pairs": POLE_PAIRS})
    np.testing.assert_allclose(i_d, i_d_true, atol=1e-10)
    np.testing.assert_allclose(i_q, i_q_true, atol=1e-10)
    # the wrong pole-pair count gives other currents
    i_d_wrong, _ = currents_dq(frame, {}, pole_pairs=2)
    assert np.abs(i_d_wrong - i_d_true).max() > 1.0


def test_clarke_park_at_zero_angle():
    # a: 1 A, b and c: -0.5 A (balanced) at theta_e = 0 -> i_d = 1, i_q = 0 (amplitude-invariant)
    i_d, i_q = clarke_park(np.array([1.0]), np.array([-0.5]), np.array([-0.5]), np.array([0.0]))
    assert i_d[0] == pytest.approx(1.0) and i_q[0] == pytest.approx(0.0, abs=1e-15)
    i_d, i_q = clarke_park(np.array([1.0]), np.array([-0.5]), np.array([-0.5]), np.array([math.pi / 2]))
    assert i_d[0] == pytest.approx(0.0, abs=1e-15) and i_q[0] == pytest.approx(-1.0)


def test_state_array_in_fmu_state_order():
    frame = frame_with_currents(1.0, 15.0)
    x = state_array(frame, {}, state_names=["i_d", "i_q", "theta", "omega"])
    assert x.shape == (len(frame), 4)
    np.testing.assert_allclose(x[:, 0], 1.0, atol=1e-10)
    np.testing.assert_allclose(x[:, 1], 15.0, atol=1e-10)
    np.testing.assert_array_equal(x[:, 2], frame["theta_rad"])
    np.testing.assert_array_equal(x[:, 3], frame["omega_rad_s"])
    np.testing.assert_array_equal(time_array(frame), frame["time_s"])
    default = state_array(frame, {})
    np.testing.assert_array_equal(default, x)
    without_currents = frame.drop(columns=["i_a_a", "i_b_a", "i_c_a"])
    assert state_array(without_currents, {}).shape == (len(frame), 2)
    with pytest.raises(DataError, match=r"column 'i_a_a' missing"):
        state_array(without_currents, {}, state_names=["i_d", "theta"])
    with pytest.raises(DataError, match=r"state\(s\) \['psi'\] are neither"):
        state_array(frame, {}, state_names=["psi"])


def test_signals_config_is_validated():
    from hybridfmu.config import ConfigError

    with pytest.raises(ConfigError, match=r"config\.signals\.pole_pairs"):
        currents_dq(frame_with_currents(0.0, 1.0), {"pole_pairs": 0})
