"""The export of a trained model as an FMI 2.0 Co-Simulation FMU (hybridfmu.export), checked with FMPy alone."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from export_checks import declared, problems, replay_deviation
from hybridfmu.export.content import neural_content
from hybridfmu.export.package import write_exported_fmu
from hybridfmu.fmu import FmuRhs, load_fmu
from hybridfmu.model import NeuralFmu, NeuralFmuSpec
from hybridfmu.model.spec import EndStop
from hybridfmu.training.inference import simulate_neural_fmu

STATES = ["i_d", "i_q", "theta", "omega"]
INPUTS = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
STATS = dict(x_mean=[0.0] * 4, x_std=[10.0, 10.0, 3.0, 100.0], u_mean=[0.5, 0.5, 0.5, 12.0, 0.0],
             u_std=[0.2, 0.2, 0.2, 1.0, 0.05], xdot_mean=[0.0] * 4, xdot_std=[1e4, 1e4, 100.0, 1e3])


def motor_inputs(time_s):
    u = np.empty((len(time_s), 5))
    u[:, :3] = 0.5 + 0.3 * np.sin(2 * np.pi * 40 * time_s[:, None] + np.array([0.0, 2.1, 4.2]))
    u[:, 3] = 12.0 + 0.1 * np.sin(50 * time_s)
    u[:, 4] = 0.05 + 0.02 * np.cos(30 * time_s)
    return u


def random_neural_fmu(fmu, delays_s, solver="rk4", end_stop=(0.0, 60.0)):
    spec = NeuralFmuSpec(state_names=STATES, input_names=INPUTS, corrected_states=["omega"], ann_states=STATES,
                         ann_inputs=INPUTS, ann_derivatives=STATES, sample_period_s=1e-4, width=6, depth=2,
                         gate_opening=0.3, ann_output_init="random", delay_min_s=-3e-4, delay_max_s=3e-4,
                         delay_init_s=delays_s,
                         delay_groups={"duties": ["d_a", "d_b", "d_c"], "supply": ["u_dc"], "load": ["tau_load"]},
                         solver=solver, end_stop=EndStop("theta", "omega", *end_stop) if end_stop else None)
    torch.manual_seed(1)
    return NeuralFmu(FmuRhs(fmu), spec, STATS).double().eval()


@pytest.mark.parametrize("delays_s, solver, end_stop", [
    ({"duties": 2.7e-5, "supply": -1.3e-4, "load": 1.7e-4}, "rk4", (0.0, 60.0)),
    ({"duties": -2.5e-4, "supply": 0.0, "load": 2.9e-4}, "euler", None),
    # the rotor runs into its end stop at 5.02 rad (the exported step clamps as the workflow's does)
    ({"duties": 1e-6, "supply": 5e-5, "load": -5e-5}, "rk4", (4.9, 5.02)),
])
def test_an_exported_neural_fmu_replays_the_workflow_open_loop(ipbmotor_fmu, tmp_path, delays_s, solver, end_stop):
    parameters = {"R": 0.031, "J": 2.1e-4}
    time_s = np.arange(0.0, 0.15, 1e-4)
    u = motor_inputs(time_s)
    with load_fmu(ipbmotor_fmu, parameters=parameters) as fmu:
        model = random_neural_fmu(fmu, delays_s, solver, end_stop)
        x0 = np.array(fmu.initial_states) + [0.0, 0.0, 4.95, 0.0]
        reference = simulate_neural_fmu(model, time_s, u, x0)
        content = neural_content(model, str(ipbmotor_fmu), parameters)
    if end_stop == (4.9, 5.02):
        assert np.any(reference[:, 2] == 5.02)  # the end stop is reached
    fmu_out = write_exported_fmu(content, "motor_neural_fmu", ipbmotor_fmu, tmp_path / "motor_neural_fmu.fmu",
                                 {"case": "motor", "commit": "0" * 40}, "0.1.0")
    assert problems(fmu_out) == []
    info = declared(fmu_out)
    assert info["co_simulation"] and info["inputs"] == INPUTS and info["outputs"] == STATES
    assert info["output_delay_s"] == pytest.approx(content.lookahead * 1e-4)
    assert info["provenance"]["case"] == "motor"
    assert "resources/IPBMotor.fmu" in info["files"] and "sources/cs_wrapper.c" in info["files"]
    deviation = replay_deviation(fmu_out, time_s, u, reference)
    assert np.all(deviation <= 1e-9), deviation


def test_a_replay_off_by_more_than_the_tolerance_is_caught(ipbmotor_fmu, tmp_path):
    """The check is no formality: the same FMU against a trajectory 1e-4 of the range off fails it."""
    from hybridfmu.export.replay import replay

    time_s = np.arange(0.0, 0.05, 1e-4)
    u = motor_inputs(time_s)
    with load_fmu(ipbmotor_fmu) as fmu:
        model = random_neural_fmu(fmu, {"duties": 2e-5, "supply": 0.0, "load": 0.0})
        x0 = np.array(fmu.initial_states)
        reference = simulate_neural_fmu(model, time_s, u, x0)
        content = neural_content(model, str(ipbmotor_fmu), {})
    fmu_out = write_exported_fmu(content, "motor_neural_fmu", ipbmotor_fmu, tmp_path / "m.fmu", {}, "0.1.0")
    good = replay(fmu_out, "test", time_s, u, INPUTS, reference, STATES, content.lookahead)
    assert good.ok and max(good.deviation.values()) < 1e-9 and good.problems == []
    off = reference.copy()
    off[1:, 3] += 1e-4 * np.ptp(reference[:, 3])
    bad = replay(fmu_out, "test", time_s, u, INPUTS, off, STATES, content.lookahead)
    assert not bad.ok and bad.deviation["omega"] == pytest.approx(1e-4, rel=0.05)


def test_the_exported_fmu_refuses_a_communication_step_off_the_sample_grid(ipbmotor_fmu, tmp_path):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    with load_fmu(ipbmotor_fmu) as fmu:
        content = neural_content(random_neural_fmu(fmu, {"duties": 0.0, "supply": 0.0, "load": 0.0}),
                                 str(ipbmotor_fmu), {})
    fmu_out = write_exported_fmu(content, "motor_neural_fmu", ipbmotor_fmu, tmp_path / "m.fmu", {}, "0.1.0")
    description = read_model_description(str(fmu_out))
    slave = FMU2Slave(guid=description.guid, unzipDirectory=extract(str(fmu_out), unzipdir=str(tmp_path / "x")),
                      modelIdentifier=description.coSimulation.modelIdentifier)
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.exitInitializationMode()
    slave.doStep(0.0, 1e-3)  # a multiple of the sample period
    with pytest.raises(Exception, match="fmi2DoStep"):
        slave.doStep(1e-3, 1.5e-4)
    slave.terminate()
    slave.freeInstance()


def hybrid_terms(problem):
    """Every kind of input change beside additive terms: a time offset of the duties, a dead zone, a gain and a
    slow actuator on the supply, a saturation and an offset of the load; friction and cogging in the speed equation."""
    from test_effect_program import motor_terms

    from hybridfmu.diagnosis.library import (InputDeadzone, InputGain, InputLag, InputOffset, InputSaturation,
                                             TimeOffset)
    from hybridfmu.diagnosis.selection import Term

    levels = np.linspace(0.0, 1.0, 11)
    return motor_terms()[:3] + [
        Term(TimeOffset(problem, 3, 0, 5e-4, columns=[0, 1, 2], name="time_offset(d_a,d_b,d_c)"),
             {"shift_s": 2.3e-4}, np.array([0.9])),
        Term(InputDeadzone(problem, 3, 3, levels * 12.0, [0.5]), {"half_width": 11.9}, np.array([0.4])),
        Term(InputGain(problem, 1, 3), {}, np.array([0.03])),
        Term(InputLag(problem, 3, 3, [3e-4]), {"actuator_lag_s": 3e-4}, np.array([0.7])),
        Term(InputSaturation(problem, 3, 4, "above", levels * 0.08, [0.2]), {"level": 0.06}, np.array([0.8])),
        Term(InputOffset(problem, 3, 4), {}, np.array([0.004])),
    ]


def test_an_exported_hybrid_replays_the_workflow_open_loop(ipbmotor_fmu, tmp_path):
    """A hybrid with every kind of input change, additive terms with trained coefficients, a parameter of its
    physical layer and learned delays: its exported FMU replays the workflow's open loop, and an effect coefficient
    set through the FMU's tunable parameter acts as in the workflow."""
    from test_effect_program import MotorProblem

    from hybridfmu.diagnosis.export import DiagnosedModel
    from hybridfmu.export.content import hybrid_content
    from hybridfmu.model.physics import PhysicsModel

    problem = MotorProblem()
    terms = hybrid_terms(problem)
    diagnosed = DiagnosedModel(terms, {"R": 0.0315}, problem, [t.effect.name for t in terms])
    calibrated = {"J": 2.1e-4}
    time_s = np.arange(0.0, 0.12, 1e-4)
    u = motor_inputs(time_s)
    u[:, 3] = 12.0 + 0.3 * np.sin(40 * time_s)  # across the dead zone's edge
    u[:, 4] = 0.05 + 0.02 * np.sin(60 * time_s)  # across the saturation level
    with load_fmu(ipbmotor_fmu, parameters=calibrated) as fmu, load_fmu(ipbmotor_fmu, parameters=calibrated) as helper:
        physics = PhysicsModel(fmu, helper, diagnosed)
        assert sorted(physics.corrected.input_changes) == [0, 1, 2, 3, 4]
        spec = NeuralFmuSpec(state_names=STATES, input_names=INPUTS, corrected_states=["omega"], ann_states=STATES,
                             ann_inputs=INPUTS, ann_derivatives=STATES, sample_period_s=1e-4, width=6, depth=2,
                             gate_opening=0.3, ann_output_init="random", delay_min_s=-3e-4, delay_max_s=3e-4,
                             delay_init_s={"duties": 2.7e-5, "supply": -1.3e-4, "load": 1.7e-4},
                             delay_groups={"duties": ["d_a", "d_b", "d_c"], "supply": ["u_dc"], "load": ["tau_load"]},
                             end_stop=EndStop("theta", "omega", 0.0, 60.0), physics_effects=physics.effects,
                             physics_coefficient_step=0.002)
        torch.manual_seed(2)
        hybrid = NeuralFmu(FmuRhs(physics), spec, STATS).double().eval()
        with torch.no_grad():
            hybrid.fmu.coefficient_change.add_(0.1 * torch.randn_like(hybrid.fmu.coefficient_change))
        x0 = np.array(fmu.initial_states) + [0.0, 0.0, 4.0, 0.0]
        reference = simulate_neural_fmu(hybrid, time_s, u, x0)
        content = hybrid_content(hybrid, str(ipbmotor_fmu), calibrated)
        assert content.coefficient_names and content.input_stages
        assert content.inner.parameters["R"][1] == 0.0315 and content.inner.parameters["J"][1] == 2.1e-4
        # the first coefficient changed as a user would set it through the exported FMU
        trained = hybrid.fmu.coefficients().detach().numpy().copy()
        changed = trained.copy()
        changed[0] *= 3.0
        physics.set_coefficients(changed)
        with torch.no_grad():
            hybrid.fmu.coefficient_change.copy_((torch.from_numpy(changed) - hybrid.fmu.coefficient_start)
                                                / hybrid.fmu.coefficient_scale)
        reference_changed = simulate_neural_fmu(hybrid, time_s, u, x0)
    assert np.max(np.abs(reference_changed - reference)) > 1e-6
    fmu_out = write_exported_fmu(content, "motor_hybrid", ipbmotor_fmu, tmp_path / "motor_hybrid.fmu", {}, "0.1.0")
    assert problems(fmu_out) == []
    assert declared(fmu_out)["output_delay_s"] == pytest.approx(content.lookahead * 1e-4)
    assert content.input_lookahead >= 3  # the time offset reads 2.3 samples ahead
    deviation = replay_deviation(fmu_out, time_s, u, reference)
    assert np.all(deviation <= 1e-9), deviation
    assert np.all(replay_deviation(fmu_out, time_s, u, reference_changed) > 1e-7)  # the coefficient matters
    deviation = replay_deviation(fmu_out, time_s, u, reference_changed,
                                 {content.coefficient_names[0]: float(changed[0])})
    assert np.all(deviation <= 1e-9), deviation


@pytest.mark.parametrize("linear", [False, True])
def test_an_exported_fmu_with_diagnosed_effects_replays_the_open_loop_with_its_events(ipbmotor_fmu, tmp_path, linear):
    """The FMU + diagnosed effects (every kind of input change, additive terms, a parameter correction), stepped as
    the evaluation simulates it: RK4 with the inputs held and the FMU's end-stop events handled. With a ``linear``
    supply voltage the exported FMU takes the sampled signal and holds the mean of each step itself."""
    from test_effect_program import MotorProblem

    from hybridfmu.data.between_samples import held_values
    from hybridfmu.diagnosis.export import DiagnosedModel, save_diagnosed
    from hybridfmu.evaluation.evaluate import simulate_diagnosed
    from hybridfmu.export.content import effects_content

    problem = MotorProblem()
    terms = hybrid_terms(problem)
    diagnosed_path = save_diagnosed(DiagnosedModel(terms, {"R": 0.0315}, problem, [t.effect.name for t in terms]),
                                    tmp_path / "diagnosed_model.pkl")
    calibrated = {"J": 2.1e-4}
    rate_hz = 10000.0
    time_s = 0.0 + np.arange(1500, dtype=np.float64) / rate_hz  # as ingest writes a grid
    sampled = motor_inputs(time_s)
    sampled[:, 3] = 12.0 + 0.3 * np.sin(40 * time_s)
    sampled[:, 4] = 0.05 + 0.02 * np.sin(60 * time_s)
    conventions = ["hold", "hold", "hold", "linear" if linear else "hold", "hold"]
    u = held_values(sampled, conventions)  # what every simulation of the workflow holds
    with load_fmu(ipbmotor_fmu) as fmu:
        x0 = np.array(fmu.initial_states) + [0.0, 0.0, 0.02, 0.0]  # near the lower end stop
    reference, _ = simulate_diagnosed(diagnosed_path, ipbmotor_fmu, calibrated, time_s, u, x0, "test")
    assert np.any(reference[:, 2] <= 1e-9)  # it runs into the end stop (state events)
    content = effects_content(str(diagnosed_path), str(ipbmotor_fmu), calibrated, rate_hz, conventions)
    assert content.events and content.coefficient_names and content.inner.parameters["R"][1] == 0.0315
    fmu_out = write_exported_fmu(content, "motor_fmu_effects", ipbmotor_fmu, tmp_path / "e.fmu", {}, "0.1.0")
    assert problems(fmu_out) == []
    deviation = replay_deviation(fmu_out, time_s, sampled, reference)
    assert np.all(deviation <= 1e-9), deviation
