"""From ingested maneuvers to the quantities the diagnosis works on.

``load_maneuver`` reads one ingested maneuver and its segments into model-ordered arrays
(speed state taken from the angle by a central difference when ``diagnosis.speed_source`` is
``angle``: the logged speed of an observer lags during acceleration). ``prepare_maneuver``
computes the equation error, the effect inputs along the data, the masks of usable samples
(inside segments, away from end stops, not at standstill) and the fitting centres.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.diagnosis.derivatives import interval_means, odd_window, savgol_derivative, savgol_smooth
from hybridfmu.diagnosis.effects import EffectInputs
from hybridfmu.diagnosis.layout import MotorLayout
from hybridfmu.diagnosis.residual import EquationError, equation_error, noise_floor_std
from hybridfmu.diagnosis.selection import ManeuverFitData
from hybridfmu.diagnosis.synthetic import dq_to_abc

LOGGER = logging.getLogger("hybridfmu.diagnosis")


@dataclass
class MeasuredManeuver:
    """One measured maneuver in the model's variable order.

    Attributes:
        name, role: maneuver name and role (train / validation / test).
        time_s: (N,) uniform grid (s), starting at 0.
        x: (N, n_x) measured states; u: (N, n_u) inputs.
        spans_s: informative segments [[t_start_s, t_end_s], ...].
        source: path of the ingested data (for messages).
    """

    name: str
    role: str
    time_s: np.ndarray
    x: np.ndarray
    u: np.ndarray
    spans_s: list[list[float]]
    source: str = ""


def load_maneuver(name: str, role: str, data_path: str | Path, segments_path: str | Path | None, model: Any,
                  config: dict[str, Any]) -> MeasuredManeuver:
    """Read an ingested maneuver (Parquet) and its segments (JSON) into model-ordered arrays."""
    from hybridfmu.data.segments import read_segments
    from hybridfmu.data.signals import input_array, state_array, time_array

    data_path = Path(data_path)
    if not data_path.is_file():
        raise FileNotFoundError(f"{data_path}: ingested data of maneuver {name!r} does not exist")
    frame = pd.read_parquet(data_path)
    signals = config.get("signals", {})
    time_s = time_array(frame)
    u = input_array(frame, signals, list(model.input_names))
    x = state_array(frame, signals, list(model.state_names))
    diagnosis = config.get("diagnosis", {})
    speed_state = signals.get("speed_state", "omega")
    angle_state = signals.get("angle_state", "theta")
    if diagnosis.get("speed_source", "angle") == "angle":
        theta = x[:, model.state_names.index(angle_state)]
        x[:, model.state_names.index(speed_state)] = np.gradient(theta, time_s)
    lags = diagnosis.get("input_lag_compensation_s", {}) or {}
    for input_name, lag_s in lags.items():
        if input_name not in model.input_names:
            raise ValueError(f"config.diagnosis.input_lag_compensation_s.{input_name}: not a model input "
                             f"{list(model.input_names)}")
        if lag_s > 0:
            j = model.input_names.index(input_name)
            window = odd_window(float(diagnosis.get("lag_compensation_window_s", 0.004)),
                                float(np.median(np.diff(time_s))), minimum=5)
            u[:, j] = savgol_smooth(u[:, j], window) + float(lag_s) * savgol_derivative(
                u[:, j], float(np.median(np.diff(time_s))), window)
    spans = read_segments(segments_path)["spans_s"] if segments_path else [[float(time_s[0]), float(time_s[-1])]]
    for column, values in (("inputs", u), ("states", x)):
        bad = ~np.isfinite(values)
        if bad.any():
            raise ValueError(f"{data_path}: non-finite {column} at {int(bad.any(axis=1).sum())} samples")
    return MeasuredManeuver(name=name, role=role, time_s=time_s, x=x, u=u, spans_s=[list(s) for s in spans],
                            source=str(data_path))


@dataclass
class PreparedManeuver:
    """A maneuver ready for the diagnosis (M = N-1 intervals).

    Attributes:
        measured: the measured maneuver.
        error: equation error.
        inputs: effect inputs along the data (data mode).
        omega_smooth: (M,) low-noise speed (rad/s) for nonlinear terms.
        masks: name -> (M,) bool: ``in_segment``, ``near_stop``, ``standstill``, ``usable``.
        fit: the fitting data (centres, target, noise).
        noise_floor: (n_x,) predicted noise std of the kernel-averaged equation error.
    """

    measured: MeasuredManeuver
    error: EquationError
    inputs: EffectInputs
    omega_smooth: np.ndarray
    masks: dict[str, np.ndarray]
    fit: ManeuverFitData
    noise_floor: np.ndarray
    extras: dict[str, Any] = field(default_factory=dict)


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


def prepare_maneuver(meas: MeasuredManeuver, model: Any, layout: MotorLayout, settings: dict[str, Any],
                     parameter_values: dict[str, float]) -> PreparedManeuver:
    """Equation error, effect inputs, masks and fitting centres of one maneuver.

    ``settings`` is the case's ``diagnosis`` section with defaults filled in (``kernel_s``,
    ``smoothing_s``, ``standstill_rad_s``, ``end_stop_margin_rad``, ``bootstrap_block_s``).
    """
    dt_s = float(np.median(np.diff(meas.time_s)))
    kernel_n = odd_window(settings["kernel_s"], dt_s)
    err = equation_error(model, meas.time_s, meas.x, meas.u, kernel_n, maneuver=meas.name,
                         noise_mask=_span_mask(meas.time_s, meas.spans_s),
                         one_step_states=layout.groups.get("electrical", []))
    smooth_n = odd_window(settings["smoothing_s"], dt_s, minimum=5)
    omega_smooth = interval_means(savgol_smooth(meas.x[:, layout.omega], smooth_n))
    i_abc = None
    if layout.i_d is not None and layout.i_q is not None and layout.pole_pairs:
        i_dq = interval_means(savgol_smooth(meas.x[:, [layout.i_d, layout.i_q]], smooth_n))
        i_abc = dq_to_abc(i_dq[:, 0], i_dq[:, 1], layout.pole_pairs * err.x[:, layout.theta])
    u_all = meas.u

    def shift(offset_s: float) -> np.ndarray:
        # Inputs held over each interval, seen ``offset_s`` later: the mean of the held signal over
        # [t_k + offset, t_k+1 + offset] = linear interpolation at the fractional sample k + offset/dt.
        index = np.arange(len(u_all) - 1) + offset_s / dt_s
        base = np.clip(np.floor(index).astype(int), 0, len(u_all) - 1)
        frac = (index - np.floor(index))[:, None]
        upper = np.clip(base + 1, 0, len(u_all) - 1)
        return (1.0 - frac) * u_all[base] + frac * u_all[upper]

    context = {}
    if layout.u_dc is not None:
        context["u_dc_mean_v"] = float(np.mean(meas.u[:, layout.u_dc]))
    inputs = EffectInputs(layout, err.x, err.u, omega_rad_s=omega_smooth, i_abc_a=i_abc, f=err.f_model,
                          dfdx=err.dfdx, dfdu=err.dfdu, shift=shift, context=context)
    masks = _masks(err, meas, layout, omega_smooth, kernel_n, settings, parameter_values)
    half = kernel_n // 2
    candidates = np.arange(half, len(err.time_s) - half, kernel_n)
    centres = candidates[masks["usable"][candidates]]
    blocks = _blocks(err.time_s, meas.spans_s, settings["bootstrap_block_s"])
    noise_x = noise_realisation(meas, layout, settings)
    noise_floor = noise_floor_std(err, noise_x, centres if len(centres) > 10 else None)
    residual_f = err.filtered_residual()
    fit = ManeuverFitData(name=meas.name, inputs=inputs, kernel=err.kernel, centres=centres,
                          span_id=blocks[centres], target=residual_f[centres], noise_std=noise_floor)
    LOGGER.info("%s: %d fitting centres (%.0f %% of the maneuver usable), noise floor %s", meas.name,
                len(centres), 100.0 * masks["usable"].mean(), np.array2string(noise_floor, precision=4))
    return PreparedManeuver(measured=meas, error=err, inputs=inputs, omega_smooth=omega_smooth, masks=masks,
                            fit=fit, noise_floor=noise_floor, extras={"residual_filtered": residual_f})


def noise_realisation(meas: MeasuredManeuver, layout: MotorLayout, settings: dict[str, Any]) -> np.ndarray:
    """A seeded realisation (N, n_x) of the measurement noise on the states, processed like the states.

    The white-noise level of every measured state is estimated from its third differences
    inside the segments; a speed differentiated from the angle gets the differentiated angle
    noise (so its correlation is right), other states white noise of their estimated level.
    """
    from hybridfmu.diagnosis.derivatives import white_noise_std

    rng = np.random.default_rng(int(settings.get("seed", 0)))
    inside = _span_mask(meas.time_s, meas.spans_s)
    sigma = np.atleast_1d(white_noise_std(meas.x, inside if inside.sum() > 10 else None))
    noise = rng.standard_normal(meas.x.shape) * sigma
    if settings.get("speed_source", "angle") == "angle":
        noise[:, layout.omega] = np.gradient(noise[:, layout.theta], meas.time_s)
    return noise


def _span_mask(time_s: np.ndarray, spans_s: list[list[float]]) -> np.ndarray:
    mask = np.zeros(len(time_s), dtype=bool)
    for start, end in spans_s:
        mask |= (time_s >= start) & (time_s <= end)
    return mask


def _masks(err: EquationError, meas: MeasuredManeuver, layout: MotorLayout, omega_smooth: np.ndarray,
           kernel_n: int, settings: dict[str, Any], parameter_values: dict[str, float]) -> dict[str, np.ndarray]:
    """Sample masks over the M intervals (a sample counts for the window around it)."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    in_segment = _span_mask(err.time_s, meas.spans_s)
    theta = err.x[:, layout.theta]
    margin = float(settings["end_stop_margin_rad"])
    names = settings.get("variables", {})
    theta_min = parameter_values.get(names.get("theta_min", "theta_min"))
    theta_max = parameter_values.get(names.get("theta_max", "theta_max"))
    near_stop = np.zeros(len(theta), dtype=bool)
    if theta_min is not None:
        near_stop |= theta <= theta_min + margin
    if theta_max is not None:
        near_stop |= theta >= theta_max - margin
    near_stop = maximum_filter1d(near_stop.astype(np.uint8), kernel_n).astype(bool)
    moving = np.abs(omega_smooth) > float(settings["standstill_rad_s"])
    standstill = ~maximum_filter1d(moving.astype(np.uint8), kernel_n).astype(bool)
    whole_window = minimum_filter1d(in_segment.astype(np.uint8), kernel_n).astype(bool)
    usable = whole_window & ~near_stop & ~standstill
    return {"in_segment": in_segment, "near_stop": near_stop, "standstill": standstill, "usable": usable}
