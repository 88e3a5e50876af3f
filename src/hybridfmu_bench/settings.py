"""The ``bench`` section of a case config, parsed into typed settings with defaults.

The defaults here equal those of ``src/hybridfmu/schemas/bench.schema.yaml`` (a test checks it), so
a bench section that passed the schema and a partial one built in a test behave the same.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from .controller import ControllerSettings
from .effects import Effect, build_effects
from .hydraulics import PressureVolumeCurve, displacement_m3_per_rad
from .maneuvers import scale_maneuver, validate_maneuver
from .parameters import nominal_parameters, true_parameters
from .supply import Supply


@dataclass(frozen=True)
class HydraulicsSettings:
    """Geometry and true pressure-volume curve (``bench.hydraulics``); units in the names."""

    piston_diameter_m: float = 0.02
    screw_lead_m: float = 0.0025
    dead_travel_rad: float = 5.3
    pressure_scale_bar: float = 4.6
    volume_scale_cm3: float = 1.45


@dataclass(frozen=True)
class EcuMapSettings:
    """The ECU's nominal pressure-volume map (``bench.controller.ecu_map``)."""

    dead_travel_rad: float = 5.0
    pressure_scale_bar: float = 5.0
    volume_scale_cm3: float = 1.5


@dataclass(frozen=True)
class SensorSettings:
    """Sensors and their logging (``bench.sensors``); units in the names.

    Attributes:
        encoder_counts_per_rev: encoder counts per mechanical revolution.
        speed_observer_bandwidth_hz: bandwidth of the speed observer (Hz).
        current_noise_a, current_step_a: phase-current noise (std, A) and ADC step (A).
        pressure_lag_s: time constant of the pressure sensor's lag (s).
        pressure_noise_bar, pressure_step_bar: pressure noise (std, bar) and step (bar).
        u_dc_noise_v, u_dc_step_v: supply-voltage noise (std, V) and step (V).
        slow_rate_hz: sampling rate of the pressure and supply-voltage channels (Hz).
    """

    encoder_counts_per_rev: int = 16384
    speed_observer_bandwidth_hz: float = 200.0
    current_noise_a: float = 0.3
    current_step_a: float = 0.05
    pressure_lag_s: float = 0.0015
    pressure_noise_bar: float = 0.2
    pressure_step_bar: float = 0.05
    u_dc_noise_v: float = 0.02
    u_dc_step_v: float = 0.01
    slow_rate_hz: float = 1000.0


@dataclass(frozen=True)
class BenchSettings:
    """Everything the emulator needs for a case (parsed ``bench`` section + nominal parameters)."""

    seed: int
    master_seed: int
    pwm_frequency_hz: float
    substeps: int
    rest_angle_rad: float
    acceleration_limit_rad_s2: float
    nominal_parameters: dict[str, float]
    parameter_offsets: dict[str, float]
    true_parameters: dict[str, float]
    hydraulics: HydraulicsSettings
    supply: Supply
    sensors: SensorSettings
    controller: ControllerSettings
    ecu_map: EcuMapSettings
    effects: list[Effect]
    maneuvers: dict[str, dict[str, Any]]
    time_scale: float = 1.0

    @property
    def period_s(self) -> float:
        return 1.0 / self.pwm_frequency_hz

    @property
    def slow_decimation(self) -> int:
        """Control periods per sample of the slow (pressure, supply) channels."""
        return int(round(self.pwm_frequency_hz / self.sensors.slow_rate_hz))

    @property
    def displacement_m3_per_rad(self) -> float:
        return displacement_m3_per_rad(self.hydraulics.piston_diameter_m, self.hydraulics.screw_lead_m)

    def true_curve(self) -> PressureVolumeCurve:
        h = self.hydraulics
        return PressureVolumeCurve(h.dead_travel_rad, h.pressure_scale_bar, h.volume_scale_cm3,
                                   self.displacement_m3_per_rad)

    def ecu_curve(self) -> PressureVolumeCurve:
        m = self.ecu_map
        return PressureVolumeCurve(m.dead_travel_rad, m.pressure_scale_bar, m.volume_scale_cm3,
                                   self.displacement_m3_per_rad)

    def duty_log_offset_s(self) -> float:
        """Sum of the time offsets the active effects put on the logged duty channels (s)."""
        return float(sum(e.duty_log_offset_s() for e in self.effects if "duty_log_offset_s" in e.hooks()))


def _dataclass_from(cls: type, section: Mapping[str, Any] | None, where: str) -> Any:
    """Build the dataclass ``cls`` from a config mapping; unknown keys and non-numbers are errors."""
    section = dict(section or {})
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(section) - set(names))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}, expected some of {sorted(names)}")
    values = {}
    for name, value in section.items():
        default = names[name].default
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ValueError(f"{where}.{name}: expected true or false, got {value!r}")
        elif isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{where}.{name}: expected a number, got {value!r}")
        elif isinstance(default, int) and not isinstance(value, int):
            raise ValueError(f"{where}.{name}: expected an integer, got {value!r}")
        values[name] = value
    return cls(**values)


def parse_bench_settings(config: Mapping[str, Any]) -> BenchSettings:
    """Parse and check ``config["bench"]`` (a whole case config) into :class:`BenchSettings`.

    Raises:
        ValueError: naming the offending field (``config.bench....``) and what was expected.
    """
    if "bench" not in config or not isinstance(config["bench"], Mapping):
        raise ValueError("config.bench: the case config has no bench section (a mapping) to emulate")
    bench = config["bench"]
    where = "config.bench"
    known = {"seed", "pwm_frequency_hz", "substeps", "rest_angle_rad", "true_parameter_offsets", "hydraulics",
             "supply", "sensors", "controller", "effects", "maneuvers", "time_scale"}
    unknown = sorted(set(bench) - known)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}, expected some of {sorted(known)}")
    pwm_frequency_hz = float(bench.get("pwm_frequency_hz", 10000.0))
    if pwm_frequency_hz <= 0.0:
        raise ValueError(f"{where}.pwm_frequency_hz: expected > 0, got {pwm_frequency_hz}")
    substeps = bench.get("substeps", 2)
    if isinstance(substeps, bool) or not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"{where}.substeps: expected an integer >= 1, got {substeps!r}")
    nominal = nominal_parameters(config.get("fmu", {}).get("parameters", {}))
    offsets = {k: float(v) for k, v in (bench.get("true_parameter_offsets") or {}).items()}
    true = true_parameters(nominal, offsets)
    effects = build_effects(dict(bench.get("effects") or {}), pwm_frequency_hz, where=f"{where}.effects")
    for effect in effects:
        effect.adjust_parameters(true)
    controller_section = dict(bench.get("controller") or {})
    ecu_map = _dataclass_from(EcuMapSettings, controller_section.pop("ecu_map", None), f"{where}.controller.ecu_map")
    acceleration_limit = float(controller_section.pop("acceleration_limit_rad_s2", 6000.0))
    if acceleration_limit <= 0.0:
        raise ValueError(f"{where}.controller.acceleration_limit_rad_s2: expected > 0, got {acceleration_limit}")
    controller = _dataclass_from(ControllerSettings, controller_section, f"{where}.controller")
    sensors = _dataclass_from(SensorSettings, bench.get("sensors"), f"{where}.sensors")
    decimation = pwm_frequency_hz / sensors.slow_rate_hz
    if sensors.slow_rate_hz <= 0.0 or abs(decimation - round(decimation)) > 1e-9 or round(decimation) < 1:
        raise ValueError(f"{where}.sensors.slow_rate_hz: expected an integer divisor of the PWM frequency "
                         f"{pwm_frequency_hz} Hz, got {sensors.slow_rate_hz}")
    rest_angle = float(bench.get("rest_angle_rad", 0.5))
    if not nominal["theta_min"] <= rest_angle <= nominal["theta_max"]:
        raise ValueError(f"{where}.rest_angle_rad: expected within the end stops [{nominal['theta_min']}, "
                         f"{nominal['theta_max']}] rad, got {rest_angle}")
    maneuvers = dict(bench.get("maneuvers") or {})
    if not maneuvers:
        raise ValueError(f"{where}.maneuvers: expected at least one maneuver")
    for name, maneuver in maneuvers.items():
        if not isinstance(maneuver, Mapping):
            raise ValueError(f"{where}.maneuvers.{name}: expected a mapping with speed_limit_rad_s, "
                             "current_limit_a and segments")
        validate_maneuver(maneuver, f"{where}.maneuvers.{name}", (nominal["theta_min"], nominal["theta_max"]))
    time_scale = bench.get("time_scale", 1.0)
    if isinstance(time_scale, bool) or not isinstance(time_scale, (int, float)) or not 0.0 < time_scale <= 1.0:
        raise ValueError(f"{where}.time_scale: expected a number in (0, 1] (1 = the designed 12..25 s maneuvers, "
                         f"less = shortened test maneuvers), got {time_scale!r}")
    maneuvers = {name: scale_maneuver(maneuver, float(time_scale)) for name, maneuver in maneuvers.items()}
    seed = bench.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"{where}.seed: expected an integer >= 0, got {seed!r}")
    return BenchSettings(
        seed=seed, master_seed=int(config.get("seed", 0)), pwm_frequency_hz=pwm_frequency_hz, substeps=substeps,
        rest_angle_rad=rest_angle, acceleration_limit_rad_s2=acceleration_limit, nominal_parameters=nominal,
        parameter_offsets=offsets, true_parameters=true,
        hydraulics=_dataclass_from(HydraulicsSettings, bench.get("hydraulics"), f"{where}.hydraulics"),
        supply=_dataclass_from(Supply, bench.get("supply"), f"{where}.supply"),
        sensors=sensors, controller=controller, ecu_map=ecu_map, effects=effects, maneuvers=maneuvers,
        time_scale=float(time_scale),
    )


def check_raw_paths(config: Mapping[str, Any], results_dir: str) -> None:
    """Check that every maneuver's ``raw`` log is the file the bench writes and that the bench defines it.

    Raises:
        ValueError: naming ``config.maneuvers.<name>.raw`` (or ``config.bench.maneuvers``) and the expected value.
    """
    bench_maneuvers = (config.get("bench") or {}).get("maneuvers") or {}
    for name, maneuver in config["maneuvers"].items():
        expected = f"{results_dir}/raw/{name}.mf4"
        if str(maneuver.get("raw", "")) != expected:
            raise ValueError(f"config.maneuvers.{name}.raw: the case has a bench section, so the raw log is the "
                             f"bench's output {expected!r}; got {maneuver.get('raw')!r}")
        if name not in bench_maneuvers:
            raise ValueError(f"config.bench.maneuvers: no maneuver {name!r} (the top-level maneuvers section has "
                             f"it), expected one of {sorted(bench_maneuvers)}")
