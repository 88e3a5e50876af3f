"""Automatic segment selection: the spans of a maneuver that carry information (paper Sec. 2.3, Fig. 8).

Measured maneuvers spend much of their time at rest (before and after the actual test). A sample is
*active* when any of these indicators exceeds its threshold (all computed on the ingested frame,
smoothed by a Savitzky-Golay filter over ``smooth_s``):

- motion: ``|omega|`` (rad/s);
- acceleration: ``|d omega / dt|`` (rad/s^2);
- load change: ``|d tau_load / dt|`` (N·m/s);
- duty activity: the magnitude of the differential duties ``|d - mean(d)|`` (a voltage vector is
  applied: the motor is driven or holds a load).

Each threshold is relative to the indicator's own spread, so the same settings work on another
case's data: ``threshold = max(floor, low + relative * (high - low))`` with ``low`` and ``high`` the
indicator's quantiles ``rest_quantile`` (the level at rest) and ``spread_quantile`` (robust to single
spikes); the floors keep pure sensor noise out. ``relative: null`` disables an indicator. Active runs closer than ``merge_gap_s`` are merged, runs
shorter than ``min_span_s`` dropped, the rest padded by ``pad_s`` on both sides (clipped to the
maneuver) and overlaps merged again.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.data.errors import DataError
from hybridfmu.data.resample import smooth, smoothing_derivative
from hybridfmu.data.settings import section_settings

LOG = logging.getLogger(__name__)

#: Indicator name -> (config key of its relative threshold, config key of its floor, unit).
INDICATORS: dict[str, tuple[str, str, str]] = {
    "omega_rad_s": ("omega_relative", "omega_floor_rad_s", "rad/s"),
    "accel_rad_s2": ("accel_relative", "accel_floor_rad_s2", "rad/s^2"),
    "load_rate_nm_s": ("load_rate_relative", "load_rate_floor_nm_s", "N·m/s"),
    "duty_activity": ("duty_relative", "duty_floor", "1"),
}
REQUIRED_COLUMNS = ("time_s", "omega_rad_s", "tau_load_nm", "duty_a", "duty_b", "duty_c")


@dataclass
class SegmentSelection:
    """Result of :func:`select_segments`.

    Attributes:
        spans_s: [(t_start_s, t_end_s), ...] sorted, non-overlapping, in ``time_s`` of the frame.
        thresholds: indicator name -> absolute threshold used (None when disabled), plus the span settings.
        fraction_kept: total span duration / maneuver duration.
        duration_s: maneuver duration (s).
        active: (T,) bool, samples where any indicator exceeded its threshold (before merging/padding).
    """

    spans_s: list[tuple[float, float]]
    thresholds: dict[str, Any]
    fraction_kept: float
    duration_s: float
    active: np.ndarray = field(repr=False)


def indicator_signals(frame: pd.DataFrame, smooth_s: float) -> dict[str, np.ndarray]:
    """The activity indicators of an ingested frame (module docstring); each (T,) non-negative."""
    missing = [column for column in REQUIRED_COLUMNS if column not in frame.columns]
    if missing:
        raise DataError(f"ingested frame: columns {missing} missing; expected {list(REQUIRED_COLUMNS)}")
    time_s = frame["time_s"].to_numpy(dtype=np.float64)
    if len(time_s) < 5:
        raise DataError(f"ingested frame: {len(time_s)} samples; expected a time series of at least 5 samples")
    rate_hz = (len(time_s) - 1) / (time_s[-1] - time_s[0])
    omega = frame["omega_rad_s"].to_numpy(dtype=np.float64)
    duties = frame[["duty_a", "duty_b", "duty_c"]].to_numpy(dtype=np.float64)
    differential = duties - duties.mean(axis=1, keepdims=True)
    return {
        "omega_rad_s": np.abs(smooth(omega, rate_hz, smooth_s)),
        "accel_rad_s2": np.abs(smoothing_derivative(omega, rate_hz, smooth_s)),
        "load_rate_nm_s": np.abs(smoothing_derivative(frame["tau_load_nm"].to_numpy(dtype=np.float64), rate_hz,
                                                      smooth_s)),
        "duty_activity": smooth(np.linalg.norm(differential, axis=1), rate_hz, smooth_s),
    }


def relative_threshold(values: np.ndarray, relative: float, rest_quantile: float, spread_quantile: float,
                       floor: float) -> float:
    """``max(floor, low + relative * (high - low))``, low/high = quantiles ``rest_quantile``/``spread_quantile``.

    Args:
        values: (T,) indicator samples.
    """
    low, high = (float(q) for q in np.quantile(values, [rest_quantile, spread_quantile]))
    return max(float(floor), low + float(relative) * (high - low))


def select_segments(frame: pd.DataFrame, segments_config: dict[str, Any] | None) -> SegmentSelection:
    """Find the informative spans of an ingested maneuver.

    Args:
        frame: ingested data (columns of ``REQUIRED_COLUMNS``; ``time_s`` uniform, (T,)).
        segments_config: the case's ``segments`` section (schema defaults filled in here).

    Returns:
        The selected spans, thresholds and kept fraction.
    """
    settings = section_settings(segments_config, "segments")
    time_s = frame["time_s"].to_numpy(dtype=np.float64) if "time_s" in frame.columns else np.empty(0)
    indicators = indicator_signals(frame, float(settings["smooth_s"]))
    active = np.zeros(len(time_s), dtype=bool)
    thresholds: dict[str, Any] = {}
    for name, (relative_key, floor_key, unit) in INDICATORS.items():
        relative = settings[relative_key]
        if relative is None:
            thresholds[name] = None
            continue
        level = relative_threshold(indicators[name], relative, float(settings["rest_quantile"]),
                                   float(settings["spread_quantile"]), float(settings[floor_key]))
        above = indicators[name] > level
        thresholds[name] = level
        LOG.info("indicator %s: threshold %.4g %s, active %.1f%% of samples", name, level, unit,
                 100.0 * above.mean())
        active |= above
    spans = spans_from_mask(time_s, active, float(settings["merge_gap_s"]), float(settings["min_span_s"]),
                            float(settings["pad_s"]))
    duration_s = float(time_s[-1] - time_s[0])
    kept_s = sum(end - start for start, end in spans)
    thresholds.update({key: settings[key] for key in
                       ("rest_quantile", "spread_quantile", "smooth_s", "merge_gap_s", "min_span_s", "pad_s")})
    thresholds.update({key: settings[key] for _, (rel, floor, _) in INDICATORS.items() for key in (rel, floor)})
    return SegmentSelection(spans, thresholds, kept_s / duration_s if duration_s > 0 else 0.0, duration_s, active)


def spans_from_mask(time_s: np.ndarray, active: np.ndarray, merge_gap_s: float, min_span_s: float,
                    pad_s: float) -> list[tuple[float, float]]:
    """Turn an activity mask into spans: merge close runs, drop short ones, pad, merge overlaps.

    Args:
        time_s: (T,) increasing time (s).
        active: (T,) bool.
        merge_gap_s: runs separated by less than this are joined.
        min_span_s: joined runs shorter than this are dropped (before padding).
        pad_s: added before and after each span (clipped to ``time_s[0]..time_s[-1]``).

    Returns:
        Sorted, non-overlapping [(t_start_s, t_end_s), ...].
    """
    padded = np.concatenate(([0], active.astype(np.int8), [0]))
    edges = np.diff(padded)
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    runs = [[float(time_s[s]), float(time_s[e])] for s, e in zip(starts, ends)]
    merged = _merge(runs, merge_gap_s)
    kept = [run for run in merged if run[1] - run[0] >= min_span_s]
    t_first, t_last = float(time_s[0]), float(time_s[-1])
    grown = [[max(t_first, start - pad_s), min(t_last, end + pad_s)] for start, end in kept]
    return [(start, end) for start, end in _merge(grown, 0.0)]


def span_mask(time_s: np.ndarray, spans_s: list[tuple[float, float]] | list[list[float]]) -> np.ndarray:
    """(T,) bool: True where ``time_s`` lies inside one of the spans (ends included)."""
    mask = np.zeros(len(time_s), dtype=bool)
    for start, end in spans_s:
        mask |= (time_s >= start) & (time_s <= end)
    return mask


def segments_record(maneuver: str, selection: SegmentSelection) -> dict[str, Any]:
    """The segments JSON of the data contract for one maneuver."""
    return {
        "maneuver": maneuver,
        "spans_s": [[round(start, 9), round(end, 9)] for start, end in selection.spans_s],
        "thresholds": selection.thresholds,
        "fraction_kept": float(selection.fraction_kept),
    }


def read_segments(path: str | Path) -> dict[str, Any]:
    """Read and check a segments JSON file (keys ``maneuver``, ``spans_s``, ``thresholds``, ``fraction_kept``).

    Raises:
        DataError: naming the file and the field that is missing or malformed.
    """
    from hybridfmu.io import read_json

    path = Path(path)
    record = read_json(path)
    for key in ("maneuver", "spans_s", "thresholds", "fraction_kept"):
        if not isinstance(record, dict) or key not in record:
            raise DataError(f"{path}: field {key!r} missing; expected a segments record")
    spans = record["spans_s"]
    if not all(isinstance(span, list) and len(span) == 2 and span[0] <= span[1] for span in spans):
        raise DataError(f"{path}: field 'spans_s': expected [[t_start_s, t_end_s], ...] with start <= end")
    return record


def select_segments_to_files(data_path: str | Path, json_path: str | Path, png_path: str | Path, maneuver: str,
                             segments_config: dict[str, Any] | None) -> SegmentSelection:
    """Select the segments of an ingested maneuver; write the JSON record and the Fig. 8 plot atomically."""
    from hybridfmu.data.segments_plot import plot_segments
    from hybridfmu.io import write_json_atomic

    data_path = Path(data_path)
    try:
        frame = pd.read_parquet(data_path)
    except Exception as err:
        raise DataError(f"{data_path}: cannot read the ingested data: {err}") from None
    try:
        selection = select_segments(frame, segments_config)
    except DataError as err:
        raise DataError(f"{data_path}: {err}") from None
    LOG.info("%s: %d spans, %.1f%% of %.4g s kept", maneuver, len(selection.spans_s),
             100.0 * selection.fraction_kept, selection.duration_s)
    plot_segments(frame, selection, maneuver, png_path)
    write_json_atomic(json_path, segments_record(maneuver, selection))
    return selection


def _merge(runs: list[list[float]], gap_s: float) -> list[list[float]]:
    merged: list[list[float]] = []
    for start, end in runs:
        if merged and start - merged[-1][1] <= gap_s:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    return merged
