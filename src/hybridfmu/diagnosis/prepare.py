"""From ingested maneuvers to the quantities the diagnosis works on.

``maneuver_from_frame`` puts one ingested maneuver (``time_s`` and one column per signal, in the model
unit) and its segments into model-ordered arrays through the case's roles; measured states named
in ``diagnosis.state_from_derivative`` are replaced by the time derivative of another measured state
(e.g. a speed from the angle: an observer's logged speed lags). Unmeasured states are filled from an
open-loop simulation of the calibrated model (``fill_unmeasured``). ``prepare_maneuver`` computes the
equation error, the effect inputs along the data (with the rate of the smoothed logged inputs for
input lags, ``diagnosis.effects.lag_derivative_window_s``), the masks of usable samples (inside segments,
away from configured end stops, not at a configured standstill) and the fitting centres.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.data.signals import held_input_array
from hybridfmu.diagnosis.derivatives import (hann_kernel, interval_means, odd_window, savgol_derivative,
                                             savgol_smooth, white_noise_std)
from hybridfmu.diagnosis.effects import EffectInputs, input_derivative
from hybridfmu.diagnosis.kernel_choice import MIN_KERNEL_SAMPLES, choose_kernel
from hybridfmu.diagnosis.problem import Problem
from hybridfmu.diagnosis.residual import EquationError, equation_error, noise_floor_std
from hybridfmu.diagnosis.selection import ManeuverFitData

LOGGER = logging.getLogger("hybridfmu.diagnosis")


@dataclass
class MeasuredManeuver:
    """One measured maneuver in the model's variable order.

    Attributes:
        name, role: maneuver name and role (train / validation / test).
        time_s: (N,) uniform grid (s).
        x: (N, n_x) states: measured columns from the data, unmeasured ones NaN until filled from a simulation.
        u: (N, n_u) inputs (model units).
        spans_s: informative segments [[t_start_s, t_end_s], ...].
        x0_unmeasured: unmeasured state -> initial value (calibration, else the model's start value).
        source: path of the ingested data (for messages).
    """

    name: str
    role: str
    time_s: np.ndarray
    x: np.ndarray
    u: np.ndarray
    spans_s: list[list[float]]
    x0_unmeasured: dict[str, float] = field(default_factory=dict)
    source: str = ""


def _column(frame: pd.DataFrame, signal: str, path: Path, role: str) -> np.ndarray:
    if signal not in frame.columns:
        raise ValueError(f"{path}: no column {signal!r} (signal of {role}); the ingested data has "
                         f"{list(frame.columns)}")
    return frame[signal].to_numpy(dtype=np.float64)


def frame_arrays(frame: pd.DataFrame, problem: Problem, path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time (N,), x (N, n_x) with NaN for unmeasured states, u (N, n_u)) of an ingested frame via the roles; u as
    every simulation holds it (:func:`hybridfmu.data.signals.held_input_array`)."""
    time_s = _column(frame, "time_s", path, "time")
    x = np.full((len(time_s), problem.n_x), np.nan)
    for i in problem.measured:
        name = problem.state_names[i]
        x[:, i] = _column(frame, problem.state_signal[name], path, f"state {name}")
    signals = [problem.input_signal[name] for name in problem.input_names]
    for name, signal in zip(problem.input_names, signals):
        _column(frame, signal, path, f"input {name}")
    u = held_input_array(frame, problem.input_names, signals).reshape(len(time_s), problem.n_u)
    return time_s, x, u


def maneuver_from_frame(name: str, role: str, frame: pd.DataFrame, spans_s: list[list[float]] | None,
                        problem: Problem, x0_unmeasured: dict[str, float] | None = None,
                        source: str | Path = "") -> MeasuredManeuver:
    """An ingested maneuver's frame (``time_s`` (s) and one column per signal in its model unit, as
    :func:`hybridfmu.data.ingest.ingest_log` returns it) in model-ordered arrays.

    Args:
        spans_s: the informative segments [[t_start_s, t_end_s], ...] (s); None: the whole record.
        x0_unmeasured: unmeasured state -> initial value.
        source: where the frame comes from, for messages (a file, or a name).

    Raises:
        ValueError: a column is missing or holds non-finite values (names ``source``).
    """
    where = Path(str(source or f"maneuver {name}"))
    time_s, x, u = frame_arrays(frame, problem, where)
    settings = problem.settings
    for state, derived_from in (settings.get("state_from_derivative") or {}).items():
        x[:, problem.state_names.index(state)] = np.gradient(x[:, problem.state_names.index(derived_from)], time_s)
    dt_s = float(np.median(np.diff(time_s)))
    for input_name, lag_s in (settings.get("input_lag_compensation_s") or {}).items():
        if lag_s > 0:
            j = problem.input_names.index(input_name)
            window = odd_window(float(settings.get("lag_compensation_window_s") or 5 * dt_s), dt_s, minimum=5)
            u[:, j] = savgol_smooth(u[:, j], window) + float(lag_s) * savgol_derivative(u[:, j], dt_s, window)
    for what, values in (("inputs", u), ("measured states", x[:, problem.measured])):
        bad = ~np.isfinite(values)
        if bad.any():
            raise ValueError(f"{where}: non-finite {what} at {int(bad.any(axis=1).sum())} samples")
    spans = spans_s if spans_s is not None else [[float(time_s[0]), float(time_s[-1])]]
    return MeasuredManeuver(name=name, role=role, time_s=time_s, x=x, u=u, spans_s=[list(s) for s in spans],
                            x0_unmeasured=dict(x0_unmeasured or {}), source=str(where))


def smoothing_samples(problem: Problem, dt_s: float) -> int:
    """Savitzky-Golay window (odd, samples) of the low-noise states: ``diagnosis.smoothing_s``, else half the kernel
    (at least 5 samples); 5 samples while the kernel is still to be chosen from the data (the unmeasured states are
    filled before, :func:`choose_kernel_from_data`)."""
    smoothing_s = problem.settings.get("smoothing_s")
    if smoothing_s:
        return odd_window(float(smoothing_s), dt_s, minimum=5)
    if not problem.settings.get("kernel_s"):
        return 5
    return odd_window(max(kernel_samples(problem, dt_s) // 2, 5) * dt_s, dt_s, minimum=5)


def start_states(meas: MeasuredManeuver, problem: Problem) -> np.ndarray:
    """Low-noise states (N, n_x) to start simulations from: measured states smoothed, unmeasured ones
    as filled (or their initial values in the first row when not yet filled)."""
    states = np.array(meas.x, dtype=float)
    dt_s = float(np.median(np.diff(meas.time_s)))
    measured = problem.measured
    states[:, measured] = savgol_smooth(states[:, measured], smoothing_samples(problem, dt_s))
    for name, value in meas.x0_unmeasured.items():
        i = problem.state_names.index(name)
        if not np.isfinite(states[0, i]):
            states[0, i] = value
    return states


def fill_unmeasured(meas: MeasuredManeuver, problem: Problem, model: Any, simulate_fn: Any) -> None:
    """Unmeasured states of ``meas`` from an open-loop simulation of the (calibrated) model, in place.

    The simulation starts from the smoothed measured states and the unmeasured initial values of the
    calibration; it is the model's own prediction of what cannot be measured (stated in the report).
    """
    if not problem.unmeasured:
        return
    from hybridfmu.diagnosis.corrected_model import simulate

    starts = start_states(meas, problem)
    states = simulate(model, simulate_fn, meas.time_s, meas.u, starts[0], None)
    if not np.all(np.isfinite(states[:, problem.unmeasured])):
        raise ValueError(f"{meas.source}: the open-loop simulation of the unmeasured states "
                         f"{[problem.state_names[i] for i in problem.unmeasured]} failed or diverged")
    meas.x[:, problem.unmeasured] = states[:, problem.unmeasured]


@dataclass
class PreparedManeuver:
    """A maneuver ready for the diagnosis (M = N-1 intervals).

    Attributes:
        measured: the measured maneuver.
        error: equation error.
        inputs: effect inputs along the data.
        masks: name -> (M,) bool: ``in_segment``, ``near_stop``, ``standstill``, ``usable``.
        fit: the fitting data (centres, target, noise).
        noise_floor: (n_x,) predicted noise std of the kernel-averaged equation error.
        residual_filtered: (M, n_x) kernel-averaged equation error (NaN near the ends).
        rate_filtered: (M, n_x) kernel-averaged measured derivative.
        starts: (N, n_x) low-noise states to start simulations from (``start_states``).
    """

    measured: MeasuredManeuver
    error: EquationError
    inputs: EffectInputs
    masks: dict[str, np.ndarray]
    fit: ManeuverFitData
    noise_floor: np.ndarray
    residual_filtered: np.ndarray
    rate_filtered: np.ndarray
    starts: np.ndarray | None = None


def kernel_samples(problem: Problem, dt_s: float) -> int:
    """Length (odd, samples) of the Hann kernel: ``diagnosis.kernel_s``, else the shortest length of
    :mod:`hybridfmu.diagnosis.kernel_choice` (:func:`choose_kernel_from_data` sets ``kernel_s`` before any
    maneuver is prepared)."""
    kernel_s = problem.settings.get("kernel_s")
    return odd_window(float(kernel_s), dt_s) if kernel_s else MIN_KERNEL_SAMPLES


def maneuver_error(meas: MeasuredManeuver, model: Any, problem: Problem, kernel_n: int) -> EquationError:
    """The equation error of one maneuver (unmeasured states filled) with a kernel of ``kernel_n`` samples."""
    one_step = [problem.state_names.index(n) for n in problem.settings.get("one_step_states") or []]
    in_span = _span_mask(meas.time_s, meas.spans_s)
    return equation_error(model, meas.time_s, meas.x, meas.u, kernel_n, maneuver=meas.name, noise_mask=in_span,
                          one_step_states=one_step)


def choose_kernel_from_data(measured: list[MeasuredManeuver], model: Any,
                            problem: Problem) -> dict[str, EquationError]:
    """Choose the kernel length from the model's fastest time scale along the fitting maneuvers ``measured`` when
    ``diagnosis.kernel_s`` is null (:func:`hybridfmu.diagnosis.kernel_choice.choose_kernel`): sets
    ``problem.settings["kernel_s"]`` and ``problem.kernel_choice``. Returns the equation errors computed for it
    (maneuver name -> error, with the chosen kernel), for :func:`prepare_maneuver` to reuse; empty when the config
    sets the kernel."""
    if problem.settings.get("kernel_s"):
        return {}
    dt_s = float(np.median(np.diff(measured[0].time_s)))
    errors = {meas.name: maneuver_error(meas, model, problem, MIN_KERNEL_SAMPLES) for meas in measured}
    inside = [_span_mask(errors[meas.name].time_s, meas.spans_s) for meas in measured]
    spans = [end - start for meas in measured for start, end in meas.spans_s] or \
        [float(meas.time_s[-1] - meas.time_s[0]) for meas in measured]
    choice = choose_kernel([errors[meas.name].dfdx for meas in measured], inside, problem.equations, dt_s,
                           float(np.median(spans)) / dt_s)
    problem.settings["kernel_s"] = choice.kernel_s
    problem.kernel_choice = choice.record()
    LOGGER.info("kernel from the model's time scale: %d samples (%.4g s): %s", choice.samples, choice.kernel_s,
                choice.reason)
    for error in errors.values():
        error.kernel = hann_kernel(choice.samples)
    return errors


def _blocks(time_s: np.ndarray, spans_s: list[list[float]], block_s: float) -> np.ndarray:
    """(M,) id of the bootstrap block (a piece of at most ``block_s`` of a segment) of each sample; -1 outside."""
    ids = np.full(len(time_s), -1)
    next_id = 0
    for start, end in spans_s:
        inside = (time_s >= start) & (time_s <= end)
        if not inside.any():
            continue
        n_blocks = max(int(np.ceil((end - start) / block_s)), 1)
        edges = np.linspace(start, end, n_blocks + 1)
        ids[inside] = next_id + np.clip(np.searchsorted(edges, time_s[inside], side="right") - 1, 0, n_blocks - 1)
        next_id += n_blocks
    return ids


def input_rates(u: np.ndarray, dt_s: float) -> np.ndarray:
    """Centred rates (M, n_u) of inputs held per sample, one per interval: (u[k+1] - u[k-1]) / (2 dt)."""
    padded = np.concatenate([u[:1], u], axis=0)
    return (padded[2:] - padded[:-2]) / (2.0 * dt_s)


def prepare_maneuver(meas: MeasuredManeuver, model: Any, problem: Problem,
                     error: EquationError | None = None) -> PreparedManeuver:
    """Equation error, effect inputs, masks and fitting centres of one maneuver (unmeasured states filled);
    ``error``: its equation error with the problem's kernel when already computed (:func:`choose_kernel_from_data`)."""
    settings = problem.settings
    dt_s = float(np.median(np.diff(meas.time_s)))
    kernel_n = kernel_samples(problem, dt_s)
    err = error if error is not None else maneuver_error(meas, model, problem, kernel_n)
    if len(err.kernel) != kernel_n:
        raise ValueError(f"{meas.name}: equation error with a kernel of {len(err.kernel)} samples, expected {kernel_n}")
    x_smooth = interval_means(savgol_smooth(meas.x, smoothing_samples(problem, dt_s)))
    # the input lag's du/dt: the filter CorrectedModel.inputs applies too, at the sample each interval holds
    du_dt_smooth = input_derivative(meas.u, dt_s, settings["effects"].get("lag_derivative_window_s"))[:-1]
    inputs = EffectInputs(err.x, err.u, x_smooth=x_smooth, f=err.f_model, dfdx=err.dfdx, dfdu=err.dfdu,
                          du_dt=input_rates(meas.u, dt_s), du_dt_smooth=du_dt_smooth, model=model,
                          parameter_step=float(settings["effects"].get("parameter_relative_step", 1e-5)),
                          u_samples=meas.u, dt_s=dt_s)
    masks = _masks(err, meas, problem, x_smooth, kernel_n)
    half = kernel_n // 2
    candidates = np.arange(half, len(err.time_s) - half, kernel_n)
    centres = candidates[masks["usable"][candidates]]
    block_s = float(settings.get("bootstrap_block_s") or 20 * kernel_n * dt_s)
    blocks = _blocks(err.time_s, meas.spans_s, block_s)
    noise_x = noise_realisation(meas, problem)
    noise_floor = noise_floor_std(err, noise_x, centres if len(centres) > 10 else None)
    residual_f = err.filtered_residual()
    fit = ManeuverFitData(name=meas.name, inputs=inputs, kernel=err.kernel, centres=centres,
                          span_id=blocks[centres], target=residual_f[centres], noise_std=noise_floor)
    LOGGER.info("%s: %d fitting centres (%.0f %% of the maneuver usable), noise floor %s", meas.name,
                len(centres), 100.0 * masks["usable"].mean(), np.array2string(noise_floor, precision=4))
    return PreparedManeuver(measured=meas, error=err, inputs=inputs, masks=masks, fit=fit, noise_floor=noise_floor,
                            residual_filtered=residual_f, rate_filtered=err.filtered_rate(),
                            starts=start_states(meas, problem))


def noise_realisation(meas: MeasuredManeuver, problem: Problem) -> np.ndarray:
    """A seeded realisation (N, n_x) of the measurement noise on the states, processed like the states.

    The white-noise level of every measured state is estimated from its third differences inside
    the segments; a state differentiated from another (``state_from_derivative``) gets the
    differentiated noise of its source; unmeasured states (simulated) get none.
    """
    rng = np.random.default_rng(int(problem.settings.get("seed", 0)))
    inside = _span_mask(meas.time_s, meas.spans_s)
    noise = np.zeros(meas.x.shape)
    measured = problem.measured
    sigma = np.atleast_1d(white_noise_std(meas.x[:, measured], inside if inside.sum() > 10 else None))
    noise[:, measured] = rng.standard_normal((len(meas.time_s), len(measured))) * sigma
    for state, source in (problem.settings.get("state_from_derivative") or {}).items():
        noise[:, problem.state_names.index(state)] = np.gradient(noise[:, problem.state_names.index(source)],
                                                                 meas.time_s)
    return noise


def _span_mask(time_s: np.ndarray, spans_s: list[list[float]]) -> np.ndarray:
    mask = np.zeros(len(time_s), dtype=bool)
    for start, end in spans_s:
        mask |= (time_s >= start) & (time_s <= end)
    return mask


def _masks(err: EquationError, meas: MeasuredManeuver, problem: Problem, x_smooth: np.ndarray,
           kernel_n: int) -> dict[str, np.ndarray]:
    """Sample masks over the M intervals (a sample counts for the window around it)."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    settings = problem.settings
    in_segment = _span_mask(err.time_s, meas.spans_s)
    near_stop = np.zeros(len(err.time_s), dtype=bool)
    stop = problem.end_stop
    if stop:
        i = stop["state"]
        margin = settings.get("end_stop_margin")
        margin = float(margin) if margin is not None else 0.01 * float(problem.spread[i] if problem.spread.size else 0.0)
        value = err.x[:, i]
        if stop.get("min") is not None:
            near_stop |= value <= stop["min"] + margin
        if stop.get("max") is not None:
            near_stop |= value >= stop["max"] - margin
        near_stop = maximum_filter1d(near_stop.astype(np.uint8), kernel_n).astype(bool)
    standstill = np.zeros(len(err.time_s), dtype=bool)
    still = settings.get("standstill")
    if still:
        i = problem.state_names.index(still["state"])
        moving = np.abs(x_smooth[:, i]) > float(still.get("below", 0.0))
        standstill = ~maximum_filter1d(moving.astype(np.uint8), kernel_n).astype(bool)
    whole_window = minimum_filter1d(in_segment.astype(np.uint8), kernel_n).astype(bool)
    usable = whole_window & ~near_stop & ~standstill
    return {"in_segment": in_segment, "near_stop": near_stop, "standstill": standstill, "usable": usable}
