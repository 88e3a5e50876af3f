"""Readers for raw measurement logs: MDF4 (asammdf), CSV and Parquet.

Each reader returns the requested channels as :class:`RawChannel` (own time base, values, unit string
from the file if it has one). Nothing is resampled or converted here. Format by file suffix:
``.mf4``/``.mdf`` (MDF4; every channel has its own time base and rate), ``.csv``/``.txt`` (a time
column and channel columns; units from a second header row or ``name [unit]`` headers), ``.parquet``/
``.pq`` (same layout as CSV; units from ``name [unit]`` column names, else the config's). Table logs
without a time column give ``sample_period_s``: sample k is then at ``k * sample_period_s``. Without a
configured time column, the table's one column named as a time (``time``, ``t``, ``timestamp``, optionally
with a unit: ``time_ms``, ``Time [s]``) is used, its unit from the file or the name.

Every failure raises :class:`~hybridfmu.data.errors.DataError` naming the file, and the channel where
one is concerned: an empty file, a truncated or corrupt file, a missing channel (with the list of
channels the file has), a channel that is not numeric or has no samples.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybridfmu.data.errors import DataError

LOG = logging.getLogger(__name__)

MDF_SUFFIXES = (".mf4", ".mdf")
CSV_SUFFIXES = (".csv", ".txt")
PARQUET_SUFFIXES = (".parquet", ".pq")
_HEADER_UNIT = re.compile(r"^\s*(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")
#: A column named as a time, with an optional unit suffix (``time``, ``t``, ``timestamp``, ``time_s``, ``time_ms``).
TIME_NAME = re.compile(r"^(?:time|t|timestamps?|zeit)(?:[ _.-]?(?:in[ _])?(?P<unit>s|sec|ms|us|µs|ns|min|h))?$",
                       re.IGNORECASE)


@dataclass
class RawChannel:
    """One channel of a raw log.

    Attributes:
        name: channel name in the file.
        time_s: (n,) float64 time stamps in ``time_unit``.
        values: (n,) float64 samples in ``unit``.
        unit: unit string from the file, or None when the file has none.
        time_unit: unit of ``time_s`` from the file ("s" for MDF4), or None when the file has none.
    """

    name: str
    time_s: np.ndarray
    values: np.ndarray
    unit: str | None
    time_unit: str | None = "s"


def time_column_of(path: Path, time_column: str | None, names_in_file: list[str]) -> tuple[str, str | None]:
    """The time column of a table and the unit its name gives (``time_ms`` -> ms; None without one).

    Args:
        time_column: the configured column, or None to find the one column named as a time (:data:`TIME_NAME`).

    Raises:
        DataError: the configured column is missing, or none or several columns are named as a time; names the
            file and its columns.
    """
    if time_column is not None:
        if time_column not in names_in_file:
            raise DataError(f"{path}: time column {time_column!r} (config.ingest.time.channel) not found; the file "
                            f"has columns {names_in_file} (set config.ingest.sample_period_s for logs without a "
                            "time column)")
        return time_column, None
    found = [(name, TIME_NAME.match(name.strip())) for name in names_in_file]
    found = [(name, match) for name, match in found if match]
    if len(found) != 1:
        what = "no column is" if not found else f"{len(found)} columns ({', '.join(n for n, _ in found)}) are"
        raise DataError(f"{path}: {what} named as a time (time, t, timestamp, optionally with a unit such as "
                        f"time_ms); the file has columns {names_in_file}; set config.ingest.time.channel to the "
                        "time column, or config.ingest.sample_period_s for logs without one")
    name, match = found[0]
    unit = match.group("unit")
    unit = {"sec": "s", "us": "µs"}.get(unit.lower(), unit) if unit else None
    LOG.info("%s: time column %r found by its name%s", path, name, f" (unit {unit})" if unit else "")
    return name, unit


def read_channels(path: str | Path, names: list[str], time_column: str | None = None,
                  csv_delimiter: str = ",", csv_decimal: str = ".",
                  sample_period_s: float | None = None) -> dict[str, RawChannel]:
    """Read channels ``names`` from a raw log; return ``{name: RawChannel}``.

    Args:
        path: the log (``.mf4``/``.mdf``, ``.csv``/``.txt``, ``.parquet``/``.pq``).
        names: raw channel names to read.
        time_column: time column of CSV/Parquet logs (ignored for MDF4); None: the one column named as a time
            (:func:`time_column_of`).
        csv_delimiter, csv_decimal: CSV field separator and decimal mark.
        sample_period_s: table logs without a time column: sample k is at ``k * sample_period_s`` (s);
            ``time_column`` is then ignored. MDF4 channels always keep their own time bases.

    Raises:
        DataError: naming the file (and channel) for a missing, empty, truncated or corrupt file,
            missing channels (listing the file's channels) and non-numeric channels.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: raw log does not exist")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: the file is empty (0 bytes); expected a measurement log")
    suffix = path.suffix.lower()
    if suffix in MDF_SUFFIXES:
        return read_mdf(path, names)
    if suffix in CSV_SUFFIXES:
        return read_csv(path, names, time_column, csv_delimiter, csv_decimal, sample_period_s)
    if suffix in PARQUET_SUFFIXES:
        return read_parquet(path, names, time_column, sample_period_s)
    raise DataError(f"{path}: unknown log format {path.suffix!r}; expected one of "
                    f"{list(MDF_SUFFIXES + CSV_SUFFIXES + PARQUET_SUFFIXES)}")


def read_mdf(path: Path, names: list[str]) -> dict[str, RawChannel]:
    """Read channels from an MDF4 file, each with its own time base (see :func:`read_channels`)."""
    from asammdf import MDF

    try:
        with _quiet_unraisable():
            mdf = MDF(path)
    except Exception as err:  # asammdf raises many types for bad files
        raise DataError(f"{path}: cannot read the MDF4 file (corrupt or truncated?): {err}") from None
    try:
        available = [name for name in mdf.channels_db if not _is_master(mdf, name)]
        if not available:
            raise DataError(f"{path}: the file is empty (no measurement channels); expected channels {names}")
        _require(path, names, available)
        result = {}
        for name in names:
            occurrences = mdf.whereis(name)
            if len(occurrences) > 1:
                LOG.warning("%s: channel %s occurs %d times; using group %d", path, name, len(occurrences),
                            occurrences[0][0])
            group, index = occurrences[0]
            try:
                signal = mdf.get(name, group=group, index=index)
            except Exception as err:
                raise DataError(f"{path}: channel {name}: cannot read its samples (corrupt or truncated "
                                f"file?): {err}") from None
            values = _numeric(path, name, signal.samples)
            time_s = np.asarray(signal.timestamps, dtype=np.float64)
            if len(time_s) != len(values):
                raise DataError(f"{path}: channel {name}: {len(values)} samples but {len(time_s)} time stamps "
                                "(corrupt file?)")
            result[name] = RawChannel(name, time_s, values, signal.unit or None)
        return result
    finally:
        with _quiet_unraisable():
            mdf.close()


def read_csv(path: Path, names: list[str], time_column: str | None = None, delimiter: str = ",",
             decimal: str = ".", sample_period_s: float | None = None) -> dict[str, RawChannel]:
    """Read channels from a CSV table (see :func:`read_channels`).

    Layout: a header row of column names, optionally a second row of units (recognised when the
    time column's entry there is not a number; without a time column, when no entry is a number),
    then one row per sample. Headers of the form ``name [unit]`` also give the unit.
    """
    import pandas as pd

    try:
        with path.open("r", encoding="utf-8-sig", newline="") as handle:
            lines = [handle.readline() for _ in range(2)]
        last_line = _last_line(path)
    except UnicodeDecodeError as err:
        raise DataError(f"{path}: not a text CSV file (corrupt?): {err}") from None
    header = [field.strip().strip('"') for field in lines[0].rstrip("\r\n").split(delimiter)]
    if not lines[0].strip() or not lines[1].strip():
        raise DataError(f"{path}: the file is empty (no data rows); expected a header row and samples")
    names_in_file, header_units = _split_header(header)
    name_unit = None
    if sample_period_s is None:
        time_column, name_unit = time_column_of(path, time_column, names_in_file)
    second = [field.strip().strip('"') for field in lines[1].rstrip("\r\n").split(delimiter)]
    if sample_period_s is None:
        units_row = len(second) == len(header) and not _is_number(second[names_in_file.index(time_column)], decimal)
    else:
        units_row = (len(second) == len(header) and any(second)
                     and not any(_is_number(field, decimal) for field in second))
    if units_row:
        header_units = [unit or from_row or None for unit, from_row in zip(header_units, second)]
    if len(last_line.split(delimiter)) < len(header):
        raise DataError(f"{path}: the last row has {len(last_line.split(delimiter))} of {len(header)} fields "
                        "(truncated file?)")
    try:
        frame = pd.read_csv(path, sep=delimiter, decimal=decimal, header=None, skiprows=2 if units_row else 1,
                            names=names_in_file, dtype=str, keep_default_na=False, encoding="utf-8-sig")
    except Exception as err:
        raise DataError(f"{path}: cannot parse the CSV file (corrupt or truncated?): {err}") from None
    if frame.empty:
        raise DataError(f"{path}: the file is empty (no data rows); expected samples below the header")
    units = dict(zip(names_in_file, header_units))
    if name_unit and not units.get(time_column):
        units[time_column] = name_unit
    return _table_channels(path, frame, names, time_column, units, decimal, sample_period_s)


def read_parquet(path: Path, names: list[str], time_column: str | None = None,
                 sample_period_s: float | None = None) -> dict[str, RawChannel]:
    """Read channels from a Parquet table (see :func:`read_channels`)."""
    import pandas as pd

    try:
        frame = pd.read_parquet(path)
    except Exception as err:
        raise DataError(f"{path}: cannot read the Parquet file (corrupt or truncated?): {err}") from None
    names_in_file, header_units = _split_header([str(column) for column in frame.columns])
    frame.columns = names_in_file
    if frame.empty or not names_in_file:
        raise DataError(f"{path}: the file is empty (no rows); expected samples")
    units = dict(zip(names_in_file, header_units))
    if sample_period_s is None:
        time_column, name_unit = time_column_of(path, time_column, names_in_file)
        if name_unit and not units.get(time_column):
            units[time_column] = name_unit
    return _table_channels(path, frame, names, time_column, units, ".", sample_period_s)


def _table_channels(path: Path, frame, names: list[str], time_column: str, units: dict[str, str | None],
                    decimal: str, sample_period_s: float | None = None) -> dict[str, RawChannel]:
    """Channels of a table: one shared time base, from the time column or ``k * sample_period_s``."""
    if sample_period_s is None:
        available = [column for column in frame.columns if column != time_column]
        _require(path, names, available)
        time_s, time_unit = _column_values(path, frame, time_column, decimal), units.get(time_column)
    else:
        _require(path, names, list(frame.columns))
        time_s, time_unit = np.arange(len(frame), dtype=np.float64) * float(sample_period_s), "s"
    return {name: RawChannel(name, time_s, _column_values(path, frame, name, decimal), units.get(name),
                             time_unit) for name in names}


def _column_values(path: Path, frame, column: str, decimal: str) -> np.ndarray:
    """A table column as float64; empty cells become NaN, other text is an error naming the row."""
    import pandas as pd

    raw = frame[column]
    if raw.dtype == object or pd.api.types.is_string_dtype(raw.dtype):
        text = raw.astype(str).str.strip()
        if decimal != ".":
            text = text.str.replace(decimal, ".", regex=False)
        values = pd.to_numeric(text.where(text != "", "nan"), errors="coerce")
        bad = values.isna() & ~text.str.lower().isin(["", "nan", "-nan", "inf", "-inf"])
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise DataError(f"{path}: column {column}: row {row + 1} holds {text.iloc[row]!r}; expected a number")
        return values.to_numpy(dtype=np.float64)
    return _numeric(path, column, raw.to_numpy())


def _numeric(path: Path, name: str, samples) -> np.ndarray:
    samples = np.asarray(samples)
    if samples.ndim != 1 or samples.dtype.kind not in "biuf":
        raise DataError(f"{path}: channel {name}: samples of type {samples.dtype} and shape {samples.shape}; "
                        "expected one numeric value per time stamp")
    return samples.astype(np.float64)


def _require(path: Path, names: list[str], available: list[str]) -> None:
    missing = [name for name in names if name not in available]
    if missing:
        shown = sorted(available)
        listing = ", ".join(shown[:80]) + (f", ... ({len(shown) - 80} more)" if len(shown) > 80 else "")
        raise DataError(f"{path}: channel(s) {', '.join(missing)} not found; the file has: {listing}")


def _split_header(header: list[str]) -> tuple[list[str], list[str | None]]:
    names, units = [], []
    for field in header:
        match = _HEADER_UNIT.match(field)
        if match and match.group("name"):
            names.append(match.group("name"))
            units.append(match.group("unit").strip() or None)
        else:
            names.append(field)
            units.append(None)
    return names, units


def _is_number(text: str, decimal: str) -> bool:
    try:
        float(text.replace(decimal, ".") if decimal != "." else text)
    except ValueError:
        return False
    return True


def _last_line(path: Path) -> str:
    """Last non-empty line of a text file (read from the end, so large files stay cheap)."""
    with path.open("rb") as handle:
        handle.seek(0, 2)
        size = handle.tell()
        handle.seek(max(0, size - 65536))
        tail = handle.read().decode("utf-8")
    lines = [line for line in tail.splitlines() if line.strip()]
    return lines[-1] if lines else ""


def _is_master(mdf, name: str) -> bool:
    """True when every occurrence of ``name`` is the master (time) channel of its group."""
    for group, index in mdf.channels_db[name]:
        if mdf.masters_db.get(group) != index:
            return False
    return True


@contextlib.contextmanager
def _quiet_unraisable():
    """Silence asammdf's destructor noise for objects left half-built by a failed open."""
    previous = sys.unraisablehook
    sys.unraisablehook = lambda *args: None
    try:
        yield
    finally:
        gc.collect()
        sys.unraisablehook = previous
