"""Synthetic maneuvers of the motor for tests and benchmarks (no bench, no FMU build needed).

``motor_inputs`` gives PWM duties of a rotating voltage vector, ``simulate_rhs`` integrates any torch
right-hand side on the sample grid (RK4, inputs held), ``ingested_frame`` writes states and inputs as the
columns of the ingested-data contract (phase currents through inverse Park/Clarke).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import torch


def motor_inputs(n_samples: int, sample_period_s: float, seed: int, speed_rad_s: float = 150.0,
                 pole_pairs: int = 4, psi_wb: float = 6e-3, theta0_rad: float = 0.0) -> np.ndarray:
    """(T, 5) inputs [d_a, d_b, d_c, u_dc, tau_load]: duties of a voltage vector that leads the q-axis of a
    rotor starting at ``theta0_rad`` and turning with a speed going 0 -> ``speed_rad_s`` -> 0 twice a second
    (amplitude = back-EMF plus a margin), 12 V with ripple, a slowly varying load (N m)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) * sample_period_s
    speed = speed_rad_s * (0.5 - 0.5 * np.cos(2 * np.pi * 2.0 * t))
    angle = pole_pairs * (theta0_rad + np.cumsum(speed) * sample_period_s) + np.pi / 2
    amplitude = (pole_pairs * psi_wb * speed + 0.6) / 12.0
    duties = [0.5 + amplitude * np.cos(angle - k * 2 * np.pi / 3) + 0.002 * rng.standard_normal(n_samples)
              for k in range(3)]
    u_dc = 12.0 + 0.05 * rng.standard_normal(n_samples)
    load = 0.05 + 0.03 * np.sin(2 * np.pi * 1.5 * t)
    return np.stack(duties + [u_dc, load], axis=1)


def simulate_rhs(rhs, u: np.ndarray, x0: np.ndarray, sample_period_s: float) -> np.ndarray:
    """RK4 with inputs held per sample: u (T, n_u), x0 (n_x,) -> states (T, n_x)."""
    h = sample_period_s
    u_t = torch.from_numpy(np.ascontiguousarray(u, dtype=np.float64))
    x = torch.from_numpy(np.asarray(x0, dtype=np.float64))[None]
    states = [x]
    with torch.no_grad():
        for k in range(u.shape[0] - 1):
            uk = u_t[k:k + 1]
            k1 = rhs(x, uk)
            k2 = rhs(x + 0.5 * h * k1, uk)
            k3 = rhs(x + 0.5 * h * k2, uk)
            k4 = rhs(x + h * k3, uk)
            x = x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            states.append(x)
    return torch.cat(states).numpy()


def ingested_frame(time_s: np.ndarray, u: np.ndarray, states: np.ndarray, pole_pairs: int = 4) -> pd.DataFrame:
    """Columns of the ingested-data contract from FMU-ordered inputs [d_a, d_b, d_c, u_dc, tau_load] and
    states [i_d, i_q, theta, omega]."""
    i_d, i_q, theta, omega = states.T
    theta_e = pole_pairs * theta
    alpha = i_d * np.cos(theta_e) - i_q * np.sin(theta_e)
    beta = i_d * np.sin(theta_e) + i_q * np.cos(theta_e)
    i_a = alpha
    i_b = -0.5 * alpha + np.sqrt(3) / 2 * beta
    i_c = -0.5 * alpha - np.sqrt(3) / 2 * beta
    return pd.DataFrame({"time_s": time_s, "duty_a": u[:, 0], "duty_b": u[:, 1], "duty_c": u[:, 2],
                         "u_dc_v": u[:, 3], "tau_load_nm": u[:, 4], "theta_rad": theta, "omega_rad_s": omega,
                         "i_a_a": i_a, "i_b_a": i_b, "i_c_a": i_c})
