"""Equation error per state: what the measurements did minus what the model says.

Inputs are held over each sampling interval (as in the open-loop simulation; a continuous input at its
mean over the interval, :mod:`hybridfmu.data.between_samples`). Over the
interval [t_k, t_k+1) the measurements changed at ``(x_k+1 - x_k) / dt``. The model's mean
rate over the interval is, for fast states (``one_step_states``, e.g. currents driven by
switched voltages), that of one classical Runge-Kutta step from the measured x_k with the held
input u_k, ``(Phi(x_k, u_k) - x_k) / dt`` (a quadrature over the sampled states would misjudge
dynamics much faster than the sampling); for the other states the trapezoid rule
``(f(x_k, u_k) + f(x_k+1, u_k)) / 2`` over the measured end states, so that an error of the
fast states' equations cannot leak into the slow ones through the model's own prediction
within the step. Their difference is the raw equation error; averaged with the Hann kernel of
``hybridfmu.diagnosis.derivatives`` it becomes a low-noise estimate of the missing term in
each state equation (units of the state's derivative).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hybridfmu.diagnosis.derivatives import (
    hann_kernel, interval_means, interval_rates, smooth_same, white_noise_std,
)
from hybridfmu.progress import Progress
from hybridfmu.runge_kutta import RK4, numpy_axpy

LOGGER = logging.getLogger("hybridfmu.diagnosis")


@dataclass
class EquationError:
    """Equation error along one measured trajectory (M = N-1 sampling intervals).

    Attributes:
        maneuver: name of the maneuver.
        dt_s: sampling interval (s).
        state_names: model state names (n_x).
        time_s: (M,) interval midpoints (s).
        x: (M, n_x) interval means of the measured states.
        u: (M, n_u) inputs held over each interval.
        rate_meas: (M, n_x) measured difference quotients (state units per s).
        f_model: (M, n_x) model's mean rate over each interval (one RK4 step from the measured state).
        dfdx: (M, n_x, n_x) model Jacobian at (x, u), or None.
        dfdu: (M, n_x, n_u) model input Jacobian at (x, u), or None.
        kernel: (W,) smoothing kernel (sums to 1).
        one_step_states: indices of the states whose model rate is a one-step RK4 prediction.
        noise_std: (n_x,) estimated white-noise std of each measured state (state units; a
            rough first look, the noise floor of the diagnosis comes from ``noise_floor_std``).
    """

    maneuver: str
    dt_s: float
    state_names: list[str]
    time_s: np.ndarray
    x: np.ndarray
    u: np.ndarray
    rate_meas: np.ndarray
    f_model: np.ndarray
    dfdx: np.ndarray | None
    dfdu: np.ndarray | None
    kernel: np.ndarray
    noise_std: np.ndarray
    one_step_states: list[int] = field(default_factory=list)
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def residual(self) -> np.ndarray:
        """Raw equation error (M, n_x): measured rate minus model rate."""
        return self.rate_meas - self.f_model

    def filtered_residual(self) -> np.ndarray:
        """Kernel-averaged equation error (M, n_x); NaN within half a kernel of the ends."""
        return smooth_same(self.residual, self.kernel)

    def filtered_rate(self) -> np.ndarray:
        """Kernel-averaged measured derivative (M, n_x); NaN near the ends."""
        return smooth_same(self.rate_meas, self.kernel)

    def filtered_model_rate(self) -> np.ndarray:
        """Kernel-averaged model derivative (M, n_x); NaN near the ends."""
        return smooth_same(self.f_model, self.kernel)


def check_uniform_grid(time_s: np.ndarray, what: str) -> float:
    """Return the sampling interval of ``time_s`` (s); raise if the grid is not uniform."""
    time_s = np.asarray(time_s, dtype=float)
    if time_s.ndim != 1 or len(time_s) < 3:
        raise ValueError(f"{what}: time_s must be a 1-D array of at least 3 samples")
    steps = np.diff(time_s)
    dt_s = float(np.median(steps))
    if dt_s <= 0 or np.max(np.abs(steps - dt_s)) > 1e-6 * dt_s + 1e-12:
        raise ValueError(f"{what}: time_s is not a uniform grid (median step {dt_s:g} s, "
                         f"steps between {steps.min():g} and {steps.max():g} s)")
    return dt_s


def _batched(func, *arrays: np.ndarray, chunk: int, progress: Progress | None):
    outputs = []
    for start in range(0, arrays[0].shape[0], chunk):
        outputs.append(func(*(a[start:start + chunk] for a in arrays)))
        if progress is not None:
            progress.update(min(chunk, arrays[0].shape[0] - start))
    if isinstance(outputs[0], tuple):
        return tuple(np.concatenate(parts, axis=0) for parts in zip(*outputs))
    return np.concatenate(outputs, axis=0)


def equation_error(model: Any, time_s: np.ndarray, x: np.ndarray, u: np.ndarray, kernel_samples: int,
                   maneuver: str = "", jacobians: bool = True, chunk: int = 20000,
                   noise_mask: np.ndarray | None = None,
                   one_step_states: list[int] | None = None) -> EquationError:
    """Equation error of ``model`` along a measured trajectory.

    Args:
        model: object with ``derivatives(x, u)`` and ``jacobians(x, u)`` (``hybridfmu.fmu`` API).
        time_s: (N,) uniform time grid (s).
        x: (N, n_x) measured states in model state order.
        u: (N, n_u) inputs in model input order (held between samples).
        kernel_samples: length of the Hann smoothing kernel (odd, samples).
        maneuver: name used in messages.
        jacobians: also evaluate the model Jacobians at the interval means.
        chunk: number of samples per model call.
        noise_mask: (N,) samples used to estimate the measurement noise (default all).
        one_step_states: indices of the states whose mean rate comes from one RK4 step
            (default none: trapezoid rule for all).
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    dt_s = check_uniform_grid(time_s, maneuver or "trajectory")
    if x.shape[0] != len(time_s) or u.shape[0] != len(time_s):
        raise ValueError(f"{maneuver}: x {x.shape} and u {u.shape} must have {len(time_s)} rows like time_s")
    for name, values in (("states", x), ("inputs", u)):
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{maneuver}: measured {name} contain NaN or inf")
    u_held = u[:-1]
    one_step = sorted(set(one_step_states or []))
    n_calls = 2 + (4 if one_step else 0) + (1 if jacobians else 0)
    progress = Progress(n_calls * (len(time_s) - 1), f"equation error {maneuver}", "model evaluations",
                        logger=LOGGER)
    f_start = _batched(model.derivatives, x[:-1], u_held, chunk=chunk, progress=progress)
    f_end = _batched(model.derivatives, x[1:], u_held, chunk=chunk, progress=progress)
    f_mean = 0.5 * (f_start + f_end)
    if one_step:
        def mean_rate(x_start: np.ndarray, u_start: np.ndarray) -> np.ndarray:
            return rk4_mean_rate(model, x_start, u_start, dt_s)

        f_rk4 = _batched(mean_rate, x[:-1], u_held, chunk=chunk, progress=None)
        progress.update(4 * (len(time_s) - 1))
        f_mean[:, one_step] = f_rk4[:, one_step]
    x_mid = interval_means(x)
    dfdx = dfdu = None
    if jacobians:
        dfdx, dfdu = _batched(model.jacobians, x_mid, u_held, chunk=chunk, progress=progress)
    progress.finish()
    return EquationError(
        maneuver=maneuver, dt_s=dt_s, state_names=list(getattr(model, "state_names", [])),
        time_s=interval_means(np.asarray(time_s, dtype=float)), x=x_mid, u=u_held,
        rate_meas=interval_rates(x, dt_s), f_model=f_mean,
        dfdx=dfdx, dfdu=dfdu, kernel=hann_kernel(kernel_samples), one_step_states=one_step,
        noise_std=np.atleast_1d(white_noise_std(x, noise_mask)),
    )


def rk4_mean_rate(model: Any, x: np.ndarray, u: np.ndarray, dt_s: float) -> np.ndarray:
    """Mean rate of change over one step of ``dt_s`` predicted by one RK4 step: (Phi(x, u) - x) / dt.

    ``x`` (K, n_x), ``u`` (K, n_u) held over the step -> (K, n_x).
    """
    plan = RK4.plan(dt_s, weight_scale=1.0)
    stages = []
    for i in range(RK4.stages):
        stages.append(np.asarray(model.derivatives(plan.stage_state(x, stages, i, numpy_axpy), u), dtype=float))
    return plan.combine(np.zeros_like(stages[0]), stages, numpy_axpy)


def noise_floor_std(err: EquationError, noise_x: np.ndarray, centres: np.ndarray | None = None) -> np.ndarray:
    """Std (n_x,) of the kernel-averaged equation error caused by measurement noise alone.

    ``noise_x`` (N, n_x) is a realisation of the noise on the measured states, processed as the
    states themselves were (e.g. a speed differentiated from a noisy angle). It is propagated
    through the same linear operations as the data: the measured side ``diff(e) / dt`` and the
    model side through the Jacobian (at both ends, or at the start for one-step states), then averaged with the
    kernel; the std is taken at ``centres`` (default: every kernel length).
    """
    if noise_x.shape[0] != err.x.shape[0] + 1:
        raise ValueError(f"noise realisation has {noise_x.shape[0]} rows, expected {err.x.shape[0] + 1}")
    raw = interval_rates(noise_x, err.dt_s)
    if err.dfdx is not None:
        start = np.einsum("mij,mj->mi", err.dfdx, noise_x[:-1])
        model_part = 0.5 * (start + np.einsum("mij,mj->mi", err.dfdx, noise_x[1:]))
        model_part[:, err.one_step_states] = start[:, err.one_step_states]
        raw = raw - model_part
    filtered = smooth_same(raw, err.kernel)
    if centres is None:
        half = len(err.kernel) // 2
        centres = np.arange(half, filtered.shape[0] - half, len(err.kernel))
    values = filtered[centres]
    values = values[np.all(np.isfinite(values), axis=1)]
    return np.sqrt(np.mean(values ** 2, axis=0)) if len(values) else np.zeros(noise_x.shape[1])
