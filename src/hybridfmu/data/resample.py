"""Resampling channels with their own time bases onto one uniform grid.

The grid starts at the common start of all channels (the latest first sample) and ends at or before
the common end (the earliest last sample), with step ``1 / rate_hz``. Discrete signals (PWM duties,
states of a controller) are held (zero-order hold: the last sample at or before the grid point);
continuous signals are interpolated linearly. Savitzky-Golay filters smooth and differentiate
uniformly sampled signals (transforms, segment indicators).
"""

from __future__ import annotations

import numpy as np


def common_grid(time_bases: dict[str, np.ndarray], rate_hz: float, start_s: float | None = None,
                end_s: float | None = None) -> np.ndarray:
    """Uniform absolute time stamps (s) covered by every time base (and inside ``start_s..end_s``).

    Args:
        time_bases: ``{name: (n,) increasing time stamps (s)}``.
        rate_hz: sample rate of the grid (Hz).
        start_s, end_s: optional bounds (absolute s) of a slice of the log; None = no bound.

    Returns:
        (T,) float64 grid ``start + k / rate_hz`` with ``start`` the common start (or ``start_s``
        when later); T >= 2.

    Raises:
        ValueError: the channels do not overlap (within the bounds) by at least two grid steps;
            names the channels.
    """
    start = max(float(time[0]) for time in time_bases.values())
    end = min(float(time[-1]) for time in time_bases.values())
    if start_s is not None:
        start = max(start, float(start_s))
    if end_s is not None:
        end = min(end, float(end_s))
    count = int(np.floor((end - start) * rate_hz + 1e-6)) + 1 if end >= start else 0
    if count < 2:
        latest = max(time_bases, key=lambda name: time_bases[name][0])
        earliest = min(time_bases, key=lambda name: time_bases[name][-1])
        bounds = "" if start_s is None and end_s is None else f" within the slice {start_s}..{end_s} s"
        raise ValueError(f"the channels do not overlap in time{bounds}: {latest} starts at "
                         f"{time_bases[latest][0]:.6g} s, {earliest} ends at {time_bases[earliest][-1]:.6g} s; "
                         f"expected at least two samples at {rate_hz:g} Hz")
    return start + np.arange(count, dtype=np.float64) / rate_hz


def zero_order_hold(time_s: np.ndarray, values: np.ndarray, grid_s: np.ndarray,
                    tolerance_s: float | None = None) -> np.ndarray:
    """Value of the last sample at or before each grid point (grid inside the samples' span).

    A sample stamped up to ``tolerance_s`` after a grid point counts as at the grid point, so time
    stamps that equal the grid up to floating-point rounding are not delayed by a whole sample.
    Default tolerance: 1e-3 of the grid step.

    Shapes: time_s (n,), values (n,), grid_s (T,) -> (T,).
    """
    if tolerance_s is None:
        tolerance_s = 1e-3 * float(grid_s[1] - grid_s[0]) if len(grid_s) > 1 else 0.0
    index = np.searchsorted(time_s, grid_s + tolerance_s, side="right") - 1
    return values[np.clip(index, 0, len(values) - 1)]


def linear(time_s: np.ndarray, values: np.ndarray, grid_s: np.ndarray) -> np.ndarray:
    """Linear interpolation of the samples at the grid points. Shapes: (n,), (n,), (T,) -> (T,)."""
    return np.interp(grid_s, time_s, values)


def smoothing_derivative(values: np.ndarray, rate_hz: float, window_s: float, polyorder: int = 2,
                         mode: str = "interp") -> np.ndarray:
    """Derivative of a uniformly sampled signal by a Savitzky-Golay filter.

    A polynomial of degree ``polyorder`` is fitted by least squares in a centred window of
    ``window_s`` (rounded to an odd number of samples, at least ``polyorder + 2``); its slope at the
    centre is the derivative (zero phase: no delay). At the ends, ``mode="interp"`` uses the fit over
    the edge window (unbiased, but noisier); ``"mirror"`` reflects the signal about its ends (the
    derivative tends to 0 there, as quiet as inside). Noise is suppressed roughly above
    ``rate_hz / window_samples`` Hz.

    Args:
        values: (T,) signal samples.
        rate_hz: sample rate (Hz).
        window_s: window length (s).
        polyorder: degree of the local polynomial.
        mode: edge handling of :func:`scipy.signal.savgol_filter` ("interp", "mirror", "nearest").

    Returns:
        (T,) derivative in units of ``values`` per second.
    """
    from scipy.signal import savgol_filter

    window = savgol_window(window_s, rate_hz, polyorder, len(values))
    return savgol_filter(values, window, polyorder, deriv=1, delta=1.0 / rate_hz, mode=mode)


def smooth(values: np.ndarray, rate_hz: float, window_s: float, polyorder: int = 2,
           mode: str = "interp") -> np.ndarray:
    """Savitzky-Golay smoothing (zero phase) of a uniformly sampled signal; (T,) -> (T,) (``mode``: ends)."""
    from scipy.signal import savgol_filter

    window = savgol_window(window_s, rate_hz, polyorder, len(values))
    return savgol_filter(values, window, polyorder, deriv=0, mode=mode)


def savgol_window(window_s: float, rate_hz: float, polyorder: int, length: int) -> int:
    """Samples of a Savitzky-Golay window of ``window_s`` at ``rate_hz``: odd, > polyorder, <= length."""
    window = max(int(round(window_s * rate_hz)) | 1, polyorder + 2 | 1)
    if window > length:
        window = length if length % 2 == 1 else length - 1
    if window <= polyorder:
        raise ValueError(f"signal of {length} samples is too short for a window of order {polyorder}")
    return window
