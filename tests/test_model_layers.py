"""Neural-FMU layers: delay, gates, pre/post-processing, forwarding, gradients to every parameter."""

import math

import numpy as np
import pytest
import torch

from hybridfmu.model import (EndStop, Gates, InputDelay, NeuralFmu, NeuralFmuSpec, ScaleShift, ShiftScale,
                             TanhMLP)
from hybridfmu.training.solver import rollout

H = 1e-4


class Pendulum:
    """A small pure-torch right-hand side for the tests: a driven, damped pendulum.

    States x = [p, v, q] (rad, rad/s, -), inputs u = [f, g] (drive in rad/s^2, damping gain):
    dp/dt = v, dv/dt = f - K sin(p) - C g v, dq/dt = g v / 2 - q (a third state the ANN leaves alone).
    Offers closed-form Jacobians like the FMU bridge.
    """

    state_names = ["p", "v", "q"]
    input_names = ["f", "g"]
    K, C = 400.0, 2.0

    def __call__(self, x, u):
        p, v, q = x.unbind(dim=1)
        f, g = u.unbind(dim=1)
        return torch.stack([v, f - self.K * torch.sin(p) - self.C * g * v, 0.5 * v * g - q], dim=1)

    def value_and_jacobians(self, x, u):
        """(xdot (N, 3), dfdx (N, 3, 3), dfdu (N, 3, 2))."""
        p, v, q = x.unbind(dim=1)
        f, g = u.unbind(dim=1)
        zero, one = torch.zeros_like(p), torch.ones_like(p)
        dfdx = torch.stack([torch.stack([zero, one, zero], 1),
                            torch.stack([-self.K * torch.cos(p), -self.C * g, zero], 1),
                            torch.stack([zero, 0.5 * g, -one], 1)], dim=1)
        dfdu = torch.stack([torch.stack([zero, zero], 1), torch.stack([one, -self.C * v], 1),
                            torch.stack([zero, 0.5 * v], 1)], dim=1)
        return self(x, u), dfdx, dfdu


STATS = dict(x_mean=[0.0, 10.0, 1.0], x_std=[0.5, 30.0, 2.0], u_mean=[50.0, 1.0], u_std=[30.0, 0.3],
             xdot_mean=[0.0, 0.0, 0.0], xdot_std=[30.0, 1e3, 10.0])


def make_spec(**overrides):
    kwargs = dict(state_names=Pendulum.state_names, input_names=Pendulum.input_names, corrected_states=["v"],
                  ann_states=Pendulum.state_names, ann_inputs=Pendulum.input_names,
                  ann_derivatives=Pendulum.state_names, sample_period_s=H, width=8, depth=2, gate_opening=0.3,
                  delay_min_s=-5e-4, delay_max_s=5e-4, ann_output_init="random")
    kwargs.update(overrides)
    return NeuralFmuSpec(**kwargs)


def inputs(batch, length, seed=0):
    """(batch, length, 2) inputs: a drive around 50 rad/s^2 and a damping gain around 1."""
    gen = torch.Generator().manual_seed(seed)
    u = torch.rand(batch, length, 2, dtype=torch.float64, generator=gen)
    return torch.stack([u[..., 0] * 60.0 + 20.0, u[..., 1] * 0.4 + 0.8], dim=-1)


def test_delay_shifts_by_whole_samples_and_interpolates():
    seq = torch.arange(20, dtype=torch.float64).reshape(1, 20, 1)
    delay = InputDelay(H, -5e-4, 5e-4, init_s=2 * H, sample_position="sample_instant")
    assert delay.delays_s().item() == pytest.approx(2 * H, rel=1e-12)
    out = delay(seq, 5, 4)
    assert torch.allclose(out.flatten(), torch.tensor([7.0, 8.0, 9.0, 10.0], dtype=torch.float64))
    half = InputDelay(H, -5e-4, 5e-4, init_s=-0.25 * H, sample_position="sample_instant")(seq, 5, 3, 0.5)
    assert torch.allclose(half.flatten(), torch.tensor([5.25, 6.25, 7.25], dtype=torch.float64))
    centred = InputDelay(H, -5e-4, 5e-4, init_s=0.0, sample_position="hold_center")(seq, 5, 2)
    assert torch.allclose(centred.flatten(), torch.tensor([4.5, 5.5], dtype=torch.float64))
    # beyond the ends the edge values are held
    edge = InputDelay(H, -5e-4, 5e-4, init_s=-3 * H, sample_position="sample_instant")(seq, 2, 3)
    assert torch.allclose(edge.flatten(), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), atol=1e-9)


def test_a_group_with_its_own_bounds_stays_within_them():
    """bounds_s narrows one group's range; the other keeps [min_s, max_s]; bad bounds are named."""
    delay = InputDelay(H, -5e-4, 5e-4, init_s={"a": 2e-5, "b": 0.0}, groups=[("a", [0]), ("b", [1])],
                       bounds_s={"a": (1.5e-5, 3e-5)})
    assert delay.delays_s().tolist() == pytest.approx([2e-5, 0.0], abs=1e-15)
    with torch.no_grad():
        delay.raw.fill_(1e6)
    assert delay.delays_s().tolist() == pytest.approx([3e-5, 5e-4], rel=1e-9)
    with torch.no_grad():
        delay.raw.fill_(-1e6)
    assert delay.delays_s().tolist() == pytest.approx([1.5e-5, -5e-4], rel=1e-9)
    assert set(delay.state_dict()) == {"raw", "group_of_input", "group_masks"}  # checkpoints keep their layout
    with pytest.raises(ValueError, match=r"group 'a' must satisfy min_s <= low < high <= max_s"):
        InputDelay(H, -5e-4, 5e-4, init_s=0.0, groups=[("a", [0])], bounds_s={"a": (1e-5, 6e-4)})
    with pytest.raises(ValueError, match=r"bounds of group 'a' to hold its init_s"):
        InputDelay(H, -5e-4, 5e-4, init_s=0.0, groups=[("a", [0])], bounds_s={"a": (1e-5, 2e-5)})
    with pytest.raises(ValueError, match=r"unknown group\(s\) \['c'\]"):
        InputDelay(H, -5e-4, 5e-4, init_s=0.0, groups=[("a", [0])], bounds_s={"c": (-1e-5, 2e-5)})


def test_delay_is_bounded_and_gradient_is_right():
    delay = InputDelay(H, -2e-4, 3e-4, init_s=0.0, scale_s=1e-4)
    with torch.no_grad():
        delay.raw.fill_(1e6)
    assert delay.delays_s().item() <= 3e-4 + 1e-18
    delay = InputDelay(H, -5e-4, 5e-4, init_s=0.37 * H, scale_s=1e-4)
    seq = torch.randn(2, 30, 3, dtype=torch.float64, requires_grad=True)
    raw = delay.raw.detach().clone().requires_grad_(True)

    def shifted(raw_value, u):
        return torch.func.functional_call(delay, {"raw": raw_value}, (u, 10, 12, 0.5))

    # gradcheck w.r.t. dt (through its raw parameter) and the sampled inputs
    assert torch.autograd.gradcheck(shifted, (raw, seq))
    # d/d(dt) of the interpolation is the local slope of the input sequence
    out = shifted(raw, seq)
    (grad_raw,) = torch.autograd.grad(out.sum(), raw)
    position = 10 + 0.5 - 0.5 + 0.37
    slope = (seq[:, 11:23] - seq[:, 10:22]).sum() / H
    d_delay_d_raw = 1e-4 * (1 - (delay.delays_s() / 5e-4) ** 2)
    assert int(position) == 10 and grad_raw.item() == pytest.approx((slope * d_delay_d_raw).item(), rel=1e-9)


def test_fixed_delay_has_no_parameter():
    delay = InputDelay(H, 1e-4, 1e-4, init_s=1e-4)
    assert list(delay.parameters()) == []
    assert delay.delays_s().item() == pytest.approx(1e-4)


def test_gates_mix_and_forward():
    gates = Gates(4, [3], opening=0.25)  # four states, the last one corrected
    xdot_f = torch.tensor([[1.0, 2.0, 3.0, 4.0]], dtype=torch.float64)
    xdot_a = torch.tensor([[8.0]], dtype=torch.float64)
    assert gates(xdot_f, xdot_a).tolist() == [[1.0, 2.0, 3.0, 4.0 + 0.25 * 8.0]]
    with torch.no_grad():
        gates.g_F.fill_(0.5)
    assert gates(xdot_f, xdot_a).tolist() == [[1.0, 2.0, 3.0, 2.0 + 2.0]]


def test_pre_and_post_invert_each_other():
    pre = ShiftScale.from_statistics(torch.tensor([1.0, -2.0, 30.0]), torch.tensor([2.0, 0.5, 10.0]))
    z = torch.randn(5, 3, dtype=torch.float64) * 10
    normalised = pre(z)
    assert torch.allclose(pre.inverse()(normalised), z, atol=1e-12)
    data = torch.randn(10000, 3, dtype=torch.float64) * torch.tensor([2.0, 0.5, 10.0]) + torch.tensor([1.0, -2.0, 30.0])
    out = pre(data)
    assert out.mean(0).abs().max() < 0.05 and (out.std(0) - 1).abs().max() < 0.05
    post = ScaleShift.from_statistics(torch.tensor([3.0]), torch.tensor([7.0]))
    assert post(torch.zeros(1, 1, dtype=torch.float64)).item() == 3.0
    assert post(torch.ones(1, 1, dtype=torch.float64)).item() == 10.0


def test_mlp_layout():
    mlp = TanhMLP(13, 1, width=16, depth=3)
    assert len(mlp.hidden) == 3 and mlp.output.out_features == 1
    assert mlp(torch.zeros(4, 13, dtype=torch.float64)).shape == (4, 1)


def test_forwarded_derivatives_untouched_and_fused_equals_layers():
    torch.manual_seed(0)
    model = NeuralFmu(Pendulum(), make_spec(depth=3), STATS)
    x = torch.randn(6, 3, dtype=torch.float64) * torch.tensor([0.5, 30.0, 2.0])
    u = inputs(6, 1)[:, 0]
    xdot = model.derivative(x, u)
    xdot_f = Pendulum()(x, u)
    assert torch.equal(xdot[:, [0, 2]], xdot_f[:, [0, 2]])
    assert not torch.allclose(xdot[:, 1], xdot_f[:, 1])
    fused = model.fused()
    assert torch.allclose(fused(x, u, fused.input_term(u)), xdot, rtol=1e-13, atol=1e-9)
    with torch.no_grad():
        model.gates.g_A.zero_()
    assert torch.equal(model.derivative(x, u), xdot_f)


def plain_pendulum(x, u):
    """The pendulum as a bare callable (no Jacobians offered: the adjoint falls back to autograd)."""
    return Pendulum()(x, u)


def test_fixture_jacobians_match_autograd():
    x = torch.tensor([[0.3, -20.0, 1.0], [1.5, 2.0, -1.0]], dtype=torch.float64)
    u = inputs(2, 1)[:, 0]
    xdot, dfdx, dfdu = Pendulum().value_and_jacobians(x, u)
    ref_x, ref_u = torch.func.vmap(torch.func.jacrev(lambda a, b: Pendulum()(a[None], b[None])[0],
                                                     argnums=(0, 1)))(x, u)
    assert torch.allclose(xdot, Pendulum()(x, u))
    assert torch.allclose(dfdx, ref_x, rtol=1e-12, atol=1e-9)
    assert torch.allclose(dfdu, ref_u, rtol=1e-12, atol=1e-9)


class BridgedPendulum:
    """The pendulum behind the FMU bridge's NumPy interface (the way ``hybridfmu.fmu.FmuRhs`` wraps an FMU:
    ``model.derivatives``, ``model.jacobians``, ``model.derivatives_and_jacobians_kernel``), so that the adjoint
    runs its stages in NumPy (``training.numpy_adjoint``). Counts the kernel's calls."""

    def __init__(self) -> None:
        self.model = self
        self.kernel_calls = 0

    def __call__(self, x, u):
        return Pendulum()(x, u)

    def derivatives(self, x, u):
        return Pendulum()(torch.from_numpy(np.asarray(x)), torch.from_numpy(np.asarray(u))).numpy()

    def jacobians(self, x, u):
        _, dfdx, dfdu = Pendulum().value_and_jacobians(torch.from_numpy(np.asarray(x)), torch.from_numpy(np.asarray(u)))
        return dfdx.numpy(), dfdu.numpy()

    def derivatives_and_jacobians_kernel(self, n):
        def kernel(x, u):
            assert x.shape[0] == n
            self.kernel_calls += 1
            xdot, dfdx, dfdu = Pendulum().value_and_jacobians(torch.from_numpy(x.copy()), torch.from_numpy(u.copy()))
            return xdot.numpy(), dfdx.numpy(), dfdu.numpy()
        return kernel


@pytest.mark.parametrize("solver,rhs", [("rk4", Pendulum()), ("euler", Pendulum()), ("rk4", plain_pendulum),
                                        ("rk4", BridgedPendulum()), ("euler", BridgedPendulum())])
def test_gradients_reach_every_parameter_and_adjoint_matches_autograd(solver, rhs):
    """The adjoint (NumPy stages for a bridged right-hand side, torch stages otherwise, and the torch stages
    forced) gives autograd's states and gradients, through the delay, the end stop and every layer."""
    torch.manual_seed(1)
    stop = EndStop("p", "v", -1.0, 0.02)
    model = NeuralFmu(rhs, make_spec(solver=solver, delay_init_s=0.3 * H, end_stop=stop), STATS)
    u = inputs(3, 60).requires_grad_(True)
    x0 = torch.tensor([[0.0, 50.0, 1.0]] * 3, dtype=torch.float64, requires_grad=True)
    results = {}
    for mode in ("autograd", "adjoint", "adjoint_torch"):
        model.zero_grad()
        u.grad = x0.grad = None
        states = rollout(model, u, 10, x0, 40, gradients=mode)
        assert states.shape == (3, 41, 3)
        loss = ((states[:, :, 0] + states[:, :, 2]) * torch.linspace(0, 1, 41, dtype=torch.float64)).sum() \
            + 1e-3 * states[:, :, 1].pow(2).mean()
        loss.backward()
        results[mode] = (states.detach(), {n: p.grad.clone() for n, p in model.named_parameters()}, u.grad.clone(),
                         x0.grad.clone())
    ref = results["autograd"]
    assert (ref[0][:, :, 0] >= 0.02 - 1e-15).any(), "the end stop must be reached in this test"
    for mode in ("adjoint", "adjoint_torch"):
        fast = results[mode]
        assert torch.allclose(ref[0], fast[0], rtol=0, atol=1e-12), mode
        for name, grad in ref[1].items():
            assert torch.isfinite(grad).all() and grad.abs().sum() > 0, f"no gradient reaches {name}"
            assert torch.allclose(fast[1][name], grad, rtol=1e-9, atol=1e-12 * grad.abs().max()), (mode, name)
        assert torch.allclose(fast[2], ref[2], rtol=1e-9, atol=1e-14), mode
        assert torch.allclose(fast[3], ref[3], rtol=1e-9, atol=1e-14), mode
    if isinstance(rhs, BridgedPendulum):  # "adjoint" ran its stages through the NumPy kernel, once per stage
        assert rhs.kernel_calls == (4 if solver == "rk4" else 1) * 40


def test_adjoint_uses_rhs_jacobians_when_offered():
    class CountingPendulum(Pendulum):
        calls = 0

        def value_and_jacobians(self, x, u):
            CountingPendulum.calls += 1
            return super().value_and_jacobians(x, u)

    torch.manual_seed(2)
    spec = make_spec()
    plain, jac = NeuralFmu(plain_pendulum, spec, STATS), NeuralFmu(CountingPendulum(), spec, STATS)
    jac.load_state_dict(plain.state_dict())
    u = inputs(2, 40)
    x0 = torch.tensor([[0.1, 20.0, 1.0]] * 2, dtype=torch.float64)
    grads = []
    for model in (plain, jac):
        rollout(model, u, 5, x0, 20)[:, :, 1].sum().backward()
        grads.append(torch.cat([p.grad.flatten() for p in model.parameters()]))
    assert CountingPendulum.calls == 4 * 20
    assert torch.allclose(grads[0], grads[1], rtol=1e-10)


def test_zero_output_init_starts_at_the_fmu():
    stats = dict(STATS, xdot_mean=[0.0, 50.0, 0.0])
    model = NeuralFmu(Pendulum(), make_spec(ann_output_init="zero", gate_opening=0.2), stats)
    x = torch.randn(5, 3, dtype=torch.float64) * torch.tensor([0.5, 30.0, 2.0])
    u = inputs(5, 1)[:, 0]
    expected = Pendulum()(x, u)
    expected[:, 1] += 0.2 * 50.0  # g_A times the post-processing shift (the mean FMU acceleration)
    assert torch.allclose(model.derivative(x, u), expected, rtol=1e-14, atol=1e-9)
    with pytest.raises(ValueError, match="ann_output_init"):
        make_spec(ann_output_init="ones")


def test_spec_names_are_checked():
    with pytest.raises(ValueError, match="corrected_states"):
        make_spec(corrected_states=["w"])
    with pytest.raises(ValueError, match="ann_inputs"):
        make_spec(ann_inputs=["voltage"])
    spec = make_spec(end_stop=EndStop("p", "v", 0.0, 6.0))
    assert NeuralFmuSpec.from_dict(spec.to_dict()) == spec
    assert math.isclose(spec.sample_period_s, H)


@pytest.mark.parametrize("gradients", ["torchdiffeq", "torchdiffeq_adjoint"])
def test_torchdiffeq_solver_agrees_with_the_classical_rk4(gradients):
    """The library path (torchdiffeq's fixed-grid RK4, the 3/8 rule, inputs from the delay at its stage times)
    integrates the same model: states and gradients close to the hand-written solver's (they differ where the
    3/8 rule samples the piecewise-linear inputs elsewhere, most in the delay's gradient, which is the inputs'
    slope); a model with an end stop is refused."""
    torch.manual_seed(3)
    model = NeuralFmu(Pendulum(), make_spec(delay_init_s=0.3 * H), STATS)
    u = inputs(2, 60)
    x0 = torch.tensor([[0.1, 20.0, 1.0], [0.5, -10.0, 0.0]], dtype=torch.float64)
    results = {}
    for mode in ("adjoint", gradients):
        model.zero_grad(set_to_none=True)
        states = rollout(model, u, 10, x0, 40, gradients=mode)
        assert states.shape == (2, 41, 3)
        (states[:, :, 0].sum() + 1e-3 * states[:, :, 1].pow(2).mean()).backward()
        results[mode] = (states.detach(), {n: p.grad.clone() for n, p in model.named_parameters()})
    (ref, ref_grads), (lib, lib_grads) = results["adjoint"], results[gradients]
    assert not torch.equal(ref, lib)  # another RK4 (3/8 rule) ...
    scale = ref.abs().amax(dim=(0, 1))
    assert ((lib - ref).abs().amax(dim=(0, 1)) <= 2e-5 * scale).all()  # ... of the same model
    for name, grad in ref_grads.items():
        relative = float((lib_grads[name] - grad).abs().max() / grad.abs().max())
        assert relative < (0.2 if name == "delay.raw" else 0.01), (name, relative)
    stopped = NeuralFmu(Pendulum(), make_spec(end_stop=EndStop("p", "v", -1.0, 0.02)), STATS)
    with pytest.raises(ValueError, match="end stop"):
        rollout(stopped, u, 10, x0, 40, gradients=gradients)


def test_groups_of_inputs_get_their_own_delay():
    seq = torch.stack([torch.arange(20.0), 100.0 + torch.arange(20.0), 200.0 + torch.arange(20.0)],
                      dim=-1).to(torch.float64).reshape(1, 20, 3)
    delay = InputDelay(H, -5e-4, 5e-4, init_s={"fast": 2 * H, "slow": -0.5 * H}, sample_position="sample_instant",
                       groups=[("fast", [0, 2]), ("slow", [1])], n_inputs=3)
    out = delay(seq, 5, 2)
    assert torch.allclose(out[0], torch.tensor([[7.0, 104.5, 207.0], [8.0, 105.5, 208.0]], dtype=torch.float64))
    assert torch.allclose(delay.input_delays_s(), torch.tensor([2 * H, -0.5 * H, 2 * H], dtype=torch.float64))
    # each group's delay gets the gradient of its own inputs only
    delay(seq, 5, 2)[..., 1].sum().backward()
    assert delay.raw.grad[0] == 0.0 and delay.raw.grad[1] != 0.0
    with pytest.raises(ValueError, match="exactly once"):
        InputDelay(H, -5e-4, 5e-4, groups=[("a", [0]), ("b", [0, 1])], n_inputs=2)
    with pytest.raises(ValueError, match="name every group"):
        InputDelay(H, -5e-4, 5e-4, init_s={"a": 0.0}, groups=[("a", [0]), ("b", [1])], n_inputs=2)


def test_spec_checks_the_delay_groups():
    spec = make_spec(delay_groups={"drive": ["f"], "gain": ["g"]}, delay_init_s={"drive": 1e-4, "gain": 0.0})
    assert spec.delay_group_columns() == {"drive": [0], "gain": [1]}
    model = NeuralFmu(Pendulum(), spec, STATS)
    assert model.delay_s() == pytest.approx({"drive": 1e-4, "gain": 0.0})
    assert model.input_delays_s() == pytest.approx({"f": 1e-4, "g": 0.0})
    assert make_spec().delay_group_columns() == {"inputs": [0, 1]}
    with pytest.raises(ValueError, match=r"in none \['g'\]"):
        make_spec(delay_groups={"drive": ["f"]})
    with pytest.raises(ValueError, match=r"unknown \['h'\]"):
        make_spec(delay_groups={"drive": ["f", "h"], "gain": ["g"]})
    with pytest.raises(ValueError, match="a value for each group"):
        make_spec(delay_groups={"drive": ["f"], "gain": ["g"]}, delay_init_s={"drive": 0.0})


def test_delays_are_written_in_a_unit_that_fits():
    from hybridfmu.model.delay import describe_delays, format_delay

    assert format_delay(2.814e-5) == "28.14 µs" and format_delay(-0.04408) == "-44.08 ms"
    assert format_delay(2.5) == "2.5 s"
    assert describe_delays({"duties": 3e-5, "supply": 0.0}) == "duties 30.00 µs, supply 0.00 µs"
