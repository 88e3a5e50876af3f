"""The bench ECU's motor-control software as the demo's closed-loop controller.

In software-in-the-loop tests the control software closes the loop around the model. The demo's control
software is the bench's cascade (:class:`hybridfmu_bench.controller.CascadeController`) with its angle-tracking
speed observer; this module exposes it through the controller interface of
:mod:`hybridfmu.evaluation.closed_loop` (config ``closed_loop.controller: hybridfmu_bench.ecu:EcuSoftware``).
It carries only what the ECU has: its tuning, the nominal motor parameters it was designed with, its
pressure-to-load factor and its rates. Nothing of the bench's plant, effects or sensors comes with it: it reads the
model's states directly (no encoder quantisation, no current noise) and the logged references and measurements.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

from .controller import CascadeController
from .hydraulics import PA_PER_BAR
from .sensors import SpeedObserver
from .settings import parse_bench_settings

#: The signals the software reads each period (SI units): its references, the measured pressure and supply.
SIGNALS = ("pressure_request", "pressure_mode", "theta_ref", "omega_ff", "alpha_ff", "speed_limit",
           "current_limit", "pressure", "u_dc")

#: The model states it reads (A, A, rad, rad/s) and the duties (0..1) it writes.
STATES = ("i_d", "i_q", "theta", "omega")
OUTPUTS = ("d_a", "d_b", "d_c")


class EcuSoftware:
    """The ECU's cascade and speed observer, one :meth:`step` per control period.

    Args:
        config: the case config (its ``bench`` section: the controller's tuning, nominal parameters, rates).
        period_s: the period the closed loop calls :meth:`step` with (s); must be the ECU's control period.

    Raises:
        ValueError: ``period_s`` is not the ECU's control period.
    """

    signals = SIGNALS
    states = STATES
    outputs = OUTPUTS

    def __init__(self, config: Mapping[str, Any], period_s: float) -> None:
        settings = parse_bench_settings(config)
        if abs(period_s - settings.period_s) > 1e-9 * settings.period_s:
            raise ValueError(f"closed_loop: the ECU software runs every {settings.period_s:.6g} s (bench PWM "
                             f"period), the closed loop steps {period_s:.6g} s; resample the logs at "
                             f"{1.0 / settings.period_s:g} Hz (config ingest.rate_hz)")
        self.period_s = settings.period_s
        self._decimation = settings.slow_decimation
        self._pole_pairs = float(settings.nominal_parameters["p"])
        self._observer_bandwidth_hz = settings.sensors.speed_observer_bandwidth_hz
        self._controller = CascadeController(settings.controller, settings.nominal_parameters,
                                             settings.displacement_m3_per_rad, self.period_s,
                                             self.period_s * self._decimation)
        self._observer = SpeedObserver(self._observer_bandwidth_hz, self.period_s, 0.0)
        self._k = 0

    def reset(self, states: Mapping[str, float], signals: Mapping[str, float]) -> None:
        """Start at rest: integrators and trim at zero, the observer at the model's angle ``states["theta"]``."""
        self._controller.reset()
        self._observer = SpeedObserver(self._observer_bandwidth_hz, self.period_s, float(states["theta"]))
        self._k = 0

    def step(self, states: Mapping[str, float], signals: Mapping[str, float]) -> dict[str, float]:
        """One control period with the model's ``states`` ({i_d, i_q: A; theta: rad; omega: rad/s}) and the
        logged ``signals`` (:data:`SIGNALS`, SI units: Pa, rad, rad/s, rad/s^2, A, V); returns the duties
        {d_a, d_b, d_c} (0..1) to apply from the next period on."""
        theta = float(states["theta"])
        omega_hat = self._observer.update(theta)
        th_e = self._pole_pairs * theta
        c, s = math.cos(th_e), math.sin(th_e)
        i_d, i_q = float(states["i_d"]), float(states["i_q"])
        i_alpha, i_beta = i_d * c - i_q * s, i_d * s + i_q * c
        i_a = i_alpha
        i_b = -0.5 * i_alpha + 0.5 * math.sqrt(3.0) * i_beta
        i_c = -0.5 * i_alpha - 0.5 * math.sqrt(3.0) * i_beta
        if self._k % self._decimation == 0:
            self._controller.update_pressure(float(signals["pressure"]) / PA_PER_BAR,
                                             float(signals["pressure_request"]) / PA_PER_BAR,
                                             float(signals["pressure_mode"]) > 0.5)
        self._k += 1
        d_a, d_b, d_c = self._controller.update(theta, omega_hat, i_a, i_b, i_c, float(signals["u_dc"]),
                                                float(signals["theta_ref"]), float(signals["omega_ff"]),
                                                float(signals["alpha_ff"]), float(signals["speed_limit"]),
                                                float(signals["current_limit"]))
        return {"d_a": d_a, "d_b": d_b, "d_c": d_c}
