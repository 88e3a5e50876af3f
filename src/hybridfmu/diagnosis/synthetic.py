"""A NumPy implementation of the motor equations and synthetic trajectories.

Used to check the diagnosis without an FMU (tests, development) and to cross-check an
FMU's derivatives: ``PmsmReference`` has the same model interface as ``hybridfmu.fmu``
(``state_names``, ``input_names``, ``derivatives``, ``jacobians``, ``set_parameters``),
implements the equations of the team conventions (amplitude-invariant Clarke/Park with
theta_e = p*theta, dq voltage equations, J domega/dt = tau_e - b*omega - tau_load) and
has no end stops.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

STATE_NAMES = ["i_d", "i_q", "theta", "omega"]
INPUT_NAMES = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
NOMINAL_PARAMETERS = {
    "p": 4.0, "R": 0.03, "L_d": 60e-6, "L_q": 60e-6, "psi": 6e-3, "J": 2e-4, "b": 2e-5,
    "theta_min": 0.0, "theta_max": 60.0,
}


def abc_to_dq(x_abc: np.ndarray, theta_e_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude-invariant Clarke, then Park. ``x_abc`` (N, 3), ``theta_e_rad`` (N,) -> (x_d, x_q) (N,) each."""
    x_abc = np.asarray(x_abc, dtype=float)
    alpha = (2.0 / 3.0) * (x_abc[:, 0] - 0.5 * x_abc[:, 1] - 0.5 * x_abc[:, 2])
    beta = (x_abc[:, 1] - x_abc[:, 2]) / np.sqrt(3.0)
    cos_e, sin_e = np.cos(theta_e_rad), np.sin(theta_e_rad)
    return alpha * cos_e + beta * sin_e, -alpha * sin_e + beta * cos_e


def dq_to_abc(x_d: np.ndarray, x_q: np.ndarray, theta_e_rad: np.ndarray) -> np.ndarray:
    """Inverse Park, then inverse amplitude-invariant Clarke. Arrays (N,) -> (N, 3)."""
    cos_e, sin_e = np.cos(theta_e_rad), np.sin(theta_e_rad)
    alpha = x_d * cos_e - x_q * sin_e
    beta = x_d * sin_e + x_q * cos_e
    a = alpha
    b = -0.5 * alpha + 0.5 * np.sqrt(3.0) * beta
    c = -0.5 * alpha - 0.5 * np.sqrt(3.0) * beta
    return np.stack([a, b, c], axis=-1)


class PmsmReference:
    """The motor's equations in NumPy, with the model interface of ``hybridfmu.fmu``.

    Args:
        parameters: overrides of ``NOMINAL_PARAMETERS`` (SI units).
    """

    state_names = list(STATE_NAMES)
    input_names = list(INPUT_NAMES)
    output_names: list[str] = []
    n_states = 4
    n_inputs = 5
    n_event_indicators = 0

    def __init__(self, parameters: dict[str, float] | None = None) -> None:
        self.parameters = dict(NOMINAL_PARAMETERS)
        self.parameter_names = list(self.parameters)
        self.set_parameters(parameters or {})

    def set_parameters(self, values: dict[str, float]) -> None:
        """Set parameters by name; unknown names raise ``KeyError``."""
        for name, value in values.items():
            if name not in self.parameters:
                raise KeyError(f"PmsmReference has no parameter {name!r}")
            self.parameters[name] = float(value)

    def derivatives(self, x: np.ndarray, u: np.ndarray, t_s: float = 0.0) -> np.ndarray:
        """State derivatives. ``x`` (N, 4), ``u`` (N, 5) -> (N, 4) in A/s, A/s, rad/s, rad/s^2."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        u = np.atleast_2d(np.asarray(u, dtype=float))
        prm = self.parameters
        pole_pairs = prm["p"]
        i_d, i_q, theta, omega = x.T
        duty = u[:, :3]
        v_abc = u[:, 3:4] * (duty - duty.mean(axis=1, keepdims=True))
        v_d, v_q = abc_to_dq(v_abc, pole_pairs * theta)
        di_d = (v_d - prm["R"] * i_d + pole_pairs * omega * prm["L_q"] * i_q) / prm["L_d"]
        di_q = (v_q - prm["R"] * i_q - pole_pairs * omega * (prm["L_d"] * i_d + prm["psi"])) / prm["L_q"]
        tau_e = 1.5 * pole_pairs * (prm["psi"] * i_q + (prm["L_d"] - prm["L_q"]) * i_d * i_q)
        domega = (tau_e - prm["b"] * omega - u[:, 4]) / prm["J"]
        return np.stack([di_d, di_q, omega, domega], axis=1)

    def jacobians(self, x: np.ndarray, u: np.ndarray, t_s: float = 0.0,
                  step: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Central finite-difference Jacobians: (dfdx (N, 4, 4), dfdu (N, 4, 5))."""
        x = np.atleast_2d(np.asarray(x, dtype=float))
        u = np.atleast_2d(np.asarray(u, dtype=float))
        return _central_jacobian(lambda xx: self.derivatives(xx, u), x, step), \
            _central_jacobian(lambda uu: self.derivatives(x, uu), u, step)


def _central_jacobian(func: Callable[[np.ndarray], np.ndarray], z: np.ndarray, step: float) -> np.ndarray:
    columns = []
    for j in range(z.shape[1]):
        scale = step * max(1.0, float(np.max(np.abs(z[:, j]))) if len(z) else 1.0)
        plus, minus = z.copy(), z.copy()
        plus[:, j] += scale
        minus[:, j] -= scale
        columns.append((func(plus) - func(minus)) / (2.0 * scale))
    return np.stack(columns, axis=2)


@dataclass
class SyntheticTrajectory:
    """A smooth trajectory on a uniform grid: ``time_s`` (N,), ``x`` (N, 4), ``u`` (N, 5), ``i_abc`` (N, 3)."""

    time_s: np.ndarray
    x: np.ndarray
    u: np.ndarray
    i_abc: np.ndarray


def smooth_random_signal(rng: np.random.Generator, time_s: np.ndarray, n_terms: int,
                         max_freq_hz: float, amplitude: float) -> np.ndarray:
    """Sum of ``n_terms`` random sinusoids up to ``max_freq_hz``, scaled to peak ``amplitude``."""
    signal = np.zeros_like(time_s)
    for _ in range(n_terms):
        freq = rng.uniform(0.05, max_freq_hz)
        signal += rng.normal() * np.sin(2 * np.pi * freq * time_s + rng.uniform(0, 2 * np.pi))
    return amplitude * signal / max(np.max(np.abs(signal)), 1e-12)


def synthetic_trajectory(rng: np.random.Generator, duration_s: float = 2.0, dt_s: float = 1e-4,
                         omega_peak_rad_s: float = 200.0, current_peak_a: float = 60.0,
                         load_peak_nm: float = 2.0, pole_pairs: float = 4.0) -> SyntheticTrajectory:
    """A smooth random state/input trajectory covering both directions, loads and angles.

    The signals are not a solution of the equations; they are a rich excitation on which
    candidate-effect regressors can be evaluated (for fitting tests on synthetic residuals).
    """
    time_s = np.arange(int(round(duration_s / dt_s))) * dt_s
    omega = smooth_random_signal(rng, time_s, 6, 3.0, omega_peak_rad_s)
    theta = 30.0 + np.cumsum(omega) * dt_s
    i_d = smooth_random_signal(rng, time_s, 4, 20.0, 0.2 * current_peak_a)
    i_q = smooth_random_signal(rng, time_s, 6, 20.0, current_peak_a)
    tau_load = np.abs(smooth_random_signal(rng, time_s, 4, 2.0, load_peak_nm))
    phase = pole_pairs * theta
    duty = 0.5 + 0.35 * np.stack(
        [np.cos(phase + 0.3), np.cos(phase + 0.3 - 2 * np.pi / 3), np.cos(phase + 0.3 + 2 * np.pi / 3)], axis=1)
    duty = duty + 0.05 * smooth_random_signal(rng, time_s, 5, 200.0, 1.0)[:, None] * np.array([1.0, -0.5, -0.5])
    u_dc = 12.0 + smooth_random_signal(rng, time_s, 3, 50.0, 0.2)
    x = np.stack([i_d, i_q, theta, omega], axis=1)
    u = np.concatenate([np.clip(duty, 0.0, 1.0), u_dc[:, None], tau_load[:, None]], axis=1)
    i_abc = dq_to_abc(i_d, i_q, pole_pairs * theta)
    return SyntheticTrajectory(time_s=time_s, x=x, u=u, i_abc=i_abc)
