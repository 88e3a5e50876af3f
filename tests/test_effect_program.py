"""The diagnosed effects in C (``effects.c`` through ``EffectProgram``): the same numbers as their Python forms,
term by term and over whole FMU simulations, and programs that do not fit the model refused."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_models import MassSpringDamper, msd_maneuvers, msd_problem
from hybridfmu.diagnosis.corrected_model import CorrectedModel, simulate_windows
from hybridfmu.diagnosis.effects_motor import InverterDeadtime
from hybridfmu.diagnosis.joint import JointEffect
from hybridfmu.diagnosis.library import Coulomb, Limit, Overflow, Periodic, ScaledCoulomb, Viscous, build_library
from hybridfmu.diagnosis.prepare import prepare_maneuver
from hybridfmu.diagnosis.problem import set_data_statistics
from hybridfmu.diagnosis.selection import Term
from hybridfmu.fmu import load_fmu, simulate_open_loop
from hybridfmu.fmu.effect_program import EffectProgram, EffectTerm

STATE_KINDS = {"viscous", "quadratic", "polynomial", "coulomb", "scaled_coulomb", "periodic", "saturation_above",
               "saturation_below"}


@pytest.fixture(scope="module")
def library():
    problem, model = msd_problem(equations=["x", "v"], periodic={"x": 1.0},
                                 effects={"polynomial_degrees": [2, 3], "periodic_max_order": 12})
    measured = msd_maneuvers(None, duration_s=5.0)
    set_data_statistics(problem, [measured["train"].x], 0.01)
    prepared = prepare_maneuver(measured["train"], model, problem)
    effects, _ = build_library(problem, prepared.inputs, model)
    return problem, model, effects


def random_points(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(n, 2) states and (n, 1) inputs spread over both signs, with exact zeros among them."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 2.0, size=(n, 2))
    u = rng.normal(0.0, 3.0, size=(n, 1))
    x[:5] = 0.0
    u[:3] = 0.0
    return x, u


def test_each_state_term_in_c_gives_the_python_row_function_to_the_bit(library):
    problem, model, effects = library
    x, u = random_points(400)
    f = model.derivatives(x, u)
    kinds = set()
    for effect in effects[0] + effects[1]:
        grid = effect.grid()
        for setting in (grid[0], grid[len(grid) // 2], grid[-1]):
            coef = np.linspace(-0.7, 1.3, len(effect.coefficient_names(setting)))
            row = effect.row_function(coef, setting)
            term = effect.stage_term(coef, setting)
            if row is None:
                continue
            assert term is not None, f"{effect.name}: a row function without a C form"
            expected = np.array([row(x[r].tolist(), u[r].tolist()) for r in range(len(x))])
            got = EffectProgram([term], problem.n_x, problem.n_u).evaluate(x, u, f)
            assert np.array_equal(got[:, effect.equation], expected), f"{effect.name} at {setting}"
            assert not np.any(np.delete(got, effect.equation, axis=1)), f"{effect.name}: other equations changed"
            kinds.add(effect.kind)
    assert STATE_KINDS <= kinds, STATE_KINDS - kinds


def test_limits_and_overflows_in_c_give_the_python_batch_functions_to_the_bit(library):
    problem, model, _ = library
    options = {"limit_quantiles": [0.9], "overflow_quantiles": [0.8]}
    set_data_statistics(problem, [random_points(200, seed=1)[0]], 0.01)
    x, u = random_points(300, seed=2)
    f = model.derivatives(x, u)
    checked = 0
    for effect, coef in ((Limit(problem, 1, "above", options), [0.8]), (Limit(problem, 1, "below", options), [1.0]),
                         (Limit(problem, 0, "above", options), [0.5]), (Overflow(problem, 1, 0, options), [1.0, 0.6])):
        for level in (-0.5, 0.0, 1.2):
            setting, coef = {"level": level}, np.array(coef)
            expected = effect.batch_function(coef, setting, model)(x, u)
            got = EffectProgram([effect.stage_term(coef, setting)], 2, 1).evaluate(x, u, f)
            assert np.array_equal(got[:, effect.equation], expected), f"{effect.name} at {level}"
            checked += 1
            if isinstance(effect, Overflow):
                j, limit = effect.source_batch_function(setting, model)
                got = EffectProgram([effect.source_stage_term(setting)], 2, 1).evaluate(x, u, f)
                assert np.array_equal(got[:, j], limit(x, u))
    assert checked == 12


class MotorProblem:
    """The few fields of a diagnosis problem the motor's effects and a corrected model read."""

    state_names = ["i_d", "i_q", "theta", "omega"]
    input_names = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
    n_x, n_u = 4, 5
    settings: dict = {}
    spread = np.array([10.0, 10.0, 3.0, 100.0])

    def rate_unit(self, equation: int) -> str:
        return "1/s"

    def unit(self, name: str) -> str:
        return ""


def motor_terms() -> list[Term]:
    """Friction, cogging and a load-dependent friction in the speed equation and an inverter dead time in both
    current equations (one joint effect): every way a term reaches the C step loop, the model evaluation included."""
    problem = MotorProblem()
    options = {"coulomb_smoothing_relative": [0.01], "stribeck_relative": [0.05], "periodic_max_order": 6,
               "periodic_harmonics": 2}
    deadtime = JointEffect([InverterDeadtime(problem, e, [0, 1, 2], (0, 1), 2, 4.0, [0.5], 0.0) for e in (0, 1)])
    return [Term(Viscous(problem, 3, 3), {}, np.array([0.02])),
            Term(Coulomb(problem, 3, 3, options), {"smoothing": 1.0, "stribeck_velocity": 5.0}, np.array([40.0, 15.0])),
            Term(Periodic(problem, 3, 2, 2 * np.pi, options), {"order": 6.0, "harmonics": 2.0},
                 np.array([30.0, -10.0, 5.0, 2.0])),
            Term(ScaledCoulomb(problem, 3, 3, 4, options), {"asymmetric": 1.0, "smoothing": 1.0}, np.array([3.0, 0.5])),
            Term(deadtime, {"current_scale_a": 0.5}, np.array([0.02]))]


def test_an_fmu_simulation_with_the_effects_in_c_equals_the_callback_per_stage(ipbmotor_fmu):
    """The demo motor with every kind of additive term, the dead time's model evaluations among them: the C step
    loop gives the states of the Python callback to the bit, and leaves the FMU's inputs as they were."""
    time_s = np.arange(0.0, 0.2, 1e-4)
    rng = np.random.default_rng(5)
    u = np.empty((len(time_s), 5))
    u[:, :3] = 0.5 + 0.3 * np.sin(2 * np.pi * 40 * time_s[:, None] + np.array([0.0, 2.1, 4.2]))
    u[:, 3] = 24.0
    u[:, 4] = 0.05 * rng.standard_normal(len(time_s))
    with load_fmu(ipbmotor_fmu) as fmu, load_fmu(ipbmotor_fmu) as helper:
        x0 = np.asarray(fmu.initial_states, dtype=float)
        corrected = CorrectedModel(motor_terms(), MotorProblem(), helper)
        program = corrected.correction()
        assert isinstance(program, EffectProgram) and program.evaluates_model
        assert [t.kind for t in program.terms] == ["viscous", "coulomb", "periodic", "scaled_coulomb",
                                                    "phase_deadtime"]
        in_c = simulate_open_loop(fmu, time_s, u, x0, correction=program).states
        called_back = simulate_open_loop(fmu, time_s, u, x0, correction=corrected).states
        plain = simulate_open_loop(fmu, time_s, u, x0).states
        again = simulate_open_loop(fmu, time_s, u, x0).states
    assert np.all(np.isfinite(in_c))
    assert np.array_equal(in_c, called_back)
    assert np.max(np.abs(in_c - plain)) > 1e-3  # the terms act
    assert np.array_equal(plain, again)  # nothing of the program stays behind


def test_the_standstill_hold_in_c_equals_its_python_form_and_holds_what_the_friction_can_hold(ipbmotor_fmu):
    """The speed held at rest by its friction (Coulomb and load-dependent): the C step loop gives the states of the
    Python callback to the bit; a push the friction at the band's edge can hold leaves the rotor at rest, where the
    smoothed friction alone lets it creep; a push beyond it moves the rotor either way."""
    from hybridfmu.diagnosis.standstill_hold import StandstillHold

    time_s = np.arange(0.0, 0.2, 1e-4)
    u = np.zeros((len(time_s), 5))
    u[:, 3] = 24.0
    hold = StandstillHold("omega", 2.0, 2000.0)
    with load_fmu(ipbmotor_fmu) as fmu, load_fmu(ipbmotor_fmu) as helper:
        x0 = np.asarray(fmu.initial_states, dtype=float)
        x0[2], x0[3] = 30.0, 0.5  # between the end stops, moving slowly, within the band
        corrected = CorrectedModel(motor_terms(), MotorProblem(), helper, hold=hold)
        program = corrected.correction()
        assert [t.kind for t in program.terms][-1] == "hold"
        assert program.terms[-1].ints == (3, 1, 3)  # the speed, its Coulomb and its load-dependent friction
        runs = {}
        for load in (0.002, 0.2):  # N m: within and beyond what the friction holds
            u[:, 4] = load
            in_c = simulate_open_loop(fmu, time_s, u, x0, correction=program).states
            called_back = simulate_open_loop(fmu, time_s, u, x0, correction=corrected).states
            assert np.array_equal(in_c, called_back), load
            free = simulate_open_loop(fmu, time_s, u, x0, correction=CorrectedModel(
                motor_terms(), MotorProblem(), helper).correction()).states
            runs[load] = (in_c, free)
    held, creeping = runs[0.002]
    assert np.max(np.abs(held[-500:, 3])) < 1e-6 and np.ptp(held[-500:, 2]) < 1e-6  # at rest
    assert np.ptp(creeping[-500:, 2]) > 1e-5  # the smoothed friction alone creeps
    assert np.ptp(runs[0.2][0][:, 2]) > 1e-3  # a push beyond the friction moves it


def test_a_hold_without_friction_in_its_equation_holds_nothing(ipbmotor_fmu):
    from hybridfmu.diagnosis.standstill_hold import StandstillHold

    terms = [t for t in motor_terms() if t.effect.kind not in ("coulomb", "scaled_coulomb")]
    with load_fmu(ipbmotor_fmu) as helper:
        corrected = CorrectedModel(terms, MotorProblem(), helper, hold=StandstillHold("omega", 2.0, 2000.0))
        assert corrected.hold is None and "hold" not in [t.kind for t in corrected.correction().terms]
    with pytest.raises(ValueError, match="needs a helper model instance"):
        CorrectedModel(motor_terms(), MotorProblem(), None, hold=StandstillHold("omega", 2.0, 2000.0))


def test_windows_with_the_effects_in_c_equal_the_windows_side_by_side(ipbmotor_fmu):
    """The restarted windows of the open-loop check: with an effect program each window runs in the C step loop,
    the same states to the bit as the windows side by side with the terms called back per stage."""
    time_s = np.arange(0.0, 0.1, 1e-4)
    u = np.empty((len(time_s), 5))
    u[:, :3] = 0.5 + 0.3 * np.sin(2 * np.pi * 40 * time_s[:, None] + np.array([0.0, 2.1, 4.2]))
    u[:, 3], u[:, 4] = 24.0, 0.05
    with load_fmu(ipbmotor_fmu) as fmu, load_fmu(ipbmotor_fmu) as helper:
        x0 = np.asarray(fmu.initial_states, dtype=float)
        corrected = CorrectedModel(motor_terms(), MotorProblem(), helper)
        whole = simulate_open_loop(fmu, time_s, u, x0, correction=corrected.correction()).states
        first = np.arange(0, len(time_s) - 200, 200)
        in_c = simulate_windows(fmu, simulate_open_loop, time_s, u, whole[first], first, 200, corrected.correction())
        side_by_side = simulate_windows(fmu, simulate_open_loop, time_s, u, whole[first], first, 200, corrected)
    assert np.all(np.isfinite(in_c))
    np.testing.assert_array_equal(in_c, side_by_side)
    np.testing.assert_array_equal(in_c[1], whole[200:401])  # a window from the whole run's state continues it


def test_a_term_without_a_c_form_keeps_the_callback(library, monkeypatch):
    problem, _, effects = library
    viscous = next(e for e in effects[1] if e.kind == "viscous")
    corrected = CorrectedModel([Term(viscous, {}, np.array([0.3]))], problem)
    assert isinstance(corrected.correction(), EffectProgram)
    monkeypatch.setattr(viscous, "stage_term", lambda coef, setting: None)  # as a plugin effect that offers only a Python row function
    assert corrected.correction() is corrected
    x, u = random_points(10)
    program = EffectProgram([EffectTerm("viscous", (1,), (1,), (0.3,))], 2, 1, python=corrected)
    np.testing.assert_array_equal(program(x, u), corrected(x, u))  # called as its Python form outside an FMU
    with pytest.raises(ValueError, match="no Python form; simulate it with an FMU"):
        EffectProgram(program.terms, 2, 1)(x, u)


@pytest.mark.parametrize("term, message", [
    (EffectTerm("stiction", (1,), (1,), (1.0,)), "unknown kind"),
    (EffectTerm("viscous", (2,), (1,), (1.0,)), r"equations \[2\]: expected state indices in 0..1"),
    (EffectTerm("viscous", (1,), (5,), (1.0,)), "index 5 at position 0: expected 0..1"),
    (EffectTerm("scaled_coulomb", (1,), (1, 1), (1.0, 0.0, 0.1)), "index 1 at position 1: expected 0..0"),
    (EffectTerm("coulomb", (1,), (1,), (1.0,)), "1 real arguments do not fit"),
    (EffectTerm("periodic", (1,), (1,), (1.0, 2.0)), "2 real arguments do not fit"),
    (EffectTerm("hold", (1,), (1, 0), (1.0, 10.0)), "friction term 0: expected an earlier term of one value"),
    (EffectTerm("hold", (1,), (1,), (1.0, 10.0)), "expected one equation, a state and at least one friction term"),
])
def test_a_program_that_does_not_fit_the_model_is_refused(term, message):
    with pytest.raises(ValueError, match=f"effect term 0 \\({term.kind}\\): {message}"):
        EffectProgram([term], 2, 1)


def test_a_program_for_another_model_is_refused_by_the_fmu(ipbmotor_fmu):
    with load_fmu(ipbmotor_fmu) as fmu:
        program = EffectProgram([EffectTerm("viscous", (1,), (1,), (1.0,))], 2, 1)
        with pytest.raises(ValueError, match="effect program for 2 states and 1 inputs, the FMU has 4 and 5"):
            simulate_open_loop(fmu, np.arange(0.0, 0.01, 1e-3), np.zeros((10, 5)),
                               np.asarray(fmu.initial_states, dtype=float), correction=program)


def test_a_hybrids_rollout_runs_its_effects_in_the_c_loop_as_the_numpy_engine_does(ipbmotor_fmu):
    """A hybrid around the demo motor plus every kind of additive term: its gradient-free rollout runs in the C
    loop with the effects installed there (the physical layer offers ``neural_rollout``), gives the NumPy engine's
    states to rounding, follows coefficients changed after the layer was made, and leaves no program behind."""
    import torch

    from hybridfmu.diagnosis.export import DiagnosedModel
    from hybridfmu.fmu import FmuRhs
    from hybridfmu.model import NeuralFmu, NeuralFmuSpec
    from hybridfmu.model.physics import PhysicsModel
    from hybridfmu.training.solver import rollout

    terms = motor_terms()
    diagnosed = DiagnosedModel(terms, {}, MotorProblem(), [t.effect.name for t in terms])
    time_s = np.arange(0.0, 0.05, 1e-4)
    u = np.empty((len(time_s), 5))
    u[:, :3] = 0.5 + 0.3 * np.sin(2 * np.pi * 40 * time_s[:, None] + np.array([0.0, 2.1, 4.2]))
    u[:, 3], u[:, 4] = 24.0, 0.05
    with load_fmu(ipbmotor_fmu) as fmu, load_fmu(ipbmotor_fmu) as helper:
        physics = PhysicsModel(fmu, helper, diagnosed)
        assert callable(physics.neural_rollout)
        spec = NeuralFmuSpec(state_names=MotorProblem.state_names, input_names=MotorProblem.input_names,
                             corrected_states=["omega"], ann_states=MotorProblem.state_names,
                             ann_inputs=MotorProblem.input_names, ann_derivatives=MotorProblem.state_names,
                             sample_period_s=1e-4, width=6, depth=2, gate_opening=0.3, ann_output_init="random",
                             physics_effects=physics.effects)
        stats = dict(x_mean=[0.0] * 4, x_std=[10.0, 10.0, 3.0, 100.0], u_mean=[0.5, 0.5, 0.5, 24.0, 0.0],
                     u_std=[0.2, 0.2, 0.2, 1.0, 0.05], xdot_mean=[0.0] * 4, xdot_std=[1e4, 1e4, 100.0, 1e3])
        torch.manual_seed(1)
        hybrid = NeuralFmu(FmuRhs(physics), spec, stats).double().eval()
        u_seq = torch.from_numpy(u)[None].repeat(2, 1, 1)
        x0 = torch.from_numpy(np.stack([fmu.initial_states, fmu.initial_states + [0.0, 0.0, 0.1, 5.0]]))

        def both():
            with torch.no_grad():
                in_c = rollout(hybrid, u_seq, 0, x0, len(time_s) - 1, gradients="adjoint_c").numpy()
                numpy = rollout(hybrid, u_seq, 0, x0, len(time_s) - 1, gradients="adjoint_numpy").numpy()
            return in_c, numpy

        in_c, numpy = both()
        scale = np.abs(numpy).max(axis=(0, 1))  # (n_x,) each state's range
        assert np.all(np.isfinite(in_c)) and np.all(scale > 0)
        assert np.max(np.abs(in_c - numpy) / scale) < 1e-9
        physics.set_coefficients(1.5 * physics.coefficients)  # as training moves them
        moved_c, moved_numpy = both()
        assert np.max(np.abs(moved_c - moved_numpy) / scale) < 1e-9
        assert np.max(np.abs(moved_c - in_c)) > 1e-6  # the C loop saw the new coefficients
        plain = simulate_open_loop(fmu, time_s, u, np.asarray(fmu.initial_states, dtype=float)).states
    with load_fmu(ipbmotor_fmu) as fresh:
        np.testing.assert_array_equal(plain, simulate_open_loop(fresh, time_s, u, fresh.initial_states).states)


def test_an_ann_that_adds_nothing_is_skipped_in_the_c_loop_with_the_same_states(ipbmotor_fmu):
    """A gradient-free rollout in C whose ANN output weights and bias are all zero (the FMU's and the physical
    layer's closed loops: gates closed) skips the hidden layers: the states are those of the NumPy engine, which
    evaluates them, and whatever the hidden weights are; a non-zero output bias alone is not skipped."""
    import torch

    from hybridfmu.fmu import FmuRhs
    from hybridfmu.model import NeuralFmu, NeuralFmuSpec
    from hybridfmu.training.adjoint import SolverEngine, _Weights

    with load_fmu(ipbmotor_fmu) as fmu:
        spec = NeuralFmuSpec(state_names=MotorProblem.state_names, input_names=MotorProblem.input_names,
                             corrected_states=["omega"], ann_states=MotorProblem.state_names,
                             ann_inputs=MotorProblem.input_names, ann_derivatives=MotorProblem.state_names,
                             sample_period_s=1e-4, width=6, depth=3, gate_opening=0.3, ann_output_init="random")
        stats = dict(x_mean=[0.0] * 4, x_std=[10.0, 10.0, 3.0, 100.0], u_mean=[0.5, 0.5, 0.5, 24.0, 0.0],
                     u_std=[0.2, 0.2, 0.2, 1.0, 0.05], xdot_mean=[0.0] * 4, xdot_std=[1e4, 1e4, 100.0, 1e3])
        torch.manual_seed(3)
        stage = NeuralFmu(FmuRhs(fmu), spec, stats).double().eval().fused()
        engine = SolverEngine(stage, 1e-4, "rk4", None)
        n, batch = 300, 2
        t = np.arange(n + 1) * 1e-4
        u = np.empty((n + 1, batch, 5))
        u[..., :3] = 0.5 + 0.3 * np.sin(2 * np.pi * 40 * t[:, None, None] + np.array([0.0, 2.1, 4.2]))
        u[..., 3], u[..., 4] = 24.0, 0.05
        u_grid = torch.from_numpy(u)
        u_half = 0.5 * (u_grid[1:] + u_grid[:-1])
        x0 = torch.from_numpy(np.stack([fmu.initial_states, fmu.initial_states + [0.0, 0.0, 0.1, 5.0]]))
        with torch.no_grad():
            z_grid, z_half = stage.input_term(u_grid), stage.input_term(u_half)

            def weights(w_out_scale, b_out, hidden_scale=1.0):
                hidden = [(hidden_scale * w, b) for w, b in stage.hidden]
                return _Weights(stage.w_xd_t, w_out_scale * stage.w_out, b_out, stage.g_fmu, hidden)

            zero = torch.zeros_like(stage.b_out)
            silent = engine._run_c(weights(0.0, zero), x0, u_grid, u_half, z_grid, z_half).numpy()
            numpy = engine._run_numpy(weights(0.0, zero), x0, u_grid, u_half, z_grid, z_half).numpy()
            other_hidden = engine._run_c(weights(0.0, zero, 3.0), x0, u_grid, u_half, z_grid, z_half).numpy()
            bias = torch.tensor([0.0, 0.0, 0.0, 50.0], dtype=torch.float64)
            biased_c = engine._run_c(weights(0.0, bias), x0, u_grid, u_half, z_grid, z_half).numpy()
            biased_numpy = engine._run_numpy(weights(0.0, bias), x0, u_grid, u_half, z_grid, z_half).numpy()
        scale = np.abs(numpy).max(axis=(0, 1))
        assert np.all(np.isfinite(silent)) and np.all(scale > 0)
        assert np.max(np.abs(silent - numpy) / scale) < 1e-12
        np.testing.assert_array_equal(silent, other_hidden)
        assert np.max(np.abs(biased_c - biased_numpy) / scale) < 1e-12
        assert np.max(np.abs(biased_c - silent)[..., 3]) > 1e-3  # the bias acts: that rollout was not skipped


def test_a_physical_layers_training_terms_in_c_equal_their_numpy_form(ipbmotor_fmu):
    """The training's call per solver stage (derivatives, Jacobians, the coefficients' Jacobian) of a physical layer
    with every kind of additive term and a standstill hold: in C (one ``hf_effect_jacobians`` call) it gives the
    NumPy form's values to rounding, the rows the hold holds and the rows it lets slide included, and follows
    coefficients changed after the layer was made."""
    from hybridfmu.diagnosis.export import DiagnosedModel
    from hybridfmu.diagnosis.standstill_hold import StandstillHold
    from hybridfmu.model.physics import PhysicsModel

    terms = motor_terms()
    diagnosed = DiagnosedModel(terms, {}, MotorProblem(), [t.effect.name for t in terms],
                               hold=StandstillHold("omega", 2.0, 2000.0))
    rng = np.random.default_rng(11)
    n = 24
    x = np.column_stack([rng.normal(0, 2.0, n), rng.normal(0, 2.0, n), rng.uniform(5, 60, n), rng.normal(0, 30, n)])
    x[:12, 3] = rng.uniform(-1.5, 1.5, 12)  # within the hold's band
    u = np.column_stack([rng.uniform(0.2, 0.8, (n, 3)), np.full(n, 24.0), rng.normal(0, 0.05, n)])
    u[:6, :3], u[:6, 4] = 0.5, 0.002  # no push: the friction holds
    with load_fmu(ipbmotor_fmu) as fmu, load_fmu(ipbmotor_fmu) as helper:
        physics = PhysicsModel(fmu, helper, diagnosed)
        assert physics.corrected.hold is not None
        for factor in (1.0, 1.5):  # the coefficients as diagnosed, then moved (as training moves them)
            physics.set_coefficients(factor * physics.coefficients)
            in_c = physics.derivatives_jacobians_and_coefficient_jacobian(x, u)
            physics.terms_in_c = False
            numpy = physics.derivatives_jacobians_and_coefficient_jacobian(x, u)
            physics.terms_in_c = True
            for name, got, expected, rtol in zip(("f", "df/dx", "df/du", "df/dc"), in_c, numpy,
                                                 (1e-12, 1e-6, 1e-6, 1e-7)):
                scale = np.abs(expected).max(axis=0) + 1e-12
                assert np.max(np.abs(got - expected) / scale) < rtol, (factor, name)
            held = physics.corrected._held_rows(x, u, physics.corrected._terms_batch(x, u))
            assert held is not None and held[2].any() and (~held[2]).any()  # both kinds of row in the band
    with pytest.raises(AssertionError):  # the check above can fail: a wrong coefficient column is caught
        np.testing.assert_allclose(in_c[3][:, :, ::-1], numpy[3], rtol=1e-7)
