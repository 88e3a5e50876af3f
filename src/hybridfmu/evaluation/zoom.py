"""Choice of the zoomed intervals of the evaluation (paper Figs. 10, 12, 14, 16).

An interval is chosen where the FMU and the data part most, judged from the FMU alone (never
from the neural FMU, so the choice does not favour the model being evaluated):

- ``angle``: the window of the configured length over which the FMU's absolute angle error
  grows most, |e(t_end)| - |e(t_start)| with e = theta_FMU - theta_data;
- ``speed``: the window of the configured length with the largest FMU speed MSE (the spikes
  and oscillations of the open-loop FMU).

Intervals set in the config replace the automatic choice for their quantity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

QUANTITIES = ("angle", "speed")


@dataclass(frozen=True)
class ZoomInterval:
    """A zoomed time interval [t_start_s, t_end_s] (s) and the quantity it was chosen for."""

    t_start_s: float
    t_end_s: float
    quantity: str
    source: str  # "auto" or "config"

    def as_dict(self) -> dict:
        return {"t_start_s": self.t_start_s, "t_end_s": self.t_end_s,
                "quantity": self.quantity, "source": self.source}


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


def choose_zoom_intervals(time_s: np.ndarray, angle_error_rad: np.ndarray, speed_error_rad_s: np.ndarray,
                          angle_length_s: float, speed_length_s: float,
                          configured: list[dict] | None = None) -> list[ZoomInterval]:
    """The zoomed intervals of one maneuver.

    Args:
        time_s: uniform time grid (T,), s.
        angle_error_rad: FMU angle minus measured angle (T,), rad.
        speed_error_rad_s: FMU speed minus measured speed (T,), rad/s.
        angle_length_s, speed_length_s: lengths of the automatically chosen windows, s.
        configured: intervals from the config, each ``{"t_start_s", "t_end_s", "quantity"}``;
            the intervals of a quantity named here replace the automatic choice for that quantity.

    Returns:
        The intervals, angle ones first, then speed ones.
    """
    time_s = np.asarray(time_s, dtype=float)
    chosen: dict[str, list[ZoomInterval]] = {quantity: [] for quantity in QUANTITIES}
    for index, item in enumerate(configured or []):
        start, end = float(item["t_start_s"]), float(item["t_end_s"])
        quantity = item.get("quantity", "angle")
        if quantity not in QUANTITIES:
            raise ValueError(f"zoom interval {index}: quantity must be one of {QUANTITIES}, got {quantity!r}")
        if not (end > start and start < time_s[-1] and end > time_s[0]):
            raise ValueError(f"zoom interval {index} [{start}, {end}] s does not overlap the maneuver "
                             f"[{time_s[0]:.6g}, {time_s[-1]:.6g}] s")
        chosen[quantity].append(ZoomInterval(start, end, quantity, "config"))
    if not chosen["angle"]:
        chosen["angle"].append(ZoomInterval(*largest_error_growth(time_s, angle_error_rad, angle_length_s),
                                            "angle", "auto"))
    if not chosen["speed"]:
        chosen["speed"].append(ZoomInterval(*largest_mean_square(time_s, speed_error_rad_s, speed_length_s),
                                            "speed", "auto"))
    return chosen["angle"] + chosen["speed"]
