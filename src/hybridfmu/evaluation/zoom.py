"""Choice of the zoomed intervals of the evaluation (paper Figs. 10, 12, 14, 16), per target signal.

An interval is chosen where the FMU and the data part most, judged from the FMU alone (never
from the neural FMU, so the choice does not favour the model being evaluated), by one of two
criteria (config ``evaluation.zoom.criterion``, per target signal or one for all):

- ``growth``: the window of the configured length over which the FMU's absolute error grows
  most, |e(t_end)| - |e(t_start)| with e = FMU - data (errors that accumulate, e.g. a position);
- ``mse``: the window of the configured length with the largest FMU MSE (spikes and
  oscillations, e.g. of a rate).

Intervals set in the config replace the automatic choice for their signal.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

#: Criteria of the automatic choice (module docstring).
CRITERIA = ("growth", "mse")
DEFAULT_LENGTH_S = 1.0


@dataclass(frozen=True)
class ZoomInterval:
    """A zoomed time interval [t_start_s, t_end_s] (s), the target signal it was chosen for, and how
    (``source``: "auto" with ``criterion``, or "config")."""

    t_start_s: float
    t_end_s: float
    signal: str
    source: str
    criterion: str = ""

    def as_dict(self) -> dict:
        return {"t_start_s": self.t_start_s, "t_end_s": self.t_end_s, "signal": self.signal,
                "source": self.source, "criterion": self.criterion}


def per_signal(value: Any, signals: Sequence[str], default: Any, field: str) -> dict[str, Any]:
    """A config value given once for all signals or as a mapping signal -> value, spread over ``signals``.

    Raises:
        ValueError: the mapping names a signal that is not a target (names the config field).
    """
    if isinstance(value, dict):
        unknown = [name for name in value if name not in signals]
        if unknown:
            raise ValueError(f"config.evaluation.zoom.{field}: signal(s) {unknown} are not target signals "
                             f"{list(signals)}")
        return {signal: value.get(signal, default) for signal in signals}
    return {signal: default if value is None else value for signal in signals}


def zoom_choices(zoom_settings: dict[str, Any] | None, signals: Sequence[str]) -> tuple[dict[str, float], dict[str, str]]:
    """(length_s per signal, criterion per signal) from config ``evaluation.zoom``."""
    zoom_settings = zoom_settings or {}
    lengths = {k: float(v) for k, v in per_signal(zoom_settings.get("length_s"), signals, DEFAULT_LENGTH_S,
                                                 "length_s").items()}
    criteria = per_signal(zoom_settings.get("criterion"), signals, "growth", "criterion")
    bad = {k: v for k, v in criteria.items() if v not in CRITERIA}
    if bad:
        raise ValueError(f"config.evaluation.zoom.criterion: {bad}; expected one of {CRITERIA}")
    return lengths, criteria


def window_samples(time_s: np.ndarray, length_s: float) -> int:
    """Number of grid steps spanned by a window of ``length_s`` on the uniform grid ``time_s`` (T,).

    Clipped to the trajectory: a window longer than the maneuver covers the whole maneuver.
    """
    time_s = np.asarray(time_s, dtype=float)
    if time_s.ndim != 1 or time_s.size < 2:
        raise ValueError(f"time grid must be 1-D with at least 2 samples, got shape {time_s.shape}")
    if length_s <= 0:
        raise ValueError(f"zoom length must be positive, got {length_s} s")
    step_s = float(np.median(np.diff(time_s)))
    return int(min(max(round(length_s / step_s), 1), time_s.size - 1))


def largest_error_growth(time_s: np.ndarray, error: np.ndarray, length_s: float) -> tuple[float, float]:
    """Window of ``length_s`` where ``|error|`` grows most: argmax of |e[k+n]| - |e[k]|.

    Args:
        time_s: uniform time grid (T,), s.
        error: simulated minus measured quantity (T,).
        length_s: window length, s.

    Returns:
        (t_start_s, t_end_s) of the window.
    """
    n = window_samples(time_s, length_s)
    magnitude = np.abs(np.asarray(error, dtype=float))
    growth = magnitude[n:] - magnitude[:-n]
    k = int(np.argmax(growth))
    return float(time_s[k]), float(time_s[k + n])


def largest_mean_square(time_s: np.ndarray, error: np.ndarray, length_s: float) -> tuple[float, float]:
    """Window of ``length_s`` with the largest mean of ``error**2`` (moving mean over n+1 samples).

    Args:
        time_s: uniform time grid (T,), s.
        error: simulated minus measured quantity (T,).
        length_s: window length, s.

    Returns:
        (t_start_s, t_end_s) of the window.
    """
    n = window_samples(time_s, length_s)
    squared = np.asarray(error, dtype=float) ** 2
    cumulative = np.concatenate([[0.0], np.cumsum(squared)])
    window_sums = cumulative[n + 1:] - cumulative[: -(n + 1)]
    k = int(np.argmax(window_sums))
    return float(time_s[k]), float(time_s[k + n])


def choose_zoom_intervals(time_s: np.ndarray, errors: dict[str, np.ndarray], lengths_s: dict[str, float],
                          criteria: dict[str, str], configured: list[dict] | None = None) -> list[ZoomInterval]:
    """The zoomed intervals of one maneuver, one or more per target signal.

    Args:
        time_s: uniform time grid (T,), s.
        errors: target signal -> FMU minus measured signal (T,), in the signal's unit.
        lengths_s, criteria: per signal, the automatic window's length (s) and criterion (``CRITERIA``).
        configured: intervals from the config, each ``{"t_start_s", "t_end_s", "signal"}`` (signal default:
            the first target); the intervals of a signal named here replace its automatic choice.

    Returns:
        The intervals, signal by signal in the order of ``errors``.
    """
    time_s = np.asarray(time_s, dtype=float)
    signals = list(errors)
    chosen: dict[str, list[ZoomInterval]] = {signal: [] for signal in signals}
    for index, item in enumerate(configured or []):
        start, end = float(item["t_start_s"]), float(item["t_end_s"])
        signal = item.get("signal") or signals[0]
        if signal not in chosen:
            raise ValueError(f"zoom interval {index}: signal must be one of the target signals {signals}, "
                             f"got {signal!r}")
        if not (end > start and start < time_s[-1] and end > time_s[0]):
            raise ValueError(f"zoom interval {index} [{start}, {end}] s does not overlap the maneuver "
                             f"[{time_s[0]:.6g}, {time_s[-1]:.6g}] s")
        chosen[signal].append(ZoomInterval(start, end, signal, "config"))
    for signal in signals:
        if chosen[signal]:
            continue
        criterion = criteria[signal]
        if criterion not in CRITERIA:
            raise ValueError(f"zoom criterion of {signal!r}: expected one of {CRITERIA}, got {criterion!r}")
        choose = largest_error_growth if criterion == "growth" else largest_mean_square
        chosen[signal].append(ZoomInterval(*choose(time_s, errors[signal], lengths_s[signal]), signal, "auto",
                                           criterion))
    return [interval for signal in signals for interval in chosen[signal]]
