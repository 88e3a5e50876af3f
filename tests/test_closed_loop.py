"""Closed loop: a controller drives a model sample by sample; the demo's ECU software is the bench's own cascade."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from hybridfmu_bench.ceiling import true_plant_closed_loop
from hybridfmu_bench.ecu import EcuSoftware
from hybridfmu_bench.emulate import REFERENCE_CHANNELS, run_maneuver
from hybridfmu_bench.settings import parse_bench_settings
from hybridfmu.data.roles import case_roles
from hybridfmu.evaluation.closed_loop import (ClosedLoopRecord, closed_loop_settings, make_controller,
                                              simulate_closed_loop)
from test_bench_emulate import short_config


class Proportional:
    """u = gain (reference - x), for the integrator x' = u; records what it saw."""

    def __init__(self, config, period_s, gain=10.0):
        self.gain, self.seen = gain, []

    def reset(self, states, signals):
        self.seen.clear()

    def step(self, states, signals):
        self.seen.append((states["x"], signals["ref"]))
        return {"command": self.gain * (signals["ref"] - states["x"])}


def integrator_step(period_s):
    def step(u, x):
        return x + period_s * u[:, :1]
    return step


def test_outputs_apply_one_sample_later_and_records_of_different_lengths_run_side_by_side():
    period_s = 0.01
    records = []
    for n, ref in ((50, 1.0), (30, -2.0)):
        u = np.column_stack([np.full(n, 0.5), np.full(n, 7.0)])  # logged: command 0.5, a second input 7
        records.append(ClosedLoopRecord(f"r{n}", u, {"ref": np.full(n, ref)}, np.zeros(1),
                                        Proportional(None, period_s)))
    states = simulate_closed_loop(integrator_step(period_s), records, ["x"], ["u", "other"], {"command": "u"},
                                  period_s)
    assert [s.shape for s in states] == [(50, 1), (30, 1)]
    for record, x, ref in zip(records, states, (1.0, -2.0)):
        expected = [0.0, 0.5 * period_s]  # sample 0 applies the logged command
        command = 0.0
        for k in range(1, x.shape[0] - 1):
            command = 10.0 * (ref - expected[k - 1])  # computed at k - 1, applied over [k, k + 1)
            expected.append(expected[k] + period_s * command)
        np.testing.assert_allclose(x[:, 0], expected, rtol=0, atol=1e-12)
        assert len(record.controller.seen) == x.shape[0] - 1  # one step per period, none after the last sample
        assert abs(x[-1, 0] - ref) < abs(ref) * 0.1  # the loop follows the reference


def test_a_controller_that_returns_no_output_is_named():
    class Broken(Proportional):
        def step(self, states, signals):
            return {"other": 1.0}

    record = ClosedLoopRecord("run", np.zeros((5, 2)), {"ref": np.ones(5)}, np.zeros(1), Broken(None, 0.1))
    with pytest.raises(ValueError, match=r"run: at sample 0 the controller returned .*outputs \['command'\]"):
        simulate_closed_loop(integrator_step(0.1), [record], ["x"], ["u", "other"], {"command": "u"}, 0.1)


def demo_roles():
    return case_roles(short_config())


def test_settings_are_checked_against_the_case():
    config = short_config()
    roles = demo_roles()
    settings = closed_loop_settings(config, roles)
    assert settings.controller == "hybridfmu_bench.ecu:EcuSoftware"
    assert settings.outputs == {"d_a": "d_a", "d_b": "d_b", "d_c": "d_c"}
    assert closed_loop_settings({**config, "closed_loop": {}}, roles) is None
    cases = [({"controller": "no_colon"}, r"controller: expected 'module:attribute'"),
             ({"signals": {"theta_ref": "angle_reference"}}, r"signals: signal\(s\) \['angle_reference'\]"),
             ({"outputs": {"d_a": "duty_a"}}, r"outputs: FMU input\(s\) \['duty_a'\]"),
             ({"outputs": {}}, r"outputs: expected at least one"),
             ({"controller": "hybridfmu.no_such_module:Ecu"}, r"controller: cannot import module 'hybridfmu.no_such_module'"),
             ({"controller": "hybridfmu_bench.ecu:NoSuchThing"}, r"controller: module 'hybridfmu_bench.ecu' has no callable 'NoSuchThing'")]
    for change, message in cases:
        edited = copy.deepcopy(config)
        edited["closed_loop"].update(change)
        with pytest.raises(ValueError, match=r"config\.closed_loop\." + message):
            make_controller(closed_loop_settings(edited, roles), edited, 1e-4)


def test_the_ecu_software_refuses_another_period():
    with pytest.raises(ValueError, match=r"runs every 0.0001 s .* steps 0.001 s"):
        EcuSoftware(short_config(), 1e-3)


def test_the_ecu_software_driving_the_true_plant_reproduces_the_bench():
    """With ideal sensors, the ECU software closing the loop around the bench's true plant, from the logged
    references, is the bench itself: the same trajectory to rounding."""
    config = short_config(offset_s=0.0)
    sensors = config["bench"]["sensors"]
    sensors.update(encoder_counts_per_rev=2 ** 40, current_noise_a=0.0, current_step_a=0.0, u_dc_noise_v=0.0,
                   u_dc_step_v=0.0, pressure_noise_bar=0.0)
    settings = parse_bench_settings(config)
    run = run_maneuver(settings, "quick", duration_s=0.6)
    n = run.time_s.size
    decimation = settings.slow_decimation
    references = {name: run.logged[channel] / factor for channel, (_, _, name, factor) in REFERENCE_CHANNELS.items()}
    signals = {"pressure_request": references["pressure_ref_bar"] * 1e5, "pressure_mode": references["pressure_mode"],
               "theta_ref": references["theta_ref_rad"], "omega_ff": references["omega_ff_rad_s"],
               "alpha_ff": references["alpha_ff_rad_s2"], "speed_limit": references["speed_limit_rad_s"],
               "current_limit": references["current_limit_a"],
               "pressure": np.repeat(run.logged["Hyd_Pressure"], decimation)[:n] * 1e5,
               "u_dc": run.truth["u_dc_v"]}
    truth = np.column_stack([run.truth[key] for key in ("i_d_a", "i_q_a", "theta_rad", "omega_rad_s")])
    first = np.array([run.logged[f"MotCtl_Duty{phase}"][0] for phase in "ABC"]) / 100.0
    states = true_plant_closed_loop(settings, EcuSoftware(config, settings.period_s), 0.0, settings.period_s,
                                    dict(zip(("i_d", "i_q", "theta", "omega"), truth[0])), first, signals,
                                    {"d_a": "d_a", "d_b": "d_b", "d_c": "d_c"})
    assert np.ptp(truth[:, 2]) > 1.0  # the maneuver moves
    np.testing.assert_allclose(states[:, 2], truth[:, 2], rtol=0, atol=1e-6)
    np.testing.assert_allclose(states[:, 3], truth[:, 3], rtol=0, atol=1e-3)


def test_the_closed_loops_held_input_step_is_the_rollout_of_a_constant_sequence_to_the_bit(ipbmotor_fmu):
    """A neural FMU around the demo motor (random ANN, learned delays away from zero, the end stop): the closed
    loop's step (its fused derivative made once, the held inputs given to the solver as they are) gives the states
    of a one-step rollout of each row's inputs held as a sequence, over many steps with new inputs each time."""
    import torch

    from hybridfmu.fmu import FmuRhs, load_fmu
    from hybridfmu.model import NeuralFmu, NeuralFmuSpec
    from hybridfmu.training.inference import make_held_input_step
    from hybridfmu.training.solver import rollout

    states = ["i_d", "i_q", "theta", "omega"]
    inputs = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
    with load_fmu(ipbmotor_fmu) as fmu:
        spec = NeuralFmuSpec(state_names=states, input_names=inputs, corrected_states=["omega"], ann_states=states,
                             ann_inputs=inputs, ann_derivatives=states, sample_period_s=1e-4, width=6, depth=2,
                             gate_opening=0.3, ann_output_init="random", delay_min_s=-2e-4, delay_max_s=2e-4,
                             delay_init_s=0.7e-4)
        stats = dict(x_mean=[0.0] * 4, x_std=[10.0, 10.0, 3.0, 100.0], u_mean=[0.5, 0.5, 0.5, 24.0, 0.0],
                     u_std=[0.2, 0.2, 0.2, 1.0, 0.05], xdot_mean=[0.0] * 4, xdot_std=[1e4, 1e4, 100.0, 1e3])
        torch.manual_seed(2)
        model = NeuralFmu(FmuRhs(fmu), spec, stats).double().eval()
        step = make_held_input_step(model)
        rng = np.random.default_rng(4)
        x_step = x_rollout = np.tile(np.asarray(fmu.initial_states, dtype=float), (3, 1)) + rng.normal(0, 0.5, (3, 4))
        for _ in range(50):
            u = np.column_stack([rng.uniform(0.1, 0.9, (3, 3)), np.full(3, 24.0), rng.normal(0, 0.05, 3)])
            x_step = step(u, x_step)
            with torch.no_grad():
                held = torch.from_numpy(np.repeat(u[:, None, :], 7, axis=1))
                x_rollout = rollout(model, held, 3, torch.from_numpy(x_rollout), 1)[:, 1].numpy()
            assert np.array_equal(x_step, x_rollout)
        assert np.ptp(x_step[:, 3]) > 0  # the rows moved apart
