"""The batched FMU bridge: variables, derivatives, Jacobians, outputs, FmuRhs, the shim cache."""

from __future__ import annotations

import os
import subprocess
import sys

import fmpy
import numpy as np
import pytest
import torch

from hybridfmu.fmu import FmuRhs, load_fmu

IPB_STATES = ["i_d", "i_q", "theta", "omega"]
IPB_INPUTS = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
IPB_PARAMETERS = ["p", "R", "L_d", "L_q", "psi", "J", "b", "theta_min", "theta_max"]


# ---------------------------------------------------------------- independent reference


def clarke_park(a, b, c, theta_e):
    """Amplitude-invariant Clarke, then Park with the electrical angle (contracts.md)."""
    alpha = (2.0 / 3.0) * (a - 0.5 * b - 0.5 * c)
    beta = (b - c) / np.sqrt(3.0)
    return (alpha * np.cos(theta_e) + beta * np.sin(theta_e),
            -alpha * np.sin(theta_e) + beta * np.cos(theta_e))


def ipb_reference(x, u, par):
    """IPBMotor right-hand side (free rotor), written from the equations in contracts.md."""
    i_d, i_q, theta, omega = x.T
    d_a, d_b, d_c, u_dc, tau_load = u.T
    p, R, L_d, L_q, psi, J, b = (par[k] for k in ("p", "R", "L_d", "L_q", "psi", "J", "b"))
    mean = (d_a + d_b + d_c) / 3.0
    v_d, v_q = clarke_park(u_dc * (d_a - mean), u_dc * (d_b - mean), u_dc * (d_c - mean), p * theta)
    tau_e = 1.5 * p * (psi * i_q + (L_d - L_q) * i_d * i_q)
    return np.column_stack([
        (v_d - R * i_d + p * omega * L_q * i_q) / L_d,
        (v_q - R * i_q - p * omega * (L_d * i_d + psi)) / L_q,
        omega,
        (tau_e - b * omega - tau_load) / J,
    ]), tau_e, v_d, v_q


def ipb_points(n, seed=1):
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.uniform(-80, 80, n), rng.uniform(-120, 120, n), rng.uniform(0.5, 59.5, n),
                         rng.uniform(-450, 450, n)])
    u = np.column_stack([rng.uniform(0, 1, (n, 3)), rng.uniform(10, 14, n), rng.uniform(-2, 2, n)])
    return x, u


def fd_jacobians(model, x, u, rel=1e-6):
    """Central differences of model.derivatives, column by column over the whole batch."""
    n, nx, nu = x.shape[0], model.n_states, model.n_inputs
    dfdx, dfdu = np.empty((n, nx, nx)), np.empty((n, nx, nu))
    for target, values, width in ((dfdx, x, nx), (dfdu, u, nu)):
        for j in range(width):
            h = rel * np.maximum(np.abs(values[:, j]), 1.0)
            plus, minus = values.copy(), values.copy()
            plus[:, j] += h
            minus[:, j] -= h
            if values is x:
                f_plus, f_minus = model.derivatives(plus, u), model.derivatives(minus, u)
            else:
                f_plus, f_minus = model.derivatives(x, plus), model.derivatives(x, minus)
            target[:, :, j] = (f_plus - f_minus) / (2.0 * h[:, None])
    return dfdx, dfdu


def row_relative_error(a, b):
    """max over rows i of max_j |a_ij - b_ij| / max_j |a_ij| (per batch element)."""
    scale = np.maximum(np.abs(np.concatenate(a, axis=2)).max(axis=2), 1e-300)
    diff = np.abs(np.concatenate(a, axis=2) - np.concatenate(b, axis=2)).max(axis=2)
    return float((diff / scale).max())


@pytest.fixture(scope="module")
def motor(ipbmotor_fmu):
    model = load_fmu(ipbmotor_fmu)
    yield model
    model.close()


@pytest.fixture(scope="module")
def oscillator(oscillator_fmu):
    model = load_fmu(oscillator_fmu)
    yield model
    model.close()


# ---------------------------------------------------------------- description


def test_variables_of_the_demo_motor(motor):
    assert motor.state_names == IPB_STATES
    assert motor.input_names == IPB_INPUTS
    assert set(IPB_PARAMETERS) <= set(motor.parameter_names)
    assert {"tau_e", "i_a", "i_b", "i_c"} <= set(motor.output_names)
    assert (motor.n_states, motor.n_inputs) == (4, 5)
    assert motor.n_event_indicators == 3
    assert motor.provides_directional_derivative
    assert motor.initial_states.shape == (4,)


def test_variables_of_the_oscillator(oscillator):
    assert oscillator.state_names == ["x", "v"]
    assert oscillator.input_names == [] and oscillator.n_inputs == 0
    assert set(oscillator.parameter_names) == {"mu", "omega_0"}
    assert not oscillator.provides_directional_derivative
    assert oscillator.n_event_indicators == 0


# ---------------------------------------------------------------- derivatives


def test_derivatives_match_numpy_equations(motor):
    x, u = ipb_points(257)
    expected, _, _, _ = ipb_reference(x, u, motor.get_parameters())
    np.testing.assert_allclose(motor.derivatives(x, u), expected, rtol=1e-11, atol=1e-9)


def test_parameters_change_the_derivatives(ipbmotor_fmu):
    changed = {"p": 3, "R": 0.05, "L_d": 50e-6, "L_q": 70e-6, "psi": 7e-3, "J": 2.5e-4, "b": 1e-4}
    with load_fmu(ipbmotor_fmu, parameters={"J": 2.1e-4}) as model:
        assert model.get_parameters(["J"]) == {"J": 2.1e-4}
        model.set_parameters(changed)
        assert model.get_parameters(list(changed)) == pytest.approx(changed, rel=0, abs=0)
        x, u = ipb_points(64, seed=2)
        expected, _, _, _ = ipb_reference(x, u, model.get_parameters())
        np.testing.assert_allclose(model.derivatives(x, u), expected, rtol=1e-11, atol=1e-9)


def test_two_instances_are_independent(ipbmotor_fmu, motor):
    x, u = ipb_points(8, seed=3)
    with load_fmu(ipbmotor_fmu, parameters={"J": 4e-4}) as other:
        before = motor.derivatives(x, u)
        slow = other.derivatives(x, u)
        np.testing.assert_allclose(slow[:, 3] * 4e-4, before[:, 3] * motor.get_parameters(["J"])["J"], rtol=1e-12)
        np.testing.assert_array_equal(motor.derivatives(x, u), before)


def test_time_scalar_or_per_row(motor):
    x, u = ipb_points(5, seed=4)
    reference = motor.derivatives(x, u)
    np.testing.assert_array_equal(motor.derivatives(x, u, t_s=1.5), reference)
    np.testing.assert_array_equal(motor.derivatives(x, u, t_s=np.linspace(0.0, 1.0, 5)), reference)
    np.testing.assert_array_equal(motor.derivatives(x, u, t_s=np.float32(2.0)), reference)


def test_outputs_and_event_indicators(motor):
    x, u = ipb_points(33, seed=5)
    _, tau_e, v_d, v_q = ipb_reference(x, u, motor.get_parameters())
    y = motor.outputs(x, u, ["tau_e", "v_d", "v_q"])
    np.testing.assert_allclose(y, np.column_stack([tau_e, v_d, v_q]), rtol=1e-11, atol=1e-9)
    # phase currents: inverse Park/Clarke of (i_d, i_q) gives them back through the forward transform
    i_abc = motor.outputs(x, u, ["i_a", "i_b", "i_c"])
    i_d, i_q = clarke_park(i_abc[:, 0], i_abc[:, 1], i_abc[:, 2], motor.get_parameters(["p"])["p"] * x[:, 2])
    np.testing.assert_allclose(np.column_stack([i_d, i_q]), x[:, :2], rtol=1e-10, atol=1e-9)
    assert motor.outputs(x, u).shape == (33, len(motor.real_output_names))
    z = motor.event_indicators(x, u)
    par = motor.get_parameters()
    assert z.shape == (33, 3)
    np.testing.assert_allclose(z[:, 0], x[:, 2] - par["theta_min"])
    np.testing.assert_allclose(z[:, 1], par["theta_max"] - x[:, 2])


# ---------------------------------------------------------------- Jacobians


def test_directional_jacobians_match_finite_differences(motor):
    x, u = ipb_points(40, seed=6)
    dfdx, dfdu = motor.jacobians(x, u)
    assert dfdx.shape == (40, 4, 4) and dfdu.shape == (40, 4, 5)
    assert row_relative_error((dfdx, dfdu), fd_jacobians(motor, x, u)) < 1e-6
    # the bridge's own finite-difference path agrees too
    motor.jacobian_method = "fd"
    try:
        assert row_relative_error((dfdx, dfdu), motor.jacobians(x, u)) < 1e-6
    finally:
        motor.jacobian_method = "auto"


def test_oscillator_jacobian_by_finite_differences_matches_analytic(oscillator):
    rng = np.random.default_rng(7)
    x = rng.uniform(-3.0, 3.0, (50, 2))
    par = oscillator.get_parameters()
    mu, w0 = par["mu"], par["omega_0"]
    dfdx, dfdu = oscillator.jacobians(x)
    analytic = np.zeros((50, 2, 2))
    analytic[:, 0, 1] = 1.0
    analytic[:, 1, 0] = -2.0 * mu * w0 * x[:, 0] * x[:, 1] - w0 ** 2
    analytic[:, 1, 1] = mu * w0 * (1.0 - x[:, 0] ** 2)
    assert dfdu.shape == (50, 2, 0)
    assert row_relative_error((dfdx,), (analytic,)) < 1e-6
    np.testing.assert_allclose(oscillator.derivatives(x)[:, 1],
                               mu * w0 * (1 - x[:, 0] ** 2) * x[:, 1] - w0 ** 2 * x[:, 0], rtol=1e-13, atol=1e-12)


# ---------------------------------------------------------------- FmuRhs


def test_fmu_rhs_gradcheck_float64(motor):
    rhs = FmuRhs(motor)
    x_np, u_np = ipb_points(3, seed=8)
    x = torch.tensor(x_np, dtype=torch.float64, requires_grad=True)
    u = torch.tensor(u_np, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: rhs(a, b), (x, u))


def test_fmu_rhs_gradcheck_finite_difference_path(oscillator):
    rhs = FmuRhs(oscillator)
    x = torch.tensor([[0.3, -1.2], [2.0, 0.5]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a: rhs(a), (x,))


def test_fmu_rhs_float32_and_leading_dimensions(motor):
    rhs = FmuRhs(motor)
    x_np, u_np = ipb_points(12, seed=9)
    x = torch.tensor(x_np.reshape(3, 4, 4), dtype=torch.float32, requires_grad=True)
    u = torch.tensor(u_np.reshape(3, 4, 5), dtype=torch.float32)
    dx = rhs(x, u)
    assert dx.shape == (3, 4, 4) and dx.dtype == torch.float32
    expected = motor.derivatives(x.detach().double().reshape(12, 4).numpy(), u.double().reshape(12, 5).numpy())
    np.testing.assert_allclose(dx.detach().reshape(12, 4).double().numpy(), expected, rtol=1e-6)
    weights = torch.randn(3, 4, 4, generator=torch.Generator().manual_seed(0))
    (dx * weights).sum().backward()
    dfdx, _ = motor.jacobians(x.detach().double().reshape(12, 4).numpy(), u.double().reshape(12, 5).numpy())
    expected_grad = np.einsum("ni,nij->nj", weights.reshape(12, 4).double().numpy(), dfdx)
    assert x.grad.dtype == torch.float32
    np.testing.assert_allclose(x.grad.reshape(12, 4).double().numpy(), expected_grad, rtol=1e-5, atol=1e-3)


# ---------------------------------------------------------------- shim cache


def test_shim_compiles_once_per_source_and_concurrently(tmp_path):
    """Two processes that build the shim into an empty cache at once both load a complete library."""
    cache = tmp_path / "cache"
    env = dict(os.environ, HYBRIDFMU_CACHE=str(cache))
    code = "from hybridfmu.fmu import shim; print(shim.load_shim()._name)"
    procs = [subprocess.Popen([sys.executable, "-c", code], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    outputs = [proc.communicate(timeout=120) for proc in procs]
    assert all(proc.returncode == 0 for proc in procs), outputs
    paths = {out.strip() for out, _ in outputs}
    assert len(paths) == 1
    assert [p.name for p in cache.iterdir()] == [os.path.basename(paths.pop())]


def test_load_from_an_extracted_folder(ipbmotor_fmu, tmp_path, motor):
    folder = fmpy.extract(str(ipbmotor_fmu), unzipdir=str(tmp_path / "extracted"))
    x, u = ipb_points(4, seed=10)
    with load_fmu(folder) as model:
        np.testing.assert_array_equal(model.derivatives(x, u), motor.derivatives(x, u))
    assert (tmp_path / "extracted" / "modelDescription.xml").is_file()  # the user's folder is kept
