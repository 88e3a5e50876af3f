"""The time offset between data and model (paper Fig. 6).

On a short window where the measured target states change fast, the FMU is started from the
measured state at the window's start and driven by the logged inputs; a constant time offset
between the logged inputs and states then shows as a shift between the simulated and the
measured targets. The offset is estimated as the input delay u(t + dt) (the neural FMU's
convention) whose simulation fits the targets best, over sub-sample delays. Targets are compared
normalised by their spread over the maneuver, so signals of different units add up.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.evaluation.zoom import window_samples
from hybridfmu.io import write_json_atomic, write_parquet_atomic
from hybridfmu.model.settings import input_delay_settings

LOG = logging.getLogger(__name__)


#: Without ``evaluation.time_offset.length_s`` / ``max_lag_s``: the window and the largest shift, in grid samples.
WINDOW_SAMPLES, MAX_LAG_SAMPLES = 200, 10


def time_offset_settings(options: dict[str, Any], sample_period_s: float) -> dict[str, Any]:
    """``evaluation.time_offset`` with ``length_s`` and ``max_lag_s`` chosen from the grid where the config leaves
    them out (null): :data:`WINDOW_SAMPLES` and :data:`MAX_LAG_SAMPLES` samples of ``sample_period_s`` (s)."""
    chosen = dict(options or {})
    if chosen.get("length_s") is None:
        chosen["length_s"] = WINDOW_SAMPLES * float(sample_period_s)
    if chosen.get("max_lag_s") is None:
        chosen["max_lag_s"] = MAX_LAG_SAMPLES * float(sample_period_s)
    return chosen


def steepest_window(time_s: np.ndarray, targets: np.ndarray, length_s: float,
                    scales: np.ndarray | None = None) -> tuple[float, float]:
    """Window of ``length_s`` over which the measured targets change most: sum_k |y_k(t_end) - y_k(t_start)| / s_k.

    Args:
        time_s: uniform time grid (T,), s.
        targets: measured target signals (T, n_t) or (T,), model units.
        length_s: window length, s.
        scales: (n_t,) spreads the changes are divided by (default: each target's std over ``targets``).

    Returns:
        (t_start_s, t_end_s).
    """
    n = window_samples(time_s, length_s)
    values = np.asarray(targets, dtype=float).reshape(np.shape(targets)[0], -1)
    scales = normalising_scales(values) if scales is None else np.asarray(scales, dtype=float)
    change = (np.abs(values[n:] - values[:-n]) / scales).sum(axis=1)
    k = int(np.argmax(change))
    return float(time_s[k]), float(time_s[k + n])


def normalising_scales(values: np.ndarray) -> np.ndarray:
    """(n_t,) spread (std) of each column of ``values`` (T, n_t); 1 where a column is constant."""
    spread = np.asarray(values, dtype=float).std(axis=0)
    return np.where(spread > 0, spread, 1.0)


def shift_inputs(u: np.ndarray, delay_s: float | np.ndarray, step_s: float) -> np.ndarray:
    """Inputs seen with an input delay: row k = u(t_k + h/2 + delay_s), each sample j placed at the centre
    t_j + h/2 of the step it is held over, linear between samples, held beyond the ends.

    With ``delay_s = 0`` the sequence is returned unchanged; with a whole number of steps it is shifted by
    whole rows. Args: u (T, n_u); delay_s (s): one value, or (n_u,) one per input column; step_s (h) in s.
    Returns (T, n_u).
    """
    u = np.asarray(u, dtype=float)
    delays = np.broadcast_to(np.asarray(delay_s, dtype=float), (u.shape[1],))
    position = np.arange(u.shape[0])[:, None] + delays[None, :] / step_s  # (T, n_u)
    lower = np.floor(position).astype(int)
    fraction = position - lower
    last = u.shape[0] - 1
    columns = np.arange(u.shape[1])[None, :]
    return ((1.0 - fraction) * u[np.clip(lower, 0, last), columns]
            + fraction * u[np.clip(lower + 1, 0, last), columns])


def estimate_input_delay_s(simulate, measured: np.ndarray, candidates_s: np.ndarray,
                           scales: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The input delay whose simulation fits the measurement best (least squares), among ``candidates_s``.

    Args:
        simulate: callable delay_s -> simulated targets, same shape as ``measured``.
        measured: the measured targets (T,) or (T, n_t).
        candidates_s: the delays to try (s); ties go to the smallest magnitude.
        scales: (n_t,) the targets' spreads; the cost is sum_k mean((sim_k - data_k)^2) / s_k^2 (default 1).

    Returns:
        (best delay in s, its simulated targets).
    """
    measured = np.asarray(measured, dtype=float)
    weights = 1.0 if scales is None else 1.0 / np.asarray(scales, dtype=float) ** 2
    best = (np.inf, 0.0, None)
    for delay_s in sorted(np.asarray(candidates_s, dtype=float), key=abs):
        simulated = simulate(float(delay_s))
        squared = ((simulated - measured) ** 2).reshape(measured.shape[0], -1).mean(axis=0)
        cost = float(np.sum(squared * weights))
        if cost < best[0]:
            best = (cost, float(delay_s), simulated)
    return best[1], best[2]


def run_time_offset(fmu_path: str | Path, calibration_path: str | Path | None, data_path: str | Path,
                    window_path: str | Path, summary_path: str | Path, options: dict[str, Any], roles: Any,
                    maneuvers: dict[str, Any] | None, maneuver: str, resolution: int = 20,
                    delay_config: dict[str, Any] | None = None) -> dict[str, Any]:
    """Simulate the calibrated FMU on the time-offset window and estimate the input delay (rule ``time_offset``).

    The FMU starts from the measured state at the window's start (unmeasured states: the FMU's baseline
    from the calibrated initial values) and is driven by the logged inputs, as logged (no delay) and with
    every candidate input delay u(t + dt) (grid of ``step / resolution`` within ``±max_lag_s``); the delay
    whose normalised target states fit the data best is the estimate.

    Then every group of inputs of ``delay_config`` gets its own estimate over many short windows
    (:mod:`hybridfmu.evaluation.group_offset`), searched within the delay's bounds: the start of the
    learned delays when ``model.input_delay.init_s`` is ``time_offset``.

    Args:
        options: config ``evaluation.time_offset`` (``length_s``, ``t_start_s`` or None, ``max_lag_s``,
            ``groups``: ``window_samples``, ``windows``).
        roles: :class:`hybridfmu.data.roles.CaseRoles`; maneuvers: config ``maneuvers``; maneuver: its name.
        delay_config: config ``model.input_delay`` (``groups``, ``min_s``, ``max_s``); None: one group of all
            inputs within ``±max_lag_s``.

    Writes ``window_path`` (Parquet: ``time_s`` and, per target signal, ``data_<signal>``, ``fmu_<signal>``,
    ``fmu_delayed_<signal>`` (with the estimated delay)) and ``summary_path`` (JSON: maneuver, window,
    ``signals``, ``scales`` (the normalising spreads), ``input_delay_s``, ``mse_without_delay`` and
    ``mse_with_delay`` per target signal, ``cost_without_delay`` / ``cost_with_delay`` (normalised), and
    ``groups``: {group: {inputs, delay_s, windows, window_samples, identified, cost_without_delay,
    cost_with_delay}}). Returns the summary.
    """
    from hybridfmu.evaluation.baseline import simulate_fmu_open_loop
    from hybridfmu.training.measured import initial_state, load_calibrated_fmu, load_calibration, read_measured

    calibration = load_calibration(calibration_path)
    with load_calibrated_fmu(fmu_path, calibration) as model:
        state_names = list(model.state_names)
        measured = read_measured(data_path, roles)
        time_s, u = measured.time_s, measured.u
        step_s = float(np.median(np.diff(time_s)))
        window = time_offset_settings(options, step_s)
        length_s, max_lag_s = float(window["length_s"]), float(window["max_lag_s"])
        signals = measured.target_signals
        target_index = [state_names.index(name) for name in measured.target_states]
        scales = normalising_scales(measured.targets)
        if options.get("t_start_s") is None:
            t_start_s, t_end_s = steepest_window(time_s, measured.targets, length_s, scales)
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
        x_start = measured.x[first].copy()
        if roles.unmeasured_states:  # the unmeasured states where the baseline from the calibration has them
            x0 = initial_state(model, measured.x[0], roles, calibration, maneuver, maneuvers)
            baseline = simulate_fmu_open_loop(model, time_s[:first + 1], u[:first + 1], x0,
                                              label=f"{maneuver} up to the time-offset window")[0]
            x_start = np.where(np.isfinite(x_start), x_start, baseline[-1])
        t = time_s[first:last]
        data = measured.targets[first:last]

        margin = int(np.ceil(max_lag_s / step_s)) + 2
        lo, hi = max(first - margin, 0), min(last + margin, time_s.size)
        u_near = u[lo:hi]  # the samples a shifted window can read (ends held as in the whole maneuver)

        def simulate(delay_s: float) -> np.ndarray:
            shifted = shift_inputs(u_near, delay_s, step_s)[first - lo:last - lo]
            return simulate_fmu_open_loop(model, t, shifted, x_start, label=f"{maneuver} time-offset window")[0]

        plain = simulate(0.0)[:, target_index]
        fine_s = step_s / resolution
        count = int(np.floor(max_lag_s / fine_s))
        delay_s, delayed = estimate_input_delay_s(lambda d: simulate(d)[:, target_index], data,
                                                  np.arange(-count, count + 1) * fine_s, scales)
        groups = _group_estimates(model, measured, roles, calibration, maneuver, maneuvers, options,
                                  delay_config, max_lag_s, fine_s, step_s)
    columns: dict[str, np.ndarray] = {"time_s": t}
    for k, signal in enumerate(signals):
        columns.update({f"data_{signal}": data[:, k], f"fmu_{signal}": plain[:, k],
                        f"fmu_delayed_{signal}": delayed[:, k]})
    write_parquet_atomic(window_path, pd.DataFrame(columns))
    mse_plain = ((plain - data) ** 2).mean(axis=0)
    mse_delayed = ((delayed - data) ** 2).mean(axis=0)
    summary = {"maneuver": maneuver, "t_start_s": float(t[0]), "t_end_s": float(t[-1]), "window": how,
               "signals": list(signals), "scales": dict(zip(signals, scales.tolist())),
               "input_delay_s": delay_s, "max_lag_s": max_lag_s,
               "mse_without_delay": dict(zip(signals, mse_plain.tolist())),
               "mse_with_delay": dict(zip(signals, mse_delayed.tolist())),
               "cost_without_delay": float(np.sum(mse_plain / scales ** 2)),
               "cost_with_delay": float(np.sum(mse_delayed / scales ** 2)),
               "groups": groups,
               "convention": "the FMU sees the logged inputs as u(t + input_delay_s), as the neural FMU's delay"}
    chosen = [f"evaluation.time_offset.{key} = {window[key] * 1e3:.4g} ms: {count} samples of the grid"
              for key, count in (("length_s", WINDOW_SAMPLES), ("max_lag_s", MAX_LAG_SAMPLES))
              if options.get(key) is None]
    if chosen:
        summary["chosen_from_data"] = chosen
    write_json_atomic(summary_path, summary)
    LOG.info("%s: time-offset window %.4f-%.4f s, estimated input delay %.3g s", maneuver, t[0], t[-1], delay_s)
    return summary


def _group_estimates(model: Any, measured: Any, roles: Any, calibration: Any, maneuver: str,
                     maneuvers: dict[str, Any] | None, options: dict[str, Any], delay_config: dict[str, Any] | None,
                     max_lag_s: float, fine_s: float, step_s: float) -> dict[str, Any]:
    """Each input group's delay over many short windows (``group_offset``) of the calibrated FMU ``model``:
    {group: {inputs, delay_s, ...}}; unmeasured states from the FMU's open loop from the calibrated start."""
    from hybridfmu.evaluation.baseline import simulate_fmu_open_loop
    from hybridfmu.training.measured import initial_state

    def simulate(time_s: np.ndarray, u: np.ndarray, x0: np.ndarray, label: str) -> np.ndarray:
        return simulate_fmu_open_loop(model, time_s, u, x0, label=label)[0]

    x = measured.x.copy()
    if roles.unmeasured_states:  # unmeasured states from the FMU's open loop from the calibrated start
        x0 = initial_state(model, measured.x[0], roles, calibration, maneuver, maneuvers)
        x = np.where(np.isfinite(x), x, simulate(measured.time_s, measured.u, x0, f"{maneuver} baseline"))
    return group_estimates(simulate, measured, x, roles, maneuver, options, delay_config, max_lag_s, fine_s, step_s)


def group_estimates(simulate: Any, measured: Any, x: np.ndarray, roles: Any, maneuver: str,
                    options: dict[str, Any], delay_config: dict[str, Any] | None, max_lag_s: float, fine_s: float,
                    step_s: float) -> dict[str, Any]:
    """Each input group's delay over many short windows (``group_offset``) of any model.

    Args:
        simulate: ``(time_s (W,), u (W, n_u), x0 (n_x,), label) -> states (W, n_x)``, the model's open loop with
            the inputs held between samples.
        measured: the maneuver (``training.measured.read_measured``); x: (T, n_x) its states with the
            unmeasured ones filled in (the windows start from them).
        options: config ``evaluation.time_offset``; delay_config: config ``model.input_delay``.
        max_lag_s: range without ``delay_config``; fine_s: grid step of the candidates; step_s: sampling period.

    Returns:
        {group: {inputs, delay_s, windows, window_samples, lead_samples, gains, identified, improvement,
        not_identified_because, cost_without_delay, cost_with_delay, standard_error_s (bootstrap over the
        windows; None for a group not identified), bootstrap_on_edge}} (``delay_s`` fixed, ``note``, when the
        delay's range is empty).
    """
    from hybridfmu.evaluation.group_offset import estimate_group_delays

    settings = dict(options.get("groups") or {})
    window_samples = int(settings.get("window_samples", 4))
    windows = int(settings.get("windows", 100))
    lead_samples = int(settings.get("lead_samples", 2))
    min_improvement = float(settings.get("min_improvement", 0.05))
    bootstrap_samples = int(settings.get("bootstrap_samples", 200))
    seed = int(settings.get("seed", 0))
    input_names = list(roles.input_names)
    configured = dict((delay_config or {}).get("groups") or {})
    groups = ({name: [input_names.index(i) for i in inputs] for name, inputs in configured.items()}
              if configured else {"inputs": list(range(len(input_names)))})
    bounds = input_delay_settings(delay_config, step_s) if delay_config else {"min_s": -max_lag_s, "max_s": max_lag_s}
    low_s, high_s = float(bounds["min_s"]), float(bounds["max_s"])
    if not high_s > low_s:
        return {name: {"inputs": [input_names[c] for c in columns], "delay_s": low_s, "windows": 0,
                       "cost_without_delay": None, "cost_with_delay": None, "note": "the delay is fixed"}
                for name, columns in groups.items()}
    # candidates strictly inside the delay's bounds (a learned delay starts inside them)
    candidates = np.arange(np.ceil(low_s / fine_s + 1e-9), np.floor(high_s / fine_s - 1e-9) + 1) * fine_s
    candidates = candidates[(candidates > low_s) & (candidates < high_s)]
    measured_index = [list(roles.state_names).index(name) for name in roles.measured_states]
    spread = normalising_scales(measured.x[:, measured_index])
    margin = int(np.ceil(max(abs(low_s), abs(high_s)) / step_s)) + 2

    def simulate_window(start: int, delays_s: np.ndarray) -> np.ndarray:
        lo, hi = start - margin, start + window_samples + 1 + margin
        shifted = shift_inputs(measured.u[lo:hi], delays_s, step_s)[margin:margin + window_samples + 1]
        states = simulate(measured.time_s[start:start + window_samples + 1], shifted, x[start].copy(),
                          f"{maneuver} time-offset window at sample {start}")
        first = measured.x[start, measured_index]
        data = measured.x[start + 1:start + window_samples + 1][:, measured_index]
        return (states[1:, measured_index] - first) / spread, (data - first) / spread

    estimate = estimate_group_delays(simulate_window, measured.u, groups, window_samples, windows, candidates,
                                     margin, lead_samples, min_improvement, bootstrap_samples, seed)
    return {name: {"inputs": [input_names[c] for c in columns], "delay_s": estimate.delays_s[name],
                   "windows": estimate.windows[name], "window_samples": window_samples,
                   "lead_samples": lead_samples,
                   "gains": dict(zip(roles.measured_states, estimate.gains[name])),
                   "identified": estimate.identified[name], "improvement": estimate.improvement[name],
                   "not_identified_because": estimate.reasons.get(name),
                   "cost_without_delay": estimate.cost_without_delay[name],
                   "cost_with_delay": estimate.cost_with_delay[name],
                   "standard_error_s": estimate.standard_errors_s.get(name),
                   "bootstrap_on_edge": estimate.bootstrap_on_edge.get(name)}
            for name, columns in groups.items()}
