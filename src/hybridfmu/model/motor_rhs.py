"""Pure-torch right-hand side of the braking-motor equations (the physics conventions of the case).

A differentiable stand-in for the FMU when testing or benchmarking the neural-FMU layers without a
compiled FMU. End stops are not modelled here (they are state events of the FMU).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class MotorParameters:
    """Motor parameters in SI units (names as the FMU's parameters)."""

    p: float = 4.0
    R: float = 0.03
    L_d: float = 60e-6
    L_q: float = 60e-6
    psi: float = 6e-3
    J: float = 2e-4
    b: float = 2e-5


class MotorRhs:
    """Callable ``(x (N, 4), u (N, 5)) -> xdot (N, 4)`` for x = [i_d, i_q, theta, omega]
    (A, A, rad, rad/s) and u = [d_a, d_b, d_c, u_dc, tau_load] (duty 0..1, V, N·m).

    Phase voltages v_k = u_dc (d_k - mean(d)), amplitude-invariant Clarke and Park with
    theta_e = p theta; dq current equations; torque 1.5 p (psi i_q + (L_d - L_q) i_d i_q).
    """

    state_names = ["i_d", "i_q", "theta", "omega"]
    input_names = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]

    def __init__(self, parameters: MotorParameters | None = None) -> None:
        self.parameters = parameters or MotorParameters()

    def __call__(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        prm = self.parameters
        i_d, i_q, theta, omega = x.unbind(dim=1)
        d_a, d_b, d_c, u_dc, tau_load = u.unbind(dim=1)
        d_mean = (d_a + d_b + d_c) / 3.0
        v_a, v_b, v_c = (u_dc * (d_a - d_mean), u_dc * (d_b - d_mean), u_dc * (d_c - d_mean))
        v_alpha = (2.0 / 3.0) * (v_a - 0.5 * v_b - 0.5 * v_c)
        v_beta = (v_b - v_c) / math.sqrt(3.0)
        theta_e = prm.p * theta
        cos_e, sin_e = torch.cos(theta_e), torch.sin(theta_e)
        v_d = v_alpha * cos_e + v_beta * sin_e
        v_q = -v_alpha * sin_e + v_beta * cos_e
        omega_e = prm.p * omega
        di_d = (v_d - prm.R * i_d + omega_e * prm.L_q * i_q) / prm.L_d
        di_q = (v_q - prm.R * i_q - omega_e * (prm.L_d * i_d + prm.psi)) / prm.L_q
        tau_e = 1.5 * prm.p * (prm.psi * i_q + (prm.L_d - prm.L_q) * i_d * i_q)
        domega = (tau_e - prm.b * omega - tau_load) / prm.J
        return torch.stack([di_d, di_q, omega, domega], dim=1)

    def value_and_jacobians(self, x: torch.Tensor, u: torch.Tensor
                            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(xdot (N, 4), dfdx (N, 4, 4), dfdu (N, 4, 5)), the Jacobians in closed form."""
        prm = self.parameters
        i_d, i_q, theta, omega = x.unbind(dim=1)
        d_a, d_b, d_c, u_dc, tau_load = u.unbind(dim=1)
        s3 = math.sqrt(3.0)
        alpha_d = (2.0 / 3.0) * (d_a - 0.5 * d_b - 0.5 * d_c)  # v_alpha / u_dc
        beta_d = (d_b - d_c) / s3                               # v_beta / u_dc
        theta_e = prm.p * theta
        cos_e, sin_e = torch.cos(theta_e), torch.sin(theta_e)
        v_d = u_dc * (alpha_d * cos_e + beta_d * sin_e)
        v_q = u_dc * (-alpha_d * sin_e + beta_d * cos_e)
        omega_e = prm.p * omega
        xdot = torch.stack([
            (v_d - prm.R * i_d + omega_e * prm.L_q * i_q) / prm.L_d,
            (v_q - prm.R * i_q - omega_e * (prm.L_d * i_d + prm.psi)) / prm.L_q,
            omega,
            (1.5 * prm.p * (prm.psi * i_q + (prm.L_d - prm.L_q) * i_d * i_q) - prm.b * omega - tau_load) / prm.J,
        ], dim=1)
        n = x.shape[0]
        dfdx = x.new_zeros(n, 4, 4)
        dfdx[:, 0, 0] = -prm.R / prm.L_d
        dfdx[:, 0, 1] = omega_e * prm.L_q / prm.L_d
        dfdx[:, 0, 2] = prm.p * v_q / prm.L_d
        dfdx[:, 0, 3] = prm.p * prm.L_q * i_q / prm.L_d
        dfdx[:, 1, 0] = -omega_e * prm.L_d / prm.L_q
        dfdx[:, 1, 1] = -prm.R / prm.L_q
        dfdx[:, 1, 2] = -prm.p * v_d / prm.L_q
        dfdx[:, 1, 3] = -prm.p * (prm.L_d * i_d + prm.psi) / prm.L_q
        dfdx[:, 2, 3] = 1.0
        dfdx[:, 3, 0] = 1.5 * prm.p * (prm.L_d - prm.L_q) * i_q / prm.J
        dfdx[:, 3, 1] = 1.5 * prm.p * (prm.psi + (prm.L_d - prm.L_q) * i_d) / prm.J
        dfdx[:, 3, 3] = -prm.b / prm.J
        # d(v_alpha, v_beta)/d(d_a, d_b, d_c, u_dc)
        d_alpha = torch.stack([2.0 / 3.0 * u_dc, -u_dc / 3.0, -u_dc / 3.0, alpha_d], dim=1)
        d_beta = torch.stack([torch.zeros_like(u_dc), u_dc / s3, -u_dc / s3, beta_d], dim=1)
        dfdu = u.new_zeros(n, 4, 5)
        dfdu[:, 0, :4] = (cos_e[:, None] * d_alpha + sin_e[:, None] * d_beta) / prm.L_d
        dfdu[:, 1, :4] = (-sin_e[:, None] * d_alpha + cos_e[:, None] * d_beta) / prm.L_q
        dfdu[:, 3, 4] = -1.0 / prm.J
        return xdot, dfdx, dfdu
