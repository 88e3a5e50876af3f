"""Hydraulics of the pressure build-up unit: ball screw, piston and the pressure-volume curve.

The ball screw (lead ``screw_lead_m`` per revolution) moves the piston (``piston_diameter_m``)
by ``lead * theta / (2 pi)``; the displaced brake-fluid volume is therefore
``V = displacement_m3_per_rad * theta``. Past a dead travel (the piston closes the
compensation port, pads close the air gap) the brake circuit stiffens exponentially:

    p(theta) = p_scale * (exp(dV / V_scale) - 1),   dV = displacement * (theta - theta_dead) > 0,
    p(theta) = 0                                    otherwise.

By virtual work the pressure loads the rotor with ``tau_load = p * displacement_m3_per_rad``
(N m, opposing positive theta); ``displacement_m3_per_rad`` is thus also the static
pressure-to-torque factor (N m per Pa).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PA_PER_BAR = 1.0e5
M3_PER_CM3 = 1.0e-6


def displacement_m3_per_rad(piston_diameter_m: float, screw_lead_m: float) -> float:
    """Brake-fluid volume displaced per radian of rotor angle (m^3/rad) = area * lead / (2 pi)."""
    area_m2 = math.pi * piston_diameter_m ** 2 / 4.0
    return area_m2 * screw_lead_m / (2.0 * math.pi)


@dataclass(frozen=True)
class PressureVolumeCurve:
    """Stiffening pressure-volume curve in terms of the rotor angle.

    Attributes:
        dead_travel_rad: rotor angle below which the pressure is zero (rad).
        pressure_scale_bar: ``p_scale`` of the exponential (bar).
        volume_scale_cm3: ``V_scale`` of the exponential (cm^3).
        displacement_m3_per_rad: fluid volume per rotor radian (m^3/rad).
    """

    dead_travel_rad: float
    pressure_scale_bar: float
    volume_scale_cm3: float
    displacement_m3_per_rad: float

    def __post_init__(self) -> None:
        for name in ("pressure_scale_bar", "volume_scale_cm3", "displacement_m3_per_rad"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"pressure-volume curve: {name} must be positive, got {getattr(self, name)}")

    @property
    def angle_scale_rad(self) -> float:
        """Rotor angle over which the pressure grows by a factor e (rad)."""
        return self.volume_scale_cm3 * M3_PER_CM3 / self.displacement_m3_per_rad

    def pressure_pa(self, theta_rad: float) -> float:
        """Pressure (Pa) at the scalar rotor angle ``theta_rad`` (rad)."""
        x = theta_rad - self.dead_travel_rad
        if x <= 0.0:
            return 0.0
        return self.pressure_scale_bar * PA_PER_BAR * (math.exp(x / self.angle_scale_rad) - 1.0)

    def pressure_bar_array(self, theta_rad: np.ndarray) -> np.ndarray:
        """Pressure (bar) for an array of rotor angles (rad), same shape."""
        x = np.maximum(np.asarray(theta_rad, dtype=float) - self.dead_travel_rad, 0.0)
        return self.pressure_scale_bar * np.expm1(x / self.angle_scale_rad)

    def angle_for_pressure_rad(self, pressure_bar: np.ndarray | float) -> np.ndarray:
        """Inverse curve: rotor angle (rad) that gives ``pressure_bar`` (bar); 0 bar -> the dead travel."""
        p = np.maximum(np.asarray(pressure_bar, dtype=float), 0.0)
        return self.dead_travel_rad + self.angle_scale_rad * np.log1p(p / self.pressure_scale_bar)

    def torque_per_pa(self) -> float:
        """Static pressure-to-load-torque factor (N m per Pa)."""
        return self.displacement_m3_per_rad
