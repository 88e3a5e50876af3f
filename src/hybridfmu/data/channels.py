"""The channel map: canonical signals of the ingested data and the raw channels they come from.

A case config maps each canonical signal (``config.ingest.channels.<signal>``) to a raw channel
name, optionally with its unit (used when the file has none, checked against the file's otherwise),
a gain and offset (applied in the raw unit) and a wrap period (for single-turn angles). This module
knows which signals exist, which are required, their physical dimension and their output column.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from hybridfmu.data.errors import DataError


@dataclass(frozen=True)
class CanonicalSignal:
    """A signal of the ingested data: its output column (SI) and physical dimension."""

    name: str
    column: str
    dimension: str


#: Canonical signals in output-column order (``time`` only names the time column of tables).
CANONICAL_SIGNALS: tuple[CanonicalSignal, ...] = (
    CanonicalSignal("duty_a", "duty_a", "ratio"),
    CanonicalSignal("duty_b", "duty_b", "ratio"),
    CanonicalSignal("duty_c", "duty_c", "ratio"),
    CanonicalSignal("u_dc", "u_dc_v", "voltage"),
    CanonicalSignal("tau_load", "tau_load_nm", "torque"),
    CanonicalSignal("angle", "theta_rad", "angle"),
    CanonicalSignal("speed", "omega_rad_s", "angular_velocity"),
    CanonicalSignal("i_a", "i_a_a", "current"),
    CanonicalSignal("i_b", "i_b_a", "current"),
    CanonicalSignal("i_c", "i_c_a", "current"),
    CanonicalSignal("pressure", "pressure_pa", "pressure"),
)
SIGNALS_BY_NAME: dict[str, CanonicalSignal] = {signal.name: signal for signal in CANONICAL_SIGNALS}
TIME_SIGNAL = CanonicalSignal("time", "time_s", "time")

#: Signals every channel map must name (load: ``tau_load`` or ``pressure``; speed may be derived).
REQUIRED_SIGNALS = ("duty_a", "duty_b", "duty_c", "u_dc", "angle")
PHASE_CURRENTS = ("i_a", "i_b", "i_c")


@dataclass(frozen=True)
class ChannelSpec:
    """One entry of the channel map.

    Attributes:
        signal: canonical signal name (``duty_a`` ... ``pressure``, or ``time``).
        name: raw channel (or column) name in the log.
        unit: unit from the channel map, or None (then the file's unit is used).
        gain, offset: value = gain * raw + offset, in the raw unit, before the SI conversion.
        wrap_period: period (raw unit) of a wrapping channel to unwrap, or None.
    """

    signal: str
    name: str
    unit: str | None = None
    gain: float = 1.0
    offset: float = 0.0
    wrap_period: float | None = None

    @property
    def dimension(self) -> str:
        return TIME_SIGNAL.dimension if self.signal == "time" else SIGNALS_BY_NAME[self.signal].dimension

    @property
    def column(self) -> str:
        return TIME_SIGNAL.column if self.signal == "time" else SIGNALS_BY_NAME[self.signal].column


def channel_specs(settings: dict[str, Any]) -> dict[str, ChannelSpec]:
    """The channel map of a validated ``ingest`` section as ``{signal: ChannelSpec}`` (without ``time``).

    Checks what the schema cannot: a load source (``tau_load``, or ``pressure`` with a conversion
    factor), phase currents complete enough (two or three of them), distinct raw names.

    Raises:
        DataError: naming the ``config.ingest`` field and what is expected.
    """
    channels = settings["channels"]
    specs = {signal: _spec(signal, entry) for signal, entry in channels.items() if signal != "time"}
    missing = [signal for signal in REQUIRED_SIGNALS if signal not in specs]
    if missing:
        raise DataError(f"config.ingest.channels: no raw channel given for {missing} (required: "
                        f"{list(REQUIRED_SIGNALS)}, plus tau_load or pressure)")
    if "tau_load" not in specs:
        if "pressure" not in specs:
            raise DataError("config.ingest.channels: needs `tau_load` (a load-torque channel) or `pressure` "
                            "(with config.ingest.tau_load_nm_per_pa or tau_load_nm_per_bar)")
        pressure_to_torque_nm_per_pa(settings)
    currents = [signal for signal in PHASE_CURRENTS if signal in specs]
    if len(currents) == 1:
        raise DataError(f"config.ingest.channels: only {currents[0]} of the phase currents is given; "
                        "give two (the third follows from i_a + i_b + i_c = 0) or all three, or none")
    names = [spec.name for spec in specs.values()]
    duplicated = sorted({name for name in names if names.count(name) > 1})
    if duplicated:
        raise DataError(f"config.ingest.channels: raw channel(s) {duplicated} mapped to more than one signal")
    return specs


def time_spec(settings: dict[str, Any]) -> ChannelSpec:
    """The time column of table logs (CSV, Parquet); MDF4 channels carry their own time bases."""
    return _spec("time", settings["channels"].get("time", {"name": "time", "unit": "s"}))


def pressure_to_torque_nm_per_pa(settings: dict[str, Any]) -> float:
    """The static load-torque factor (N·m per Pa) from ``tau_load_nm_per_pa`` or ``tau_load_nm_per_bar``."""
    per_pa = settings.get("tau_load_nm_per_pa")
    per_bar = settings.get("tau_load_nm_per_bar")
    if per_pa is not None and per_bar is not None:
        raise DataError("config.ingest: give tau_load_nm_per_pa or tau_load_nm_per_bar, not both")
    if per_pa is None and per_bar is None:
        raise DataError("config.ingest: the load torque comes from `pressure`, so tau_load_nm_per_pa "
                        "(or tau_load_nm_per_bar) is required")
    return float(per_pa) if per_pa is not None else float(per_bar) / 1e5


def _spec(signal: str, entry: dict[str, Any]) -> ChannelSpec:
    return ChannelSpec(
        signal=signal,
        name=str(entry["name"]),
        unit=entry.get("unit"),
        gain=float(entry.get("gain", 1.0)),
        offset=float(entry.get("offset", 0.0)),
        wrap_period=entry.get("wrap_period"),
    )
