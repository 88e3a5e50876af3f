"""Ingestion: a raw log -> canonical signals in SI units on the case's uniform grid -> Parquet.

Steps (config section ``ingest``):
1. read the mapped channels (:mod:`hybridfmu.data.readers`), each with its own time base;
2. check each channel: time stamps finite and strictly increasing, no run of more than
   ``max_nonfinite_samples`` NaN/inf samples (shorter runs are dropped), no gap longer than
   ``max_gap_s`` between usable samples;
3. convert to SI: unwrap (``wrap_period``), ``gain * raw + offset``, unit factor; the unit comes from
   the file or, where the file has none, from the channel map; both must agree where both exist;
4. resample onto ``rate_hz`` from the common start of all channels (``time_s`` starts at 0): held
   (zero-order hold) for the signals listed in ``discrete``, linear for the others;
5. derive what is not logged: ``tau_load_nm`` from ``pressure_pa`` with the static factor
   ``tau_load_nm_per_pa`` (or ``tau_load_nm_per_bar``), ``omega_rad_s`` from ``theta_rad`` by a
   Savitzky-Golay differentiator (``speed_from_angle``), a missing third phase current from
   ``i_a + i_b + i_c = 0``.

Output columns (float64): ``time_s``, ``duty_a``, ``duty_b``, ``duty_c``, ``u_dc_v``, ``tau_load_nm``,
``theta_rad``, ``omega_rad_s``, then ``i_a_a``, ``i_b_a``, ``i_c_a`` (if currents are mapped) and
``pressure_pa`` (if pressure is mapped).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.data.channels import (
    CANONICAL_SIGNALS, PHASE_CURRENTS, SIGNALS_BY_NAME, ChannelSpec, channel_specs, pressure_to_torque_nm_per_pa,
    time_spec,
)
from hybridfmu.data.errors import DataError
from hybridfmu.data.readers import MDF_SUFFIXES, RawChannel, read_channels
from hybridfmu.data.resample import common_grid, linear, smoothing_derivative, zero_order_hold
from hybridfmu.data.settings import section_settings
from hybridfmu.data.units import UnitError, si_factor
from hybridfmu.io import write_parquet_atomic

LOG = logging.getLogger(__name__)


def ingest_to_parquet(raw_path: str | Path, output_path: str | Path, ingest_config: dict[str, Any] | None) -> Path:
    """Ingest ``raw_path`` (see :func:`ingest_log`) and write the frame atomically to ``output_path``.

    Nothing is written when any check fails.
    """
    frame = ingest_log(raw_path, ingest_config)
    write_parquet_atomic(output_path, frame)
    LOG.info("wrote %s: %d samples x %d columns (%.3f s)", output_path, len(frame), frame.shape[1],
             frame["time_s"].iloc[-1])
    return Path(output_path)


def ingest_log(raw_path: str | Path, ingest_config: dict[str, Any] | None) -> pd.DataFrame:
    """Read, check, convert and resample a raw log (steps in the module docstring).

    Args:
        raw_path: MDF4, CSV or Parquet log.
        ingest_config: the case's ``ingest`` section (schema defaults are filled in here).

    Returns:
        DataFrame (T rows) of the canonical float64 columns, ``time_s`` from 0 with step 1/rate_hz.

    Raises:
        DataError: naming the file, the channel and what was expected.
    """
    raw_path = Path(raw_path)
    settings = section_settings(ingest_config, "ingest")
    specs = channel_specs(settings)
    rate_hz = float(settings["rate_hz"])
    tspec = time_spec(settings)
    raw = read_channels(raw_path, [spec.name for spec in specs.values()], time_column=tspec.name,
                        csv_delimiter=settings["csv"]["delimiter"], csv_decimal=settings["csv"]["decimal"])

    clean: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for signal, spec in specs.items():
        channel = raw[spec.name]
        time_s, values = checked_samples(raw_path, channel, signal, _time_factor(raw_path, tspec, channel),
                                         float(settings["max_gap_s"]), int(settings["max_nonfinite_samples"]))
        clean[signal] = (time_s, to_si(raw_path, spec, channel.unit, values))
        LOG.info("%s: %s -> %s: %d samples, %.4g Hz mean rate, unit %s", raw_path.name, spec.name, signal,
                 len(time_s), (len(time_s) - 1) / max(time_s[-1] - time_s[0], 1e-12),
                 channel.unit or spec.unit)

    try:
        grid_s = common_grid({specs[signal].name: time for signal, (time, _) in clean.items()}, rate_hz)
    except ValueError as err:
        raise DataError(f"{raw_path}: {err}") from None
    _log_trimmed(raw_path, clean, grid_s)
    discrete = set(settings["discrete"])
    columns: dict[str, np.ndarray] = {}
    for signal, (time_s, values) in clean.items():
        resample = zero_order_hold if signal in discrete else linear
        columns[SIGNALS_BY_NAME[signal].column] = resample(time_s, values, grid_s)
    _derive_missing(columns, specs, settings, rate_hz)

    frame = pd.DataFrame({"time_s": grid_s - grid_s[0]})
    for signal in CANONICAL_SIGNALS:
        if signal.column in columns:
            frame[signal.column] = np.asarray(columns[signal.column], dtype=np.float64)
    bad = [column for column in frame.columns if not np.isfinite(frame[column].to_numpy()).all()]
    if bad:
        raise DataError(f"{raw_path}: columns {bad} hold NaN/inf after resampling; expected finite values")
    LOG.info("%s: %d samples at %.6g Hz over %.4g s, columns %s", raw_path.name, len(frame), rate_hz,
             frame["time_s"].iloc[-1], list(frame.columns))
    return frame


def checked_samples(path: Path, channel: RawChannel, signal: str, time_factor: float, max_gap_s: float,
                    max_nonfinite_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Check one channel's time base and samples; return (time_s (n,), values (n,)) without NaN/inf.

    Raises:
        DataError: naming file and channel for too few samples, non-finite / duplicated / decreasing
            time stamps, a NaN/inf run longer than ``max_nonfinite_samples``, a gap over ``max_gap_s``.
    """
    where = f"{path}: channel {channel.name} ({signal})"
    time_s = np.asarray(channel.time_s, dtype=np.float64) * time_factor
    values = np.asarray(channel.values, dtype=np.float64)
    if len(time_s) < 2:
        raise DataError(f"{where}: {len(time_s)} sample(s); expected a time series (at least 2 samples)")
    if not np.isfinite(time_s).all():
        index = int(np.flatnonzero(~np.isfinite(time_s))[0])
        raise DataError(f"{where}: time stamp {index} is {time_s[index]}; expected finite time stamps")
    steps = np.diff(time_s)
    if (steps <= 0).any():
        index = int(np.flatnonzero(steps <= 0)[0])
        kind = "duplicated" if steps[index] == 0 else "decreasing"
        raise DataError(f"{where}: time stamps not strictly increasing ({kind}) at sample {index + 1}: "
                        f"{time_s[index]:.9g} s -> {time_s[index + 1]:.9g} s; expected increasing time stamps")
    finite = np.isfinite(values)
    if not finite.all():
        start, length = _longest_run(~finite)
        if length > max_nonfinite_samples:
            raise DataError(f"{where}: {length} consecutive NaN/inf samples from {time_s[start]:.6g} s "
                            f"(limit config.ingest.max_nonfinite_samples = {max_nonfinite_samples}); "
                            "expected finite samples")
        time_s, values = time_s[finite], values[finite]
        if len(time_s) < 2:
            raise DataError(f"{where}: fewer than 2 finite samples; expected a time series")
    steps = np.diff(time_s)
    if steps.max() > max_gap_s:
        index = int(np.argmax(steps))
        raise DataError(f"{where}: gap of {steps[index]:.6g} s after {time_s[index]:.6g} s exceeds "
                        f"config.ingest.max_gap_s = {max_gap_s:g} s; expected continuous samples")
    return time_s, values


def to_si(path: Path, spec: ChannelSpec, file_unit: str | None, values: np.ndarray) -> np.ndarray:
    """Unwrap, apply gain/offset and convert ``values`` (raw unit) to SI; (n,) -> (n,).

    Raises:
        DataError: no unit known, a unit that cannot be converted to the signal's dimension, or a file
            unit that disagrees with the channel map's unit.
    """
    factor = unit_factor(path, spec, file_unit)
    if spec.wrap_period is not None:
        values = np.unwrap(values, period=float(spec.wrap_period))
    return (spec.gain * values + spec.offset) * factor


def unit_factor(path: Path, spec: ChannelSpec, file_unit: str | None) -> float:
    """SI factor of a channel's unit: the file's, or the channel map's where the file has none."""
    where = f"{path}: channel {spec.name} ({spec.signal})"
    file_unit = file_unit.strip() if file_unit and file_unit.strip() else None
    if file_unit is None and spec.unit is None:
        raise DataError(f"{where}: no unit in the file and none in config.ingest.channels.{spec.signal}.unit; "
                        f"expected a unit of {spec.dimension}")
    file_factor = map_factor = None
    if file_unit is not None:
        try:
            file_factor = si_factor(file_unit, spec.dimension)
        except UnitError as err:
            if spec.unit is None:
                raise DataError(f"{where}: {err}") from None
            LOG.warning("%s: unit %r from the file is unknown; using %r from the channel map", where, file_unit,
                        spec.unit)
    if spec.unit is not None:
        try:
            map_factor = si_factor(spec.unit, spec.dimension)
        except UnitError as err:
            raise DataError(f"{where}: config.ingest.channels.{spec.signal}.unit: {err}") from None
    if file_factor is not None and map_factor is not None and not np.isclose(file_factor, map_factor, rtol=1e-12):
        raise DataError(f"{where}: the file says unit {file_unit!r} but config.ingest.channels.{spec.signal}.unit "
                        f"says {spec.unit!r}; expected the same unit (fix or remove the unit in the channel map)")
    return file_factor if file_factor is not None else map_factor


def _time_factor(path: Path, tspec: ChannelSpec, channel: RawChannel) -> float:
    """SI factor of a channel's time stamps: seconds in MDF4; the time column's unit in tables."""
    if path.suffix.lower() in MDF_SUFFIXES:
        return 1.0
    return unit_factor(path, tspec, channel.time_unit)


def _derive_missing(columns: dict[str, np.ndarray], specs: dict[str, ChannelSpec], settings: dict[str, Any],
                    rate_hz: float) -> None:
    if "tau_load" not in specs:
        columns["tau_load_nm"] = pressure_to_torque_nm_per_pa(settings) * columns["pressure_pa"]
    if "speed" not in specs:
        options = settings["speed_from_angle"]
        columns["omega_rad_s"] = smoothing_derivative(columns["theta_rad"], rate_hz, float(options["window_s"]),
                                                      int(options["polyorder"]))
    present = [signal for signal in PHASE_CURRENTS if signal in specs]
    if len(present) == 2:
        missing = next(signal for signal in PHASE_CURRENTS if signal not in specs)
        columns[SIGNALS_BY_NAME[missing].column] = -sum(columns[SIGNALS_BY_NAME[s].column] for s in present)


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start index, length) of the longest run of True in a boolean array (with at least one True)."""
    padded = np.concatenate(([0], mask.astype(np.int8), [0]))
    edges = np.diff(padded)
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    longest = int(np.argmax(ends - starts))
    return int(starts[longest]), int(ends[longest] - starts[longest])


def _log_trimmed(path: Path, clean: dict[str, tuple[np.ndarray, np.ndarray]], grid_s: np.ndarray) -> None:
    first = min(time[0] for time, _ in clean.values())
    last = max(time[-1] for time, _ in clean.values())
    if grid_s[0] - first > 0 or last - grid_s[-1] > 0:
        LOG.info("%s: common span %.6g..%.6g s of the channels' %.6g..%.6g s is used", path.name, grid_s[0],
                 grid_s[-1], first, last)
