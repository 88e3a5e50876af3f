"""Error measures between simulated and measured trajectories, and improvement factors.

All errors are in SI units: angle MAE in rad, angle MSE in rad^2, speed MAE in rad/s,
speed MSE in (rad/s)^2.
"""

from __future__ import annotations

import math

import numpy as np

#: Keys of every metrics object, in the order they are written.
METRIC_KEYS = ("angle_mae", "angle_mse", "speed_mae", "speed_mse")


def mae(simulated: np.ndarray, measured: np.ndarray) -> float:
    """Mean absolute error of two arrays of the same shape (T,), in the unit of the inputs."""
    simulated, measured = _pair(simulated, measured)
    return float(np.mean(np.abs(simulated - measured)))


def mse(simulated: np.ndarray, measured: np.ndarray) -> float:
    """Mean squared error of two arrays of the same shape (T,), in the unit of the inputs squared."""
    simulated, measured = _pair(simulated, measured)
    return float(np.mean((simulated - measured) ** 2))


def trajectory_errors(angle_sim_rad: np.ndarray, speed_sim_rad_s: np.ndarray,
                      angle_data_rad: np.ndarray, speed_data_rad_s: np.ndarray) -> dict[str, float]:
    """Angle and speed MAE and MSE of one simulated trajectory against the data.

    Args:
        angle_sim_rad, speed_sim_rad_s: simulated angle (rad) and speed (rad/s), shape (T,).
        angle_data_rad, speed_data_rad_s: measured angle and speed on the same grid, shape (T,).

    Returns:
        ``{"angle_mae", "angle_mse", "speed_mae", "speed_mse"}`` as floats (SI units).
    """
    return {
        "angle_mae": mae(angle_sim_rad, angle_data_rad),
        "angle_mse": mse(angle_sim_rad, angle_data_rad),
        "speed_mae": mae(speed_sim_rad_s, speed_data_rad_s),
        "speed_mse": mse(speed_sim_rad_s, speed_data_rad_s),
    }


def improvement_factors(reference: dict[str, float], candidate: dict[str, float]) -> dict[str, float | None]:
    """Improvement of ``candidate`` over ``reference``: reference error / candidate error per key.

    A factor of 4 means the candidate's error is four times smaller. When the candidate's error is
    zero the factor is unbounded and written as ``None`` (JSON null), since JSON has no infinity.
    """
    factors: dict[str, float | None] = {}
    for key in METRIC_KEYS:
        ref, cand = float(reference[key]), float(candidate[key])
        if cand > 0.0:
            factors[key] = ref / cand
        elif ref == 0.0:
            factors[key] = 1.0
        else:
            factors[key] = None
    return factors


def interval_mask(time_s: np.ndarray, t_start_s: float, t_end_s: float) -> np.ndarray:
    """Boolean mask (T,) of the samples with ``t_start_s <= time_s <= t_end_s``."""
    time_s = np.asarray(time_s, dtype=float)
    if not t_end_s > t_start_s:
        raise ValueError(f"interval [{t_start_s}, {t_end_s}] s: the end must be after the start")
    mask = (time_s >= t_start_s) & (time_s <= t_end_s)
    if not mask.any():
        raise ValueError(f"interval [{t_start_s}, {t_end_s}] s holds no sample of the time grid "
                         f"[{time_s[0]:.6g}, {time_s[-1]:.6g}] s")
    return mask


def format_error(value: float, unit: str) -> str:
    """Short loss label for legends, e.g. ``MAE 1.23 rad``; three significant digits."""
    if value is None or not math.isfinite(value):
        return f"n/a {unit}"
    return f"{value:.3g} {unit}"


def _pair(simulated: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    simulated = np.asarray(simulated, dtype=float)
    measured = np.asarray(measured, dtype=float)
    if simulated.shape != measured.shape:
        raise ValueError(f"simulated shape {simulated.shape} and measured shape {measured.shape} differ")
    if simulated.size == 0:
        raise ValueError("cannot compute an error over an empty trajectory")
    if not (np.all(np.isfinite(simulated)) and np.all(np.isfinite(measured))):
        raise ValueError("trajectory holds NaN or infinite values")
    return simulated, measured
