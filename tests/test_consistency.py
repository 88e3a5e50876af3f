"""The FMU against the bench through the whole data chain: emulate -> MDF4 -> ingest -> open loop.

With every bench effect off and the bench's true parameters equal to the FMU's nominal ones, the
FMU driven open loop by the INGESTED inputs follows the LOGGED angle to within encoder counts over
0.5 s of motion; with the demo's effects on it drifts by hundreds of counts: that drift is the gap
the neural FMU and the diagnosis work on.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybridfmu_bench.emulate import emulate_bench
from hybridfmu.data.roles import case_roles
from hybridfmu.data.ingest import ingest_log
from hybridfmu.data.signals import input_array, state_array, time_array
from hybridfmu.fmu import load_fmu, simulate_open_loop

from test_bench_emulate import short_config

ENCODER_COUNT_RAD = 2 * math.pi / 16384  # the demo bench's 14-bit encoder


def angle_error_counts(tmp_path, ipbmotor_fmu, config) -> tuple[np.ndarray, float]:
    """Open-loop angle error (encoder counts, per sample) and the seconds of motion (|omega| > 5 rad/s)."""
    mdf = tmp_path / "quick.mf4"
    emulate_bench(config, "quick", mdf, tmp_path / "quick.truth.json", duration_s=0.8,
                  check_spread_of_maneuvers=False)
    frame = ingest_log(mdf, config)
    roles = case_roles(config)
    with load_fmu(ipbmotor_fmu) as model:
        time_s = time_array(frame)
        u = input_array(frame, roles)
        x = state_array(frame, roles, model.state_names)
        result = simulate_open_loop(model, time_s, u, x[0])
    theta = model.state_names.index("theta")
    omega = model.state_names.index("omega")
    error_counts = np.abs(result.states[:, theta] - x[:, theta]) / ENCODER_COUNT_RAD
    motion_s = float(np.sum(np.abs(x[:, omega]) > 5.0) * (time_s[1] - time_s[0]))
    return error_counts, motion_s


@pytest.fixture(scope="module")
def ideal_and_demo(tmp_path_factory, ipbmotor_fmu):
    ideal = short_config()
    ideal["bench"]["effects"] = {}
    ideal["bench"]["true_parameter_offsets"] = {}
    return (angle_error_counts(tmp_path_factory.mktemp("ideal"), ipbmotor_fmu, ideal),
            angle_error_counts(tmp_path_factory.mktemp("demo"), ipbmotor_fmu, short_config()))


def test_fmu_follows_the_logged_angle_when_the_bench_has_no_effects(ideal_and_demo):
    (errors, motion_s), _ = ideal_and_demo
    assert motion_s >= 0.5
    # Sensor noise, the pressure sensor's lag in the logged load and the encoder's truncation remain.
    assert np.mean(errors) < 10
    assert np.max(errors) < 40


def test_fmu_drifts_from_the_logged_angle_with_the_demo_effects(ideal_and_demo):
    (ideal_errors, _), (demo_errors, motion_s) = ideal_and_demo
    assert motion_s >= 0.5
    assert np.mean(demo_errors) > 10 * np.mean(ideal_errors)
    assert np.max(demo_errors) > 200
