"""Bad raw logs of the demo case: each kind stops the ingest with an error naming the log file and the
channel, and an earlier ingested Parquet (and every other earlier output) survives the failed ingest."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridfmu.config import validate_case_config
from hybridfmu.data.errors import DataError
from hybridfmu.data.ingest import ingest_to_parquet

REPO = Path(__file__).resolve().parents[2]


def _suite_checks():
    # the shared checks of tests/bad_input/conftest.py, by path: another conftest module of the suite may
    # already be imported under the name "conftest"
    import importlib.util

    spec = importlib.util.spec_from_file_location("bad_input_suite_checks", Path(__file__).with_name("conftest.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.assert_intact, module.assert_names, module.snapshot


assert_intact, assert_names, snapshot = _suite_checks()
DEMO = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
RATE_HZ = 10_000.0
DURATION_S = 0.5

#: The demo's signals that only its closed loop reads (the ECU's references, logged by the bench); the synthetic
#: logs here carry the measured channels only.
ECU_REFERENCE_SIGNALS = ("pressure_request", "pressure_mode", "angle_ref", "speed_ff", "accel_ff", "speed_limit",
                         "current_limit")


def demo_config(**signal_changes) -> dict:
    """The demo case's data sections (IPBMotor from its C sources), one maneuver 'run', signal entries changed."""
    config = {key: copy.deepcopy(DEMO[key]) for key in ("case", "fmu", "signals", "transforms", "roles", "ingest")}
    config["maneuvers"] = {"run": {"role": "train", "raw": "run.mf4"}}
    config["signals"] = {name: entry for name, entry in config["signals"].items() if name not in ECU_REFERENCE_SIGNALS}
    for name, change in signal_changes.items():
        config["signals"][name].update(change)
    return validate_case_config(config)


def demo_channels() -> dict[str, tuple[np.ndarray, np.ndarray, str]]:
    """{channel: (time_s, values, unit)}: a consistent 0.5 s recording of the demo's channels at 10 kHz.

    The rotor turns by theta = 3 + 20 sin(2 pi 1.5 t) rad (an encoder of 4096 counts/rev, logged in deg) and
    the speed channel is its derivative in rpm, as the demo's config declares.
    """
    t = np.arange(0.0, DURATION_S, 1.0 / RATE_HZ)
    theta = 3.0 + 20.0 * np.sin(2 * math.pi * 1.5 * t)
    omega = 20.0 * 2 * math.pi * 1.5 * np.cos(2 * math.pi * 1.5 * t)
    angle_deg = np.round(theta / (2 * math.pi) * 4096) * 360.0 / 4096
    current = 20.0 * np.sin(2 * math.pi * 40.0 * t)
    return {
        "MotCtl_DutyA": (t, 50 + 30 * np.sin(2 * math.pi * 7.0 * t), "%"),
        "MotCtl_DutyB": (t, 50 + 30 * np.sin(2 * math.pi * 7.0 * t - 2.0944), "%"),
        "MotCtl_DutyC": (t, 50 + 30 * np.sin(2 * math.pi * 7.0 * t + 2.0944), "%"),
        "Sply_UDc": (t, 12.0 + 0.2 * np.sin(2 * math.pi * 50.0 * t), "V"),
        "Hyd_Pressure": (t, 40.0 * np.sin(2 * math.pi * t) ** 2, "bar"),
        "MotPos_Angle": (t, angle_deg, "deg"),
        "MotPos_Speed": (t, omega * 60 / (2 * math.pi), "rpm"),
        "MotCur_IPhA": (t, current, "A"),
        "MotCur_IPhB": (t, np.roll(current, 80), "A"),
        "MotCur_IPhC": (t, -current - np.roll(current, 80), "A"),
    }


def write_mdf(path: Path, channels, units: bool = True) -> Path:
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    mdf.append([Signal(values, time_s, name=name, unit=unit if units else "")
                for name, (time_s, values, unit) in channels.items()])
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def write_csv(path: Path, channels) -> Path:
    time_s = next(iter(channels.values()))[0]
    pd.DataFrame({"time": time_s, **{name: values for name, (_, values, _) in channels.items()}}).to_csv(
        path, index=False)
    return path


@pytest.fixture
def earlier(outputs: Path) -> Path:
    """``outputs`` plus the Parquet of an earlier, good ingest at the path the bad log is ingested to."""
    good = write_mdf(outputs.parent / "good.mf4", demo_channels())
    target = outputs / "data" / "run.parquet"
    ingest_to_parquet(good, target, demo_config(), "run")
    return target


def ingest_fails(raw: Path, target: Path, config: dict, outputs: Path, *parts: str) -> str:
    """Ingest ``raw`` onto ``target``: expect a DataError naming the file and ``parts``; outputs intact."""
    before = snapshot(outputs)
    with pytest.raises(DataError) as info:
        ingest_to_parquet(raw, target, config, "run")
    message = str(info.value)
    assert_names(message, str(raw), *parts)
    assert_intact(outputs, before)
    return message


def test_angle_logged_in_rad_but_declared_deg(outputs, earlier):
    channels = demo_channels()
    time_s, angle_deg, _ = channels["MotPos_Angle"]
    channels["MotPos_Angle"] = (time_s, np.deg2rad(angle_deg), "")  # the file carries no unit
    raw = write_mdf(outputs.parent / "angle_in_rad.mf4", channels, units=False)
    message = ingest_fails(raw, earlier, demo_config(), outputs, "MotPos_Angle", "MotPos_Speed", "'deg'", "'rpm'",
                           "57.3 = deg per rad")
    ratio = float(message.split("changes ")[1].split(" times")[0])
    assert ratio == pytest.approx(math.pi / 180, rel=0.01)


def test_speed_logged_in_rad_per_s_but_declared_rpm(outputs, earlier):
    channels = demo_channels()
    time_s, rpm, _ = channels["MotPos_Speed"]
    channels["MotPos_Speed"] = (time_s, rpm * 2 * math.pi / 60, "")
    raw = write_mdf(outputs.parent / "speed_in_rad_s.mf4", channels, units=False)
    message = ingest_fails(raw, earlier, demo_config(), outputs, "MotPos_Speed", "MotPos_Angle", "'rpm'",
                           "9.55 = rpm per rad/s")
    ratio = float(message.split("changes ")[1].split(" times")[0])
    assert ratio == pytest.approx(60 / (2 * math.pi), rel=0.01)


def test_single_huge_outlier(outputs, earlier):
    channels = demo_channels()
    channels["MotPos_Angle"][1][2345] = 1e9
    raw = write_mdf(outputs.parent / "outlier.mf4", channels)
    ingest_fails(raw, earlier, demo_config(), outputs, "MotPos_Angle", "(angle)", "1e+09 deg",
                 f"t = {channels['MotPos_Angle'][0][2345]:.9g} s", "config.ingest.outliers.factor")


def test_value_outside_the_configured_range(outputs, earlier):
    channels = demo_channels()
    channels["Sply_UDc"][1][1000:1200] = 31.0  # a plausible-looking plateau, but beyond the supply's range
    raw = write_mdf(outputs.parent / "overvoltage.mf4", channels)
    config = demo_config(u_dc={"range": [6.0, 18.0]})
    ingest_fails(raw, earlier, config, outputs, "Sply_UDc", "(u_dc)", "31 V", "t = 0.1 s",
                 "config.signals.u_dc.range = [6, 18] V", "200 sample(s) outside")


def test_channel_missing(outputs, earlier):
    channels = demo_channels()
    channels.pop("MotCur_IPhB")
    raw = write_mdf(outputs.parent / "no_phase_b.mf4", channels)
    ingest_fails(raw, earlier, demo_config(), outputs, "MotCur_IPhB not found", "MotCur_IPhA")


def test_nan_run(outputs, earlier):
    channels = demo_channels()
    channels["Hyd_Pressure"][1][400:450] = np.nan
    raw = write_mdf(outputs.parent / "nan_run.mf4", channels)
    ingest_fails(raw, earlier, demo_config(), outputs, "Hyd_Pressure", "(pressure)", "50 consecutive NaN/inf",
                 "config.ingest.max_nonfinite_samples = 0")


def test_duplicate_time_stamps_in_csv(outputs, earlier):
    channels = demo_channels()
    time_s = channels["MotCtl_DutyA"][0].copy()
    time_s[300] = time_s[299]
    channels = {name: (time_s, values, unit) for name, (_, values, unit) in channels.items()}
    raw = write_csv(outputs.parent / "duplicated.csv", channels)
    ingest_fails(raw, earlier, demo_config(), outputs, "MotCtl_DutyA", "(duty_a)", "duplicated", "sample 300")


def test_unit_in_the_file_contradicts_the_config(outputs, earlier):
    channels = demo_channels()
    channels["MotCur_IPhC"] = (*channels["MotCur_IPhC"][:2], "mA")
    raw = write_mdf(outputs.parent / "milliamps.mf4", channels)
    ingest_fails(raw, earlier, demo_config(), outputs, "MotCur_IPhC", "(i_c)", "'mA'",
                 "config.signals.i_c.unit says 'A'")


def test_log_shorter_than_the_maneuver_slice(outputs, earlier):
    raw = write_mdf(outputs.parent / "short.mf4", demo_channels())
    config = demo_config()
    config["maneuvers"]["run"].update(t_start_s=0.7, t_end_s=5.0)  # starts after the 0.5 s log ends
    ingest_fails(raw, earlier, config, outputs, "MotCtl_DutyA", "sample(s) in the slice",
                 "config.maneuvers.<maneuver>.t_start_s")


def test_empty_csv(outputs, earlier):
    raw = outputs.parent / "empty.csv"
    raw.write_text("time,MotCtl_DutyA,MotCtl_DutyB\n")
    ingest_fails(raw, earlier, demo_config(), outputs, "the file is empty")


def test_truncated_mdf(outputs, earlier):
    good = write_mdf(outputs.parent / "whole.mf4", demo_channels())
    raw = outputs.parent / "truncated.mf4"
    raw.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    ingest_fails(raw, earlier, demo_config(), outputs, "corrupt or truncated")


def test_corrupt_parquet(outputs, earlier):
    good = outputs.parent / "whole.parquet"
    channels = demo_channels()
    pd.DataFrame({"time": channels["MotCtl_DutyA"][0],
                  **{name: values for name, (_, values, _) in channels.items()}}).to_parquet(good, index=False)
    raw = outputs.parent / "corrupt.parquet"
    raw.write_bytes(good.read_bytes()[:-300])
    ingest_fails(raw, earlier, demo_config(), outputs, "cannot read the Parquet file")


def test_the_good_log_passes_every_check(outputs, earlier):
    """The checks above fire on the bad logs only: the consistent log (and a range it keeps) ingests."""
    frame = pd.read_parquet(earlier)
    assert len(frame) == int(DURATION_S * RATE_HZ)
    config = demo_config(u_dc={"range": [6.0, 18.0]}, angle={"range": [-1200.0, 1500.0]})
    raw = write_mdf(outputs.parent / "good_again.mf4", demo_channels())
    ingest_to_parquet(raw, outputs / "data" / "again.parquet", config, "run")
    pd.testing.assert_frame_equal(pd.read_parquet(outputs / "data" / "again.parquet"), frame)
