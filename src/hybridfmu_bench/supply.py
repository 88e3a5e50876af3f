"""Supply of the bench inverter: a battery line with ripple and a resistive sag under load."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Supply:
    """U_dc(t) = U_nominal + A sin(2 pi f t) - R_source * i_dc.

    Attributes:
        nominal_v: open-circuit supply voltage (V).
        source_resistance_ohm: resistance of battery and wiring (ohm).
        ripple_amplitude_v: amplitude of the ripple (V).
        ripple_frequency_hz: frequency of the ripple (Hz).
    """

    nominal_v: float = 12.0
    source_resistance_ohm: float = 0.015
    ripple_amplitude_v: float = 0.1
    ripple_frequency_hz: float = 90.0

    def __post_init__(self) -> None:
        if not self.nominal_v > 0.0:
            raise ValueError(f"config.bench.supply.nominal_v: expected a positive voltage, got {self.nominal_v}")
        if self.source_resistance_ohm < 0.0 or self.ripple_amplitude_v < 0.0 or self.ripple_frequency_hz < 0.0:
            raise ValueError("config.bench.supply: source_resistance_ohm, ripple_amplitude_v and "
                             "ripple_frequency_hz must be >= 0")

    def voltage_v(self, t_s: float, i_dc_a: float) -> float:
        """Inverter input voltage (V) at time ``t_s`` (s) when the inverter draws ``i_dc_a`` (A)."""
        return (self.nominal_v + self.ripple_amplitude_v * math.sin(2.0 * math.pi * self.ripple_frequency_hz * t_s)
                - self.source_resistance_ohm * i_dc_a)
