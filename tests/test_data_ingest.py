"""Ingestion of raw logs by the case's declared signals: MDF4, CSV and Parquet, units, slices, bad inputs."""

from __future__ import annotations

import copy
import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridfmu.config import validate_case_config
from hybridfmu.data.errors import DataError
from hybridfmu.data.ingest import ingest_log, ingest_to_parquet

REPO = Path(__file__).resolve().parents[1]
RATE_HZ = 10_000.0
DURATION_S = 0.5
COUNTS_PER_REV = 4096
POLE_PAIRS = 4
NM_PER_BAR = 0.0125


#: The demo's signals that only its closed loop reads (the ECU's references, logged by the bench); the synthetic
#: logs here carry the measured channels only.
ECU_REFERENCE_SIGNALS = ("pressure_request", "pressure_mode", "angle_ref", "speed_ff", "accel_ff", "speed_limit",
                         "current_limit")


def case_config(**sections) -> dict:
    """The demo case's data sections (IPBMotor's interface from its C sources), validated, with overrides."""
    demo = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    config = {key: copy.deepcopy(demo[key]) for key in ("case", "fmu", "maneuvers", "signals", "transforms",
                                                         "roles", "ingest")}
    config["maneuvers"] = {"run": {"role": "train", "raw": "run.mf4"}}
    config["signals"] = {name: entry for name, entry in config["signals"].items() if name not in ECU_REFERENCE_SIGNALS}
    config.update(copy.deepcopy(sections))
    return validate_case_config(config)


CONFIG = case_config()


# Analytic truth in SI units: the logs sample these functions (ECU units) at their own rates.
def duty(t, phase):
    return 0.5 + 0.3 * np.sin(2 * math.pi * 7.0 * t + phase)


def theta_rad(t):
    return 3.0 + 20.0 * np.sin(2 * math.pi * 1.5 * t)


def omega_rad_s(t):
    return 20.0 * 2 * math.pi * 1.5 * np.cos(2 * math.pi * 1.5 * t)


def pressure_pa(t):
    return 40e5 * np.sin(2 * math.pi * 1.0 * t) ** 2


def u_dc_v(t):
    return 12.0 + 0.2 * np.sin(2 * math.pi * 50.0 * t)


def dq_a(t):
    """Rotor-frame currents (i_d, i_q) in A that the phase currents of the logs carry."""
    return 2.0 + 0.5 * np.sin(2 * math.pi * 3.0 * t), 25.0 * np.cos(2 * math.pi * 2.0 * t)


def phase_currents_a(t):
    """Phase currents (3, n) from dq_a by the inverse Clarke-Park transform with the true angle."""
    i_d, i_q = dq_a(t)
    angle = POLE_PAIRS * theta_rad(t)
    alpha = i_d * np.cos(angle) - i_q * np.sin(angle)
    beta = i_d * np.sin(angle) + i_q * np.cos(angle)
    a = alpha
    b = -0.5 * alpha + math.sqrt(3) / 2 * beta
    return np.stack([a, b, -a - b])


def raw_signals(duration_s=DURATION_S):
    """{channel: (time_s, values in the ECU unit, unit)}, 10 kHz and 1 kHz time bases, offset starts."""
    fast = np.arange(0.0, duration_s, 1e-4) + 0.0002
    slow = np.arange(0.0, duration_s, 1e-3) + 0.0005
    counts = np.round(theta_rad(fast) / (2 * math.pi) * COUNTS_PER_REV)
    currents = phase_currents_a(fast)
    return {
        "MotCtl_DutyA": (fast, 100 * duty(fast, 0.0), "%"),
        "MotCtl_DutyB": (fast, 100 * duty(fast, -2.0944), "%"),
        "MotCtl_DutyC": (fast, 100 * duty(fast, 2.0944), "%"),
        "MotPos_Angle": (fast, counts * 360.0 / COUNTS_PER_REV, "deg"),
        "MotPos_Speed": (fast, omega_rad_s(fast) * 60 / (2 * math.pi), "rpm"),
        "MotCur_IPhA": (fast, currents[0], "A"),
        "MotCur_IPhB": (fast, currents[1], "A"),
        "MotCur_IPhC": (fast, currents[2], "A"),
        "Hyd_Pressure": (slow, pressure_pa(slow) / 1e5, "bar"),
        "Sply_UDc": (slow, u_dc_v(slow), "V"),
        "Other_Channel": (slow, np.zeros_like(slow), "-"),
    }


def write_mdf(path, signals):
    """Write ``{name: (time_s, values, unit)}`` as MDF4, one group per time base (as a logger does)."""
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    groups: dict[bytes, list] = {}
    for name, (time_s, values, unit) in signals.items():
        key = np.asarray(time_s, dtype=np.float64).tobytes()  # channels with identical time stamps share a group
        groups.setdefault(key, []).append(Signal(np.asarray(values), np.asarray(time_s), name=name, unit=unit))
    for group in groups.values():
        mdf.append(group)
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def write_table(path, signals, units_row=True, time_factor=1.0, time_unit="s", time_column=True):
    """CSV/Parquet of all channels on the 10 kHz time base (CSV: name row and unit row)."""
    fast = {name: sig for name, sig in signals.items() if len(sig[0]) == len(signals["MotCtl_DutyA"][0])}
    time_s = signals["MotCtl_DutyA"][0]
    frame = pd.DataFrame({"time": time_s * time_factor, **{name: sig[1] for name, sig in fast.items()}})
    slow_t = signals["Sply_UDc"][0]
    for name in ("Sply_UDc", "Hyd_Pressure"):
        frame[name] = np.interp(time_s, slow_t, signals[name][1])
    units = [time_unit] + [fast[name][2] for name in fast] + ["V", "bar"]
    if not time_column:
        frame, units = frame.drop(columns=["time"]), units[1:]
    if path.suffix == ".csv":
        with path.open("w") as handle:
            handle.write(",".join(frame.columns) + "\n")
            if units_row:
                handle.write(",".join(units) + "\n")
            frame.to_csv(handle, header=False, index=False, lineterminator="\n")
    else:
        frame.columns = [f"{name} [{unit}]" for name, unit in zip(frame.columns, units)]
        frame.to_parquet(path, index=False)
    return path


@pytest.fixture(scope="module")
def mdf_path(tmp_path_factory):
    return write_mdf(tmp_path_factory.mktemp("raw") / "maneuver.mf4", raw_signals())


def test_mdf_round_trip_in_model_units(mdf_path, tmp_path):
    out = ingest_to_parquet(mdf_path, tmp_path / "data" / "maneuver.parquet", CONFIG, "run")
    frame = pd.read_parquet(out)
    assert list(frame.columns) == ["time_s", "duty_a", "duty_b", "duty_c", "u_dc", "pressure", "angle", "speed",
                                   "i_a", "i_b", "i_c", "load_torque", "current_d", "current_q"]
    assert all(frame[column].dtype == np.float64 for column in frame.columns)
    time_s = frame["time_s"].to_numpy()
    assert time_s[0] == 0.0
    np.testing.assert_allclose(np.diff(time_s), 1.0 / RATE_HZ, rtol=1e-9)
    # common start is the latest first sample (the 1 kHz channels start at 0.5 ms)
    t_abs = time_s + 0.0005
    assert len(frame) == 4991
    # duties: % -> 1 (the FMU's unit), held onto the grid (exact up to float rounding)
    held = np.searchsorted(raw_signals()["MotCtl_DutyA"][0], t_abs + 1e-12, side="right") - 1
    np.testing.assert_allclose(frame["duty_a"], duty(raw_signals()["MotCtl_DutyA"][0][held], 0.0), atol=1e-9)
    # deg -> rad, rpm -> rad/s, bar -> Pa (to_unit), linear interpolation and encoder quantisation only
    np.testing.assert_allclose(frame["angle"], theta_rad(t_abs), atol=2 * math.pi / COUNTS_PER_REV)
    np.testing.assert_allclose(frame["speed"], omega_rad_s(t_abs), atol=0.05)
    np.testing.assert_allclose(frame["pressure"], pressure_pa(t_abs), atol=0.02e5)
    np.testing.assert_allclose(frame["u_dc"], u_dc_v(t_abs), atol=0.01)
    # transforms in natural units: bar * 0.0125 N*m/bar; Park with the measured angle in deg
    np.testing.assert_allclose(frame["load_torque"], NM_PER_BAR * pressure_pa(t_abs) / 1e5, atol=0.02 * NM_PER_BAR)
    i_d, i_q = dq_a(t_abs)
    np.testing.assert_allclose(frame["current_d"], i_d, atol=0.5)
    np.testing.assert_allclose(frame["current_q"], i_q, atol=0.5)


def test_csv_with_unit_row_and_affine_unit(tmp_path):
    signals = raw_signals()
    signals["Temp"] = (signals["MotCtl_DutyA"][0], np.full(len(signals["MotCtl_DutyA"][0]), 25.0), "degC")
    path = write_table(tmp_path / "log.csv", signals)
    config = case_config()
    config["signals"]["temperature"] = {"channel": "Temp", "unit": "degC", "to_unit": "K"}
    frame = ingest_log(path, config)
    t_abs = frame["time_s"].to_numpy() + 0.0002
    assert len(frame) == 5000
    np.testing.assert_allclose(frame["temperature"], 298.15, atol=1e-9)  # affine degC -> K
    np.testing.assert_allclose(frame["angle"], theta_rad(t_abs), atol=2 * math.pi / COUNTS_PER_REV)
    np.testing.assert_allclose(frame["speed"], omega_rad_s(t_abs), atol=0.05)


def test_csv_without_units_and_time_in_ms(tmp_path):
    plain = ingest_log(write_table(tmp_path / "log.csv", raw_signals(), units_row=False), CONFIG)
    assert plain["duty_a"].between(0.19, 0.81).all()
    in_ms = write_table(tmp_path / "log_ms.csv", raw_signals(), units_row=False, time_factor=1e3)
    config = case_config(ingest={"time": {"channel": "time", "unit": "ms"}})
    pd.testing.assert_frame_equal(ingest_log(in_ms, config), plain, rtol=1e-9, atol=1e-9)


def test_the_time_column_is_found_by_its_name_with_the_unit_it_names(tmp_path):
    """Without config.ingest.time, a column named ``time_ms`` is the time base in ms, ``Time [s]`` in s: the same
    frame as with the column and unit configured."""
    plain = ingest_log(write_table(tmp_path / "log.csv", raw_signals(), units_row=False), CONFIG)
    in_ms = write_table(tmp_path / "log_ms.csv", raw_signals(), units_row=False, time_factor=1e3)
    in_ms.write_text(in_ms.read_text().replace("time", "time_ms", 1))
    pd.testing.assert_frame_equal(ingest_log(in_ms, CONFIG), plain, rtol=1e-9, atol=1e-9)
    bracketed = tmp_path / "bracketed.csv"
    bracketed.write_text((tmp_path / "log.csv").read_text().replace("time", "Time [s]", 1))
    pd.testing.assert_frame_equal(ingest_log(bracketed, CONFIG), plain, rtol=1e-9, atol=1e-9)
    with pytest.raises(DataError, match="the file says unit 'ms' but config.ingest.time.unit says 's'"):
        ingest_log(in_ms, case_config(ingest={"time": {"unit": "s"}}))


def test_sample_period_without_time_column(tmp_path):
    path = write_table(tmp_path / "log.csv", raw_signals(), time_column=False)
    frame = ingest_log(path, case_config(ingest={"sample_period_s": 1e-4}))
    assert len(frame) == 5000 and frame["time_s"].iloc[-1] == pytest.approx(0.4999)
    t_abs = frame["time_s"].to_numpy() + 0.0002  # sample 0 was taken at 0.2 ms
    np.testing.assert_allclose(frame["speed"], omega_rad_s(t_abs), atol=0.05)
    with pytest.raises(DataError, match=r"no column is named as a time.*sample_period_s"):
        ingest_log(path, CONFIG)
    with pytest.raises(DataError, match=r"time column 'zeit' \(config.ingest.time.channel\) not found"):
        ingest_log(path, case_config(ingest={"time": {"channel": "zeit"}}))


def test_parquet_with_units_in_column_names(tmp_path):
    path = write_table(tmp_path / "log.parquet", raw_signals())
    frame = ingest_log(path, CONFIG)
    t_abs = frame["time_s"].to_numpy() + 0.0002
    np.testing.assert_allclose(frame["duty_a"], duty(t_abs, 0.0), atol=1e-9)
    np.testing.assert_allclose(frame["pressure"], pressure_pa(t_abs), atol=0.02e5)


def test_per_maneuver_channel_override(tmp_path):
    signals = raw_signals()
    time_s, values, unit = signals["MotPos_Angle"]
    signals["MotPos_Angle_Rig2"] = (time_s, values + 90.0, unit)  # a second record beside the first
    raw = write_mdf(tmp_path / "two.mf4", signals)
    config = case_config(maneuvers={"rig1": {"role": "train", "raw": str(raw)},
                                    "rig2": {"role": "test", "raw": str(raw),
                                             "channels": {"angle": "MotPos_Angle_Rig2"}}})
    rig1, rig2 = ingest_log(raw, config, "rig1"), ingest_log(raw, config, "rig2")
    np.testing.assert_allclose(rig2["angle"] - rig1["angle"], math.pi / 2, atol=1e-9)
    np.testing.assert_array_equal(rig2["speed"], rig1["speed"])
    config["maneuvers"]["rig2"]["channels"] = {"winkel": "MotPos_Angle_Rig2"}
    with pytest.raises(DataError, match=r"config\.maneuvers\.rig2\.channels\.winkel: not a logged signal"):
        ingest_log(raw, config, "rig2")
    with pytest.raises(DataError, match=r"config\.maneuvers: no maneuver 'rig3'"):
        ingest_log(raw, config, "rig3")


def test_maneuver_slice_starts_at_zero(mdf_path):
    config = case_config(maneuvers={"middle": {"role": "train", "raw": str(mdf_path), "t_start_s": 0.1,
                                               "t_end_s": 0.3}})
    whole = ingest_log(mdf_path, CONFIG)
    part = ingest_log(mdf_path, config, "middle")
    assert part["time_s"].iloc[0] == 0.0
    assert part["time_s"].iloc[-1] == pytest.approx(0.2)
    t_abs = part["time_s"].to_numpy() + 0.1002  # relative to the log's first sample (0.2 ms)
    np.testing.assert_allclose(part["speed"], omega_rad_s(t_abs), atol=0.05)
    np.testing.assert_allclose(part["pressure"], pressure_pa(t_abs), atol=0.02e5)
    assert len(part) < len(whole)
    config["maneuvers"]["middle"]["t_end_s"] = 0.05
    with pytest.raises(DataError, match=r"config\.maneuvers\.middle: t_end_s = 0.05 is not after t_start_s"):
        ingest_log(mdf_path, config, "middle")


# ---- bad inputs: a clear DataError naming file and channel, and no output file ----------------------------

def _set(channel, index, value):
    def change(signals):
        signals[channel][1][index] = value
    return change


def _time(channel, transform):
    def change(signals):
        time_s, values, unit = signals[channel]
        signals[channel] = (transform(time_s.copy()), values, unit)
    return change


def _duplicate(time_s):
    time_s[100] = time_s[99]
    return time_s


def _decrease(time_s):
    time_s[100] = time_s[98]
    return time_s


def _gap(time_s):
    time_s[200:] += 0.05
    return time_s


def _unit(channel, unit):
    return lambda s: s.__setitem__(channel, (*s[channel][:2], unit))


BAD_MDF = {
    "missing channel": (lambda s: s.pop("MotPos_Speed"), r"MotPos_Speed not found; the file has: .*MotPos_Angle"),
    "duplicated time": (_time("MotCtl_DutyB", _duplicate), r"MotCtl_DutyB \(duty_b\): time stamps not strictly "
                                                             r"increasing \(duplicated\)"),
    "decreasing time": (_time("Sply_UDc", _decrease), r"Sply_UDc \(u_dc\): time stamps not strictly increasing "
                                                      r"\(decreasing\)"),
    "nan run": (lambda s: s["MotCur_IPhA"][1].__setitem__(slice(300, 320), np.nan),
                r"MotCur_IPhA \(i_a\): 20 consecutive NaN/inf samples"),
    "inf sample": (_set("Hyd_Pressure", 10, np.inf), r"Hyd_Pressure \(pressure\): 1 consecutive NaN/inf"),
    "log slower than the gap limit": (_time("Hyd_Pressure", lambda t: (t - t[0]) * 20 + t[0]),
                                      r"Hyd_Pressure \(pressure\): sampled every 0.02 s \(median step\), slower than "
                                      r"config.ingest.max_gap_s = 0.01 s allows"),
    "long gap": (_time("Hyd_Pressure", _gap), r"Hyd_Pressure \(pressure\): gap of 0.051 s after 0.1995 s exceeds "
                                              r".*max_gap_s = 0.01"),
    "unit of another dimension": (_unit("MotPos_Speed", "N"), r"MotPos_Speed \(speed\): the file says unit 'N' but "
                                                              r"config.signals.speed.unit says 'rpm'"),
    "unit disagrees with config": (_unit("MotPos_Angle", "rad"), r"MotPos_Angle \(angle\): the file says unit "
                                                                 r"'rad' but config.signals.angle.unit says 'deg'"),
    "stuck phase sensor": (lambda s: s["MotCur_IPhA"][1].__setitem__(slice(None), 0.0),
                           r"config\.transforms: park: phases \['i_a', 'i_b', 'i_c'\] sum to .* \['i_a'\] never "
                           r"changes; expected about 0 .* a phase sensor stuck"),
}


@pytest.mark.parametrize("case", sorted(BAD_MDF))
def test_bad_mdf_input_raises_and_writes_nothing(case, tmp_path):
    change, message = BAD_MDF[case]
    signals = raw_signals()
    change(signals)
    raw = write_mdf(tmp_path / "bad.mf4", signals)
    out = tmp_path / "data" / "bad.parquet"
    with pytest.raises(DataError, match=message) as info:
        ingest_to_parquet(raw, out, CONFIG)
    assert str(raw) in str(info.value)
    assert not out.exists()
    assert not (tmp_path / "data").exists() or not list((tmp_path / "data").glob("*"))


def test_file_units_that_agree_or_are_unknown(tmp_path, caplog):
    signals = raw_signals()
    signals["MotPos_Angle"] = (*signals["MotPos_Angle"][:2], "degree")  # = deg
    signals["MotCur_IPhA"] = (*signals["MotCur_IPhA"][:2], "ampere")    # = A
    signals["MotPos_Speed"] = (*signals["MotPos_Speed"][:2], "UpM")     # unknown: the config's rpm is used
    raw = write_mdf(tmp_path / "odd_units.mf4", signals)
    with caplog.at_level(logging.WARNING):
        frame = ingest_log(raw, CONFIG)
    assert "unit 'UpM' from the file is unknown; using 'rpm' from config.signals.speed.unit" in caplog.text
    t_abs = frame["time_s"].to_numpy() + 0.0005
    np.testing.assert_allclose(frame["speed"], omega_rad_s(t_abs), atol=0.05)
    np.testing.assert_allclose(frame["angle"], theta_rad(t_abs), atol=2 * math.pi / COUNTS_PER_REV)


def test_gain_offset_and_wrap_in_the_raw_unit(tmp_path):
    signals = raw_signals()
    time_s, values, _ = signals["MotPos_Angle"]
    signals["MotPos_Angle"] = (time_s, np.mod(values, 360.0) / 2.0, "deg")  # single-turn, half scale
    raw = write_mdf(tmp_path / "wrapped.mf4", signals)
    config = case_config()
    config["signals"]["angle"].update(gain=2.0, offset=0.0, wrap_period=180.0)
    frame = ingest_log(raw, config)
    t_abs = frame["time_s"].to_numpy() + 0.0005
    np.testing.assert_allclose(frame["angle"], theta_rad(t_abs), atol=2 * math.pi / COUNTS_PER_REV)


def test_nan_runs_up_to_the_limit_are_dropped(tmp_path):
    signals = raw_signals()
    signals["MotCur_IPhA"][1][300:303] = np.nan
    raw = write_mdf(tmp_path / "nan.mf4", signals)
    frame = ingest_log(raw, case_config(ingest={"max_nonfinite_samples": 3}))
    t_abs = frame["time_s"].to_numpy() + 0.0005
    np.testing.assert_allclose(frame["i_a"], phase_currents_a(t_abs)[0], atol=1.0)


@pytest.mark.parametrize("case", ["empty", "header only", "truncated", "garbage", "no channels"])
def test_empty_truncated_corrupt_mdf(case, mdf_path, tmp_path):
    raw = tmp_path / "broken.mf4"
    data = mdf_path.read_bytes()
    if case == "empty":
        raw.write_bytes(b"")
        expected = "file is empty"
    elif case == "header only":
        raw.write_bytes(data[:64])
        expected = "corrupt or truncated"
    elif case == "truncated":
        raw.write_bytes(data[: len(data) * 2 // 3])
        expected = "corrupt or truncated"
    elif case == "garbage":
        raw.write_bytes(bytes(range(256)) * 40)
        expected = "corrupt or truncated"
    else:
        from asammdf import MDF

        MDF(version="4.10").save(raw, overwrite=True)
        expected = "file is empty"
    out = tmp_path / "out.parquet"
    with pytest.raises(DataError, match=expected) as info:
        ingest_to_parquet(raw, out, CONFIG)
    assert str(raw) in str(info.value)
    assert not out.exists()


def _replace_cell(text, row, column, cell):
    lines = text.split("\n")
    fields = lines[row].split(",")
    fields[column] = cell
    lines[row] = ",".join(fields)
    return "\n".join(lines)


def test_bad_csv_inputs(tmp_path):
    good = write_table(tmp_path / "good.csv", raw_signals()).read_text()
    cases = {
        "empty.csv": ("", "file is empty"),
        "header.csv": (good.split("\n", 1)[0] + "\n", "file is empty"),
        "units_only.csv": ("\n".join(good.split("\n")[:2]) + "\n", "file is empty"),
        "truncated.csv": (good[: len(good) // 2].rsplit(",", 3)[0], "last row has .* fields .*truncated"),
        "text.csv": (_replace_cell(good, row=12, column=3, cell="n/a"), r"column MotCtl_DutyC: row 11 holds "
                                                                       r"'n/a'; expected a number"),
        "missing.csv": (good.replace("MotPos_Angle", "MotPos_Winkel"), "MotPos_Angle not found; the file has: "),
        "notime.csv": (good.replace("time", "stamp", 1), "no column is named as a time"),
        "twotimes.csv": (good.replace("MotCtl_DutyA", "t", 1), r"2 columns \(time, t\) are named as a time"),
    }
    for name, (text, message) in cases.items():
        raw = tmp_path / name
        raw.write_text(text)
        out = tmp_path / f"{name}.parquet"
        with pytest.raises(DataError, match=message) as info:
            ingest_to_parquet(raw, out, CONFIG)
        assert str(raw) in str(info.value), name
        assert not out.exists()


def test_corrupt_or_empty_parquet_and_unknown_format(tmp_path):
    good = write_table(tmp_path / "good.parquet", raw_signals())
    broken = tmp_path / "broken.parquet"
    broken.write_bytes(good.read_bytes()[:-200])
    with pytest.raises(DataError, match="broken.parquet: cannot read the Parquet file"):
        ingest_log(broken, CONFIG)
    empty = tmp_path / "empty.parquet"
    pd.read_parquet(good).iloc[:0].to_parquet(empty, index=False)
    with pytest.raises(DataError, match="empty.parquet: the file is empty"):
        ingest_log(empty, CONFIG)
    other = tmp_path / "log.xlsx"
    other.write_bytes(b"PK")
    with pytest.raises(DataError, match=r"unknown log format '.xlsx'"):
        ingest_log(other, CONFIG)


def test_phases_of_an_idle_machine_or_with_offsets_pass_the_phase_sum_check():
    """Noise only (an idle machine), or running phases with a few per cent of offset: no error. One phase at a
    fifth of its scale while the machine runs: an error."""
    from hybridfmu.data.transforms.base import TransformError
    from hybridfmu.data.transforms.motor import check_phase_sum

    rng = np.random.default_rng(3)
    noise = [0.05 * rng.standard_normal(5000) for _ in range(3)]
    check_phase_sum(noise, ["a", "b", "c"], "A")
    t = np.arange(5000) * 1e-4
    running = [20 * np.cos(2 * np.pi * 50 * t - k * 2 * np.pi / 3) + 0.5 + noise[k] for k in range(3)]
    check_phase_sum(running, ["a", "b", "c"], "A")
    with pytest.raises(TransformError, match=r"park: phases \['a', 'b', 'c'\] sum to .* expected about 0"):
        check_phase_sum([0.2 * running[0], running[1], running[2]], ["a", "b", "c"], "A")
