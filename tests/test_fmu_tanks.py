"""The cascaded-tanks FMU (CascadedTanks): build, FMPy validation, equations against NumPy, exact
directional derivatives against finite differences, parameter checks and simulation (FMPy and the
bridge's open loop against an independent reference)."""

from __future__ import annotations

import math
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp

from hybridfmu.fmu import FmuError, load_fmu, simulate_open_loop
from hybridfmu.fmu.build import available_models, build_fmu

START = {"k1": 0.05, "k2": 0.06, "k3": 0.09, "k4": 0.05}
BLEND_V = 1e-3  # SQRT_BLEND_V of CascadedTanks.c


@pytest.fixture(scope="module")
def tanks_fmu(tmp_path_factory) -> Path:
    return build_fmu("CascadedTanks", tmp_path_factory.mktemp("tanks") / "CascadedTanks.fmu")


@pytest.fixture()
def tanks(tanks_fmu):
    model = load_fmu(tanks_fmu)
    yield model
    model.close()


def guarded_sqrt(x):
    """The model's s(x) in NumPy: 0 below 0, the C1 quadratic blend on (0, 1e-3), sqrt above."""
    x = np.asarray(x, dtype=float)
    blend = x / math.sqrt(BLEND_V) * (1.5 - 0.5 * x / BLEND_V)
    return np.where(x <= 0, 0.0, np.where(x >= BLEND_V, np.sqrt(np.maximum(x, 0.0)), blend))


def reference_rhs(x, u, k):
    """(N, 2) derivatives of the Torricelli model for states x (N, 2) and inputs u (N, 1)."""
    s1, s2 = guarded_sqrt(x[:, 0]), guarded_sqrt(x[:, 1])
    return np.stack([-k["k1"] * s1 + k["k4"] * u[:, 0], k["k2"] * s1 - k["k3"] * s2], axis=1)


def test_builds_as_a_model_exchange_fmu_that_validates(tanks_fmu):
    assert "CascadedTanks" in available_models()
    with zipfile.ZipFile(tanks_fmu) as archive:
        assert sorted(archive.namelist()) == ["binaries/linux64/CascadedTanks.so", "modelDescription.xml"]
    assert validate_fmu(str(tanks_fmu)) == []
    description = fmpy.read_model_description(str(tanks_fmu))
    assert description.modelExchange.providesDirectionalDerivative
    assert [d.variable.derivative.name for d in description.derivatives] == ["x1", "x2"]
    units = {v.name: v.unit for v in description.modelVariables}
    assert units["x1"] == units["x2"] == units["u"] == "V"


def test_interface_and_start_values(tanks):
    assert tanks.state_names == ["x1", "x2"]
    assert tanks.input_names == ["u"]
    assert tanks.get_parameters() == pytest.approx(START)
    np.testing.assert_allclose(tanks.initial_states, [5.0, 5.0])


def test_derivatives_and_output_match_the_equations(tanks):
    rng = np.random.default_rng(0)
    k = {"k1": 0.04, "k2": 0.07, "k3": 0.1, "k4": 0.06}
    tanks.set_parameters(k)
    x = np.concatenate([rng.uniform(0.0, 10.0, (40, 2)), [[-1.0, 2.0], [3.0, -0.5], [5e-4, 2e-4], [0.0, 0.0]]])
    u = rng.uniform(0.0, 10.0, (x.shape[0], 1))
    np.testing.assert_allclose(tanks.derivatives(x, u), reference_rhs(x, u, k), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(tanks.outputs(x, u, names=["y"])[:, 0], x[:, 1], rtol=0, atol=0)


def test_guarded_sqrt_is_continuous_with_finite_slope(tanks):
    levels = np.array([-1e-9, 0.0, 1e-9, BLEND_V * (1 - 1e-9), BLEND_V, BLEND_V * (1 + 1e-9)])
    x = np.stack([levels, np.full_like(levels, 4.0)], axis=1)
    dx = tanks.derivatives(x, np.zeros((levels.size, 1)))
    s = -dx[:, 0] / START["k1"]
    assert s[0] == s[1] == 0.0
    assert s[2] == pytest.approx(0.0, abs=1e-7)
    assert s[3] == pytest.approx(s[4], rel=1e-8) and s[5] == pytest.approx(s[4], rel=1e-8)
    dfdx, _ = tanks.jacobians(x, np.zeros((levels.size, 1)))
    assert np.all(np.isfinite(dfdx))
    assert dfdx[3, 0, 0] == pytest.approx(dfdx[5, 0, 0], rel=1e-6)  # C1 at the blend point


def test_exact_jacobian_matches_central_differences(tanks):
    rng = np.random.default_rng(1)
    tanks.set_parameters({"k1": 0.05, "k2": 0.08, "k3": 0.07, "k4": 0.04})
    x = rng.uniform(0.2, 10.0, (25, 2))
    u = rng.uniform(0.0, 10.0, (25, 1))
    assert tanks.provides_directional_derivative
    tanks.jacobian_method = "directional"
    dfdx, dfdu = tanks.jacobians(x, u)
    tanks.jacobian_method = "fd"
    fd_dx, fd_du = tanks.jacobians(x, u)
    np.testing.assert_allclose(dfdx, fd_dx, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(dfdu, fd_du, rtol=1e-6, atol=1e-9)
    # and against our own differences of the NumPy reference
    h = 1e-6
    for j in range(2):
        step = np.zeros((1, 2))
        step[0, j] = h
        numeric = (tanks.derivatives(x + step, u) - tanks.derivatives(x - step, u)) / (2 * h)
        np.testing.assert_allclose(dfdx[:, :, j], numeric, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(dfdu[:, 0, 0], 0.04)
    np.testing.assert_allclose(dfdu[:, 1, 0], 0.0)


def test_negative_parameter_is_rejected_with_its_name(tanks_fmu):
    with pytest.raises(FmuError, match=r"k3.*>= 0"):
        load_fmu(tanks_fmu, parameters={"k3": -0.1})


def _staircase(n: int, dt_s: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    time_s = np.arange(n) * dt_s
    levels = rng.uniform(1.0, 8.0, n // 10 + 1)
    return time_s, np.repeat(levels, 10)[:n]


def _reference_trajectory(time_s, u, x0, k) -> np.ndarray:
    """(T, 2) levels from solve_ivp, input held per sample."""
    states = [np.asarray(x0, float)]
    for i in range(time_s.size - 1):
        sol = solve_ivp(lambda t, x: reference_rhs(x[None, :], np.array([[u[i]]]), k)[0],
                        (time_s[i], time_s[i + 1]), states[-1], rtol=1e-10, atol=1e-12)
        states.append(sol.y[:, -1])
    return np.array(states)


def test_open_loop_simulation_matches_a_reference(tanks):
    time_s, u = _staircase(120, 4.0, 2)
    reference = _reference_trajectory(time_s, u, [6.0, 3.0], START)
    result = simulate_open_loop(tanks, time_s, u[:, None], np.array([6.0, 3.0]))
    np.testing.assert_allclose(result.states, reference, atol=2e-4)
    assert np.ptp(result.states[:, 1]) > 1.0


@pytest.mark.parametrize("solver", ["CVode", "Euler"])
def test_simulates_with_fmpy(tanks_fmu, solver):
    # a constant pump voltage: FMPy applies inputs at its communication points only
    signal = np.array([(0.0, 4.0), (400.0, 4.0)], dtype=[("time", float), ("u", float)])
    options = {"relative_tolerance": 1e-9, "output_interval": 4.0} if solver == "CVode" else \
        {"output_interval": 0.05, "step_size": 0.05}
    result = fmpy.simulate_fmu(str(tanks_fmu), stop_time=400.0, solver=solver, input=signal,
                               output=["x1", "x2", "y"], start_values={"x1": 6.0, "x2": 3.0, "k3": 0.08},
                               **options)
    k = dict(START, k3=0.08)
    ref = solve_ivp(lambda t, x: reference_rhs(x[None, :], np.array([[4.0]]), k)[0], (0.0, 400.0), [6.0, 3.0],
                    t_eval=result["time"], rtol=1e-11, atol=1e-12)
    tolerance = 1e-6 if solver == "CVode" else 2e-3
    np.testing.assert_allclose(result["x1"], ref.y[0], atol=tolerance)
    np.testing.assert_allclose(result["x2"], ref.y[1], atol=tolerance)
    np.testing.assert_array_equal(result["y"], result["x2"])
    assert result["x1"][-1] > 12.0  # the pump filled the upper tank
