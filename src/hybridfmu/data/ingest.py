"""Ingestion: a raw log -> the case's signals in their model units on the case's uniform grid -> Parquet.

The case config declares what is read (:func:`hybridfmu.data.roles.case_roles`): every logged signal of
``config.signals`` names a raw channel and its unit; ``config.maneuvers.<m>.channels`` may map a
signal to another channel for one maneuver. Steps:

1. read the channels (:mod:`hybridfmu.data.readers`), each with its own time base (table logs: the
   time column ``config.ingest.time`` or the one named as a time, or sample k at
   ``k * config.ingest.sample_period_s``);
2. check each channel: time stamps finite and strictly increasing, no run of more than
   ``max_nonfinite_samples`` NaN/inf samples (shorter runs are dropped), no gap longer than
   ``max_gap_s`` (default: 10 of the channel's own steps) between usable samples; a unit in the file must agree with the config's unit (an
   unknown file unit is warned about and the config's unit used); no isolated implausible sample
   (``config.ingest.outliers``, :mod:`hybridfmu.data.plausibility`);
3. in the raw unit: unwrap (``wrap_period``), ``gain * raw + offset``; every sample inside
   ``config.signals.<name>.range`` where one is given;
4. slice the maneuver (``t_start_s``/``t_end_s``, relative to the log's first sample) and resample
   onto ``rate_hz`` from the common start of all channels: zero-order hold or linear per signal (without
   ``config.ingest.rate_hz``: the rate :func:`choose_grid` chose from the train and validation logs);
5. apply the transforms (:mod:`hybridfmu.data.transforms`) in natural units (the raw unit of a
   logged signal, the unit a transform gives a derived one);
6. convert every column to its model unit (``Signal.unit``; affine conversions allowed);
7. where the FMU says one measured state is the time derivative of another (a kinematic pair), the
   logged position must move as the logged rate says (``config.ingest.kinematic``): a wrong declared
   unit of either stops the ingest.

Output: a DataFrame with ``time_s`` (from 0, step ``1 / rate_hz``) and one float64 column per signal
of ``case_roles(config).signals`` (logged signals, then derived ones), each in its model unit, and in its
``attrs`` how each FMU input passes between the samples in the simulations (:mod:`hybridfmu.data.between_samples`:
declared, else chosen by :func:`choose_grid` from the train and validation logs, else from this log).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.data.roles import CaseRoles, Signal, case_roles, maneuver_source
from hybridfmu.data.between_samples import (ATTRS_KEY, choose_conventions, declared_conventions,
                                             logged_sources)
from hybridfmu.data.errors import DataError
from hybridfmu.data.grid import choose_rate_hz, median_step_s
from hybridfmu.data.readers import MDF_SUFFIXES, RawChannel, read_channels
from hybridfmu.data.plausibility import check_kinematic_pairs, check_outliers, check_range, kinematic_pairs
from hybridfmu.data.resample import common_grid, linear, zero_order_hold
from hybridfmu.data.settings import section_settings
from hybridfmu.data.transforms import TransformError, apply_transforms
from hybridfmu.io import write_json_atomic, write_parquet_atomic
from hybridfmu.units import UnitError, converter, parse_unit

LOG = logging.getLogger(__name__)

#: Resampling functions by ``Signal.resample``: (time_s (n,), values (n,), grid_s (T,)) -> (T,).
RESAMPLERS = {"hold": zero_order_hold, "linear": linear}


def ingest_to_parquet(raw_path: str | Path, output_path: str | Path, config: dict[str, Any],
                      maneuver: str | None = None, rate_hz: float | None = None,
                      between_samples: dict[str, str] | None = None) -> Path:
    """Ingest ``raw_path`` (see :func:`ingest_log`) and write the frame atomically to ``output_path``.

    Nothing is written when any check fails.
    """
    frame = ingest_log(raw_path, config, maneuver, rate_hz, between_samples)
    write_parquet_atomic(output_path, frame)
    LOG.info("wrote %s: %d samples x %d columns (%.3f s)", output_path, len(frame), frame.shape[1],
             frame["time_s"].iloc[-1])
    return Path(output_path)


def read_logged_channels(raw_path: str | Path, config: dict[str, Any], maneuver: str | None = None
                         ) -> tuple[dict[str, RawChannel], dict[str, float]]:
    """The raw channels of the logged signals of ``raw_path`` and each channel's factor to seconds of its time
    stamps (channel -> factor).

    Raises:
        DataError: naming the file (and channel) for a file that cannot be read or a time column that does not
            fit the config.
    """
    raw_path = Path(raw_path)
    settings = section_settings(config.get("ingest"), "ingest")
    source = maneuver_source(config, case_roles(config), maneuver)
    raw = read_channels(raw_path, sorted(set(source.channels.values())), time_column=settings["time"]["channel"],
                        csv_delimiter=settings["csv"]["delimiter"], csv_decimal=settings["csv"]["decimal"],
                        sample_period_s=settings["sample_period_s"])
    return raw, {name: _time_factor(raw_path, settings, channel) for name, channel in raw.items()}


def logged_time_bases(raw_path: str | Path, config: dict[str, Any], maneuver: str | None = None
                      ) -> dict[str, np.ndarray]:
    """Time stamps (s) of each logged (not derived) signal's channel in ``raw_path``: signal -> (n,) array.

    Raises:
        DataError: as :func:`hybridfmu.data.ingest.ingest_log` for the file's reading and its time column.
    """
    raw, factors = read_logged_channels(raw_path, config, maneuver)
    return _time_bases(raw, factors, maneuver_source(config, case_roles(config), maneuver).channels)


def _time_bases(raw: dict[str, RawChannel], factors: dict[str, float], channels: dict[str, str]
                ) -> dict[str, np.ndarray]:
    """Signal -> time stamps (s) of its raw channel, for the signals whose channel was read."""
    return {name: np.asarray(raw[channel].time_s, dtype=float) * factors[channel]
            for name, channel in channels.items() if channel in raw}


def choose_grid(raw_paths: dict[str, str | Path], config: dict[str, Any], out_path: str | Path) -> dict[str, Any]:
    """Rule ``choose_grid``: what the case's grid takes from the given maneuvers' logs (maneuver -> raw path; the
    workflow gives the train and validation maneuvers, never a test maneuver), written atomically to ``out_path``.

    The record: ``rate_hz`` (chosen where ``config.ingest.rate_hz`` leaves it out: ``"chosen_from": "data"`` and a
    ``text``), ``maneuvers: {name: {"median_step_s"}}``, and ``between_samples``: the conventions of the FMU inputs
    the config leaves out (:func:`hybridfmu.data.between_samples.choose_conventions`)."""
    settings = section_settings(config.get("ingest"), "ingest")
    roles = case_roles(config)
    undeclared = [name for name, convention in declared_conventions(config, roles).items() if convention is None]
    wanted = {source for name in undeclared for source in logged_sources(roles.inputs[name], roles)}
    steps, samples = {}, {source: [] for source in wanted}
    for name, path in raw_paths.items():
        raw, factors = read_logged_channels(path, config, name)
        source = maneuver_source(config, roles, name)
        steps[name] = median_step_s(path, _time_bases(raw, factors, source.channels))
        for signal in wanted:
            samples[signal].append(_sliced_values(raw, factors, source, signal))
    record: dict[str, Any] = {"maneuvers": {name: {"median_step_s": step} for name, step in steps.items()}}
    if settings["rate_hz"] is None:
        rate_hz, text = choose_rate_hz(steps)
        record.update({"rate_hz": rate_hz, "chosen_from": "data", "text": text})
        LOG.info("grid rate chosen from the data: %s", text)
    else:
        record.update({"rate_hz": float(settings["rate_hz"]), "chosen_from": "config"})
    record["between_samples"] = choose_conventions(undeclared, samples, roles)
    for name, entry in record["between_samples"].items():
        LOG.info("FMU input %s between samples chosen from the data: %s", name, entry["text"])
    write_json_atomic(out_path, record)
    return record


def _sliced_values(raw: dict[str, RawChannel], factors: dict[str, float], source: Any, signal: str) -> np.ndarray:
    """The raw samples of a logged signal's channel within the maneuver's slice (relative to the log's first
    sample, as :func:`ingest_log` slices), (n,)."""
    channel = raw[source.channels[signal]]
    time_s = np.asarray(channel.time_s, dtype=float) * factors[channel.name]
    log_start_s = _log_start_s(raw, factors)
    keep = np.ones(time_s.size, dtype=bool)
    if source.t_start_s is not None:
        keep &= time_s >= log_start_s + source.t_start_s
    if source.t_end_s is not None:
        keep &= time_s <= log_start_s + source.t_end_s
    return np.asarray(channel.values, dtype=float)[keep]


def _log_start_s(raw: dict[str, RawChannel], factors: dict[str, float]) -> float:
    """The log's first time stamp (s): the earliest first stamp of its channels."""
    return min(float(channel.time_s[0]) * factors[name] for name, channel in raw.items() if len(channel.time_s))


def ingest_log(raw_path: str | Path, config: dict[str, Any], maneuver: str | None = None,
               rate_hz: float | None = None, between_samples: dict[str, str] | None = None) -> pd.DataFrame:
    """Read, check, resample, transform and convert a raw log (steps in the module docstring).

    Args:
        raw_path: MDF4 (``.mf4``/``.mdf``), CSV (``.csv``/``.txt``) or Parquet log.
        config: the case config (sections ``fmu``, ``signals``, ``transforms``, ``roles``, ``ingest``
            and, for ``maneuver``, ``maneuvers``); schema defaults of ``ingest`` are filled in here.
        maneuver: name of the maneuver in ``config.maneuvers`` (its channel overrides and slice), or
            None for the log as a whole.
        rate_hz: the grid's rate (Hz) where ``config.ingest.rate_hz`` leaves it out (chosen from the case's logs,
            :func:`choose_grid`); the config's rate wins; without either, the rate of this log's fastest channel.
        between_samples: FMU input -> convention chosen from the case's logs (:func:`choose_grid`) for the inputs
            the config leaves out; a declared convention wins; without either, chosen from this log alone.

    Returns:
        DataFrame of T rows: ``time_s`` (s, from 0, step ``1 / rate_hz``), then one float64 column per
        signal of ``case_roles(config).signals``, each in its model unit ``Signal.unit``. Its
        ``attrs["between_samples"]`` holds every FMU input's convention (:mod:`hybridfmu.data.between_samples`),
        kept in the Parquet file.

    Raises:
        DataError: naming the file, the channel (and signal) and what was expected.
        ConfigError: the config's roles or units are inconsistent (naming the field).
    """
    raw_path = Path(raw_path)
    settings = section_settings(config.get("ingest"), "ingest")
    roles = case_roles(config)
    source = maneuver_source(config, roles, maneuver)
    if settings["rate_hz"] is not None:
        rate_hz = float(settings["rate_hz"])
    logged = {name: signal for name, signal in roles.signals.items() if not signal.derived}

    raw, time_factor = read_logged_channels(raw_path, config, maneuver)
    if rate_hz is None:  # neither configured nor chosen from the case's logs: this log's own
        rate_hz, text = choose_rate_hz({raw_path.name: median_step_s(
            raw_path, _time_bases(raw, time_factor, source.channels))})
        LOG.info("%s: grid rate chosen from this log: %s", raw_path.name, text)
    log_start_s = _log_start_s(raw, time_factor)
    start_s = None if source.t_start_s is None else log_start_s + source.t_start_s
    end_s = None if source.t_end_s is None else log_start_s + source.t_end_s

    clean: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, signal in logged.items():
        channel = raw[source.channels[name]]
        time_s, values = checked_samples(raw_path, channel, name, time_factor[channel.name],
                                         settings["max_gap_s"], int(settings["max_nonfinite_samples"]),
                                         start_s, end_s)
        check_file_unit(raw_path, channel, signal)
        check_outliers(raw_path, channel.name, name, signal.natural_unit, time_s, values,
                       settings["outliers"]["factor"], float(settings["outliers"]["quantile"]))
        natural = raw_to_natural(signal, values)
        check_range(raw_path, channel.name, name, signal.natural_unit, time_s, natural,
                    (config["signals"].get(name) or {}).get("range"))
        clean[name] = (time_s, natural)
        LOG.info("%s: %s -> %s: %d samples, %.4g Hz mean rate, unit %s", raw_path.name, channel.name, name,
                 len(time_s), (len(time_s) - 1) / max(time_s[-1] - time_s[0], 1e-12), signal.natural_unit)

    try:
        grid_s = common_grid({source.channels[name]: time for name, (time, _) in clean.items()}, rate_hz,
                             start_s, end_s)
    except ValueError as err:
        raise DataError(f"{raw_path}: {err}") from None
    _log_trimmed(raw_path, clean, grid_s)
    columns = {name: RESAMPLERS[logged[name].resample](time_s, values, grid_s)
               for name, (time_s, values) in clean.items()}
    columns = derive_signals(raw_path, roles, columns, rate_hz)
    frame = model_frame(raw_path, roles, grid_s - grid_s[0], columns)
    if settings["kinematic"]["enabled"]:
        pairs = kinematic_pairs(config, roles.measured_states)
        check_kinematic_pairs(raw_path, pairs, roles, source.channels,
                              {name: frame[name].to_numpy() for name in roles.signals}, rate_hz,
                              settings["kinematic"])
    frame.attrs[ATTRS_KEY] = _input_conventions(raw_path, config, roles, raw, time_factor, source, between_samples)
    LOG.info("%s: %d samples at %.6g Hz over %.4g s, columns %s; FMU inputs between samples: %s", raw_path.name,
             len(frame), rate_hz, frame["time_s"].iloc[-1], list(frame.columns), frame.attrs[ATTRS_KEY])
    return frame


def _input_conventions(raw_path: Path, config: dict[str, Any], roles: CaseRoles, raw: dict[str, RawChannel],
                       factors: dict[str, float], source: Any, chosen: dict[str, str] | None) -> dict[str, str]:
    """Every FMU input's convention: declared, else ``chosen`` from the case's logs, else from this log."""
    conventions = declared_conventions(config, roles)
    chosen = dict(chosen or {})
    left = [name for name, convention in conventions.items() if convention is None and name not in chosen]
    if left:
        samples = {signal: [_sliced_values(raw, factors, source, signal)]
                   for name in left for signal in logged_sources(roles.inputs[name], roles)}
        for name, entry in choose_conventions(left, samples, roles).items():
            chosen[name] = entry["convention"]
            LOG.info("%s: FMU input %s between samples chosen from this log: %s", raw_path.name, name, entry["text"])
    return {name: convention or chosen[name] for name, convention in conventions.items()}


#: Without config.ingest.max_gap_s, a channel may pause this many of its own median steps between two samples.
GAP_STEPS = 10


def checked_samples(path: Path, channel: RawChannel, signal: str, time_factor: float, max_gap_s: float | None,
                    max_nonfinite_samples: int, start_s: float | None = None,
                    end_s: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Check one channel's time base and samples; return (time_s (n,), values (n,)) without NaN/inf.

    The time stamps are checked over the whole channel; the samples (NaN runs, gaps) only inside
    ``start_s..end_s`` (absolute s, plus the sample just outside either bound, which interpolation needs).

    Raises:
        DataError: naming file and channel for too few samples, non-finite / duplicated / decreasing
            time stamps, a NaN/inf run longer than ``max_nonfinite_samples``, a gap over ``max_gap_s`` (None:
            over :data:`GAP_STEPS` of the channel's own median steps).
    """
    where = f"{path}: channel {channel.name} ({signal})"
    time_s = np.asarray(channel.time_s, dtype=np.float64) * time_factor
    values = np.asarray(channel.values, dtype=np.float64)
    _check_time_stamps(where, time_s)
    time_s, values = _slice(time_s, values, start_s, end_s)
    if len(time_s) < 2:
        raise DataError(f"{where}: {len(time_s)} sample(s) in the slice {start_s}..{end_s} s; expected a time "
                        "series (check config.maneuvers.<maneuver>.t_start_s/t_end_s)")
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
    typical_s = float(np.median(steps))
    if max_gap_s is None:
        limit_s = GAP_STEPS * typical_s
        if steps.max() > limit_s:
            index = int(np.argmax(steps))
            raise DataError(f"{where}: gap of {steps[index]:.6g} s after {time_s[index]:.6g} s, more than "
                            f"{GAP_STEPS} of the channel's median step {typical_s:.6g} s; expected continuous "
                            "samples (config.ingest.max_gap_s sets the longest gap allowed)")
        return time_s, values
    if typical_s > max_gap_s:  # not a gap: the whole log is sampled slower than the limit
        raise DataError(f"{where}: sampled every {typical_s:.6g} s (median step), slower than "
                        f"config.ingest.max_gap_s = {max_gap_s:g} s allows between two samples; expected "
                        f"config.ingest.max_gap_s above the log's own sample step (or a time column in s: "
                        "check config.ingest.time)")
    if steps.max() > max_gap_s:
        index = int(np.argmax(steps))
        raise DataError(f"{where}: gap of {steps[index]:.6g} s after {time_s[index]:.6g} s exceeds "
                        f"config.ingest.max_gap_s = {max_gap_s:g} s; expected continuous samples")
    return time_s, values


def check_file_unit(path: Path, channel: RawChannel, signal: Signal) -> None:
    """Check that the unit the file gives a channel (if any) is the config's unit of the signal.

    Units agree when they convert with factor 1 and offset 0 (``N.m`` = ``N*m``, ``1/min`` = ``rpm``).
    A file unit pint does not know is warned about; the config's unit is used.

    Raises:
        DataError: naming file, channel and ``config.signals.<signal>.unit`` when the units differ.
    """
    file_unit = (channel.unit or "").strip()
    if not file_unit:
        return
    where = f"{path}: channel {channel.name} ({signal.name})"
    if not _known_unit(file_unit):
        LOG.warning("%s: unit %r from the file is unknown; using %r from config.signals.%s.unit", where,
                    file_unit, signal.natural_unit, signal.name)
        return
    try:
        factor, offset = converter(file_unit, signal.natural_unit)
    except UnitError as err:
        raise DataError(f"{where}: the file says unit {file_unit!r} but config.signals.{signal.name}.unit says "
                        f"{signal.natural_unit!r} ({err}); expected the same unit") from None
    if not (np.isclose(factor, 1.0, rtol=1e-9, atol=0.0) and abs(offset) <= 1e-9):
        raise DataError(f"{where}: the file says unit {file_unit!r} but config.signals.{signal.name}.unit says "
                        f"{signal.natural_unit!r} (1 {file_unit} = {factor:.6g} {signal.natural_unit}"
                        f"{f' + {offset:.6g}' if offset else ''}); expected the same unit (fix the config's unit)")


def raw_to_natural(signal: Signal, values: np.ndarray) -> np.ndarray:
    """Unwrap (``wrap_period``) and apply ``gain * raw + offset``, all in the raw unit; (n,) -> (n,)."""
    if signal.wrap_period is not None:
        values = np.unwrap(values, period=float(signal.wrap_period))
    return signal.gain * values + signal.offset


def derive_signals(path: Path, roles: CaseRoles, columns: dict[str, np.ndarray],
                   rate_hz: float) -> dict[str, np.ndarray]:
    """Add the transforms' outputs to ``columns`` (each (T,), natural units) and return it.

    Raises:
        DataError: a transform fails on the data (naming the file and the transform).
    """
    natural = {name: signal.natural_unit for name, signal in roles.signals.items()}
    try:
        return apply_transforms(roles.transforms, columns, natural, rate_hz)
    except (TransformError, UnitError, ValueError) as err:
        raise DataError(f"{path}: config.transforms: {err}") from None


def model_frame(path: Path, roles: CaseRoles, time_s: np.ndarray, columns: dict[str, np.ndarray]) -> pd.DataFrame:
    """The output frame: ``time_s`` (T,) then every signal converted from its natural to its model unit.

    Raises:
        DataError: a column holds NaN/inf after resampling and transforms (naming file and columns).
    """
    frame = {"time_s": np.asarray(time_s, dtype=np.float64)}
    for name, signal in roles.signals.items():
        factor, offset = converter(signal.natural_unit, signal.unit)
        frame[name] = factor * np.asarray(columns[name], dtype=np.float64) + offset
    bad = [name for name, values in frame.items() if not np.isfinite(values).all()]
    if bad:
        raise DataError(f"{path}: columns {bad} hold NaN/inf after resampling and transforms; expected finite "
                        "values")
    return pd.DataFrame(frame)


def _time_factor(path: Path, settings: dict[str, Any], channel: RawChannel) -> float:
    """Factor to seconds of a channel's time stamps: 1 for MDF4 and ``sample_period_s``; else the time unit.

    The time column's unit comes from the file where it has one (its units row, a ``name [unit]`` header, or
    a name such as ``time_ms``; checked against ``config.ingest.time.unit`` where that is set), else from the
    config, else seconds.
    """
    if path.suffix.lower() in MDF_SUFFIXES or settings["sample_period_s"] is not None:
        return 1.0
    time_cfg = settings["time"]
    file_unit = (channel.time_unit or "").strip()
    config_unit = time_cfg["unit"] or (file_unit if file_unit and _known_unit(file_unit) else "s")
    where = f"{path}: time column {time_cfg['channel'] or '(found by its name)'}"
    try:
        factor, offset = converter(config_unit, "s")
    except UnitError as err:
        raise DataError(f"config.ingest.time.unit: {err}; expected a unit of time") from None
    if file_unit and not _known_unit(file_unit):
        LOG.warning("%s: unit %r from the file is unknown; using %r from config.ingest.time.unit", where,
                    file_unit, config_unit)
    elif file_unit:
        try:
            file_factor, _ = converter(file_unit, "s")
        except UnitError as err:
            raise DataError(f"{where}: unit {file_unit!r} from the file: {err}; expected a unit of time") from None
        if not np.isclose(file_factor, factor, rtol=1e-9):
            raise DataError(f"{where}: the file says unit {file_unit!r} but config.ingest.time.unit says "
                            f"{config_unit!r}; expected the same unit")
    return factor


def _known_unit(text: str) -> bool:
    try:
        parse_unit(text)
    except UnitError:
        return False
    return True


def _check_time_stamps(where: str, time_s: np.ndarray) -> None:
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


def _slice(time_s: np.ndarray, values: np.ndarray, start_s: float | None,
           end_s: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Samples inside ``start_s..end_s`` plus the one just outside each bound; (n,), (n,) -> (m,), (m,)."""
    first = 0 if start_s is None else max(int(np.searchsorted(time_s, start_s, side="right")) - 1, 0)
    last = len(time_s) if end_s is None else int(np.searchsorted(time_s, end_s, side="left")) + 1
    return time_s[first:last], values[first:last]


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
        LOG.info("%s: span %.6g..%.6g s of the channels' %.6g..%.6g s is used", path.name, grid_s[0],
                 grid_s[-1], first, last)
