"""Transforms of three-phase electric machines: phase quantities to the rotor (dq) frame.

``{kind: park, phases: [a, b, c], angle: <signal>, pole_pairs: <int>, outputs: [d, q]}``: the
amplitude-invariant Clarke transform of the phase signals, then the Park transform with the
electrical angle ``pole_pairs * angle`` (the MEASURED angle, converted to rad from its unit):

    alpha = (2/3)(a - b/2 - c/2),  beta = (b - c)/sqrt(3)
    d = alpha cos(theta_e) + beta sin(theta_e),  q = -alpha sin(theta_e) + beta cos(theta_e)

With two phases given, the third follows from ``a + b + c = 0``. The outputs carry the unit of
the first phase (the others are converted to it). With three phases given, their sum is checked first: in a
three-phase machine without a neutral conductor it is 0 up to sensor noise and offsets, so a sum of the order
of the phases themselves means a phase sensor that is stuck, disconnected or scaled wrongly
(:func:`check_phase_sum`), and the log is refused rather than turned into wrong rotor-frame signals.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hybridfmu.data.transforms.base import Transform, TransformError
from hybridfmu.units import UnitError, converter, same_dimension


def clarke_park(phase_a: np.ndarray, phase_b: np.ndarray, phase_c: np.ndarray,
                electrical_angle_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude-invariant Clarke then Park transform; all arguments (T,) -> (d, q), each (T,)."""
    alpha = (2.0 / 3.0) * (phase_a - 0.5 * phase_b - 0.5 * phase_c)
    beta = (phase_b - phase_c) / np.sqrt(3.0)
    cos_e, sin_e = np.cos(electrical_angle_rad), np.sin(electrical_angle_rad)
    return alpha * cos_e + beta * sin_e, -alpha * sin_e + beta * cos_e


def inverse_clarke_park(d: np.ndarray, q: np.ndarray, electrical_angle_rad: np.ndarray) -> np.ndarray:
    """Rotor-frame (d, q), each (T,), back to the three phases (T, 3) (inverse of :func:`clarke_park`)."""
    cos_e, sin_e = np.cos(electrical_angle_rad), np.sin(electrical_angle_rad)
    alpha = d * cos_e - q * sin_e
    beta = d * sin_e + q * cos_e
    phase_a = alpha
    phase_b = -0.5 * alpha + (np.sqrt(3.0) / 2.0) * beta
    return np.stack([phase_a, phase_b, -phase_a - phase_b], axis=-1)


#: A phase sum above this fraction of the phases' RMS is implausible (measured logs: a few per cent; one phase
#: stuck at 0: about 1).
PHASE_SUM_RELATIVE = 0.5
#: ... and above this many times the sum's noise (from the phases' sample-to-sample noise): an idle machine's
#: phases are noise only, and their sum is as large as they are.
PHASE_SUM_NOISE_FACTOR = 5.0


def check_phase_sum(phases: list[np.ndarray], names: list[str], unit: str) -> None:
    """Raise TransformError when three phase signals (each (T,), in ``unit``) do not sum to about 0.

    The sum's RMS must stay below :data:`PHASE_SUM_RELATIVE` times the phases' RMS or below
    :data:`PHASE_SUM_NOISE_FACTOR` times the noise the sum has anyway (each phase's white noise estimated from
    its first differences)."""
    values = np.stack([np.asarray(v, dtype=np.float64) for v in phases])
    total_rms = float(np.sqrt(np.mean(values.sum(axis=0) ** 2)))
    phase_rms = float(np.sqrt(np.mean(values ** 2)))
    noise_rms = float(np.sqrt(sum(np.var(np.diff(v)) / 2.0 for v in values)))
    if total_rms > PHASE_SUM_RELATIVE * phase_rms and total_rms > PHASE_SUM_NOISE_FACTOR * noise_rms:
        flat = [name for name, v in zip(names, values) if np.ptp(v) == 0.0]
        hint = f"; {flat} never change{'s' if len(flat) == 1 else ''}" if flat else ""
        raise TransformError(f"park: phases {names} sum to {total_rms:.3g} {unit} RMS, {total_rms / phase_rms:.0%} of "
                             f"the phases' {phase_rms:.3g} {unit} RMS{hint}; expected about 0 (a + b + c = 0 in a "
                             "three-phase machine without neutral): a phase sensor stuck, disconnected or scaled "
                             "wrongly")


class Park(Transform):
    """Clarke + Park of phase signals with a measured mechanical angle (module docstring)."""

    kind = "park"

    def inputs(self, spec: dict[str, Any]) -> list[str]:
        return [*spec["phases"], spec["angle"]]

    def outputs(self, spec: dict[str, Any]) -> list[str]:
        return list(spec["outputs"])

    def output_units(self, spec: dict[str, Any], units: dict[str, str], where: str) -> dict[str, str]:
        phases = list(spec["phases"])
        if len(phases) not in (2, 3):
            raise TransformError(f"{where}.phases: {phases}; expected two or three phase signals")
        if len(spec["outputs"]) != 2:
            raise TransformError(f"{where}.outputs: {spec['outputs']}; expected two names (d, q)")
        if int(spec.get("pole_pairs", 0)) < 1:
            raise TransformError(f"{where}.pole_pairs: {spec.get('pole_pairs')!r}; expected an integer >= 1")
        first = units[phases[0]]
        for name in phases[1:]:
            if not same_dimension(units[name], first):
                raise TransformError(f"{where}.phases: {name} is in {units[name]!r}, {phases[0]} in {first!r}; "
                                     "expected phases of one dimension")
        try:
            converter(units[spec["angle"]], "rad")
        except UnitError as err:
            raise TransformError(f"{where}.angle: signal {spec['angle']!r}: {err}; expected an angle") from None
        return {name: first for name in spec["outputs"]}

    def apply(self, spec: dict[str, Any], columns: dict[str, np.ndarray], units: dict[str, str],
              rate_hz: float) -> dict[str, np.ndarray]:
        phases = list(spec["phases"])
        first = units[phases[0]]
        values = []
        for name in phases:
            factor, offset = converter(units[name], first)
            values.append(factor * np.asarray(columns[name], dtype=np.float64) + offset)
        if len(values) == 2:
            values.append(-values[0] - values[1])
        else:
            check_phase_sum(values, phases, first)
        factor, offset = converter(units[spec["angle"]], "rad")
        angle_rad = factor * np.asarray(columns[spec["angle"]], dtype=np.float64) + offset
        d, q = clarke_park(*values, int(spec["pole_pairs"]) * angle_rad)
        name_d, name_q = spec["outputs"]
        return {name_d: d, name_q: q}
