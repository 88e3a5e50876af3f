"""The time offset between data and model (paper Fig. 6).

On a short window where the measured speed changes fast, the FMU is started from the measured
state at the window's start and driven by the logged inputs; a constant time offset between the
logged inputs and states then shows as a shift between the simulated and the measured speed.
The shift is estimated by least squares over sub-sample shifts.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.evaluation.zoom import window_samples
from hybridfmu.io import write_json_atomic, write_parquet_atomic

LOG = logging.getLogger(__name__)


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


def run_time_offset(fmu_path: str | Path, data_path: str | Path, window_path: str | Path,
                    summary_path: str | Path, options: dict[str, Any], fmu_parameters: dict[str, float] | None,
                    signals_config: dict[str, Any] | None, maneuver: str) -> dict[str, Any]:
    """Simulate the FMU on the time-offset window and estimate the offset (rule ``time_offset``).

    The FMU starts from the measured state at the window's start (one sample before it, so the
    first compared sample is already simulated) and is driven by the logged inputs.

    Args:
        options: config ``evaluation.time_offset`` (``length_s``, ``t_start_s`` or None, ``max_lag_s``).

    Writes ``window_path`` (Parquet: ``time_s``, ``data_speed_rad_s``, ``fmu_speed_rad_s``,
    ``data_angle_rad``, ``fmu_angle_rad``) and ``summary_path`` (JSON: maneuver, window, ``lag_s``,
    errors before and after the shift). Returns the summary.
    """
    from hybridfmu.evaluation.baseline import mechanical_states, read_maneuver, simulate_fmu_open_loop
    from hybridfmu.fmu import load_fmu

    length_s = float(options.get("length_s", 0.02))
    max_lag_s = float(options.get("max_lag_s", 1e-3))
    with load_fmu(fmu_path, parameters=dict(fmu_parameters or {})) as model:
        state_names, input_names = list(model.state_names), list(model.input_names)
        time_s, u, x_measured = read_maneuver(data_path, state_names, input_names, signals_config)
        angle_state, speed_state = mechanical_states(signals_config)
        angle_i, speed_i = state_names.index(angle_state), state_names.index(speed_state)
        if options.get("t_start_s") is None:
            t_start_s, t_end_s = steepest_window(time_s, x_measured[:, speed_i], length_s)
            how = "auto"
        else:
            t_start_s, t_end_s = float(options["t_start_s"]), float(options["t_start_s"]) + length_s
            how = "config"
            if t_start_s >= time_s[-1]:
                raise ValueError(f"config.evaluation.time_offset.t_start_s = {t_start_s} s lies beyond the end of "
                                 f"maneuver {maneuver!r} ({time_s[-1]:.6g} s)")
        first = max(int(np.searchsorted(time_s, t_start_s)), 0)
        last = min(int(np.searchsorted(time_s, t_end_s, side="right")), time_s.size)
        if last - first < 3:
            raise ValueError(f"time-offset window [{t_start_s}, {t_end_s}] s of {maneuver!r} holds {last - first} "
                             "samples; at least 3 are needed (config.evaluation.time_offset.length_s)")
        window = slice(first, last)
        states, _ = simulate_fmu_open_loop(model, time_s[window], u[window], x_measured[first],
                                           label=f"{maneuver} time-offset window")
    t = time_s[window]
    data_speed, fmu_speed = x_measured[window, speed_i], states[:, speed_i]
    lag_s = estimate_lag_s(t, data_speed, fmu_speed, max_lag_s)
    shifted = np.interp(t - lag_s, t, fmu_speed)
    valid = (t - lag_s >= t[0]) & (t - lag_s <= t[-1])
    frame = pd.DataFrame({"time_s": t, "data_speed_rad_s": data_speed, "fmu_speed_rad_s": fmu_speed,
                          "data_angle_rad": x_measured[window, angle_i], "fmu_angle_rad": states[:, angle_i]})
    write_parquet_atomic(window_path, frame)
    summary = {"maneuver": maneuver, "t_start_s": float(t[0]), "t_end_s": float(t[-1]), "window": how,
               "lag_s": lag_s, "max_lag_s": max_lag_s,
               "speed_mse_unshifted": float(np.mean((data_speed[valid] - fmu_speed[valid]) ** 2)),
               "speed_mse_shifted": float(np.mean((data_speed[valid] - shifted[valid]) ** 2)),
               "sign": "positive lag_s: the measured speed lags the FMU driven by the logged inputs"}
    write_json_atomic(summary_path, summary)
    LOG.info("%s: time-offset window %.4f-%.4f s, estimated offset %.3g s", maneuver, t[0], t[-1], lag_s)
    return summary
