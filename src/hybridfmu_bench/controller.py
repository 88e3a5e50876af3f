"""The bench ECU's motor control: a cascade of position, speed and current loops at the PWM rate.

Pressure requests become position references through the ECU's (nominal) pressure-volume map
(see :mod:`hybridfmu_bench.maneuvers`); a slow integral pressure trim at the sensor rate
corrects the map with the measured pressure. Then, every PWM period, with the MEASURED
(quantised) angle and the observer's speed estimate:

- position P loop + speed feed-forward -> speed reference (limited);
- speed PI (+ load and acceleration feed-forward) -> q-current reference (limited);
- d/q current PI with decoupling (nominal parameters), voltage-circle limit, conditional
  integration as anti-windup;
- inverse Park with the measured electrical angle advanced by 1.5 periods (one period of
  computation delay plus half a period of PWM hold), inverse Clarke, min-max zero sequence,
  duties saturated to 0..1.
The duties computed at t_k are applied from t_{k+1} (one sample of computation delay: the
caller holds them for a period).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

SQRT3_2 = math.sqrt(3.0) / 2.0
INV_SQRT3 = 1.0 / math.sqrt(3.0)


@dataclass(frozen=True)
class ControllerSettings:
    """Tuning of the cascade (from ``bench.controller``).

    Attributes:
        current_bandwidth_hz: bandwidth of the d/q current loops (Hz).
        speed_bandwidth_hz: bandwidth of the speed loop (Hz).
        speed_integral_ratio: speed-loop integral corner as a fraction of its bandwidth.
        position_gain_1_s: position-loop gain (rad/s per rad).
        current_limit_a: q-current limit (A); segments may lower it.
        voltage_margin: fraction of the linear voltage limit u_dc/sqrt(3) the loops may use.
        pressure_trim_gain_rad_per_bar_s: integral gain of the pressure trim (rad per bar s).
        pressure_trim_limit_rad: limit of the trim (rad).
        pressure_trim_min_bar: the trim integrates only while the request exceeds this (bar).
        pressure_trim_max_rate_bar_s: ... and while the request changes slower than this (bar/s).
        pressure_trim_error_limit_bar: the pressure error is clipped to +-this before integration (bar).
        pressure_trim_decay_s: time constant with which the trim fades while it does not integrate (s).
        load_feedforward: add the measured pressure's load torque to the q-current reference.
    """

    current_bandwidth_hz: float = 600.0
    speed_bandwidth_hz: float = 40.0
    speed_integral_ratio: float = 0.25
    position_gain_1_s: float = 40.0
    current_limit_a: float = 120.0
    voltage_margin: float = 0.97
    pressure_trim_gain_rad_per_bar_s: float = 0.2
    pressure_trim_limit_rad: float = 2.0
    pressure_trim_min_bar: float = 2.0
    pressure_trim_max_rate_bar_s: float = 100.0
    pressure_trim_error_limit_bar: float = 5.0
    pressure_trim_decay_s: float = 0.1
    load_feedforward: bool = True


class CascadeController:
    """Position -> speed -> current cascade with PWM duty output.

    Args:
        settings: tuning.
        nominal: nominal motor parameters (p, R, L_d, L_q, psi, J) used for gains and decoupling.
        torque_per_pa: the ECU's pressure-to-load-torque factor (N m/Pa) for the load feed-forward.
        period_s: control period = PWM period (s).
        pressure_period_s: period of the pressure samples (s).
    """

    def __init__(self, settings: ControllerSettings, nominal: Mapping[str, float], torque_per_pa: float,
                 period_s: float, pressure_period_s: float) -> None:
        self.settings = settings
        self.period_s = period_s
        self.pressure_period_s = pressure_period_s
        self._p = float(nominal["p"])
        self._Ld = float(nominal["L_d"])
        self._Lq = float(nominal["L_q"])
        self._psi = float(nominal["psi"])
        k_t = 1.5 * self._p * self._psi  # N m per A of i_q
        self._inv_kt = 1.0 / k_t
        w_i = 2.0 * math.pi * settings.current_bandwidth_hz
        self.kp_d = self._Ld * w_i
        self.kp_q = self._Lq * w_i
        self.ki_i = float(nominal["R"]) * w_i
        w_s = 2.0 * math.pi * settings.speed_bandwidth_hz
        self.kp_w = float(nominal["J"]) * w_s * self._inv_kt
        self.ki_w = self.kp_w * w_s * settings.speed_integral_ratio
        self._j_over_kt = float(nominal["J"]) * self._inv_kt
        self._load_ff = torque_per_pa * 1.0e5 * self._inv_kt if settings.load_feedforward else 0.0
        self._trim_decay = math.exp(-pressure_period_s / settings.pressure_trim_decay_s)
        self.reset()

    def reset(self) -> None:
        """Zero the integrators and the pressure trim."""
        self.int_d = 0.0
        self.int_q = 0.0
        self.int_w = 0.0
        self.trim_rad = 0.0
        self.pressure_bar = 0.0
        self.pressure_ref_bar = 0.0
        self.i_q_ref = 0.0

    def update_pressure(self, pressure_meas_bar: float, pressure_ref_bar: float, pressure_mode: bool) -> None:
        """Pressure-trim step at the sensor rate with a new measured pressure (bar).

        The trim integrates the clipped pressure error while the request is above
        ``pressure_trim_min_bar`` and changes slowly; it holds during fast changes and fades in
        position mode.
        """
        s = self.settings
        self.pressure_bar = pressure_meas_bar
        rate_bar_s = (pressure_ref_bar - self.pressure_ref_bar) / self.pressure_period_s
        self.pressure_ref_bar = pressure_ref_bar
        if not pressure_mode:
            self.trim_rad *= self._trim_decay
        elif pressure_ref_bar > s.pressure_trim_min_bar and abs(rate_bar_s) < s.pressure_trim_max_rate_bar_s:
            limit = s.pressure_trim_error_limit_bar
            error = min(max(pressure_ref_bar - pressure_meas_bar, -limit), limit)
            trim = self.trim_rad + s.pressure_trim_gain_rad_per_bar_s * self.pressure_period_s * error
            self.trim_rad = min(max(trim, -s.pressure_trim_limit_rad), s.pressure_trim_limit_rad)

    def update(self, theta_meas_rad: float, omega_est_rad_s: float, i_a_a: float, i_b_a: float, i_c_a: float,
               u_dc_meas_v: float, theta_ref_rad: float, omega_ff_rad_s: float, alpha_ff_rad_s2: float,
               speed_limit_rad_s: float, current_limit_a: float) -> tuple[float, float, float]:
        """One control period; returns the duties (d_a, d_b, d_c), each in 0..1."""
        T = self.period_s
        # position -> speed reference
        w_ref = omega_ff_rad_s + self.settings.position_gain_1_s * (theta_ref_rad + self.trim_rad - theta_meas_rad)
        if w_ref > speed_limit_rad_s:
            w_ref = speed_limit_rad_s
        elif w_ref < -speed_limit_rad_s:
            w_ref = -speed_limit_rad_s
        # speed PI -> q-current reference
        e_w = w_ref - omega_est_rad_s
        i_lim = min(current_limit_a, self.settings.current_limit_a)
        ff = self._load_ff * self.pressure_bar + self._j_over_kt * alpha_ff_rad_s2
        raw = self.kp_w * e_w + self.int_w + ff
        i_q_ref = min(max(raw, -i_lim), i_lim)
        if raw == i_q_ref or (raw > i_lim and e_w < 0.0) or (raw < -i_lim and e_w > 0.0):
            self.int_w = min(max(self.int_w + self.ki_w * T * e_w, -i_lim), i_lim)
        self.i_q_ref = i_q_ref
        # measured currents -> d/q with the measured angle
        th_e = self._p * theta_meas_rad
        c, s = math.cos(th_e), math.sin(th_e)
        i_al = (2.0 / 3.0) * (i_a_a - 0.5 * (i_b_a + i_c_a))
        i_be = INV_SQRT3 * (i_b_a - i_c_a)
        i_d = i_al * c + i_be * s
        i_q = i_be * c - i_al * s
        # current PI with decoupling
        w_e = self._p * omega_est_rad_s
        e_d = -i_d
        e_q = i_q_ref - i_q
        v_d = self.kp_d * e_d + self.int_d - w_e * self._Lq * i_q
        v_q = self.kp_q * e_q + self.int_q + w_e * (self._Ld * i_d + self._psi)
        u_dc = u_dc_meas_v if u_dc_meas_v > 1.0 else 1.0
        v_max = self.settings.voltage_margin * u_dc * INV_SQRT3
        v_abs = math.hypot(v_d, v_q)
        if v_abs > v_max:
            scale = v_max / v_abs
            v_d *= scale
            v_q *= scale
        else:
            self.int_d += self.ki_i * T * e_d
            self.int_q += self.ki_i * T * e_q
        # inverse Park with delay compensation, inverse Clarke, min-max zero sequence
        th_apply = th_e + 1.5 * w_e * T
        c, s = math.cos(th_apply), math.sin(th_apply)
        v_al = v_d * c - v_q * s
        v_be = v_d * s + v_q * c
        v_a = v_al
        v_b = -0.5 * v_al + SQRT3_2 * v_be
        v_c = -0.5 * v_al - SQRT3_2 * v_be
        v_0 = -0.5 * (max(v_a, v_b, v_c) + min(v_a, v_b, v_c))
        inv_u = 1.0 / u_dc
        d_a = 0.5 + (v_a + v_0) * inv_u
        d_b = 0.5 + (v_b + v_0) * inv_u
        d_c = 0.5 + (v_c + v_0) * inv_u
        return (min(max(d_a, 0.0), 1.0), min(max(d_b, 0.0), 1.0), min(max(d_c, 0.0), 1.0))
