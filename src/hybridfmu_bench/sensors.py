"""Sensors of the bench and the ECU's signal processing: what the controller and the logger see.

- encoder: multi-turn mechanical angle quantised to ``counts_per_rev`` counts (truncation);
- speed: angle-tracking observer (type-2 PLL) on the quantised angle;
- phase currents: true current + Gaussian noise, quantised to the ADC step;
- pressure: first-order lag (the sensor and its line) + noise, quantised;
- supply voltage: true U_dc + noise, quantised.
Noise samples are drawn in advance (vectorised) from the seeded generator and passed in.
"""

from __future__ import annotations

import math


def quantise(value: float, step: float) -> float:
    """Round ``value`` to the nearest multiple of ``step`` (step <= 0: unchanged)."""
    return round(value / step) * step if step > 0.0 else value


class Encoder:
    """Rotor-angle sensor with a multi-turn counter.

    Args:
        counts_per_rev: counts per mechanical revolution.
    """

    def __init__(self, counts_per_rev: int) -> None:
        if counts_per_rev < 4:
            raise ValueError(f"config.bench.sensors.encoder_counts_per_rev: expected >= 4, got {counts_per_rev}")
        self.counts_per_rev = int(counts_per_rev)
        self.step_rad = 2.0 * math.pi / self.counts_per_rev
        self._inv_step = 1.0 / self.step_rad

    def measure_rad(self, theta_rad: float) -> float:
        """Measured angle (rad): the true angle truncated to whole counts."""
        return math.floor(theta_rad * self._inv_step) * self.step_rad


class SpeedObserver:
    """Angle-tracking observer (type-2 PLL) giving the speed estimate from the quantised angle.

    theta_hat += T (omega_hat + k1 e); omega_hat += T k2 e, with e = theta_m - theta_hat,
    k1 = 2 zeta w_n, k2 = w_n^2, w_n = 2 pi bandwidth_hz.

    Args:
        bandwidth_hz: natural frequency of the observer (Hz).
        period_s: update period (s).
        theta0_rad: initial angle estimate (rad).
        damping: zeta.
    """

    def __init__(self, bandwidth_hz: float, period_s: float, theta0_rad: float, damping: float = 0.8) -> None:
        w_n = 2.0 * math.pi * bandwidth_hz
        self.k1 = 2.0 * damping * w_n
        self.k2 = w_n * w_n
        self.period_s = period_s
        if self.k1 * period_s > 0.5:
            raise ValueError(f"config.bench.sensors.speed_observer_bandwidth_hz: {bandwidth_hz} Hz is too high for "
                             f"the sampling period {period_s} s")
        self.theta_hat = theta0_rad
        self.omega_hat = 0.0

    def update(self, theta_meas_rad: float) -> float:
        """Feed one angle sample (rad); return the speed estimate (rad/s)."""
        e = theta_meas_rad - self.theta_hat
        self.theta_hat += self.period_s * (self.omega_hat + self.k1 * e)
        self.omega_hat += self.period_s * self.k2 * e
        return self.omega_hat


class PressureSensor:
    """Pressure sensor with first-order lag ``lag_s`` (s); sampled with noise and quantisation.

    Args:
        lag_s: time constant of the lag (s).
        period_s: period at which :meth:`track` is called (s).
        step_bar: quantisation step (bar).
    """

    def __init__(self, lag_s: float, period_s: float, step_bar: float) -> None:
        if lag_s < 0.0:
            raise ValueError(f"config.bench.sensors.pressure_lag_s: expected >= 0, got {lag_s}")
        self.alpha = 1.0 - math.exp(-period_s / lag_s) if lag_s > 0.0 else 1.0
        self.step_bar = step_bar
        self.state_bar = 0.0

    def track(self, pressure_bar: float) -> None:
        """Advance the lag by one period with the true pressure (bar) at the period's start."""
        self.state_bar += self.alpha * (pressure_bar - self.state_bar)

    def sample_bar(self, noise_bar: float) -> float:
        """A measurement (bar): lagged pressure + noise, quantised."""
        return quantise(self.state_bar + noise_bar, self.step_bar)
