"""The time offset between data and model (paper Fig. 6).

On a short window where the measured speed changes fast, the FMU is started from the measured
state at the window's start and driven by the logged inputs; a constant time offset between the
logged inputs and states then shows as a shift between the simulated and the measured speed.
The offset is estimated as the input delay u(t + dt) (the neural FMU's convention) whose
simulation fits the measured speed best, over sub-sample delays.
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


def shift_inputs(u: np.ndarray, delay_s: float, step_s: float) -> np.ndarray:
    """Inputs seen with an input delay: row k = u(t_k + h/2 + delay_s), each sample j placed at the centre
    t_j + h/2 of the step it is held over, linear between samples, held beyond the ends.

    With ``delay_s = 0`` the sequence is returned unchanged; with a whole number of steps it is shifted by
    whole rows. Args: u (T, n_u); delay_s and step_s (h) in s. Returns (T, n_u).
    """
    u = np.asarray(u, dtype=float)
    position = np.arange(u.shape[0]) + delay_s / step_s
    lower = np.floor(position).astype(int)
    fraction = (position - lower)[:, None]
    last = u.shape[0] - 1
    return (1.0 - fraction) * u[np.clip(lower, 0, last)] + fraction * u[np.clip(lower + 1, 0, last)]


def estimate_input_delay_s(simulate, measured: np.ndarray, candidates_s: np.ndarray) -> tuple[float, np.ndarray]:
    """The input delay whose simulation fits the measurement best (least squares), among ``candidates_s``.

    Args:
        simulate: callable delay_s -> simulated quantity (T,).
        measured: the measured quantity (T,).
        candidates_s: the delays to try (s); ties go to the smallest magnitude.

    Returns:
        (best delay in s, its simulated quantity (T,)).
    """
    best = (np.inf, 0.0, None)
    for delay_s in sorted(np.asarray(candidates_s, dtype=float), key=abs):
        simulated = simulate(float(delay_s))
        cost = float(np.mean((simulated - measured) ** 2))
        if cost < best[0]:
            best = (cost, float(delay_s), simulated)
    return best[1], best[2]


def run_time_offset(fmu_path: str | Path, data_path: str | Path, window_path: str | Path,
                    summary_path: str | Path, options: dict[str, Any], fmu_parameters: dict[str, float] | None,
                    signals_config: dict[str, Any] | None, maneuver: str, resolution: int = 20) -> dict[str, Any]:
    """Simulate the FMU on the time-offset window and estimate the input delay (rule ``time_offset``).

    The FMU starts from the measured state at the window's start and is driven by the logged inputs,
    as logged (no delay) and with every candidate input delay u(t + dt) (grid of ``step / resolution``
    within ``±max_lag_s``); the delay whose speed fits the data best is the estimate.

    Args:
        options: config ``evaluation.time_offset`` (``length_s``, ``t_start_s`` or None, ``max_lag_s``).

    Writes ``window_path`` (Parquet: ``time_s``, ``data_speed_rad_s``, ``fmu_speed_rad_s``,
    ``fmu_delayed_speed_rad_s`` (with the estimated delay), ``data_angle_rad``, ``fmu_angle_rad``) and
    ``summary_path`` (JSON: maneuver, window, ``input_delay_s``, speed MSE without and with it).
    Returns the summary.
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
        step_s = float(np.median(np.diff(time_s)))
        # inputs from the whole maneuver, so a shifted window reads the samples around it
        t = time_s[first:last]
        data_speed = x_measured[first:last, speed_i]

        margin = int(np.ceil(max_lag_s / step_s)) + 2
        lo, hi = max(first - margin, 0), min(last + margin, time_s.size)
        u_near = u[lo:hi]  # the samples a shifted window can read (ends held as in the whole maneuver)

        def simulate(delay_s: float) -> np.ndarray:
            shifted = shift_inputs(u_near, delay_s, step_s)[first - lo:last - lo]
            return simulate_fmu_open_loop(model, t, shifted, x_measured[first], label=f"{maneuver} time-offset window")[0]

        plain = simulate(0.0)
        fine_s = step_s / resolution
        count = int(np.floor(max_lag_s / fine_s))
        delay_s, _ = estimate_input_delay_s(lambda d: simulate(d)[:, speed_i], data_speed,
                                            np.arange(-count, count + 1) * fine_s)
        delayed = simulate(delay_s)
    frame = pd.DataFrame({"time_s": t, "data_speed_rad_s": data_speed, "fmu_speed_rad_s": plain[:, speed_i],
                          "fmu_delayed_speed_rad_s": delayed[:, speed_i],
                          "data_angle_rad": x_measured[first:last, angle_i], "fmu_angle_rad": plain[:, angle_i]})
    write_parquet_atomic(window_path, frame)
    summary = {"maneuver": maneuver, "t_start_s": float(t[0]), "t_end_s": float(t[-1]), "window": how,
               "input_delay_s": delay_s, "max_lag_s": max_lag_s,
               "speed_mse_without_delay": float(np.mean((data_speed - plain[:, speed_i]) ** 2)),
               "speed_mse_with_delay": float(np.mean((data_speed - delayed[:, speed_i]) ** 2)),
               "convention": "the FMU sees the logged inputs as u(t + input_delay_s), as the neural FMU's delay"}
    write_json_atomic(summary_path, summary)
    LOG.info("%s: time-offset window %.4f-%.4f s, estimated input delay %.3g s", maneuver, t[0], t[-1], delay_s)
    return summary
