"""Physical units through pint: parsing log and FMU unit strings, conversions, dimension checks.

Any unit pint knows is accepted (``rpm``, ``bar``, ``N*m``, ``%``, ``degC`` ...). FMU unit strings
follow the Modelica convention (``N.m``, ``kg.m2``, ``rad/s2``: ``.`` multiplies, a trailing
number is an exponent); :func:`parse_unit` reads both spellings. Conversions may be affine
(``degC`` -> ``K``); :func:`converter` returns ``(factor, offset)`` with
``value_target = factor * value_source + offset``.

Radians count as dimensionless (pint's convention), so an angle and a ratio share a dimension;
``deg`` still converts to ``rad`` by its factor.

API::

    parse_unit(text) -> pint.Unit
    unit_string(unit) -> str                       # canonical short spelling ("rad/s")
    same_dimension(a, b) -> bool
    converter(source, target) -> (factor, offset)
    base_unit(text) -> str                         # the SI (base) unit of a unit string
"""

from __future__ import annotations

import functools
import re

import pint

#: The one registry of the package (quantities of different registries do not mix).
UREG = pint.UnitRegistry(autoconvert_offset_to_baseunit=True)
UREG.define("Ohm = ohm")  # the spelling of Modelica's SIunits
if hasattr(UREG, "formatter"):  # keep the written order of factors ("N*m", not pint's sorted "m*N")
    UREG.formatter.default_sort_func = None

#: ECU spellings of revolutions per minute: pint reads "1/min" as 1/(60 s), and with radians
#: dimensionless that is 1/(2 pi) rpm; a speed logged in "1/min" means rev/min.
_RPM_SPELLINGS = {"1/min", "U/min", "u/min", "r/min", "rev/min", "min^-1", "min-1", "min**-1", "1/min."}

_MODELICA_FACTOR = re.compile(r"(?<=[A-Za-z\)])\.(?=[A-Za-z\(])")
_MODELICA_EXPONENT = re.compile(r"(?<=[A-Za-z])(-?\d+)(?![\d.])")


class UnitError(ValueError):
    """A unit string is unknown, or two units do not share a dimension."""


def _pint_spelling(text: str) -> str:
    """Normalise a unit string: Modelica ``N.m``/``kg.m2``, ``·``, ``µ``, ``°`` -> pint's spelling."""
    spelled = text.strip()
    if spelled.replace(" ", "") in _RPM_SPELLINGS:
        return "rpm"
    spelled = spelled.replace("·", "*").replace("⋅", "*").replace("µ", "u").replace("μ", "u")
    spelled = spelled.replace("°C", "degC").replace("°F", "degF").replace("°", "deg")
    spelled = _MODELICA_FACTOR.sub("*", spelled)
    spelled = _MODELICA_EXPONENT.sub(r"**\1", spelled)
    if spelled in ("", "-", "1"):
        return "dimensionless"
    return spelled


@functools.lru_cache(maxsize=512)
def parse_unit(text: str) -> pint.Unit:
    """The pint unit of a unit string (log, config or FMU spelling).

    Raises:
        UnitError: pint does not know the unit (the message quotes it).
    """
    if not isinstance(text, str):
        raise UnitError(f"unit {text!r}: expected a unit string")
    try:
        return UREG.parse_units(_pint_spelling(text))
    except (pint.errors.UndefinedUnitError, pint.errors.DefinitionSyntaxError, AttributeError, TypeError,
            ValueError, AssertionError) as err:
        raise UnitError(f"unknown unit {text!r} ({err})") from None


def unit_string(unit: pint.Unit | str) -> str:
    """Short canonical spelling of a unit (``"rad/s"``, ``"N*m"``, ``""`` for dimensionless)."""
    unit = parse_unit(unit) if isinstance(unit, str) else unit
    return f"{unit:~C}" if unit != UREG.dimensionless else ""


def dimension(text: str) -> str:
    """The dimensionality of a unit string, spelled for messages (``"[length] / [time]"``)."""
    dims = parse_unit(text).dimensionality
    return str(dims) if dims else "dimensionless"


def same_dimension(a: str, b: str) -> bool:
    """True when the two unit strings measure the same physical dimension."""
    return parse_unit(a).dimensionality == parse_unit(b).dimensionality


@functools.lru_cache(maxsize=512)
def converter(source: str, target: str) -> tuple[float, float]:
    """``(factor, offset)`` with ``value_in_target = factor * value_in_source + offset``.

    Raises:
        UnitError: a unit is unknown, or the two do not share a dimension (names both).
    """
    src, dst = parse_unit(source), parse_unit(target)
    if src.dimensionality != dst.dimensionality:
        raise UnitError(f"cannot convert {source!r} ({dimension(source)}) to {target!r} ({dimension(target)})")
    zero = UREG.Quantity(0.0, src).to(dst).magnitude
    one = UREG.Quantity(1.0, src).to(dst).magnitude
    return float(one - zero), float(zero)


def base_unit(text: str) -> str:
    """The SI base unit of a unit string, spelled canonically (``bar`` -> ``"kg/m/s**2"``)."""
    quantity = UREG.Quantity(1.0, parse_unit(text)).to_base_units()
    return unit_string(quantity.units)


def parse_quantity(text: str) -> pint.Quantity:
    """A quantity from a string with a number and a unit (``"1.25e-7 N*m/Pa"``).

    Raises:
        UnitError: the string is not a number followed by a known unit.
    """
    try:
        number, _, unit = str(text).strip().partition(" ")
        return UREG.Quantity(float(number), parse_unit(unit.strip() or "1"))
    except (ValueError, UnitError) as err:
        raise UnitError(f"{text!r}: expected a number and a unit, e.g. '0.0125 N*m/bar' ({err})") from None
