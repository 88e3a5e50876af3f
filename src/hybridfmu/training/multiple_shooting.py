"""Multiple shooting: a model over many short windows of a record, each started from the measured state.

An open-loop simulation over a whole record judges two things at once: how accurate a model is, and whether it
stays with the measurement through the whole record (a motor model that slips by an electrical period is
off by radians from then on). Restarting the model from the measured state every ``window`` samples measures the
first alone: the **windowed trajectory** is the concatenation of the windows' simulations on the record's grid
(the first sample of each window is the state it started from), and its error against the data is the windowed
error of :mod:`hybridfmu.evaluation.comparison`.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

#: Windows per record when no window length is configured (``evaluation.windows.length_s``): chosen from the data.
DEFAULT_WINDOWS_PER_RECORD = 200

#: The fewest samples a window spans.
MIN_WINDOW_SAMPLES = 10


def window_samples(length_s: float | None, sample_period_s: float, shortest_record_s: float) -> int:
    """Steps per window: ``length_s`` (s) on the grid of ``sample_period_s``, or with None the shortest evaluated
    record over :data:`DEFAULT_WINDOWS_PER_RECORD` (at least :data:`MIN_WINDOW_SAMPLES` samples either way)."""
    if length_s is None:
        length_s = shortest_record_s / DEFAULT_WINDOWS_PER_RECORD
    if not length_s > 0.0:
        raise ValueError(f"config.evaluation.windows.length_s: expected a positive length, got {length_s}")
    return max(int(round(length_s / sample_period_s)), MIN_WINDOW_SAMPLES)


def window_starts(n_samples: int, steps: int) -> np.ndarray:
    """First sample of each window (0, steps, 2 steps, ...) of a record of ``n_samples`` samples: the windows tile
    the record; each spans ``steps`` steps (the last one fewer)."""
    if steps < 1:
        raise ValueError(f"window_starts: steps must be >= 1, got {steps}")
    return np.arange(0, max(n_samples - 1, 1), steps, dtype=np.int64)


def windowed_trajectory(simulate: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray], time_s: np.ndarray,
                        u: np.ndarray, x_start: np.ndarray, steps: int) -> np.ndarray:
    """A model over consecutive windows, each simulated from ``x_start`` at its first sample.

    Args:
        simulate: (time_s (n,), u (n, n_u), x0 (n_x,)) -> states (n, n_x), the model open loop over a slice.
        time_s: (T,) grid (s); u: (T, n_u) inputs; x_start: (T, n_x) the state a window started at sample k
            starts from (measured states; unmeasured ones e.g. from the model's own whole-record simulation).
        steps: steps per window (:func:`window_samples`).

    Returns:
        (T, n_x): each window's simulation on its samples (a window's first sample is its start state; a failed
        window's samples are NaN).
    """
    time_s, u, x_start = np.asarray(time_s, float), np.asarray(u, float), np.asarray(x_start, float)
    out = np.full(x_start.shape, np.nan)
    for start in window_starts(time_s.size, steps):
        end = min(int(start) + steps, time_s.size - 1)
        try:
            states = np.asarray(simulate(time_s[start:end + 1], u[start:end + 1], x_start[start]), dtype=float)
        except (FloatingPointError, RuntimeError, ValueError):
            out[start:end + 1] = np.nan
            continue
        out[start:end + 1] = states
    return out


def batched_window_rows(n_samples: int, steps: int) -> tuple[np.ndarray, int]:
    """(starts of the full windows, steps of the last, shorter window or 0): for simulators that run the full
    windows side by side in one batch."""
    starts = window_starts(n_samples, steps)
    last_steps = (n_samples - 1) - int(starts[-1])
    full = starts if last_steps == steps else starts[:-1]
    return full, 0 if last_steps == steps else last_steps


def describe_windows(steps: int, sample_period_s: float, n_samples: int) -> str:
    """``'200 windows of 0.1 s'`` for a log line."""
    count = math.ceil((n_samples - 1) / steps) if n_samples > 1 else 0
    return f"{count} windows of {steps * sample_period_s:.4g} s"
