"""The bench's plant: PMSM, ball screw, piston and brake circuit, with end stops and effects.

Average-value model over the PWM period (duties held, phase voltages
``v_k = u_dc (d_k + Delta d_k - mean(d + Delta d))``), the motor equations of the physics
conventions with the bench's true parameters, the hydraulic load
``tau_load = p(theta) * displacement`` and the torques of the active effects:

    J domega/dt = tau_e - b omega - tau_load + sum(effect torques)

Each PWM period is integrated with ``substeps`` classical Runge-Kutta (RK4) steps; the
supply voltage and the effects' duty errors are evaluated at the start of each sub-step.
End stops: when theta crosses theta_min/theta_max it is clamped, omega set to 0, and the
rotor stays while the net torque pushes into the stop. Scalar ``math`` only (fast in CPython).
"""

from __future__ import annotations

import math
from typing import Sequence

from .effects import Effect
from .hydraulics import PA_PER_BAR, PressureVolumeCurve
from .supply import Supply

SQRT3_2 = math.sqrt(3.0) / 2.0
INV_SQRT3 = 1.0 / math.sqrt(3.0)


class Plant:
    """Motor, mechanics and hydraulics of the bench; state x = [i_d, i_q, theta, omega].

    Args:
        params: true motor parameters (FMU names, SI: p, R, L_d, L_q, psi, J, b, theta_min, theta_max).
        curve: the true pressure-volume curve.
        effects: active effects (their torque and duty-error hooks are used).
        supply: supply model (U_dc).
        period_s: PWM period (s).
        substeps: RK4 steps per PWM period.
        theta0_rad: initial rotor angle (rad); currents and speed start at 0.
    """

    def __init__(self, params: dict[str, float], curve: PressureVolumeCurve, effects: Sequence[Effect],
                 supply: Supply, period_s: float, substeps: int, theta0_rad: float) -> None:
        if substeps < 1:
            raise ValueError(f"config.bench.substeps: expected >= 1, got {substeps}")
        self.params = dict(params)
        self.curve = curve
        self.supply = supply
        self.period_s = float(period_s)
        self.substeps = int(substeps)
        self.h_s = self.period_s / self.substeps
        self._p = float(params["p"])
        self._R = float(params["R"])
        self._Ld = float(params["L_d"])
        self._Lq = float(params["L_q"])
        self._psi = float(params["psi"])
        self._inv_J = 1.0 / float(params["J"])
        self._b = float(params["b"])
        self._theta_min = float(params["theta_min"])
        self._theta_max = float(params["theta_max"])
        self._k_torque = 1.5 * self._p
        self._dL = self._Ld - self._Lq
        self._dead = curve.dead_travel_rad
        self._inv_angle_scale = 1.0 / curve.angle_scale_rad
        self._load_scale_nm = curve.pressure_scale_bar * PA_PER_BAR * curve.displacement_m3_per_rad
        self._torque_hooks = tuple(e.torque_nm for e in effects if "torque_nm" in e.hooks())
        self._duty_hooks = tuple(e.duty_error for e in effects if "duty_error" in e.hooks())
        self.i_d = 0.0
        self.i_q = 0.0
        self.theta = float(theta0_rad)
        self.omega = 0.0
        self.stop = 0  # -1 at theta_min, +1 at theta_max, 0 free
        self.stop_contacts = 0
        self.u_dc_v = supply.nominal_v
        if not self._theta_min <= self.theta <= self._theta_max:
            raise ValueError(f"initial rotor angle {self.theta} rad is outside the end stops "
                             f"[{self._theta_min}, {self._theta_max}]")

    # ----------------------------------------------------------------- outputs
    def tau_load_nm(self, theta_rad: float | None = None) -> float:
        """Hydraulic load torque (N m) at ``theta_rad`` (default: the current angle)."""
        x = (self.theta if theta_rad is None else theta_rad) - self._dead
        return self._load_scale_nm * (math.exp(x * self._inv_angle_scale) - 1.0) if x > 0.0 else 0.0

    def pressure_bar(self) -> float:
        """True brake pressure (bar) at the current angle."""
        return self.curve.pressure_pa(self.theta) / PA_PER_BAR

    def phase_currents(self) -> tuple[float, float, float]:
        """True phase currents (A) from i_d, i_q and the rotor angle (amplitude-invariant)."""
        th = self._p * self.theta
        c, s = math.cos(th), math.sin(th)
        i_al = self.i_d * c - self.i_q * s
        i_be = self.i_d * s + self.i_q * c
        return i_al, -0.5 * i_al + SQRT3_2 * i_be, -0.5 * i_al - SQRT3_2 * i_be

    def electrical_torque_nm(self) -> float:
        """Electromagnetic torque (N m) of the current state."""
        return self._k_torque * (self._psi * self.i_q + self._dL * self.i_d * self.i_q)

    # ----------------------------------------------------------------- dynamics
    def derivatives(self, i_d: float, i_q: float, theta: float, omega: float,
                    v_al: float, v_be: float) -> tuple[float, float, float, float]:
        """State derivatives (A/s, A/s, rad/s, rad/s^2) for stator-frame voltages v_alpha, v_beta (V)."""
        th = self._p * theta
        c = math.cos(th)
        s = math.sin(th)
        v_d = v_al * c + v_be * s
        v_q = v_be * c - v_al * s
        pw = self._p * omega
        di_d = (v_d - self._R * i_d + pw * self._Lq * i_q) / self._Ld
        di_q = (v_q - self._R * i_q - pw * (self._Ld * i_d + self._psi)) / self._Lq
        x = theta - self._dead
        tau_load = self._load_scale_nm * (math.exp(x * self._inv_angle_scale) - 1.0) if x > 0.0 else 0.0
        tau = self._k_torque * (self._psi * i_q + self._dL * i_d * i_q) - self._b * omega - tau_load
        for hook in self._torque_hooks:
            tau += hook(theta, omega, tau_load)
        if self.stop and tau * self.stop >= 0.0:
            return di_d, di_q, 0.0, 0.0
        return di_d, di_q, omega, tau * self._inv_J

    def advance(self, d_a: float, d_b: float, d_c: float, t_s: float, duration_s: float | None = None) -> None:
        """Integrate one PWM period from ``t_s`` (s) with the duties ``d_a, d_b, d_c`` (0..1) held; with
        ``duration_s`` (s, > 0) only that part of a period (a start between two PWM instants)."""
        h = self.h_s if duration_s is None else float(duration_s) / self.substeps
        half = 0.5 * h
        sixth = h / 6.0
        f = self.derivatives
        i_d, i_q, theta, omega = self.i_d, self.i_q, self.theta, self.omega
        for n in range(self.substeps):
            th = self._p * theta
            c, s = math.cos(th), math.sin(th)
            i_al = i_d * c - i_q * s
            i_be = i_d * s + i_q * c
            i_a = i_al
            i_b = -0.5 * i_al + SQRT3_2 * i_be
            i_c = -0.5 * i_al - SQRT3_2 * i_be
            e_a, e_b, e_c = d_a, d_b, d_c
            for hook in self._duty_hooks:
                x_a, x_b, x_c = hook(i_a, i_b, i_c)
                e_a += x_a
                e_b += x_b
                e_c += x_c
            u_dc = self.supply.voltage_v(t_s + n * h, e_a * i_a + e_b * i_b + e_c * i_c)
            v_al = u_dc * (2.0 / 3.0) * (e_a - 0.5 * (e_b + e_c))
            v_be = u_dc * INV_SQRT3 * (e_b - e_c)
            k1 = f(i_d, i_q, theta, omega, v_al, v_be)
            k2 = f(i_d + half * k1[0], i_q + half * k1[1], theta + half * k1[2], omega + half * k1[3], v_al, v_be)
            k3 = f(i_d + half * k2[0], i_q + half * k2[1], theta + half * k2[2], omega + half * k2[3], v_al, v_be)
            k4 = f(i_d + h * k3[0], i_q + h * k3[1], theta + h * k3[2], omega + h * k3[3], v_al, v_be)
            i_d += sixth * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0])
            i_q += sixth * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1])
            theta += sixth * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2])
            omega += sixth * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3])
            if theta < self._theta_min:
                theta, omega = self._theta_min, 0.0
                if self.stop != -1:
                    self.stop = -1
                    self.stop_contacts += 1
            elif theta > self._theta_max:
                theta, omega = self._theta_max, 0.0
                if self.stop != 1:
                    self.stop = 1
                    self.stop_contacts += 1
            elif self.stop and self._theta_min < theta < self._theta_max:
                self.stop = 0
            self.u_dc_v = u_dc
        self.i_d, self.i_q, self.theta, self.omega = i_d, i_q, theta, omega
