"""The hybrid's physical layer: the diagnosed model saved and loaded, the FMU plus its effects with the bridge's
interface (values, Jacobians, parameters, input changes), and a neural FMU trained around it."""

from __future__ import annotations

import os
import pickle

import numpy as np
import pytest
import torch

from diagnosis_models import MassSpringDamper, msd_maneuvers, msd_problem
from hybridfmu.diagnosis.corrected_model import CorrectedModel
from hybridfmu.diagnosis.export import DiagnosedModel, load_diagnosed, save_diagnosed
from hybridfmu.diagnosis.library import build_library
from hybridfmu.diagnosis.prepare import prepare_maneuver
from hybridfmu.diagnosis.problem import set_data_statistics
from hybridfmu.diagnosis.selection import Term
from hybridfmu.fmu import FmuRhs
from hybridfmu.model import NeuralFmu, NeuralFmuSpec
from hybridfmu.model.physics import PhysicsModel, physics_effects
from hybridfmu.model.settings import uses_physics
from hybridfmu.training.solver import rollout

H = 0.01
#: the kinds some tests' physical layers leave out (the diagnosed time offsets of inputs)
DELAY_KINDS = ("time_offset",)


class BridgedSpring(MassSpringDamper):
    """The mass-spring-damper with the FMU bridge's signatures (a time argument, a name, counts)."""

    model_name = "BridgedSpring"
    n_states, n_inputs = 2, 1
    initial_states = np.zeros(2)

    def derivatives(self, x, u=None, t_s=0.0):
        return super().derivatives(x, u)

    def jacobians(self, x, u=None, t_s=0.0):
        return super().jacobians(x, u)


@pytest.fixture(scope="module")
def diagnosed():
    """A diagnosed model of the mass-spring-damper with an additive term of every shape the library fits by row
    (Coulomb with a Stribeck peak, friction scaled by |F|, periodic, viscous), a parameter error, an input gain
    and a time offset."""
    problem, model = msd_problem(equations=["x", "v"], periodic={"x": 1.0}, effects={"periodic_max_order": 12})
    measured = msd_maneuvers(None, duration_s=5.0)
    set_data_statistics(problem, [measured["train"].x], H)
    prepared = prepare_maneuver(measured["train"], model, problem)
    effects, _ = build_library(problem, prepared.inputs, model)
    by_name = {e.name: e for e in effects[1]}
    coulomb = by_name["coulomb(v)"]
    setting = next(s for s in coulomb.grid() if s["stribeck_velocity"] > 0)
    scaled = by_name["coulomb(v)*|F|"]
    periodic = by_name["periodic(x)"]
    periodic_setting = periodic.grid()[-1]
    terms = [Term(coulomb, setting, np.array([0.3, 0.2])),
             Term(scaled, {"asymmetric": 1.0, "smoothing": scaled.grid()[0]["smoothing"]}, np.array([0.05, 0.01])),
             Term(periodic, periodic_setting,
                  np.linspace(0.1, 0.4, len(periodic.coefficient_names(periodic_setting)))),
             Term(by_name["viscous(v)"], {}, np.array([0.2])),
             Term(by_name["parameter(m)"], {}, np.array([0.1 / 1.1])),  # a mass 10 % larger (dv/dt ~ 1 / m)
             Term(by_name["input_gain(F)"], {}, np.array([0.05])),
             Term(by_name["time_offset(F)"], {"shift_s": 2 * H}, np.array([1.0]))]
    return DiagnosedModel(terms, {"k": 4.4}, problem, [t.effect.name for t in terms])


def states_and_inputs(n=40, seed=3):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.normal(0, 0.5, n), rng.normal(0, 2.0, n)]), rng.normal(0, 3.0, (n, 1))


def test_vectorised_terms_equal_the_row_terms(diagnosed):
    """The batch evaluation the training uses gives the per-row values of the diagnosis' simulation."""
    corrected = CorrectedModel(diagnosed.terms, diagnosed.problem)
    x, u = states_and_inputs()
    np.testing.assert_allclose(corrected.additive_batch(x, u), corrected(x, u), rtol=1e-12, atol=1e-12)
    assert np.abs(corrected.additive_batch(x, u)[:, 1]).max() > 0.1


def test_physics_model_adds_the_effects_to_the_fmu(diagnosed):
    fmu, helper = BridgedSpring(), BridgedSpring()
    physics = PhysicsModel(fmu, helper, diagnosed)
    # the refit's parameter and the parameter error of parameter(m) are set on both instances
    assert fmu.values == pytest.approx({"m": 1.1, "k": 4.4, "c": 0.4}, rel=1e-4)
    assert helper.values == fmu.values
    x, u = states_and_inputs()
    terms = CorrectedModel(diagnosed.terms, diagnosed.problem)(x, u)
    np.testing.assert_allclose(physics.derivatives(x, u), fmu.derivatives(x, u) + terms, rtol=1e-12)
    # input changes act on whole sequences: the gain and the time offset by two samples
    sequence = np.arange(10.0)[:, None]
    seen = physics.inputs(sequence, H)
    np.testing.assert_allclose(seen[:-2, 0], 1.05 * sequence[2:, 0])


class KernelSpring(BridgedSpring):
    """The bridged spring with the bridge's low-overhead kernel: one buffer, overwritten by every call."""

    def derivatives_kernel(self, n):
        buffer = np.empty((n, 2))

        def kernel(x, u):
            buffer[:] = self.derivatives(x, u)
            return buffer

        return kernel


@pytest.mark.parametrize("fmu_class", [BridgedSpring, KernelSpring])
def test_physics_kernel_gives_the_derivatives_in_fresh_arrays(diagnosed, fmu_class):
    """The gradient-free rollouts' kernel: the FMU's kernel (or its derivatives) plus the terms, the values of
    ``derivatives`` to the bit, and a result that the next call does not overwrite."""
    physics = PhysicsModel(fmu_class(), fmu_class(), diagnosed)
    x, u = states_and_inputs(n=6)
    kernel = physics.derivatives_kernel(6)
    first = kernel(x, u)
    np.testing.assert_array_equal(first, physics.derivatives(x, u))
    kept = first.copy()
    second = kernel(x + 1.0, u)
    np.testing.assert_array_equal(first, kept)
    np.testing.assert_array_equal(second, physics.derivatives(x + 1.0, u))
    assert not np.array_equal(first, second)


def test_physics_jacobians_match_central_differences(diagnosed):
    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed)
    x, u = states_and_inputs(n=12)
    dfdx, dfdu = physics.jacobians(x, u)
    for j in range(2):
        step = np.zeros(2)
        step[j] = 1e-6
        numeric = (physics.derivatives(x + step, u) - physics.derivatives(x - step, u)) / 2e-6
        np.testing.assert_allclose(dfdx[:, :, j], numeric, rtol=1e-5, atol=1e-6)
    numeric = (physics.derivatives(x, u + 1e-6) - physics.derivatives(x, u - 1e-6)) / 2e-6
    np.testing.assert_allclose(dfdu[:, :, 0], numeric, rtol=1e-5, atol=1e-6)
    # the friction terms make the Jacobian differ from the FMU's
    assert np.abs(dfdx - physics.fmu.jacobians(x, u)[0]).max() > 1e-2


def test_selection_leaves_out_delay_kinds_and_names_unknown_effects(diagnosed):
    kept = diagnosed.selected(None, DELAY_KINDS)
    assert "time_offset(F)" not in kept.effects and len(kept.effects) == len(diagnosed.effects) - 1
    assert diagnosed.selected(["viscous(v)"]).effects == ["viscous(v)"]
    with pytest.raises(ValueError, match=r"config.model.physics_terms: \['friction\(z\)'\] are not effects"):
        diagnosed.selected(["friction(z)"])
    assert physics_effects("from_diagnosis") is None and physics_effects(["a"]) == ["a"]
    with pytest.raises(ValueError, match="physics_terms"):
        physics_effects("none")
    assert uses_physics({"physics_terms": "from_diagnosis"}) and not uses_physics({})


def test_physics_model_refuses_another_fmu(diagnosed):
    class Other(BridgedSpring):
        state_names = ["y", "w"]

    with pytest.raises(ValueError, match=r"diagnosed model: states \['x', 'v'\].*differ from the FMU's \['y', 'w'\]"):
        PhysicsModel(Other(), Other(), diagnosed)


def test_saved_model_loads_back_and_bad_files_are_named(diagnosed, tmp_path):
    path = save_diagnosed(diagnosed, tmp_path / "diagnosis" / "diagnosed_model.pkl")
    loaded = load_diagnosed(path)
    assert loaded.effects == diagnosed.effects and loaded.parameters == diagnosed.parameters
    x, u = states_and_inputs()
    np.testing.assert_allclose(CorrectedModel(loaded.terms, loaded.problem).additive_batch(x, u),
                               CorrectedModel(diagnosed.terms, diagnosed.problem).additive_batch(x, u))
    assert [p.name for p in path.parent.iterdir()] == ["diagnosed_model.pkl"]  # no temporary file left
    umask = os.umask(0o022)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask  # as any file the user writes, not owner-only
    with pytest.raises(FileNotFoundError, match="no diagnosed model; run the diagnosis"):
        load_diagnosed(tmp_path / "missing.pkl")
    garbage = tmp_path / "garbage.pkl"
    garbage.write_bytes(b"not a pickle")
    with pytest.raises(ValueError, match=f"{garbage}: not a diagnosed model"):
        load_diagnosed(garbage)
    other = tmp_path / "other.pkl"
    other.write_bytes(pickle.dumps({"format_version": 99, "model": diagnosed}))
    with pytest.raises(ValueError, match="field .format_version. is 99, expected 'diagnosed_model/3'"):
        load_diagnosed(other)


def test_hybrid_gradients_through_the_physical_layer_match_autograd(diagnosed):
    """A neural FMU around the physical layer: the adjoint (its NumPy engine through the layer's kernels) gives
    autograd's states and gradients; the untrained hybrid with a shut ANN is the FMU plus the effects."""
    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed.selected(None, DELAY_KINDS))
    spec = NeuralFmuSpec(state_names=["x", "v"], input_names=["F"], corrected_states=["v"], ann_states=["x", "v"],
                         ann_inputs=["F"], ann_derivatives=["x", "v"], sample_period_s=H, width=6, depth=2,
                         gate_opening=0.3, delay_min_s=-2 * H, delay_max_s=2 * H, delay_init_s=0.3 * H,
                         ann_output_init="random", physics_effects=physics.effects)
    stats = dict(x_mean=[0.0, 0.0], x_std=[0.5, 2.0], u_mean=[0.0], u_std=[3.0], xdot_mean=[0.0, 0.0],
                 xdot_std=[2.0, 5.0])
    torch.manual_seed(0)
    model = NeuralFmu(FmuRhs(physics), spec, stats)
    rng = np.random.default_rng(1)
    u = torch.from_numpy(rng.normal(0, 3.0, (2, 50, 1))).requires_grad_(True)
    x0 = torch.tensor([[0.2, -0.5], [-0.1, 1.0]], dtype=torch.float64)
    results = {}
    for mode in ("autograd", "adjoint"):
        model.zero_grad()
        u.grad = None
        states = rollout(model, u, 5, x0, 30, gradients=mode)
        (states[:, :, 0] * torch.linspace(0, 1, 31, dtype=torch.float64)).sum().backward()
        results[mode] = (states.detach(), {n: p.grad.clone() for n, p in model.named_parameters()}, u.grad.clone())
    ref, fast = results["autograd"], results["adjoint"]
    assert torch.allclose(ref[0], fast[0], rtol=0, atol=1e-12)
    for name, grad in ref[1].items():
        assert grad.abs().sum() > 0, f"no gradient reaches {name}"
        assert torch.allclose(fast[1][name], grad, rtol=1e-8, atol=1e-12 * grad.abs().max()), name
    assert torch.allclose(fast[2], ref[2], rtol=1e-8, atol=1e-14)
    # the ANN shut (g_A = 0, g_F = 1), inputs constant per row (the delay and the interpolation change nothing):
    # the states are the physical layer's own RK4 simulation
    held = torch.tensor([[[2.0]], [[-1.5]]], dtype=torch.float64).expand(2, 50, 1)
    with torch.no_grad():
        model.gates.g_A.zero_()
        model.gates.g_F.fill_(1.0)
        shut = rollout(model, held, 5, x0, 30)
    x = x0.numpy().copy()
    for _ in range(30):
        uk = held[:, 0].numpy()
        k1 = physics.derivatives(x, uk)
        k2 = physics.derivatives(x + 0.5 * H * k1, uk)
        k3 = physics.derivatives(x + 0.5 * H * k2, uk)
        k4 = physics.derivatives(x + H * k3, uk)
        x = x + H / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    np.testing.assert_allclose(shut[:, -1].numpy(), x, rtol=1e-9, atol=1e-12)


def test_untrained_hybrid_is_its_physical_layer(diagnosed):
    """A hybrid's ANN starts at a zero correction (zero output layer and no post-processing shift), while a
    neural FMU's post-processing starts at the mean derivative."""
    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed.selected(None, DELAY_KINDS))
    stats = dict(x_mean=[0.0, 0.0], x_std=[0.5, 2.0], u_mean=[0.0], u_std=[3.0], xdot_mean=[0.3, -4.0],
                 xdot_std=[2.0, 5.0])
    common = dict(state_names=["x", "v"], input_names=["F"], corrected_states=["v"], ann_states=["x", "v"],
                  ann_inputs=["F"], ann_derivatives=["x", "v"], sample_period_s=H, gate_opening=0.5)
    x, u = states_and_inputs(n=6)
    x_t, u_t = torch.from_numpy(x), torch.from_numpy(u)
    hybrid = NeuralFmu(FmuRhs(physics), NeuralFmuSpec(**common, physics_effects=physics.effects), stats)
    np.testing.assert_allclose(hybrid.derivative(x_t, u_t).detach().numpy(), physics.derivatives(x, u), rtol=1e-12)
    neural = NeuralFmu(FmuRhs(physics), NeuralFmuSpec(**common), stats)
    shifted = neural.derivative(x_t, u_t).detach().numpy() - physics.derivatives(x, u)
    np.testing.assert_allclose(shifted[:, 1], 0.5 * -4.0, rtol=1e-12)


def test_hybrid_windows_start_unmeasured_states_from_the_physical_layer(diagnosed):
    """A hybrid's training data: inputs through the diagnosed input changes, the unmeasured state along the
    physical layer's own open loop (from the recalibrated initial value), the measured one untouched."""
    from hybridfmu.diagnosis.corrected_model import CorrectedModel, rk4_simulate
    from hybridfmu.training.data import ManeuverArrays
    from hybridfmu.training.trial import hybrid_arrays

    kept = diagnosed.selected(None, DELAY_KINDS)
    kept.initial_states = {"train": {"v": 0.7}}
    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), kept)
    n = 200
    time_s = np.arange(n) * H
    u = np.sin(2 * np.pi * 1.5 * time_s)[:, None] * 3.0
    x_init = np.column_stack([np.linspace(0.0, 0.3, n), np.full(n, 99.0)])  # v: the calibrated FMU's (wrong)
    arrays = ManeuverArrays(name="train", time_s=time_s, u=u, x_init=x_init, targets=x_init[:, :1].copy(),
                            spans=np.array([[0, n]]), state_names=["x", "v"], input_names=["F"], target_states=["x"],
                            target_signals=["position"], measured_states=["x"])
    hybrid = hybrid_arrays(arrays, physics)
    np.testing.assert_allclose(hybrid.u, physics.inputs(u, H))
    np.testing.assert_array_equal(hybrid.x_init[:, 0], x_init[:, 0])
    corrected = CorrectedModel(kept.terms, kept.problem, physics.helper)
    expected = rk4_simulate(physics.fmu, time_s, corrected.inputs(u, H), np.array([0.0, 0.7]), corrected).states
    np.testing.assert_allclose(hybrid.x_init[:, 1], expected[:, 1], rtol=1e-12)
    assert hybrid.x_init[0, 1] == 0.7


def test_coefficients_set_and_their_jacobian_match_differences(diagnosed):
    """The additive terms' coefficients: read in order, set back, refused in the wrong count; df/dtheta equals
    central differences of the derivatives (the terms are linear in them)."""
    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed)
    names, theta = physics.coefficient_names, physics.coefficients
    effects = [n.rsplit("[", 1)[0] for n in names]
    assert sorted(set(effects), key=effects.index) == ["coulomb(v)", "coulomb(v)*|F|", "periodic(x)", "viscous(v)"]
    assert theta.size == len(names) and theta[:2].tolist() == [0.3, 0.2]
    x, u = states_and_inputs(n=7)
    jac = physics.coefficient_jacobian(x, u)
    assert jac.shape == (7, 2, theta.size)
    step = 1e-6
    for c in range(theta.size):
        up, down = theta.copy(), theta.copy()
        up[c] += step
        down[c] -= step
        physics.set_coefficients(up)
        f_up = physics.derivatives(x, u)
        physics.set_coefficients(down)
        f_down = physics.derivatives(x, u)
        np.testing.assert_allclose(jac[:, :, c], (f_up - f_down) / (2 * step), rtol=1e-6, atol=1e-8)
    physics.set_coefficients(theta)
    _, _, _, jac_kernel = physics.coefficient_kernel(7)(x, u)
    np.testing.assert_array_equal(jac_kernel, jac)
    with pytest.raises(ValueError, match=f"expected {theta.size} finite coefficients"):
        physics.set_coefficients(theta[:-1])
    # the diagnosed model's own terms are not changed by a physical layer's coefficients
    assert diagnosed.terms[0].coef.tolist() == [0.3, 0.2]


def _trainable_hybrid(diagnosed, step=0.01):
    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed.selected(None, DELAY_KINDS))
    spec = NeuralFmuSpec(state_names=["x", "v"], input_names=["F"], corrected_states=["v"], ann_states=["x", "v"],
                         ann_inputs=["F"], ann_derivatives=["x", "v"], sample_period_s=H, width=6, depth=2,
                         gate_opening=0.3, delay_min_s=-2 * H, delay_max_s=2 * H, delay_init_s=0.3 * H,
                         ann_output_init="random", physics_effects=physics.effects, physics_coefficient_step=step)
    stats = dict(x_mean=[0.0, 0.0], x_std=[0.5, 2.0], u_mean=[0.0], u_std=[3.0], xdot_mean=[0.0, 0.0],
                 xdot_std=[2.0, 5.0])
    torch.manual_seed(0)
    return physics, NeuralFmu(FmuRhs(physics), spec, stats)


def test_trainable_coefficients_get_the_gradients_of_autograd(diagnosed):
    """With ``physics_coefficient_step`` the hybrid's FMU layer trains the terms' coefficients: the NumPy engine
    of the adjoint gives autograd's gradient for them (and for everything else); a changed coefficient changes
    the physical layer's derivative as setting it on the layer does; the C and torch engines refuse them."""
    physics, model = _trainable_hybrid(diagnosed)
    change = model.fmu.coefficient_change
    assert change is not None and change.shape == (physics.coefficients.size,)
    with torch.no_grad():
        change.copy_(torch.linspace(-0.2, 0.3, change.numel(), dtype=torch.float64))
    rng = np.random.default_rng(1)
    u = torch.from_numpy(rng.normal(0, 3.0, (2, 50, 1)))
    x0 = torch.tensor([[0.2, -0.5], [-0.1, 1.0]], dtype=torch.float64)
    results = {}
    for mode in ("autograd", "adjoint", "torchdiffeq"):
        model.zero_grad()
        states = rollout(model, u, 5, x0, 30, gradients=mode)
        (states[:, :, 0] * torch.linspace(0, 1, 31, dtype=torch.float64)).sum().backward()
        results[mode] = (states.detach(), {n: p.grad.clone() for n, p in model.named_parameters()})
    ref, fast = results["autograd"], results["adjoint"]
    assert torch.allclose(ref[0], fast[0], rtol=0, atol=1e-12)
    # every coefficient but the Stribeck peak's (its regressor vanishes away from v = 0) has a gradient
    assert int((ref[1]["fmu.coefficient_change"] != 0).sum()) >= change.numel() - 1
    for name, grad in ref[1].items():
        assert torch.allclose(fast[1][name], grad, rtol=1e-8, atol=1e-12 * grad.abs().max()), name
    # torchdiffeq's RK4 (the 3/8 rule) through the FMU layer: the same gradient to the solvers' difference
    assert torch.allclose(results["torchdiffeq"][1]["fmu.coefficient_change"], ref[1]["fmu.coefficient_change"],
                          rtol=0, atol=0.05 * ref[1]["fmu.coefficient_change"].abs().max())
    # the coefficients in the model are the start scaled by the change
    theta = (model.fmu.coefficient_start * (1 + change.detach())).numpy()
    np.testing.assert_allclose(physics.coefficients, theta, rtol=1e-14)
    learned = model.physics_coefficients()
    assert list(learned) == physics.coefficient_names
    assert learned[physics.coefficient_names[0]] == {"diagnosed": 0.3, "trained": pytest.approx(0.3 * 0.8)}
    for engine in ("adjoint_c", "adjoint_torch"):
        with pytest.raises(ValueError, match="coefficients train only with the NumPy engine"):
            rollout(model, u, 5, x0, 30, gradients=engine)


def test_coefficients_have_their_own_adam_group_and_survive_a_checkpoint(diagnosed):
    """The trainer steps the coefficients' relative changes at ``physics_coefficient_step``; a state dict holds
    them, and a rebuilt hybrid loads them and applies them to its own physical layer."""
    from hybridfmu.training.trainer import parameter_groups

    physics, model = _trainable_hybrid(diagnosed, step=0.004)
    groups = parameter_groups(model)
    assert [g.get("lr") for g in groups[1:]] == [0.004]
    assert groups[1]["params"][0] is model.fmu.coefficient_change
    assert all(p is not model.fmu.coefficient_change for p in groups[0]["params"])
    with torch.no_grad():
        model.fmu.coefficient_change.fill_(0.5)
    state = model.state_dict()
    other_physics, other = _trainable_hybrid(diagnosed)
    other.load_state_dict(state)
    x, u = states_and_inputs(n=5)
    x_t, u_t = torch.from_numpy(x), torch.from_numpy(u)
    np.testing.assert_allclose(other.derivative(x_t, u_t).detach().numpy(), model.derivative(x_t, u_t).detach().numpy(),
                               rtol=1e-13)
    np.testing.assert_allclose(other_physics.coefficients, physics.coefficients, rtol=1e-14)
    assert np.all(physics.coefficients != np.concatenate([t.coef for t in diagnosed.terms[:4]]))
    # a neural FMU (no physical layer) refuses a coefficient step
    with pytest.raises(ValueError, match="only a hybrid"):
        NeuralFmuSpec(state_names=["x", "v"], input_names=["F"], corrected_states=["v"], ann_states=["x"],
                      ann_inputs=[], ann_derivatives=[], sample_period_s=H, physics_coefficient_step=0.01)


def test_the_hybrids_time_offset_is_estimated_on_its_physical_layer(diagnosed):
    """The time-offset stage on the physical layer (rule hybrid_time_offset): data made by the FMU plus the
    effects with the input logged 0.4 samples late give that delay back; a delay of zero is not identified."""
    from types import SimpleNamespace

    from hybridfmu.evaluation.hybrid_offset import physics_group_estimates
    from hybridfmu.evaluation.offset import shift_inputs

    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed.selected(None, DELAY_KINDS))
    rng = np.random.default_rng(4)
    n = 3000
    time_s = np.arange(n) * H
    u = np.repeat(rng.normal(0.0, 3.0, n // 20), 20)[:, None]  # steps every 20 samples
    roles = SimpleNamespace(unmeasured_states=[], measured_states=["x", "v"], state_names=["x", "v"],
                            input_names=["F"])
    options = {"groups": {"window_samples": 4, "windows": 40}}
    delay_config = {"groups": {}, "min_s": -3 * H, "max_s": 3 * H}
    for true_delay_s in (0.4 * H, 0.0):
        # the logged input lags: the model sees it as u_logged(t + true_delay)
        x = physics.diagnosed.simulate(physics.fmu, physics.helper, time_s, shift_inputs(u, true_delay_s, H),
                                       np.array([0.1, 0.0]))
        measured = SimpleNamespace(time_s=time_s, u=u, x=x)
        (estimate,) = physics_group_estimates(physics, measured, roles, x[0], "m", options, delay_config).values()
        if true_delay_s:
            assert estimate["identified"] and estimate["delay_s"] == pytest.approx(true_delay_s, abs=0.02 * H)
        else:
            assert not estimate["identified"] and estimate["delay_s"] == 0.0


def _validation_arrays(n=300, seed=5):
    from hybridfmu.training.data import ManeuverArrays

    rng = np.random.default_rng(seed)
    time_s = np.arange(n) * H
    u = np.repeat(rng.normal(0.0, 3.0, n // 20), 20)[:, None]
    x_init = np.column_stack([np.cumsum(rng.normal(0, 0.01, n)), rng.normal(0, 0.1, n)])
    return ManeuverArrays(name="validation", time_s=time_s, u=u, x_init=x_init, targets=x_init.copy(),
                          spans=np.array([[10, 120], [150, 290]]), state_names=["x", "v"], input_names=["F"],
                          target_states=["x", "v"], target_signals=["position", "velocity"],
                          measured_states=["x", "v"])


def _untrained_hybrid(physics, width, depth, gate_opening, delay_init_s=0.3 * H):
    spec = NeuralFmuSpec(state_names=["x", "v"], input_names=["F"], corrected_states=["v"], ann_states=["x", "v"],
                         ann_inputs=["F"], ann_derivatives=["x", "v"], sample_period_s=H, width=width, depth=depth,
                         gate_opening=gate_opening, delay_min_s=-2 * H, delay_max_s=2 * H,
                         delay_init_s=delay_init_s, physics_effects=physics.effects)
    stats = dict(x_mean=[0.0, 0.0], x_std=[0.5, 2.0], u_mean=[0.0], u_std=[3.0], xdot_mean=[0.3, -4.0],
                 xdot_std=[2.0, 5.0], target_std=[0.5, 2.0])
    return NeuralFmu(FmuRhs(physics), spec, stats), stats


def test_the_shared_rollout_of_the_physical_layer_scores_like_each_trials_own_validation(diagnosed, tmp_path):
    """Rule physical_layer_rollout's file, scored with another configuration's loss, gives that configuration's
    own validation to the bit; a trained model, other delays or another physical layer's files do not use it."""
    from hybridfmu.training.losses import Objective
    from hybridfmu.training.physical_layer_rollout import (read_physical_layer_rollout, untrained_is_physical_layer,
                                                           write_physical_layer_rollout)
    from hybridfmu.training.validation import score_states, validate, validation_batch

    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed.selected(None, DELAY_KINDS))
    arrays = _validation_arrays()
    sources = {"fmu": "f1", "calibration": "c1", "diagnosed": "d1"}
    shared, _ = _untrained_hybrid(physics, width=8, depth=2, gate_opening=0.1)
    path = tmp_path / "physical_layer_rollout.pt"
    write_physical_layer_rollout(path, shared, arrays, sources)
    trial, stats = _untrained_hybrid(physics, width=16, depth=3, gate_opening=0.4)  # another configuration
    assert untrained_is_physical_layer(trial)
    objective = Objective("MAE", {"x": 0.5, "v": 0.5})
    weights = {"x": 0.2, "v": 0.8}
    batch = validation_batch(trial.spec, arrays)
    saved = read_physical_layer_rollout(path, trial, arrays, sources)
    assert saved is not None
    assert score_states(*saved, batch, arrays, "MSE", weights, objective, stats) == validate(
        trial, arrays, "MSE", weights, objective, stats, batch)
    # not the same untrained trajectory: not used
    assert read_physical_layer_rollout(path, trial, arrays, {**sources, "diagnosed": "d2"}) is None
    other_delay, _ = _untrained_hybrid(physics, width=16, depth=3, gate_opening=0.4, delay_init_s=0.5 * H)
    assert read_physical_layer_rollout(path, other_delay, arrays, sources) is None
    with torch.no_grad():
        trial.ann.output.bias.fill_(0.1)  # a trained ANN contributes: its state is no longer the physical layer
    assert not untrained_is_physical_layer(trial)
    assert read_physical_layer_rollout(path, trial, arrays, sources) is None
    neural = NeuralFmu(FmuRhs(physics), NeuralFmuSpec(**{**shared.spec.to_dict(), "physics_effects": None}), stats)
    with pytest.raises(ValueError, match="not an untrained hybrid"):
        write_physical_layer_rollout(tmp_path / "other.pt", neural, arrays, sources)
    (tmp_path / "bad.pt").write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match=r"bad\.pt: not a physical-layer rollout"):
        read_physical_layer_rollout(tmp_path / "bad.pt", shared, arrays, sources)


def _physical_layer_hybrid(diagnosed, delay_min_s=0.0, delay_max_s=0.0):
    """A hybrid around every diagnosed effect (the time offset included), ANN at zero, coefficients trainable."""
    physics = PhysicsModel(BridgedSpring(), BridgedSpring(), diagnosed)
    spec = NeuralFmuSpec(state_names=["x", "v"], input_names=["F"], corrected_states=["v"], ann_states=["x", "v"],
                         ann_inputs=["F"], ann_derivatives=["x", "v"], sample_period_s=H, width=6, depth=2,
                         gate_opening=0.3, delay_min_s=delay_min_s, delay_max_s=delay_max_s, delay_init_s=0.0,
                         physics_effects=physics.effects, physics_coefficient_step=0.01)
    stats = dict(x_mean=[0.0, 0.0], x_std=[0.5, 2.0], u_mean=[0.0], u_std=[3.0], xdot_mean=[0.0, 0.0],
                 xdot_std=[2.0, 5.0])
    return NeuralFmu(FmuRhs(physics), spec, stats)


def test_the_open_loop_of_many_windows_is_simulate_to_the_bit_with_one_set_up(diagnosed):
    """DiagnosedModel.open_loop: many runs (a record, then short windows as the time-offset stage and the windowed
    errors make them) give simulate's states bit for bit; the parameters (the diagnosis' and the corrected
    model's) are set once for the block, and restored after it."""
    rng = np.random.default_rng(5)
    n = 300
    time_s = np.arange(n) * H
    u = np.repeat(rng.normal(0.0, 3.0, n // 15), 15)[:, None]
    fmu, helper = BridgedSpring(), BridgedSpring()
    before = fmu.get_parameters(["k", "m"]), helper.get_parameters(["k", "m"])
    starts = [(0, n, np.array([0.1, -0.2]))] + [(k, 6, rng.normal(0.0, 0.5, 2)) for k in range(0, n - 6, 7)]
    expected = [diagnosed.simulate(fmu, helper, time_s[k:k + w], u[k:k + w], x0) for k, w, x0 in starts]
    calls = []
    original = fmu.set_parameters
    fmu.set_parameters = lambda values: (calls.append(dict(values)), original(values))[1]
    with diagnosed.open_loop(fmu, helper) as open_loop:
        got = [open_loop(time_s[k:k + w], u[k:k + w], x0) for k, w, x0 in starts]
        assert fmu.get_parameters(["k"])["k"] == 4.4
    assert len(calls) == 4  # the diagnosis' and the corrected model's parameters, each set and restored once
    for value, reference in zip(got, expected):
        assert np.all(np.isfinite(reference))
        np.testing.assert_array_equal(value, reference)
    assert (fmu.get_parameters(["k", "m"]), helper.get_parameters(["k", "m"])) == before


def test_a_hybrid_that_is_its_physical_layer_is_the_fmu_plus_effects_to_the_bit(diagnosed):
    """The hybrid's physical-layer candidate (ANN at zero, delays fixed at zero, coefficients as diagnosed) gives
    the diagnosed model's own trajectories, open loop and windowed; any trained part makes it a hybrid again."""
    from hybridfmu.training.inference import (is_its_physical_layer, simulate_neural_fmu,
                                              simulate_neural_fmu_windows)
    from hybridfmu.training.multiple_shooting import windowed_trajectory

    rng = np.random.default_rng(11)
    n = 400
    time_s = np.arange(n) * H
    u = np.repeat(rng.normal(0.0, 3.0, n // 20), 20)[:, None]
    x0 = np.array([0.1, -0.2])
    model = _physical_layer_hybrid(diagnosed)
    assert is_its_physical_layer(model)

    def simulate(t, v, x):
        return diagnosed.simulate(BridgedSpring(), BridgedSpring(), t, v, x)

    expected = simulate(time_s, u, x0)
    assert np.all(np.isfinite(expected))
    np.testing.assert_array_equal(simulate_neural_fmu(model, time_s, u, x0), expected)
    x_start = np.column_stack([np.linspace(0.0, 0.5, n), np.linspace(-1.0, 1.0, n)])
    np.testing.assert_array_equal(simulate_neural_fmu_windows(model, time_s, u, x_start, 50),
                                  windowed_trajectory(simulate, time_s, u, x_start, 50))
    # the hybrid's own rollout differs (inputs interpolated between samples at the solver's stages): the
    # candidate is simulated as the FMU + effects, not approximated by it
    trainable = _physical_layer_hybrid(diagnosed, -2 * H, 2 * H)
    assert not is_its_physical_layer(trainable)
    assert np.abs(simulate_neural_fmu(trainable, time_s, u, x0) - expected).max() > 1e-6
    with torch.no_grad():
        model.ann.output.bias.fill_(1e-3)
    assert not is_its_physical_layer(model)
    model = _physical_layer_hybrid(diagnosed)
    physics = model.fmu.rhs.model
    physics.set_coefficients(physics.coefficients * 1.01)
    assert not is_its_physical_layer(model)


def test_the_physical_layer_candidate_has_its_delays_fixed_at_zero():
    """``without_delays``: the plan loses the delays' start and bounds, the model section fixes them at zero."""
    from hybridfmu.training.finalists import without_delays

    plan = {"search_id": "s", "initial_delays_s": {"duties": 3e-5}, "delay_bounds_s": {"duties": [2e-5, 4e-5]}}
    assert without_delays(plan) == {"search_id": "s"}
    section = {"corrected_states": ["omega"], "input_delay": {"groups": {"duties": ["d_a"]}, "min_s": -3e-4,
                                                              "max_s": 3e-4, "init_s": "time_offset",
                                                              "within_standard_errors": 3.0}}
    fixed = without_delays(section)
    assert fixed["input_delay"] == {"groups": {"duties": ["d_a"]}, "min_s": 0.0, "max_s": 0.0, "init_s": 0.0}
    assert section["input_delay"]["init_s"] == "time_offset"  # the caller's section is not changed
