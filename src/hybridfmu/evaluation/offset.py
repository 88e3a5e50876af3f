"""The time offset between data and model (paper Fig. 6).

On a short window where the measured speed changes fast, the FMU is started from the measured
state at the window's start and driven by the logged inputs; a constant time offset between the
logged inputs and states then shows as a shift between the simulated and the measured speed.
The shift is estimated by least squares over sub-sample shifts.
"""

from __future__ import annotations

import numpy as np

from hybridfmu.evaluation.zoom import window_samples


def steepest_window(time_s: np.ndarray, speed_rad_s: np.ndarray, length_s: float) -> tuple[float, float]:
    """Window of ``length_s`` over which the measured speed changes most, |ω(t_end) - ω(t_start)|.

    Args:
        time_s: uniform time grid (T,), s.
        speed_rad_s: measured speed (T,), rad/s.
        length_s: window length, s.

    Returns:
        (t_start_s, t_end_s).
    """
    n = window_samples(time_s, length_s)
    speed = np.asarray(speed_rad_s, dtype=float)
    change = np.abs(speed[n:] - speed[:-n])
    k = int(np.argmax(change))
    return float(time_s[k]), float(time_s[k + n])


def estimate_lag_s(time_s: np.ndarray, measured: np.ndarray, simulated: np.ndarray, max_lag_s: float,
                   resolution: int = 20) -> float:
    """Shift of ``measured`` against ``simulated`` that fits best in the least-squares sense.

    The returned ``lag_s`` minimises the mean of (measured(t) - simulated(t - lag_s))^2 over the
    samples where the shifted curve is defined; positive means the measurement lags the model.
    Shifts are searched on a grid of ``step / resolution`` within ``[-max_lag_s, max_lag_s]``
    (linear interpolation between samples).

    Args:
        time_s: uniform time grid (T,), s.
        measured, simulated: the same quantity (T,).
        max_lag_s: largest shift searched, s.
        resolution: grid points per sample step.
    """
    time_s = np.asarray(time_s, dtype=float)
    measured = np.asarray(measured, dtype=float)
    simulated = np.asarray(simulated, dtype=float)
    if not (time_s.shape == measured.shape == simulated.shape) or time_s.size < 3:
        raise ValueError(f"time, measured and simulated must share one shape with at least 3 samples, got "
                         f"{time_s.shape}, {measured.shape}, {simulated.shape}")
    step_s = float(np.median(np.diff(time_s)))
    max_lag_s = min(max_lag_s, 0.5 * (time_s[-1] - time_s[0]))
    fine_s = step_s / resolution
    count = int(np.floor(max_lag_s / fine_s))
    candidates = np.arange(-count, count + 1) * fine_s
    best_lag, best_cost = 0.0, np.inf
    for lag in candidates:
        shifted_t = time_s - lag
        valid = (shifted_t >= time_s[0]) & (shifted_t <= time_s[-1])
        if valid.sum() < 3:
            continue
        cost = float(np.mean((measured[valid] - np.interp(shifted_t[valid], time_s, simulated)) ** 2))
        if cost < best_cost - 1e-15 or (abs(cost - best_cost) <= 1e-15 and abs(lag) < abs(best_lag)):
            best_lag, best_cost = float(lag), cost
    return best_lag
