"""The ceiling of the emulated case: the bench's own true plant, open loop from the logged duties.

Every model of the workflow is simulated open loop from the measured initial state with the logged inputs, and
judged against the logged measurements. The best any model can do in that test is what the true plant itself
does in it: the bench's motor, hydraulics, supply and effects (no sensor noise inside the model), started from
the same measured state, driven by the duties the log recorded (re-aligned by the bench's own channel offset),
and compared with the same noisy, quantised, lagging measurements. Its error is the floor of every model's
error in these metrics; a model may slip out of step where even the true plant does.

Evaluation only: the rule that writes it feeds the evaluation, never training, selection or diagnosis.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from hybridfmu.data.readers import read_mdf
from hybridfmu.evaluation.closed_loop import closed_loop_settings, make_controller
from hybridfmu.io import write_parquet_atomic
from .plant import Plant
from .settings import BenchSettings, parse_bench_settings

LOGGER = logging.getLogger("hybridfmu_bench")

#: The logged duty channels of phases a, b, c (%, the duty applied from t logged at t + the channel offset).
DUTY_CHANNELS = ("MotCtl_DutyA", "MotCtl_DutyB", "MotCtl_DutyC")

#: The plant's states, named like the FMU's states they stand for.
STATE_NAMES = ("i_d", "i_q", "theta", "omega")


def applied_duties(raw_path: str | Path, settings: BenchSettings) -> tuple[int, np.ndarray]:
    """The duties the inverter applied, per PWM period, from a bench log.

    Returns:
        (k_first, duties): the period index of the first logged duty and (N, 3) duties (0..1) of the periods
        k_first, k_first + 1, ... (period k spans [k T, (k + 1) T), T the PWM period).
    Raises:
        ValueError: the duty channels are not one sample per period (naming the file and channel).
    """
    channels = read_mdf(Path(raw_path), list(DUTY_CHANNELS))
    period_s = settings.period_s
    stamps = np.asarray(channels[DUTY_CHANNELS[0]].time_s, dtype=float)
    index = np.rint((stamps - settings.duty_log_offset_s()) / period_s).astype(np.int64)
    if index.size < 2 or np.any(np.diff(index) != 1):
        raise ValueError(f"{raw_path}: channel {DUTY_CHANNELS[0]} is not one sample per PWM period of "
                         f"{period_s:.6g} s; expected a log written by the bench emulator")
    duties = np.column_stack([np.asarray(channels[name].values, dtype=float) / 100.0 for name in DUTY_CHANNELS])
    if duties.shape[0] != index.size:
        raise ValueError(f"{raw_path}: the duty channels {list(DUTY_CHANNELS)} have different lengths")
    return int(index[0]), duties


def grid_start_s(raw_path: str | Path, channels: list[str], t_start_s: float | None = None) -> float:
    """Absolute log time (s) of the ingested grid's first sample: the latest first sample of ``channels`` (and
    the log's first sample + ``t_start_s`` when the maneuver is a slice), as the ingestion chooses it."""
    raw = read_mdf(Path(raw_path), list(channels))
    firsts = [float(channel.time_s[0]) for channel in raw.values() if len(channel.time_s)]
    start = max(firsts)
    if t_start_s is not None:
        start = max(start, min(firsts) + float(t_start_s))
    return start


def started_plant(settings: BenchSettings, period_s: float, x0: Mapping[str, float]) -> Plant:
    """The bench's true plant with PWM period ``period_s`` (s), started from ``x0`` by :data:`STATE_NAMES` (A, A,
    rad, rad/s; a missing state at 0, the angle at the rest angle, clipped to the end stops)."""
    plant = Plant(settings.true_parameters, settings.true_curve(), settings.effects, settings.supply, period_s,
                  settings.substeps, settings.rest_angle_rad)
    theta_min, theta_max = float(settings.true_parameters["theta_min"]), float(settings.true_parameters["theta_max"])
    plant.i_d, plant.i_q = float(x0.get("i_d", 0.0)), float(x0.get("i_q", 0.0))
    plant.theta = min(max(float(x0.get("theta", settings.rest_angle_rad)), theta_min), theta_max)
    plant.omega = float(x0.get("omega", 0.0))
    return plant


def true_plant_open_loop(settings: BenchSettings, k_first: int, duties: np.ndarray, start_s: float,
                         time_s: np.ndarray, x0: Mapping[str, float]) -> np.ndarray:
    """The true plant open loop from ``x0`` at absolute time ``start_s`` over the grid ``time_s``.

    Args:
        settings: the bench's settings (true parameters, hydraulics, supply, effects).
        k_first, duties: the applied duties per PWM period (:func:`applied_duties`).
        start_s: absolute time (s) of the grid's first sample.
        time_s: (T,) grid relative to ``start_s`` (s).
        x0: initial state by :data:`STATE_NAMES` (A, A, rad, rad/s); a missing one starts at 0.

    Returns:
        (T, 4) states in :data:`STATE_NAMES` order at ``start_s + time_s``, interpolated linearly between the PWM
        instants (as the ingestion interpolates the logged angle).
    """
    period_s = settings.period_s
    plant = started_plant(settings, period_s, x0)
    end_s = start_s + float(time_s[-1])
    k = int(math.floor(start_s / period_s + 1e-9))
    k_last = int(math.ceil(end_s / period_s - 1e-9))
    times = [start_s]
    states = [(plant.i_d, plant.i_q, plant.theta, plant.omega)]
    t = start_s
    n_duties = duties.shape[0]
    while k < k_last:
        row = min(max(k - k_first, 0), n_duties - 1)  # before the first / after the last logged duty: held
        d_a, d_b, d_c = duties[row]
        t_next = (k + 1) * period_s
        if t_next - t > 1e-12:
            plant.advance(d_a, d_b, d_c, t, None if abs(t_next - t - period_s) < 1e-12 else t_next - t)
            times.append(t_next)
            states.append((plant.i_d, plant.i_q, plant.theta, plant.omega))
        t = t_next
        k += 1
    times_abs = np.asarray(times)
    states_arr = np.asarray(states)
    query = start_s + np.asarray(time_s, dtype=float)
    return np.column_stack([np.interp(query, times_abs, states_arr[:, i]) for i in range(len(STATE_NAMES))])


def true_plant_closed_loop(settings: BenchSettings, controller: Any, start_s: float, period_s: float,
                           x0: Mapping[str, float], first_duties: np.ndarray, signals: Mapping[str, np.ndarray],
                           outputs: Mapping[str, str]) -> np.ndarray:
    """The true plant driven by the case's controller from ``x0``, as the closed-loop evaluation drives the models.

    Per grid sample k (absolute time ``start_s + k period_s``): the controller reads the plant's states and the
    logged ``signals`` at sample k; the plant advances one period with the controller's outputs of the sample
    before (the logged ``first_duties`` at sample 0). The plant's own hydraulics and supply act (no logged load).

    Args:
        settings: the bench's settings; controller: a fresh instance of the case's controller.
        start_s: absolute time (s) of the grid's first sample; period_s: the grid's sample period (s).
        x0: initial state by :data:`STATE_NAMES`; first_duties: (3,) the logged duties (0..1) at sample 0.
        signals: the controller's signal name -> (T,) logged values (model units).
        outputs: the controller's output name -> FMU input (``d_a``, ``d_b``, ``d_c``).

    Returns:
        (T, 4) states in :data:`STATE_NAMES` order on the grid.
    """
    if sorted(outputs.values()) != ["d_a", "d_b", "d_c"]:
        raise ValueError(f"config.closed_loop.outputs: the bench's plant takes the duties d_a, d_b, d_c from a "
                         f"controller, got {sorted(outputs.values())}")
    plant = started_plant(settings, period_s, x0)
    n = len(next(iter(signals.values())))
    rows = [dict(zip(signals, values)) for values in zip(*(np.asarray(v, dtype=float).tolist()
                                                          for v in signals.values()))]
    by_input = {name: output for output, name in outputs.items()}
    applied = [float(value) for value in first_duties]
    states = np.empty((n, len(STATE_NAMES)))
    controller.reset(dict(zip(STATE_NAMES, (plant.i_d, plant.i_q, plant.theta, plant.omega))), rows[0])
    for k in range(n):
        x = (plant.i_d, plant.i_q, plant.theta, plant.omega)
        states[k] = x
        if k == n - 1:
            break
        command = controller.step(dict(zip(STATE_NAMES, x)), rows[k])
        plant.advance(applied[0], applied[1], applied[2], start_s + k * period_s)
        applied = [float(command[by_input[name]]) for name in ("d_a", "d_b", "d_c")]
    return states


def write_ceiling(config: Mapping[str, Any], maneuver: str, raw_path: str | Path, data_path: str | Path,
                  roles: Any, output_path: str | Path, window_length_s: float | None = None) -> pd.DataFrame:
    """Simulate the true plant over an ingested maneuver and write its trajectory.

    Args:
        config: the case config (sections ``bench``, ``seed``, ``fmu``, ``signals``, ``maneuvers``).
        maneuver: the maneuver's name; raw_path, data_path: its bench log and its ingested frame.
        roles: :class:`hybridfmu.data.roles.CaseRoles` (which signal measures which state, the target signals).
        output_path: Parquet with ``time_s``, ``ceiling_state_<state>`` for each plant state,
            ``ceiling_<signal>`` for each target signal (model units) and ``windowed_ceiling_<signal>``: the same
            over the evaluation's windows, each started from the measured state
            (:mod:`hybridfmu.training.multiple_shooting`); with ``config.closed_loop``, also
            ``closed_loop_ceiling_<signal>``: the true plant driven by the case's controller
            (:func:`true_plant_closed_loop`).
        window_length_s: config ``evaluation.windows.length_s`` (None: chosen as the evaluation chooses it).
    """
    from hybridfmu.training.multiple_shooting import window_samples, windowed_trajectory

    settings = parse_bench_settings(config)
    frame = pd.read_parquet(data_path)
    time_s = frame["time_s"].to_numpy(dtype=float)
    channels = sorted({signal["channel"] for signal in config["signals"].values()})
    start_s = grid_start_s(raw_path, channels, (config["maneuvers"].get(maneuver) or {}).get("t_start_s"))
    measured = np.column_stack([frame[roles.states[state]].to_numpy(dtype=float) if state in roles.states
                                else np.full(time_s.size, np.nan) for state in STATE_NAMES])
    x0 = {state: float(measured[0, i]) for i, state in enumerate(STATE_NAMES) if state in roles.states}
    k_first, duties = applied_duties(raw_path, settings)
    wall = time.perf_counter()
    states = true_plant_open_loop(settings, k_first, duties, start_s, time_s, x0)

    def window(t: np.ndarray, _u: np.ndarray, x: np.ndarray) -> np.ndarray:
        return true_plant_open_loop(settings, k_first, duties, start_s + float(t[0]), t - t[0],
                                    dict(zip(STATE_NAMES, x)))

    steps = window_samples(window_length_s, float(np.median(np.diff(time_s))), float(time_s[-1] - time_s[0]))
    windowed = windowed_trajectory(window, time_s, np.zeros((time_s.size, 0)),
                                   np.where(np.isnan(measured), states, measured), steps)
    columns: dict[str, np.ndarray] = {"time_s": time_s}
    for i, name in enumerate(STATE_NAMES):
        columns[f"ceiling_state_{name}"] = states[:, i]
    for state, signal in zip(roles.target_states, roles.target_signals):
        if state not in STATE_NAMES:
            raise ValueError(f"config.roles.targets: state {state!r} is not a state of the bench's plant "
                             f"{list(STATE_NAMES)}")
        columns[f"ceiling_{signal}"] = states[:, STATE_NAMES.index(state)]
        columns[f"windowed_ceiling_{signal}"] = windowed[:, STATE_NAMES.index(state)]
    closed_loop = closed_loop_settings(config, roles)
    if closed_loop is not None:
        period_s = float(np.median(np.diff(time_s)))
        duties = frame[[roles.inputs[name] for name in ("d_a", "d_b", "d_c")]].to_numpy(dtype=float)[0]
        signals = {name: frame[signal].to_numpy(dtype=float) for name, signal in closed_loop.signals.items()}
        closed = true_plant_closed_loop(settings, make_controller(closed_loop, config, period_s), start_s, period_s,
                                        x0, duties, signals, closed_loop.outputs)
        for state, signal in zip(roles.target_states, roles.target_signals):
            columns[f"closed_loop_ceiling_{signal}"] = closed[:, STATE_NAMES.index(state)]
    result = pd.DataFrame(columns)
    write_parquet_atomic(output_path, result)
    errors = ", ".join(f"{signal} MAE {np.mean(np.abs(columns[f'ceiling_{signal}'] - frame[signal])):.4g}"
                       for signal in roles.target_signals)
    LOGGER.info("ceiling %s: the true plant open loop over %.3f s in %.1f s wall (grid start %.6g s in the log); "
                "%s; wrote %s", maneuver, time_s[-1] - time_s[0], time.perf_counter() - wall, start_s, errors,
                output_path)
    return result
