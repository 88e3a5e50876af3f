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
