"""Motor parameters of the bench: the FMU's nominal values and the bench's "true" values.

The nominal values are those of the physics conventions (FMU parameter names, SI units);
a case may override them in ``fmu.parameters``. The bench motor uses the nominal values
scaled by relative offsets (``bench.true_parameter_offsets``), so the FMU is a few percent
off the "hardware" it models.
"""

from __future__ import annotations

from typing import Any, Mapping

#: Nominal FMU parameters (SI): pole pairs, resistance (ohm), inductances (H), flux linkage (Wb),
#: inertia (kg m^2), viscous friction (N m s), end stops (rad).
NOMINAL_PARAMETERS: dict[str, float] = {
    "p": 4,
    "R": 0.03,
    "L_d": 60e-6,
    "L_q": 60e-6,
    "psi": 6e-3,
    "J": 2e-4,
    "b": 2e-5,
    "theta_min": 0.0,
    "theta_max": 60.0,
}

#: Parameters that may carry a relative offset on the bench.
OFFSET_PARAMETERS: tuple[str, ...] = ("R", "L_d", "L_q", "psi", "J", "b")


def nominal_parameters(fmu_overrides: Mapping[str, Any] | None = None) -> dict[str, float]:
    """Nominal parameters, updated with the case's ``fmu.parameters`` where they name a known one."""
    params = dict(NOMINAL_PARAMETERS)
    for name, value in (fmu_overrides or {}).items():
        if name in params:
            params[name] = int(value) if name == "p" else float(value)
    if params["p"] < 1:
        raise ValueError(f"config.fmu.parameters.p: expected a positive number of pole pairs, got {params['p']}")
    if not params["theta_min"] < params["theta_max"]:
        raise ValueError("config.fmu.parameters: expected theta_min < theta_max, got "
                         f"{params['theta_min']} and {params['theta_max']}")
    return params


def true_parameters(nominal: Mapping[str, float], offsets: Mapping[str, float]) -> dict[str, float]:
    """Bench ("true") parameters: ``nominal[name] * (1 + offsets[name])`` for each offset.

    Raises:
        ValueError: an offset names an unknown parameter or would make it non-positive.
    """
    params = dict(nominal)
    for name, offset in offsets.items():
        if name not in OFFSET_PARAMETERS:
            raise ValueError(f"config.bench.true_parameter_offsets.{name}: unknown parameter, "
                             f"expected one of {list(OFFSET_PARAMETERS)}")
        if not -0.5 < float(offset) < 0.5:
            raise ValueError(f"config.bench.true_parameter_offsets.{name}: expected a relative offset "
                             f"in (-0.5, 0.5), got {offset}")
        params[name] = nominal[name] * (1.0 + float(offset))
    return params
