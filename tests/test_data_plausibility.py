"""Plausibility checks at ingest: isolated outliers, ranges, kinematic pairs found from the FMU."""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import pytest

from hybridfmu.config import load_case_config
from hybridfmu.data.errors import DataError
from hybridfmu.data.ingest import ingest_log
from hybridfmu.data.plausibility import (KinematicPair, _isolated_departure, check_outliers, kinematic_pairs,
                                         measured_ratio, unit_hint)

REPO = Path(__file__).resolve().parents[1]


def test_kinematic_pairs_come_from_the_fmu():
    demo = load_case_config(REPO / "config" / "config.yaml")
    assert kinematic_pairs(demo, ["i_d", "i_q", "theta", "omega"]) == [KinematicPair("theta", "omega", 1.0)]
    assert kinematic_pairs(demo, ["i_d", "i_q", "theta"]) == []  # the rate is not measured: nothing to check
    oscillator = {"fmu": {"source": "build", "model_name": "Oscillator", "path": ""}}
    assert kinematic_pairs(oscillator, ["x", "v"]) == [KinematicPair("x", "v", 1.0)]
    tanks = load_case_config(REPO / "config" / "cases" / "tanks.yaml")
    assert kinematic_pairs(tanks, ["x1", "x2"]) == []  # der(x2) depends on x1 and x2: no pair


def test_kinematic_pair_of_a_user_fmu(tmp_path):
    from hybridfmu.fmu.build import build_fmu_from_description

    fmu = build_fmu_from_description(REPO / "tests" / "fixtures" / "mass_spring" / "modelDescription.xml",
                                     tmp_path / "MassSpring.fmu")
    config = {"fmu": {"source": "path", "model_name": "MassSpring", "path": str(fmu)}}
    assert kinematic_pairs(config, ["x", "v"]) == [KinematicPair("x", "v", 1.0)]


def test_measured_ratio_and_unit_hints():
    t = np.arange(0.0, 1.0, 1e-3)
    rate = np.cos(2 * math.pi * 3 * t)
    position = np.sin(2 * math.pi * 3 * t) / (2 * math.pi * 3)
    ratio, used = measured_ratio(position, rate, 1e-3, 20, 0.1)
    assert ratio == pytest.approx(1.0, abs=2e-3) and used >= 30
    ratio, _ = measured_ratio(position * 180 / math.pi, rate, 1e-3, 20, 0.1)
    assert ratio == pytest.approx(180 / math.pi, rel=2e-3)
    assert measured_ratio(position, np.zeros_like(rate), 1e-3, 20, 0.1)[1] == 0  # no motion: nothing to compare
    assert "deg per rad" in unit_hint(math.pi / 180) and "deg per rad" in unit_hint(57.0)
    assert "rpm per rad/s" in unit_hint(2 * math.pi / 60)
    assert "2 pi" in unit_hint(-2 * math.pi) and "opposite sign" in unit_hint(-2 * math.pi)
    assert "gain -1" in unit_hint(-1.0)
    assert unit_hint(1.7) == ""


def test_outliers_fire_on_isolated_samples_only():
    t = np.arange(2000) * 1e-4
    duty = np.where((t * 50) % 1 < 0.5, 10.0, 90.0)  # PWM-like steps: depart from one neighbour only
    check_outliers(Path("log.mf4"), "Duty", "duty", "%", t, duty, 10.0, 0.01)
    pulse = duty.copy()
    pulse[700] = 50.0  # a one-sample pulse within the signal's range is not implausible either
    check_outliers(Path("log.mf4"), "Duty", "duty", "%", t, pulse, 10.0, 0.01)
    spike = duty.copy()
    spike[700] = 1e4
    with pytest.raises(DataError, match=r"log.mf4: channel Duty \(duty\): isolated implausible sample 10000 % "
                                        r"at t = 0.07 s"):
        check_outliers(Path("log.mf4"), "Duty", "duty", "%", t, spike, 10.0, 0.01)
    check_outliers(Path("log.mf4"), "Duty", "duty", "%", t, spike, None, 0.01)  # disabled
    last = duty.copy()
    last[-1] = -1e4
    with pytest.raises(DataError, match=r"sample 1999"):
        check_outliers(Path("log.mf4"), "Duty", "duty", "%", t, last, 10.0, 0.01)
    np.testing.assert_array_equal(_isolated_departure(np.array([0.0, 5.0, 1.0, 2.0, 3.0])), [5.0, 4.0, 1.0, 0.0, 1.0])


def test_checks_can_be_relaxed_in_the_config(tmp_path):
    """The angle-in-rad log passes with the kinematic check off, the outlier with a larger factor."""
    import sys

    sys.path.insert(0, str(REPO / "tests" / "bad_input"))
    from test_bad_logs import demo_channels, demo_config, write_mdf

    channels = demo_channels()
    channels["MotPos_Angle"] = (channels["MotPos_Angle"][0], np.deg2rad(channels["MotPos_Angle"][1]), "")
    raw = write_mdf(tmp_path / "rad.mf4", channels, units=False)
    config = demo_config()
    with pytest.raises(DataError, match="57.3 = deg per rad"):
        ingest_log(raw, config)
    config["ingest"]["kinematic"]["enabled"] = False
    assert len(ingest_log(raw, config)) == 5000
    channels = demo_channels()
    channels["MotPos_Speed"][1][100] *= 3.0  # 3x a sample of the speed: within 10x its spread, passes
    config = demo_config()
    ingest_log(write_mdf(tmp_path / "small.mf4", channels), config)


def test_the_real_cascaded_tanks_records_pass():
    """The quantised real records (1024 samples each) pass the outlier check with the defaults."""
    config = load_case_config(REPO / "config" / "cases" / "tanks.yaml")
    for maneuver in ("train", "validation", "test"):
        frame = ingest_log(REPO / config["maneuvers"][maneuver]["raw"], config, maneuver)
        assert len(frame) > 250


def test_the_demo_bench_log_passes_with_a_ratio_near_one(tmp_path, caplog):
    """An emulated demo log (time offset between channels, encoder quantisation) passes; its measured
    angle/speed ratio is within 0.002 of 1, far inside the default tolerance 0.1."""
    from hybridfmu_bench.emulate import emulate_bench

    config = load_case_config(REPO / "config" / "config.yaml")
    raw = tmp_path / "train.mf4"
    emulate_bench(config, "train", raw, tmp_path / "train.truth.json", duration_s=4.0,
                  check_spread_of_maneuvers=False)
    with caplog.at_level(logging.INFO, logger="hybridfmu.data.plausibility"):
        ingest_log(raw, config, "train")
    line = next(line for line in caplog.messages if "d(angle)/dt" in line)
    ratio = float(line.split(" = ")[1].split(" x ")[0])
    windows = int(line.split(" over ")[1].split(" windows")[0])
    assert abs(ratio - 1.0) < 0.002 and windows >= 20, line
