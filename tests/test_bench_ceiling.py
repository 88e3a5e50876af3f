"""The ceiling: the bench's true plant open loop from the logged duties reproduces the bench's true trajectory."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfmu_bench.ceiling import DUTY_CHANNELS, applied_duties, grid_start_s, true_plant_open_loop
from hybridfmu_bench.emulate import CHANNELS, channel_groups, run_maneuver
from hybridfmu_bench.mdf_writer import write_mdf4
from hybridfmu_bench.settings import parse_bench_settings
from test_bench_emulate import short_config


def logged_run(tmp_path, offset_s: float):
    settings = parse_bench_settings(short_config(offset_s=offset_s))
    run = run_maneuver(settings, "quick", duration_s=0.5)
    path = tmp_path / f"quick_{offset_s:+g}.mf4"
    write_mdf4(path, channel_groups(run, settings), "ceiling test")
    return settings, run, path


@pytest.mark.parametrize("offset_s", [3e-5, -3e-5])
def test_applied_duties_undo_the_channel_offset(tmp_path, offset_s):
    settings, run, path = logged_run(tmp_path, offset_s)
    k_first, duties = applied_duties(path, settings)
    assert k_first == (0 if offset_s > 0 else 1)  # a negative offset drops the first sample (stamped < 0)
    logged = np.column_stack([run.logged[name] for name in DUTY_CHANNELS]) / 100.0
    np.testing.assert_array_equal(duties, logged)
    assert grid_start_s(path, list(CHANNELS)) == pytest.approx(run.duty_time_s[0])


def test_true_plant_from_the_true_state_reproduces_the_truth(tmp_path):
    settings, run, path = logged_run(tmp_path, 3e-5)
    k_first, duties = applied_duties(path, settings)
    time_s = run.time_s[:4000]
    truth = np.column_stack([run.truth[key][:4000] for key in ("i_d_a", "i_q_a", "theta_rad", "omega_rad_s")])
    x0 = dict(zip(("i_d", "i_q", "theta", "omega"), truth[0]))
    states = true_plant_open_loop(settings, k_first, duties, 0.0, time_s, x0)
    np.testing.assert_allclose(states, truth, rtol=0, atol=1e-9)
    # started between two PWM instants (the ingested grid starts at the first duty stamp): the partial first
    # period keeps it on the true trajectory, interpolated to the grid like the logged angle
    start = float(run.duty_time_s[0])
    shifted = np.column_stack([np.interp(start + time_s[:-1], time_s, truth_col) for truth_col in truth.T])
    late = true_plant_open_loop(settings, k_first, duties, start, time_s[:-1], dict(zip(x0, shifted[0])))
    theta_step = float(np.max(np.abs(np.diff(truth[:, 2]))))
    assert np.max(np.abs(late[:, 2] - shifted[:, 2])) < 0.05 * theta_step + 1e-6
    # a changed duty record changes the trajectory: the duties are what drives it
    other = true_plant_open_loop(settings, k_first, duties[::-1].copy(), 0.0, time_s, x0)
    assert np.max(np.abs(other[:, 2] - truth[:, 2])) > 1e-3


def test_a_log_of_another_pwm_period_is_named(tmp_path):
    _, _, path = logged_run(tmp_path, 3e-5)
    config = short_config()
    config["bench"]["pwm_frequency_hz"] = 20000.0  # the log holds one duty per 0.1 ms, not per 0.05 ms
    with pytest.raises(ValueError, match=r"quick_\+3e-05\.mf4: channel MotCtl_DutyA is not one sample per PWM"):
        applied_duties(path, parse_bench_settings(config))
