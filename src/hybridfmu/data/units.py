"""Unit strings of measurement logs -> SI scale factors, per physical dimension.

Every canonical signal has a dimension (``ratio``, ``angle``, ``angular_velocity``, ``voltage``,
``current``, ``pressure``, ``torque``, ``time``); a unit is accepted only for its dimension, so a duty
logged in volts or an angle in bar is an error, not a silent mis-scaling. All conversions used here
are pure scale factors (SI value = factor * value).

Spelling variants are normalised before the lookup: spaces and the multiplication signs ``·``, ``*``,
``.`` are dropped (``N·m`` = ``Nm``), ``°`` reads as ``deg`` and ``µ``/``μ`` as ``u``. When the exact
spelling is unknown, a case-insensitive match is accepted if it is unique (``RPM``, ``Bar``, ``DEG``).
"""

from __future__ import annotations

import math

#: SI unit of each dimension (what the converted values are in).
SI_UNITS: dict[str, str] = {
    "ratio": "1",
    "angle": "rad",
    "angular_velocity": "rad/s",
    "voltage": "V",
    "current": "A",
    "pressure": "Pa",
    "torque": "N·m",
    "time": "s",
}

_RPM = 2.0 * math.pi / 60.0

#: Accepted units per dimension (normalised spelling -> factor to the SI unit).
UNIT_FACTORS: dict[str, dict[str, float]] = {
    "ratio": {"1": 1.0, "-": 1.0, "ratio": 1.0, "%": 0.01, "percent": 0.01, "‰": 1e-3, "permille": 1e-3},
    "angle": {"rad": 1.0, "mrad": 1e-3, "deg": math.pi / 180.0, "rev": 2.0 * math.pi, "turn": 2.0 * math.pi},
    "angular_velocity": {
        "rad/s": 1.0, "deg/s": math.pi / 180.0, "rpm": _RPM, "1/min": _RPM, "U/min": _RPM, "r/min": _RPM,
        "rev/min": _RPM, "min^-1": _RPM, "min-1": _RPM, "krpm": 1e3 * _RPM, "rps": 2.0 * math.pi,
        "rev/s": 2.0 * math.pi,
    },
    "voltage": {"V": 1.0, "mV": 1e-3, "uV": 1e-6, "kV": 1e3},
    "current": {"A": 1.0, "mA": 1e-3, "uA": 1e-6, "kA": 1e3},
    "pressure": {
        "Pa": 1.0, "hPa": 1e2, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "mbar": 1e2, "psi": 6894.757293168361,
    },
    "torque": {"Nm": 1.0, "mNm": 1e-3, "Ncm": 1e-2, "kNm": 1e3, "Nmm": 1e-3},
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "min": 60.0, "h": 3600.0},
}


class UnitError(ValueError):
    """A unit string is unknown or belongs to another dimension."""


def normalise_unit(unit: str) -> str:
    """Canonical spelling of a unit string (see the module docstring)."""
    text = unit.strip()
    for sign in (" ", "·", "*", "⋅", "."):
        text = text.replace(sign, "")
    return text.replace("°", "deg").replace("µ", "u").replace("μ", "u")


def si_factor(unit: str, dimension: str) -> float:
    """Factor that converts values in ``unit`` to the SI unit of ``dimension``.

    Raises:
        UnitError: the unit is unknown, or known but of another dimension (the message lists
            the units accepted for ``dimension``).
    """
    if dimension not in UNIT_FACTORS:
        raise UnitError(f"unknown dimension {dimension!r}; known: {sorted(UNIT_FACTORS)}")
    table = UNIT_FACTORS[dimension]
    key = normalise_unit(unit)
    if key in table:
        return table[key]
    folded = [name for name in table if name.lower() == key.lower()]
    if len(folded) == 1:
        return table[folded[0]]
    accepted = ", ".join(repr(name) for name in table)
    other = [dim for dim, units in UNIT_FACTORS.items() if key in units or
             any(name.lower() == key.lower() for name in units)]
    hint = f" ({unit!r} is a unit of {other[0]})" if other else ""
    raise UnitError(f"cannot convert unit {unit!r} to {SI_UNITS[dimension]} ({dimension}){hint}; "
                    f"accepted units: {accepted}")
