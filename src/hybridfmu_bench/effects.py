"""Catalog of unmodelled effects of the test bench, each a small switchable component.

Every effect is a subclass of :class:`Effect` registered in :data:`EFFECTS` under its name.
Its parameters come from ``bench.effects.<name>`` of the case config (``enabled: false`` or
absence switches it off) with the defaults in ``PARAMETERS``. An effect acts through one or
more hooks; the plant only calls the hooks an effect overrides:

- ``torque_nm(theta_rad, omega_rad_s, tau_load_nm)``: extra torque on the rotor (N m,
  positive = towards positive theta); friction returns a negative value for positive speed;
- ``duty_error(i_a_a, i_b_a, i_c_a)``: error of the effective phase duty cycles (fractions of the
  PWM period, added to the commanded duties) as a function of the phase currents (A);
- ``adjust_parameters(params)``: changes the bench's true motor parameters in place;
- ``duty_log_offset_s()``: time offset (s) added to the time stamps of the logged duty channels.

A new effect is one new subclass plus ``@register_effect``.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Mapping

#: Registry: effect name -> effect class.
EFFECTS: dict[str, type["Effect"]] = {}

HOOKS = ("torque_nm", "duty_error", "adjust_parameters", "duty_log_offset_s")


def register_effect(cls: type["Effect"]) -> type["Effect"]:
    """Class decorator: add ``cls`` to :data:`EFFECTS` under ``cls.name``."""
    if not getattr(cls, "name", ""):
        raise TypeError(f"{cls.__name__}: an effect needs a class attribute `name`")
    if cls.name in EFFECTS:
        raise ValueError(f"effect {cls.name!r} is registered twice")
    EFFECTS[cls.name] = cls
    return cls


class Effect:
    """Base class of the effects: parameter handling and do-nothing hooks.

    Args:
        params: parameter values from the config (names as in ``PARAMETERS``); missing ones
            take the defaults.
        pwm_frequency_hz: PWM (and control) frequency of the bench (Hz).
        where: config location used in error messages.
    """

    name: ClassVar[str] = ""
    #: parameter name -> default value (numbers; lists for structured parameters).
    PARAMETERS: ClassVar[dict[str, Any]] = {}

    def __init__(self, params: Mapping[str, Any] | None = None, pwm_frequency_hz: float = 1.0e4,
                 where: str = "") -> None:
        where = where or f"config.bench.effects.{self.name}"
        params = dict(params or {})
        unknown = sorted(set(params) - set(self.PARAMETERS))
        if unknown:
            raise ValueError(f"{where}: unknown parameter(s) {unknown}, expected some of {sorted(self.PARAMETERS)}")
        self.params: dict[str, Any] = {}
        for key, default in self.PARAMETERS.items():
            value = params.get(key, default)
            if isinstance(default, (int, float)) and not isinstance(default, bool):
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ValueError(f"{where}.{key}: expected a finite number, got {value!r}")
                value = float(value)
            self.params[key] = value
        self.pwm_frequency_hz = float(pwm_frequency_hz)
        self.where = where
        self.setup()

    def setup(self) -> None:
        """Check the parameters and precompute constants (override in subclasses)."""

    def _positive(self, *keys: str) -> None:
        for key in keys:
            if not self.params[key] > 0.0:
                raise ValueError(f"{self.where}.{key}: expected a positive number, got {self.params[key]}")

    def _non_negative(self, *keys: str) -> None:
        for key in keys:
            if not self.params[key] >= 0.0:
                raise ValueError(f"{self.where}.{key}: expected a number >= 0, got {self.params[key]}")

    def hooks(self) -> list[str]:
        """Names of the hooks this effect overrides."""
        return [hook for hook in HOOKS if getattr(type(self), hook) is not getattr(Effect, hook)]

    def describe(self) -> dict[str, Any]:
        """Name, one-line description, hooks and parameters (for the ground-truth file)."""
        doc = (type(self).__doc__ or "").strip().splitlines()
        return {"name": self.name, "description": doc[0] if doc else "", "hooks": self.hooks(),
                "parameters": dict(self.params)}

    # Hooks: the base versions do nothing.
    def torque_nm(self, theta_rad: float, omega_rad_s: float, tau_load_nm: float) -> float:
        return 0.0

    def duty_error(self, i_a_a: float, i_b_a: float, i_c_a: float) -> tuple[float, float, float]:
        return (0.0, 0.0, 0.0)

    def adjust_parameters(self, params: dict[str, float]) -> None:
        return None

    def duty_log_offset_s(self) -> float:
        return 0.0


@register_effect
class CoulombFriction(Effect):
    """Coulomb friction with a Stribeck peak at low speed, smooth in the sign of the speed.

    tau = -(T_c + (T_s - T_c) exp(-(omega/omega_s)^2)) tanh(omega/omega_eps)
    """

    name = "coulomb_friction"
    PARAMETERS = {"coulomb_torque_nm": 0.04, "breakaway_torque_nm": 0.06,
                  "stribeck_speed_rad_s": 3.0, "smoothing_speed_rad_s": 0.5}

    def setup(self) -> None:
        self._non_negative("coulomb_torque_nm", "breakaway_torque_nm")
        self._positive("stribeck_speed_rad_s", "smoothing_speed_rad_s")
        self._tc = self.params["coulomb_torque_nm"]
        self._dt = self.params["breakaway_torque_nm"] - self._tc
        self._inv_ws = 1.0 / self.params["stribeck_speed_rad_s"]
        self._inv_we = 1.0 / self.params["smoothing_speed_rad_s"]

    def torque_nm(self, theta_rad: float, omega_rad_s: float, tau_load_nm: float) -> float:
        x = omega_rad_s * self._inv_ws
        return -(self._tc + self._dt * math.exp(-x * x)) * math.tanh(omega_rad_s * self._inv_we)


@register_effect
class ViscousFriction(Effect):
    """Extra viscous friction (bearings, seals, fluid) on top of the FMU's b: tau = -c omega."""

    name = "viscous_friction"
    PARAMETERS = {"coefficient_nm_s": 4e-5}

    def setup(self) -> None:
        self._non_negative("coefficient_nm_s")
        self._c = self.params["coefficient_nm_s"]

    def torque_nm(self, theta_rad: float, omega_rad_s: float, tau_load_nm: float) -> float:
        return -self._c * omega_rad_s


@register_effect
class LoadDependentFriction(Effect):
    """Ball-screw efficiency: friction proportional to the load torque |tau_load|.

    tau = -c(omega) |tau_load| tanh(omega/omega_eps), where c blends smoothly between
    ``coefficient_apply`` (moving to positive theta, the motor drives the screw: 1/eta_f - 1)
    and ``coefficient_release`` (the load back-drives the screw: 1 - eta_b).
    """

    name = "load_dependent_friction"
    PARAMETERS = {"coefficient_apply": 0.08, "coefficient_release": 0.08, "smoothing_speed_rad_s": 0.5}

    def setup(self) -> None:
        self._non_negative("coefficient_apply", "coefficient_release")
        self._positive("smoothing_speed_rad_s")
        self._mean = 0.5 * (self.params["coefficient_apply"] + self.params["coefficient_release"])
        self._half_diff = 0.5 * (self.params["coefficient_apply"] - self.params["coefficient_release"])
        self._inv_we = 1.0 / self.params["smoothing_speed_rad_s"]

    def torque_nm(self, theta_rad: float, omega_rad_s: float, tau_load_nm: float) -> float:
        s = math.tanh(omega_rad_s * self._inv_we)
        return -(self._mean + self._half_diff * s) * abs(tau_load_nm) * s


@register_effect
class Cogging(Effect):
    """Cogging torque: harmonics periodic in the mechanical rotor angle.

    tau = sum_k A_k sin(n_k theta + phi_k), ``harmonics`` = list of
    {order_per_rev: n_k (periods per mechanical revolution), amplitude_nm: A_k, phase_rad: phi_k}.
    With p pole pairs, order p*m is the m-th harmonic of the electrical angle.
    """

    name = "cogging"
    PARAMETERS = {"harmonics": [{"order_per_rev": 24, "amplitude_nm": 0.01, "phase_rad": 0.0}]}

    def setup(self) -> None:
        harmonics = self.params["harmonics"]
        if not isinstance(harmonics, list) or not harmonics:
            raise ValueError(f"{self.where}.harmonics: expected a non-empty list of "
                             "{order_per_rev, amplitude_nm, phase_rad}")
        terms = []
        for index, item in enumerate(harmonics):
            where = f"{self.where}.harmonics[{index}]"
            if not isinstance(item, Mapping) or set(item) - {"order_per_rev", "amplitude_nm", "phase_rad"}:
                raise ValueError(f"{where}: expected a mapping with keys order_per_rev, amplitude_nm, phase_rad")
            order = item.get("order_per_rev")
            if isinstance(order, bool) or not isinstance(order, int) or order < 1:
                raise ValueError(f"{where}.order_per_rev: expected a positive integer, got {order!r}")
            amplitude = item.get("amplitude_nm")
            if isinstance(amplitude, bool) or not isinstance(amplitude, (int, float)) or amplitude < 0:
                raise ValueError(f"{where}.amplitude_nm: expected a number >= 0, got {amplitude!r}")
            phase = item.get("phase_rad", 0.0)
            if isinstance(phase, bool) or not isinstance(phase, (int, float)):
                raise ValueError(f"{where}.phase_rad: expected a number, got {phase!r}")
            terms.append((float(order), float(amplitude), float(phase)))
        self._terms = tuple(terms)
        self.params["harmonics"] = [{"order_per_rev": int(n), "amplitude_nm": a, "phase_rad": ph}
                                    for n, a, ph in terms]

    def torque_nm(self, theta_rad: float, omega_rad_s: float, tau_load_nm: float) -> float:
        total = 0.0
        for order, amplitude, phase in self._terms:
            total += amplitude * math.sin(order * theta_rad + phase)
        return total


@register_effect
class InverterDeadtime(Effect):
    """Uncompensated inverter dead time: each phase loses t_dead*f_pwm of duty in the current's direction.

    Delta d_k = -t_dead f_pwm tanh(i_k / i_eps); lowers the effective voltage magnitude.
    """

    name = "inverter_deadtime"
    PARAMETERS = {"deadtime_s": 2e-7, "current_smoothing_a": 0.5}

    def setup(self) -> None:
        self._non_negative("deadtime_s")
        self._positive("current_smoothing_a")
        self._loss = self.params["deadtime_s"] * self.pwm_frequency_hz
        if self._loss >= 0.1:
            raise ValueError(f"{self.where}.deadtime_s: {self.params['deadtime_s']} s is >= 10 % of the PWM "
                             f"period at {self.pwm_frequency_hz} Hz")
        self._inv_eps = 1.0 / self.params["current_smoothing_a"]

    def duty_error(self, i_a_a: float, i_b_a: float, i_c_a: float) -> tuple[float, float, float]:
        loss, k = self._loss, self._inv_eps
        return (-loss * math.tanh(i_a_a * k), -loss * math.tanh(i_b_a * k), -loss * math.tanh(i_c_a * k))


@register_effect
class ChannelTimeOffset(Effect):
    """Time offset of the logged PWM duty channels against the angle (the input delay).

    The duty applied from time t is stamped t + offset_s in the log, so a model must use
    u_logged(t + offset_s) to see the input the motor saw at t (input delay Delta t = offset_s).
    """

    name = "channel_time_offset"
    PARAMETERS = {"offset_s": 3e-5}

    def setup(self) -> None:
        if abs(self.params["offset_s"]) >= 1e-3:
            raise ValueError(f"{self.where}.offset_s: expected |offset| < 1e-3 s, got {self.params['offset_s']}")

    def duty_log_offset_s(self) -> float:
        return self.params["offset_s"]


@register_effect
class InertiaMismatch(Effect):
    """The true rotor inertia (rotor, screw, piston reflected) is ``scale`` times the nominal one."""

    name = "inertia_mismatch"
    PARAMETERS = {"scale": 1.05}

    def setup(self) -> None:
        if not 0.5 < self.params["scale"] < 2.0:
            raise ValueError(f"{self.where}.scale: expected a factor in (0.5, 2), got {self.params['scale']}")

    def adjust_parameters(self, params: dict[str, float]) -> None:
        params["J"] = params["J"] * self.params["scale"]


def build_effects(config_effects: Mapping[str, Any] | None, pwm_frequency_hz: float,
                  where: str = "config.bench.effects") -> list[Effect]:
    """Instantiate the enabled effects of ``bench.effects`` (name -> {enabled, params...}).

    Raises:
        ValueError: an unknown effect name or a bad parameter, naming the config field.
    """
    effects: list[Effect] = []
    for name, section in (config_effects or {}).items():
        if name not in EFFECTS:
            raise ValueError(f"{where}.{name}: unknown effect, expected one of {sorted(EFFECTS)}")
        section = dict(section or {})
        enabled = section.pop("enabled", True)
        if not isinstance(enabled, bool):
            raise ValueError(f"{where}.{name}.enabled: expected true or false, got {enabled!r}")
        if enabled:
            effects.append(EFFECTS[name](section, pwm_frequency_hz=pwm_frequency_hz, where=f"{where}.{name}"))
    return effects
