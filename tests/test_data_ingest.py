"""Ingestion of raw logs: MDF4 round trip, CSV and Parquet readers, and every kind of bad input."""

from __future__ import annotations

import copy
import math

import numpy as np
import pandas as pd
import pytest

from hybridfmu.data.errors import DataError
from hybridfmu.data.ingest import ingest_log, ingest_to_parquet

RATE_HZ = 10_000.0
DURATION_S = 0.5
COUNTS_PER_REV = 4096
BAR_TO_NM = 2.5e-7 * 1e5  # N m per bar for tau_load_nm_per_pa = 2.5e-7

CHANNELS = {
    "duty_a": {"name": "MotCtl_DutyA", "unit": "%"},
    "duty_b": {"name": "MotCtl_DutyB", "unit": "%"},
    "duty_c": {"name": "MotCtl_DutyC", "unit": "%"},
    "u_dc": {"name": "Sply_UDc", "unit": "V"},
    "pressure": {"name": "Hyd_Pressure", "unit": "bar"},
    "angle": {"name": "MotPos_Angle", "unit": "deg"},
    "speed": {"name": "MotPos_Speed", "unit": "rpm"},
    "i_a": {"name": "MotCur_IPhA", "unit": "A"},
    "i_b": {"name": "MotCur_IPhB", "unit": "A"},
    "i_c": {"name": "MotCur_IPhC", "unit": "A"},
}
INGEST = {"rate_hz": RATE_HZ, "max_gap_s": 0.01, "tau_load_nm_per_pa": 2.5e-7, "channels": CHANNELS}


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


def current_a(t, phase):
    return 30.0 * np.sin(2 * math.pi * 40.0 * t + phase)


def raw_signals(duration_s=DURATION_S):
    """{channel: (time_s, values in the ECU unit, unit)}, 10 kHz and 1 kHz time bases, offset starts."""
    fast = np.arange(0.0, duration_s, 1e-4) + 0.0002
    slow = np.arange(0.0, duration_s, 1e-3) + 0.0005
    counts = np.round(theta_rad(fast) / (2 * math.pi) * COUNTS_PER_REV)
    return {
        "MotCtl_DutyA": (fast, 100 * duty(fast, 0.0), "%"),
        "MotCtl_DutyB": (fast, 100 * duty(fast, -2.0944), "%"),
        "MotCtl_DutyC": (fast, 100 * duty(fast, 2.0944), "%"),
        "MotPos_Angle": (fast, counts * 360.0 / COUNTS_PER_REV, "deg"),
        "MotPos_Speed": (fast, omega_rad_s(fast) * 60 / (2 * math.pi), "rpm"),
        "MotCur_IPhA": (fast, current_a(fast, 0.0), "A"),
        "MotCur_IPhB": (fast, current_a(fast, -2.0944), "A"),
        "MotCur_IPhC": (fast, current_a(fast, 2.0944), "A"),
        "Hyd_Pressure": (slow, pressure_pa(slow) / 1e5, "bar"),
        "Sply_UDc": (slow, u_dc_v(slow), "V"),
        "Other_Channel": (slow, np.zeros_like(slow), "-"),
    }


def write_mdf(path, signals):
    """Write ``{name: (time_s, values, unit)}`` as MDF4, one group per time base (as a logger does)."""
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    groups: dict[tuple, list] = {}
    for name, (time_s, values, unit) in signals.items():
        key = np.asarray(time_s, dtype=np.float64).tobytes()  # channels with identical time stamps share a group
        groups.setdefault(key, []).append(Signal(np.asarray(values), np.asarray(time_s), name=name, unit=unit))
    for group in groups.values():
        mdf.append(group)
    mdf.save(path, overwrite=True)
    mdf.close()
    return path


def write_table(path, signals, units_row=True, time_factor=1.0, time_unit="s"):
    """CSV/Parquet of all channels on the 10 kHz time base (CSV: name row and unit row)."""
    fast = {name: sig for name, sig in signals.items() if len(sig[0]) == len(signals["MotCtl_DutyA"][0])}
    time_s = signals["MotCtl_DutyA"][0]
    frame = pd.DataFrame({"time": time_s * time_factor, **{name: sig[1] for name, sig in fast.items()}})
    slow_t = signals["Sply_UDc"][0]
    for name in ("Sply_UDc", "Hyd_Pressure"):
        frame[name] = np.interp(time_s, slow_t, signals[name][1])
    units = [time_unit] + [fast[name][2] for name in fast] + ["V", "bar"]
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


def test_mdf_round_trip_multi_rate(mdf_path, tmp_path):
    out = ingest_to_parquet(mdf_path, tmp_path / "data" / "maneuver.parquet", INGEST)
    frame = pd.read_parquet(out)
    assert list(frame.columns) == ["time_s", "duty_a", "duty_b", "duty_c", "u_dc_v", "tau_load_nm", "theta_rad",
                                   "omega_rad_s", "i_a_a", "i_b_a", "i_c_a", "pressure_pa"]
    assert all(frame[column].dtype == np.float64 for column in frame.columns)
    time_s = frame["time_s"].to_numpy()
    assert time_s[0] == 0.0
    np.testing.assert_allclose(np.diff(time_s), 1.0 / RATE_HZ, rtol=1e-9)
    # common start is the latest first sample (the 1 kHz channels start at 0.5 ms)
    t_abs = time_s + 0.0005
    assert t_abs[-1] <= 0.0005 + 0.499 + 1e-9 and len(frame) == 4991
    # duties are held (zero-order hold onto the same 10 kHz instants: exact up to float rounding)
    held = np.searchsorted(raw_signals()["MotCtl_DutyA"][0], t_abs + 1e-12, side="right") - 1
    np.testing.assert_allclose(frame["duty_a"], duty(raw_signals()["MotCtl_DutyA"][0][held], 0.0), atol=1e-9)
    # continuous signals: linear interpolation error and encoder quantisation only
    quantum_rad = 2 * math.pi / COUNTS_PER_REV
    np.testing.assert_allclose(frame["theta_rad"], theta_rad(t_abs), atol=quantum_rad)
    np.testing.assert_allclose(frame["omega_rad_s"], omega_rad_s(t_abs), atol=0.05)
    np.testing.assert_allclose(frame["pressure_pa"], pressure_pa(t_abs), atol=0.02e5)
    np.testing.assert_allclose(frame["tau_load_nm"], 2.5e-7 * pressure_pa(t_abs), atol=0.02 * BAR_TO_NM)
    np.testing.assert_allclose(frame["u_dc_v"], u_dc_v(t_abs), atol=0.01)
    np.testing.assert_allclose(frame["i_b_a"], current_a(t_abs, -2.0944), atol=0.2)


def test_speed_derived_from_angle_and_third_current(mdf_path):
    config = copy.deepcopy(INGEST)
    del config["channels"]["speed"], config["channels"]["i_c"]
    config["speed_from_angle"] = {"window_s": 0.004, "polyorder": 2}
    frame = ingest_log(mdf_path, config)
    t_abs = frame["time_s"].to_numpy() + 0.0005
    inner = slice(50, -50)  # the filter's edge windows
    np.testing.assert_allclose(frame["omega_rad_s"].to_numpy()[inner], omega_rad_s(t_abs)[inner], atol=1.5)
    np.testing.assert_allclose(frame["i_c_a"], current_a(t_abs, 2.0944), atol=0.5)


def test_tau_load_per_bar_and_load_channel(mdf_path):
    config = copy.deepcopy(INGEST)
    config["tau_load_nm_per_pa"] = None
    config["tau_load_nm_per_bar"] = 2.5e-2
    per_bar = ingest_log(mdf_path, config)
    per_pa = ingest_log(mdf_path, INGEST)
    np.testing.assert_allclose(per_bar["tau_load_nm"], per_pa["tau_load_nm"], rtol=1e-12)
    both = copy.deepcopy(INGEST)
    both["tau_load_nm_per_bar"] = 2.5e-2
    with pytest.raises(DataError, match="not both"):
        ingest_log(mdf_path, both)


def test_csv_with_unit_row(tmp_path):
    path = write_table(tmp_path / "log.csv", raw_signals())
    config = copy.deepcopy(INGEST)
    for spec in config["channels"].values():
        spec.pop("unit")  # units come from the file's unit row
    frame = ingest_log(path, config)
    t_abs = frame["time_s"].to_numpy() + 0.0002
    assert len(frame) == 5000
    np.testing.assert_allclose(frame["theta_rad"], theta_rad(t_abs), atol=2 * math.pi / COUNTS_PER_REV)
    np.testing.assert_allclose(frame["omega_rad_s"], omega_rad_s(t_abs), atol=0.05)


def test_csv_without_units_uses_channel_map_and_time_column(tmp_path):
    path = write_table(tmp_path / "log.csv", raw_signals(), units_row=False)
    frame = ingest_log(path, INGEST)
    assert frame["duty_a"].between(0.19, 0.81).all()
    in_ms = write_table(tmp_path / "log_ms.csv", raw_signals(), units_row=False, time_factor=1e3)
    config = copy.deepcopy(INGEST)
    config["channels"]["time"] = {"name": "time", "unit": "ms"}
    pd.testing.assert_frame_equal(ingest_log(in_ms, config), frame, rtol=1e-9, atol=1e-9)


def test_parquet_with_units_in_column_names(tmp_path):
    path = write_table(tmp_path / "log.parquet", raw_signals())
    config = copy.deepcopy(INGEST)
    config["channels"]["duty_a"].pop("unit")
    frame = ingest_log(path, config)
    t_abs = frame["time_s"].to_numpy() + 0.0002
    np.testing.assert_allclose(frame["duty_a"], duty(t_abs, 0.0), atol=1e-9)
    np.testing.assert_allclose(frame["pressure_pa"], pressure_pa(t_abs), atol=0.02e5)


# ---- bad inputs: a clear DataError naming file and channel, and no output file ----------------------------

def _bad(name, change):
    signals = raw_signals()
    change(signals)
    return name, signals


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


BAD_MDF = {
    "missing channel": (lambda s: s.pop("MotPos_Speed"), r"MotPos_Speed not found; the file has: .*MotPos_Angle"),
    "duplicated time": (_time("MotCtl_DutyB", _duplicate), r"MotCtl_DutyB \(duty_b\): time stamps not strictly "
                                                             r"increasing \(duplicated\)"),
    "decreasing time": (_time("Sply_UDc", _decrease), r"Sply_UDc \(u_dc\): time stamps not strictly increasing "
                                                      r"\(decreasing\)"),
    "nan run": (lambda s: s["MotCur_IPhA"][1].__setitem__(slice(300, 320), np.nan),
                r"MotCur_IPhA \(i_a\): 20 consecutive NaN/inf samples"),
    "inf sample": (_set("Hyd_Pressure", 10, np.inf), r"Hyd_Pressure \(pressure\): 1 consecutive NaN/inf"),
    "long gap": (_time("Hyd_Pressure", _gap), r"Hyd_Pressure \(pressure\): gap of 0.051 s after 0.1995 s exceeds .*max_gap_s = 0.01"),
    "unknown unit": (lambda s: s.__setitem__("MotPos_Speed", (*s["MotPos_Speed"][:2], "furlong/fortnight")),
                     r"MotPos_Speed \(speed\): cannot convert unit 'furlong/fortnight' to rad/s"),
    "unit disagrees with map": (lambda s: s.__setitem__("MotPos_Angle", (*s["MotPos_Angle"][:2], "rad")),
                                r"MotPos_Angle \(angle\): the file says unit 'rad' but .*channels.angle.unit "
                                r"says 'deg'"),
}


@pytest.mark.parametrize("case", sorted(BAD_MDF))
def test_bad_mdf_input_raises_and_writes_nothing(case, tmp_path):
    change, message = BAD_MDF[case]
    signals = raw_signals()
    change(signals)
    raw = write_mdf(tmp_path / "bad.mf4", signals)
    out = tmp_path / "data" / "bad.parquet"
    config = copy.deepcopy(INGEST)
    config["channels"]["speed"].pop("unit")  # the file's units decide where the map gives none
    with pytest.raises(DataError, match=message) as info:
        ingest_to_parquet(raw, out, config)
    assert str(raw) in str(info.value)
    assert not out.exists()
    assert not list((tmp_path / "data").glob("*")) if (tmp_path / "data").exists() else True


def test_channel_map_unit_stands_in_for_an_unknown_file_unit(tmp_path):
    signals = raw_signals()
    signals["MotPos_Speed"] = (*signals["MotPos_Speed"][:2], "UpM")
    raw = write_mdf(tmp_path / "odd_unit.mf4", signals)
    frame = ingest_log(raw, INGEST)  # the map says rpm
    t_abs = frame["time_s"].to_numpy() + 0.0005
    np.testing.assert_allclose(frame["omega_rad_s"], omega_rad_s(t_abs), atol=0.05)


def test_nan_runs_up_to_the_limit_are_dropped(tmp_path):
    signals = raw_signals()
    signals["MotCur_IPhA"][1][300:303] = np.nan
    raw = write_mdf(tmp_path / "nan.mf4", signals)
    config = dict(INGEST, max_nonfinite_samples=3)
    frame = ingest_log(raw, config)
    t_abs = frame["time_s"].to_numpy() + 0.0005
    np.testing.assert_allclose(frame["i_a_a"], current_a(t_abs, 0.0), atol=1.0)


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
        ingest_to_parquet(raw, out, INGEST)
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
        "notime.csv": (good.replace("time", "zeit", 1), "time column 'time' not found"),
    }
    for name, (text, message) in cases.items():
        raw = tmp_path / name
        raw.write_text(text)
        out = tmp_path / f"{name}.parquet"
        with pytest.raises(DataError, match=message) as info:
            ingest_to_parquet(raw, out, {**INGEST, "channels": {k: {"name": v["name"]} for k, v in CHANNELS.items()}})
        assert str(raw) in str(info.value), name
        assert not out.exists()


def test_corrupt_or_empty_parquet_and_unknown_format(tmp_path):
    good = write_table(tmp_path / "good.parquet", raw_signals())
    broken = tmp_path / "broken.parquet"
    broken.write_bytes(good.read_bytes()[:-200])
    with pytest.raises(DataError, match="broken.parquet: cannot read the Parquet file"):
        ingest_log(broken, INGEST)
    empty = tmp_path / "empty.parquet"
    pd.read_parquet(good).iloc[:0].to_parquet(empty, index=False)
    with pytest.raises(DataError, match="empty.parquet: the file is empty"):
        ingest_log(empty, INGEST)
    other = tmp_path / "log.xlsx"
    other.write_bytes(b"PK")
    with pytest.raises(DataError, match=r"unknown log format '.xlsx'"):
        ingest_log(other, INGEST)


def test_channel_map_errors(mdf_path):
    no_load = copy.deepcopy(INGEST)
    del no_load["channels"]["pressure"]
    with pytest.raises(DataError, match="needs `tau_load`"):
        ingest_log(mdf_path, no_load)
    no_factor = dict(INGEST, tau_load_nm_per_pa=None)
    with pytest.raises(DataError, match="tau_load_nm_per_pa .* is required"):
        ingest_log(mdf_path, no_factor)
    bad_unit = copy.deepcopy(INGEST)
    bad_unit["channels"]["duty_a"]["unit"] = "V"
    with pytest.raises(DataError, match=r"channels.duty_a.unit: cannot convert unit 'V' to 1 \(ratio\)"):
        ingest_log(mdf_path, bad_unit)
