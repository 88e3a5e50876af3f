"""Error measures between simulated and measured trajectories, and improvement factors.

Errors are per target signal, in the signal's model unit: ``<signal>_mae`` (unit),
``<signal>_mse`` (unit squared), ``<signal>_rmse`` (unit).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

#: The error measures of each target signal, in the order they are written (``<signal>_<measure>``).
MEASURES = ("mae", "mse", "rmse")


def metric_keys(signals: Sequence[str]) -> list[str]:
    """Keys of a metrics object for the target ``signals``: ``<signal>_<measure>``, signal by signal."""
    return [f"{signal}_{measure}" for signal in signals for measure in MEASURES]


def mae(simulated: np.ndarray, measured: np.ndarray) -> float:
    """Mean absolute error of two arrays of the same shape (T,), in the unit of the inputs."""
    simulated, measured = _pair(simulated, measured)
    return float(np.mean(np.abs(simulated - measured)))


def mse(simulated: np.ndarray, measured: np.ndarray) -> float:
    """Mean squared error of two arrays of the same shape (T,), in the unit of the inputs squared."""
    simulated, measured = _pair(simulated, measured)
    return float(np.mean((simulated - measured) ** 2))


def trajectory_errors(simulated: np.ndarray, measured: np.ndarray, signals: Sequence[str]) -> dict[str, float]:
    """MAE, MSE and RMSE of one simulated trajectory against the data, per target signal.

    Args:
        simulated, measured: (T, n_t) target signals (model units), or (T,) for a single signal.
        signals: (n_t,) names of the target signals (columns).

    Returns:
        ``{"<signal>_mae", "<signal>_mse", "<signal>_rmse", ...}`` in :func:`metric_keys` order.
    """
    simulated = np.asarray(simulated, dtype=float).reshape(np.shape(simulated)[0], -1)
    measured = np.asarray(measured, dtype=float).reshape(np.shape(measured)[0], -1)
    if simulated.shape[1] != len(signals) or measured.shape[1] != len(signals):
        raise ValueError(f"trajectory_errors: {len(signals)} signals {list(signals)} but arrays of shape "
                         f"{simulated.shape} and {measured.shape}")
    errors: dict[str, float] = {}
    for k, signal in enumerate(signals):
        square = mse(simulated[:, k], measured[:, k])
        errors[f"{signal}_mae"] = mae(simulated[:, k], measured[:, k])
        errors[f"{signal}_mse"] = square
        errors[f"{signal}_rmse"] = math.sqrt(square)
    return errors


def windowed_errors(simulated: np.ndarray, measured: np.ndarray, signals: Sequence[str]) -> dict[str, float | None]:
    """MAE, MSE and RMSE per target signal of a windowed trajectory (:mod:`hybridfmu.training.multiple_shooting`)
    over the samples its windows reached (a failed window's samples are NaN), and ``failed_share``: the share of
    samples without a value. Shapes as :func:`trajectory_errors`; errors None when no window succeeded."""
    simulated = np.asarray(simulated, dtype=float).reshape(np.shape(simulated)[0], -1)
    measured = np.asarray(measured, dtype=float).reshape(np.shape(measured)[0], -1)
    reached = np.all(np.isfinite(simulated), axis=1)
    out: dict[str, float | None] = {"failed_share": float(1.0 - np.mean(reached))}
    if not reached.any():
        out.update({key: None for key in metric_keys(signals)})
        return out
    out.update(trajectory_errors(simulated[reached], measured[reached], signals))
    return out


def tolerance_errors(simulated: np.ndarray, measured: np.ndarray, signals: Sequence[str],
                     tolerance: dict[str, float]) -> dict[str, float | int | None]:
    """How long a simulation stays with the measurement, and its errors while it does.

    A sample is *within tolerance* when every signal named in ``tolerance`` is within its tolerance of the
    measurement (|simulated - measured| <= tolerance; e.g. a motor's angle within a quarter of an electrical
    period: in step).

    Args:
        simulated, measured: (T, n_t) target signals (model units).
        signals: (n_t,) their names; tolerance: signal -> tolerance (model unit), a non-empty subset of them.

    Returns:
        ``in_tolerance_share`` (0..1), ``tolerance_exits`` (how often the simulation leaves the tolerance), and per
        signal ``<signal>_mae_in_tolerance`` / ``<signal>_rmse_in_tolerance`` over the samples within (None when
        there is none).
    """
    simulated = np.asarray(simulated, dtype=float).reshape(np.shape(simulated)[0], -1)
    measured = np.asarray(measured, dtype=float).reshape(np.shape(measured)[0], -1)
    unknown = sorted(set(tolerance) - set(signals))
    if unknown or not tolerance:
        raise ValueError(f"tolerance: signal(s) {unknown or '(none)'} are not among the target signals {list(signals)}")
    error = np.abs(simulated - measured)
    within = np.ones(error.shape[0], dtype=bool)
    for signal, bound in tolerance.items():
        within &= error[:, list(signals).index(signal)] <= float(bound)
    out: dict[str, float | int | None] = {"in_tolerance_share": float(np.mean(within)),
                                          "tolerance_exits": int(np.count_nonzero(within[:-1] & ~within[1:]))}
    for k, signal in enumerate(signals):
        inside = error[within, k]
        out[f"{signal}_mae_in_tolerance"] = float(np.mean(inside)) if inside.size else None
        out[f"{signal}_rmse_in_tolerance"] = float(np.sqrt(np.mean(inside ** 2))) if inside.size else None
    return out


def range_tolerance(measured: Sequence[np.ndarray], fraction: float, signal: str = "the signal") -> float:
    """``fraction`` of a signal's range (1st to 99th percentile) over several measured records (each (T,))."""
    values = np.concatenate([np.asarray(m, dtype=float).reshape(-1) for m in measured])
    low, high = np.percentile(values, [1.0, 99.0])
    span = float(high - low)
    if not span > 0.0:
        raise ValueError(f"range_tolerance: {signal} does not vary in the validation maneuvers (1st and 99th "
                         f"percentile equal); name its tolerance in config.evaluation.tolerance.signals")
    return fraction * span


def summary_statistics(values: Sequence[float | None]) -> dict[str, float | int | None]:
    """``{"median", "min", "max", "n"}`` of the finite values among ``values`` (None where there is none)."""
    finite = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not finite:
        return {"median": None, "min": None, "max": None, "n": 0}
    return {"median": float(np.median(finite)), "min": min(finite), "max": max(finite), "n": len(finite)}


def improvement_factors(reference: dict[str, float], candidate: dict[str, float]) -> dict[str, float | None]:
    """Improvement of ``candidate`` over ``reference``: reference error / candidate error per key of ``reference``.

    A factor of 4 means the candidate's error is four times smaller. When the candidate's error is
    zero the factor is unbounded and written as ``None`` (JSON null), since JSON has no infinity.
    """
    factors: dict[str, float | None] = {}
    for key in reference:
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
