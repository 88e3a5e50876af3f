"""Automatic segment selection: the spans of a maneuver that carry information (paper Sec. 2.3, Fig. 8).

Measured maneuvers spend much of their time at rest (before and after the actual test). What moves
is read from the case's roles, never from a particular machine: one *indicator* per signal of a
measured state and per signal of an FMU input (each signal once), the smoothed absolute rate of
change of the signal::

    rate(t)      = d signal / dt        (Savitzky-Golay differentiator over smooth_s, degree 2,
                                         the signal mirrored at its ends)
    indicator(t) = mean of |rate| over a centred window of smooth_s

A sample is *active* when any indicator exceeds its threshold

    threshold = max(noise_floor * noise, low + relative * (high - low))

with ``low`` and ``high`` the indicator's quantiles ``rest_quantile`` (its level at rest) and
``spread_quantile`` (its spread, robust to single spikes), and ``noise`` the larger of ``low`` and the
level pure white sensor noise gives the indicator (the robust standard deviation of the signal's
sample-to-sample differences, through the same filters). Both parts are relative to the signal's
own data, so the same settings work in any unit and on any case. Active runs closer than
``merge_gap_s`` are merged, runs shorter than ``min_span_s`` dropped, the rest padded by ``pad_s``
on both sides (clipped to the maneuver) and overlaps merged again.

API::

    indicator_signals(frame, signals, smooth_s) -> {signal: (T,)}
    select_segments(frame, roles, segments_config) -> SegmentSelection
    read_segments(path) -> record;  span_mask(time_s, spans_s) -> (T,) bool
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pandas as pd

from hybridfmu.data.roles import CaseRoles
from hybridfmu.data.errors import DataError
from hybridfmu.data.resample import savgol_window, smoothing_derivative
from hybridfmu.data.settings import section_settings

LOG = logging.getLogger(__name__)

#: Settings copied into the record's ``thresholds`` (beside the per-signal thresholds).
RECORDED_SETTINGS = ("rest_quantile", "spread_quantile", "smooth_s", "relative", "noise_floor", "input_levels",
                     "merge_gap_s", "min_span_s", "pad_s")
MIN_SAMPLES = 5


@dataclass
class SegmentSelection:
    """Result of :func:`select_segments`.

    Attributes:
        spans_s: [(t_start_s, t_end_s), ...] sorted, non-overlapping, in ``time_s`` of the frame.
        thresholds: signal -> threshold of its indicator (the signal's model unit per second), plus
            the settings used (``RECORDED_SETTINGS``).
        fraction_kept: total span duration / maneuver duration.
        duration_s: maneuver duration (s).
        active: (T,) bool, samples where any indicator exceeded its threshold (before merging/padding).
        indicators: signal -> (T,) indicator values (for the figure; not written to the record).
    """

    spans_s: list[tuple[float, float]]
    thresholds: dict[str, Any]
    fraction_kept: float
    duration_s: float
    active: np.ndarray = field(repr=False)
    indicators: dict[str, np.ndarray] = field(default_factory=dict, repr=False)


def indicator_signals_of(roles: CaseRoles, settings: dict[str, Any]) -> list[str]:
    """Signals with an indicator: ``settings["signals"]`` if given, else every measured-state signal then
    every input signal (each once).

    Raises:
        DataError: a listed signal is not a signal of the case (names ``config.segments.signals``).
    """
    chosen = settings.get("signals")
    if chosen:
        unknown = [name for name in chosen if name not in roles.signals]
        if unknown:
            raise DataError(f"config.segments.signals: {unknown} are not signals of the case; expected some of "
                            f"{list(roles.signals)}")
        return list(dict.fromkeys(chosen))
    return list(dict.fromkeys([*roles.states.values(), *roles.input_signals]))


def indicator_signals(frame: pd.DataFrame, signals: Sequence[str], smooth_s: float) -> dict[str, np.ndarray]:
    """The indicator of each signal (module docstring): ``{signal: (T,) >= 0}`` in the signal's unit per s.

    Raises:
        DataError: a column is missing, or the frame is too short or not uniformly sampled.
    """
    time_s = _time(frame)
    rate_hz = (len(time_s) - 1) / (time_s[-1] - time_s[0])
    missing = [name for name in signals if name not in frame.columns]
    if missing:
        raise DataError(f"ingested frame: columns {missing} missing; expected the signals {list(signals)}")
    window = savgol_window(smooth_s, rate_hz, 2, len(time_s))
    rates = {name: smoothing_derivative(frame[name].to_numpy(dtype=np.float64), rate_hz, smooth_s, 2, "mirror")
             for name in signals}
    return {name: _moving_mean(np.abs(rate), window) for name, rate in rates.items()}


def noise_level(values: np.ndarray, rate_hz: float, smooth_s: float) -> float:
    """Indicator level that white sensor noise alone gives a signal (signal unit per s).

    The noise's standard deviation is the robust (MAD) standard deviation of the sample-to-sample
    differences divided by sqrt(2); it passes the Savitzky-Golay differentiator with the gain of its
    coefficients' 2-norm, and the mean of |Gaussian| is sqrt(2/pi) times its standard deviation.
    """
    from scipy.signal import savgol_coeffs

    steps = np.diff(np.asarray(values, dtype=np.float64))
    sigma = 1.4826 * float(np.median(np.abs(steps - np.median(steps)))) / np.sqrt(2.0)
    window = savgol_window(smooth_s, rate_hz, 2, len(values))
    gain = float(np.linalg.norm(savgol_coeffs(window, 2, deriv=1, delta=1.0 / rate_hz)))
    return sigma * gain * np.sqrt(2.0 / np.pi)


def input_level(values: np.ndarray, rest: np.ndarray, rate_hz: float, smooth_s: float, relative: float,
                rest_quantile: float, spread_quantile: float, noise_floor: float) -> tuple[np.ndarray, float]:
    """Level indicator of an input: the smoothed distance from its rest value, and its threshold.

    The rest value is the input's median over the samples before the first and after the last
    sample where a rate indicator is active (``rest``, (T,) bool: no rate indicator active; all of
    them when the maneuver starts and ends in motion); the distance of the smoothed input (Savitzky-Golay over ``smooth_s``,
    degree 2) from it is averaged over ``smooth_s``. The threshold is
    ``max(noise_floor * noise, low + relative * (high - low))`` as for the rates, the noise being the
    larger of ``low`` and the robust (MAD) standard deviation of what the smoothing removes (sensor
    noise, ripple: everything faster than ``smooth_s``).

    Returns:
        ((T,) indicator >= 0 in the input's unit, threshold).
    """
    from hybridfmu.data.resample import smooth

    reference = float(np.median(values[_outer_rest(rest)]))
    window = savgol_window(smooth_s, rate_hz, 2, len(values))
    smoothed = smooth(values, rate_hz, smooth_s, 2, "mirror")
    distance = _moving_mean(np.abs(smoothed - reference), window)
    residual = values - smoothed
    noise = max(float(np.quantile(distance, rest_quantile)),
                1.4826 * float(np.median(np.abs(residual - np.median(residual)))))
    return distance, relative_threshold(distance, relative, rest_quantile, spread_quantile, noise_floor * noise)


def relative_threshold(values: np.ndarray, relative: float, rest_quantile: float, spread_quantile: float,
                       floor: float) -> float:
    """``max(floor, low + relative * (high - low))``, low/high = quantiles ``rest_quantile``/``spread_quantile``.

    Args:
        values: (T,) indicator samples.
    """
    low, high = (float(q) for q in np.quantile(values, [rest_quantile, spread_quantile]))
    return max(float(floor), low + float(relative) * (high - low))


def select_segments(frame: pd.DataFrame, roles: CaseRoles, segments_config: dict[str, Any] | None) -> SegmentSelection:
    """Find the informative spans of an ingested maneuver.

    Args:
        frame: ingested data: ``time_s`` (T,) uniform, and a column per signal of the roles.
        roles: the case's roles (which signals are measured states and inputs).
        segments_config: the case's ``segments`` section (schema defaults filled in here).

    Returns:
        The selected spans, thresholds and kept fraction.

    Raises:
        DataError: a column missing, or too few samples.
    """
    settings = section_settings(segments_config, "segments")
    time_s = _time(frame)
    rate_hz = (len(time_s) - 1) / (time_s[-1] - time_s[0])
    smooth_s = float(settings["smooth_s"])
    signals = indicator_signals_of(roles, settings)
    indicators = indicator_signals(frame, signals, smooth_s)
    thresholds: dict[str, Any] = {}
    rest_q, spread_q = float(settings["rest_quantile"]), float(settings["spread_quantile"])
    floor, relative = float(settings["noise_floor"]), float(settings["relative"])
    active = np.zeros(len(time_s), dtype=bool)
    for name, values in indicators.items():
        low = float(np.quantile(values, rest_q))
        noise = max(low, noise_level(frame[name].to_numpy(dtype=np.float64), rate_hz, smooth_s))
        level = relative_threshold(values, relative, rest_q, spread_q, floor * noise)
        above = values > level
        thresholds[name] = level
        LOG.info("indicator d%s/dt: threshold %.4g (%s)/s, noise %.3g, active %.1f%% of samples", name, level,
                 roles.signals[name].unit or "1", noise, 100.0 * above.mean())
        active |= above
    if settings["input_levels"]:
        rest = ~active.copy()
        for name in [name for name in dict.fromkeys(roles.input_signals) if name in signals]:
            values, level = input_level(frame[name].to_numpy(dtype=np.float64), rest, rate_hz, smooth_s,
                                        relative, rest_q, spread_q, floor)
            above = values > level
            indicators[f"level_{name}"] = values
            thresholds[f"level_{name}"] = level
            LOG.info("indicator |%s - rest|: threshold %.4g %s, active %.1f%% of samples", name, level,
                     roles.signals[name].unit or "1", 100.0 * above.mean())
            active |= above
    spans = spans_from_mask(time_s, active, float(settings["merge_gap_s"]), float(settings["min_span_s"]),
                            float(settings["pad_s"]))
    duration_s = float(time_s[-1] - time_s[0])
    kept_s = sum(end - start for start, end in spans)
    thresholds.update({key: settings[key] for key in RECORDED_SETTINGS})
    return SegmentSelection(spans, thresholds, kept_s / duration_s if duration_s > 0 else 0.0, duration_s, active,
                            indicators)


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


def _time(frame: pd.DataFrame) -> np.ndarray:
    if "time_s" not in frame.columns:
        raise DataError(f"ingested frame: column 'time_s' missing; the frame has {list(frame.columns)}")
    time_s = frame["time_s"].to_numpy(dtype=np.float64)
    if len(time_s) < MIN_SAMPLES or not time_s[-1] > time_s[0]:
        raise DataError(f"ingested frame: {len(time_s)} samples; expected a time series of at least "
                        f"{MIN_SAMPLES} samples")
    return time_s


def _outer_rest(rest: np.ndarray) -> np.ndarray:
    """(T,) bool: the leading and trailing runs of ``rest`` (or all of ``rest``, or everything, if empty)."""
    if not rest.any():
        return np.ones_like(rest)
    if rest.all():
        return rest
    moving = np.flatnonzero(~rest)
    outer = np.zeros_like(rest)
    outer[:moving[0]] = True
    outer[moving[-1] + 1:] = True
    return outer if outer.any() else rest


def _moving_mean(values: np.ndarray, window: int) -> np.ndarray:
    """Centred moving mean over ``window`` samples (edges: the mean over the part inside); (T,) -> (T,)."""
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(values, size=window, mode="nearest")


def _merge(runs: list[list[float]], gap_s: float) -> list[list[float]]:
    merged: list[list[float]] = []
    for start, end in runs:
        if merged and start - merged[-1][1] <= gap_s:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    return merged
