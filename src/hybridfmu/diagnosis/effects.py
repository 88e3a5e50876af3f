"""Library of candidate effects: each a term with physical meaning in one state equation.

An effect contributes ``A(x, u; s) @ c + b(x, u; s)`` to the state derivatives, linear in its
coefficients ``c`` (fitted by least squares) with an optional setting ``s`` of nonlinear
parameters (searched on a grid and refined, e.g. the Stribeck velocity or a time offset).
Mechanical effects are torques divided by the rotor inertia; electrical effects act on the
dq current equations. The same term is used to fit the equation error (data mode: Jacobians
from the measured trajectory) and as the explicit correction in the open-loop simulation
(simulation mode: responses evaluated with a model). Effects register themselves once in
``EFFECTS`` with ``@register``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import cached_property
from typing import Any, Callable

import math

import numpy as np

from hybridfmu.diagnosis.layout import MotorLayout
from hybridfmu.diagnosis.synthetic import dq_to_abc

#: Registry of candidate effects by name.
EFFECTS: dict[str, "Effect"] = {}

#: Defaults of the options the effects read (config section ``diagnosis.effects`` overrides).
DEFAULT_OPTIONS: dict[str, Any] = {
    "sign_smoothing_rad_s": 0.5,
    "stribeck_velocities_rad_s": [1.0, 2.0, 3.0, 5.0, 7.0, 10.0, 15.0, 20.0, 30.0, 50.0],
    "cogging_orders": [6, 8, 12, 18, 24, 36, 48],
    "cogging_harmonics": 2,
    "deadtime_current_scales_a": [0.5, 2.0, 5.0],
    "pwm_frequency_hz": 0.0,
    "max_time_offset_s": 5e-4,
    "time_offset_inputs": [],
}


def register(effect_cls: type["Effect"]) -> type["Effect"]:
    """Class decorator: instantiate the effect and add it to ``EFFECTS`` (names must be unique)."""
    effect = effect_cls()
    if effect.name in EFFECTS:
        raise ValueError(f"candidate effect {effect.name!r} registered twice")
    EFFECTS[effect.name] = effect
    return effect_cls


class EffectInputs:
    """What the effects' terms are computed from, along M samples.

    Data mode: ``f``, ``dfdx``, ``dfdu`` come from the measured trajectory and ``shift``
    returns the inputs shifted in time. Simulation mode: pass ``model`` instead; ``f`` and the
    responses to state/input perturbations are then evaluated with it (finite differences
    of the derivatives, exact for terms affine in the perturbed variable).

    Args:
        layout: the motor layout.
        x: (M, n_x) states; u: (M, n_u) inputs.
        omega_rad_s: (M,) speed for nonlinear regressors (default the speed state).
        i_abc_a: (M, 3) phase currents (default from the dq currents by inverse Park).
        f, dfdx, dfdu: model derivatives (M, n_x) and Jacobians (data mode).
        model: model for simulation mode.
        shift: callable offset_s -> (M, n_u) inputs shifted in time (data mode).
        context: constants of the data set (e.g. ``u_dc_mean_v``) used in reports.
    """

    def __init__(self, layout: MotorLayout, x: np.ndarray, u: np.ndarray, *, omega_rad_s: np.ndarray | None = None,
                 i_abc_a: np.ndarray | None = None, f: np.ndarray | None = None, dfdx: np.ndarray | None = None,
                 dfdu: np.ndarray | None = None, model: Any = None,
                 shift: Callable[[float], np.ndarray] | None = None, context: dict[str, float] | None = None) -> None:
        self.layout = layout
        self.x = np.asarray(x, dtype=float)
        self.u = np.asarray(u, dtype=float)
        self._omega = omega_rad_s
        self._i_abc = i_abc_a
        self._f = f
        self.dfdx = dfdx
        self.dfdu = dfdu
        self.model = model
        self._shift = shift
        self.context = context or {}

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def simulation_mode(self) -> bool:
        return self._shift is None

    @property
    def omega(self) -> np.ndarray:
        return self.x[:, self.layout.omega] if self._omega is None else self._omega

    @property
    def theta(self) -> np.ndarray:
        return self.x[:, self.layout.theta]

    @property
    def tau_load(self) -> np.ndarray:
        return self.u[:, self.layout.tau_load]

    @cached_property
    def i_abc(self) -> np.ndarray:
        if self._i_abc is not None:
            return self._i_abc
        lay = self.layout
        return dq_to_abc(self.x[:, lay.i_d], self.x[:, lay.i_q], lay.pole_pairs * self.theta)

    @cached_property
    def f(self) -> np.ndarray:
        if self._f is not None:
            return self._f
        return np.asarray(self.model.derivatives(self.x, self.u), dtype=float)

    def input_response(self, delta_u: np.ndarray) -> np.ndarray:
        """Change of the derivatives (M, n_x) for an input change ``delta_u`` (M, n_u), to first order."""
        if self.dfdu is not None:
            return np.einsum("mij,mj->mi", self.dfdu, delta_u)
        eps = 1e-3 / max(float(np.max(np.abs(delta_u))), 1e-12)
        return (np.asarray(self.model.derivatives(self.x, self.u + eps * delta_u)) - self.f) / eps

    def state_response(self, delta_x: np.ndarray) -> np.ndarray:
        """Change of the derivatives (M, n_x) for a state change ``delta_x`` (M, n_x), to first order."""
        if self.dfdx is not None:
            return np.einsum("mij,mj->mi", self.dfdx, delta_x)
        eps = 1e-3 / max(float(np.max(np.abs(delta_x))), 1e-12)
        return (np.asarray(self.model.derivatives(self.x + eps * delta_x, self.u)) - self.f) / eps

    def shifted_inputs(self, offset_s: float) -> np.ndarray:
        """Inputs ``u(t + offset_s)`` (M, n_u) (data mode only)."""
        if self._shift is None:
            raise RuntimeError("shifted inputs are only available along measured data")
        return self._shift(offset_s)


def smooth_sign(value: np.ndarray, scale: float) -> np.ndarray:
    """tanh(value / scale): a sign that is continuous through zero (for friction-like terms)."""
    return np.tanh(np.asarray(value, dtype=float) / scale) if scale > 0 else np.sign(value)


def linear_estimate(coef: np.ndarray, cov: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    """Value and standard error of ``weights @ coef``."""
    weights = np.asarray(weights, dtype=float)
    value = float(weights @ coef)
    var = float(weights @ cov @ weights)
    return value, float(np.sqrt(max(var, 0.0)))


def _param(name: str, value: float, se: float | None, unit: str, description: str) -> dict[str, Any]:
    return {"name": name, "value": float(value), "se": None if se is None else float(se), "unit": unit,
            "description": description}


class Effect(ABC):
    """A candidate effect: one term with physical meaning in one equation group.

    Attributes:
        name: registry name (equal to the bench's effect names where they exist).
        group: "mechanical" or "electrical".
        description: one line for the report.
        equation: the term as a formula (for the report).
        continuous: name of the nonlinear parameter refined continuously after the grid, or None.
        log_scale: refine ``continuous`` on a logarithmic scale.
    """

    name: str = ""
    group: str = ""
    description: str = ""
    equation: str = ""
    continuous: str | None = None
    log_scale: bool = False

    def requirement(self, layout: MotorLayout) -> str | None:
        """Why the effect cannot be used with ``layout`` (None if it can)."""
        return None

    def grid(self, options: dict[str, Any], layout: MotorLayout) -> list[dict[str, float]]:
        """Settings of the nonlinear parameters to try ([{}] for a purely linear effect)."""
        return [{}]

    def bounds(self, options: dict[str, Any], layout: MotorLayout) -> tuple[float, float] | None:
        """Search interval of ``continuous``."""
        return None

    @abstractmethod
    def coefficient_names(self, setting: dict[str, float]) -> list[str]:
        """Names of the linear coefficients for ``setting``."""

    @abstractmethod
    def terms(self, inputs: EffectInputs, setting: dict[str, float],
              options: dict[str, Any]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Regressors ``A`` (M, n_x, n_coef) and fixed part ``b`` (M, n_x) (either may be None)."""

    @abstractmethod
    def physical(self, coef: np.ndarray, cov: np.ndarray, setting: dict[str, float],
                 setting_se: dict[str, float], layout: MotorLayout, options: dict[str, Any],
                 context: dict[str, float]) -> list[dict[str, Any]]:
        """Physical parameters with standard errors, from coefficients and their covariance."""

    def input_shift_s(self, setting: dict[str, float]) -> float:
        """Time by which the effect shifts the inputs in the corrected simulation (s)."""
        return 0.0

    def relative_error(self, coef: np.ndarray) -> float | None:
        """For a parameter error: (true - model) / model implied by ``coef``; None for other effects."""
        return None

    def scalar_torque(self, coef: np.ndarray, setting: dict[str, float],
                      options: dict[str, Any]) -> Callable[[float, float, float], float] | None:
        """A fast scalar version (theta, omega, tau_load) -> torque (N m) of a torque effect, or None."""
        return None

    def scalar_rows(self, coef: np.ndarray, setting: dict[str, float], options: dict[str, Any],
                    layout: MotorLayout) -> Callable[[list[float], list[float]], list[tuple[int, float]]] | None:
        """A fast scalar version (x row, u row) -> [(state index, value), ...] of ``correction`` built
        from ``layout.constants`` (calibrated model coefficients), or None when they are missing."""
        return None

    def fast_correction(self, coef: np.ndarray, setting: dict[str, float], options: dict[str, Any],
                        layout: MotorLayout, model: Any) -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
        """A fast version (x (N, n_x), u (N, n_u)) -> (N, n_x) of ``correction`` using ``model``, or None."""
        return None

    def correction(self, inputs: EffectInputs, coef: np.ndarray, setting: dict[str, float],
                   options: dict[str, Any]) -> np.ndarray:
        """The effect's additive derivative term (M, n_x) with fitted coefficients."""
        regressors, fixed = self.terms(inputs, setting, options)
        out = np.zeros((inputs.n, inputs.layout.n_x))
        if regressors is not None and regressors.shape[2]:
            out += regressors @ np.asarray(coef, dtype=float)
        if fixed is not None:
            out += fixed
        return out


def _mechanical_regressors(inputs: EffectInputs, torques_nm: list[np.ndarray]) -> np.ndarray:
    lay = inputs.layout
    regressors = np.zeros((inputs.n, lay.n_x, len(torques_nm)))
    for j, torque in enumerate(torques_nm):
        regressors[:, lay.omega, j] = torque / lay.inertia_kg_m2
    return regressors


class MechanicalEffect(Effect):
    group = "mechanical"

    def requirement(self, layout: MotorLayout) -> str | None:
        if not layout.inertia_kg_m2:
            return "rotor inertia unknown (no load-torque input and no diagnosis.inertia_kg_m2)"
        return None


@register
class CoulombFriction(MechanicalEffect):
    name = "coulomb_friction"
    description = "Coulomb friction with a Stribeck peak at low speed"
    equation = "tau = -(F_c + dF_s * exp(-(omega/v_s)^2)) * sign(omega)"
    continuous = "stribeck_velocity_rad_s"
    log_scale = True

    def grid(self, options, layout):
        return [{"stribeck_velocity_rad_s": 0.0}] + [
            {"stribeck_velocity_rad_s": float(v)} for v in options["stribeck_velocities_rad_s"]]

    def bounds(self, options, layout):
        values = [float(v) for v in options["stribeck_velocities_rad_s"]]
        return (min(values), max(values)) if values else None

    def coefficient_names(self, setting):
        if setting.get("stribeck_velocity_rad_s", 0.0) > 0:
            return ["coulomb_torque_nm", "stribeck_excess_torque_nm"]
        return ["coulomb_torque_nm"]

    def terms(self, inputs, setting, options):
        sign = smooth_sign(inputs.omega, options["sign_smoothing_rad_s"])
        torques = [-sign]
        v_s = setting.get("stribeck_velocity_rad_s", 0.0)
        if v_s > 0:
            torques.append(-sign * np.exp(-(inputs.omega / v_s) ** 2))
        return _mechanical_regressors(inputs, torques), None

    def scalar_torque(self, coef, setting, options):
        eps = float(options["sign_smoothing_rad_s"])
        t_c = float(coef[0])
        t_s = float(coef[1]) if len(coef) > 1 else 0.0
        inv_vs = 1.0 / setting["stribeck_velocity_rad_s"] if setting.get("stribeck_velocity_rad_s", 0.0) > 0 else 0.0

        def torque(theta: float, omega: float, tau_load: float) -> float:
            x = omega * inv_vs
            return -(t_c + t_s * math.exp(-x * x)) * math.tanh(omega / eps)
        return torque

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        out = [_param("coulomb_torque_nm", *linear_estimate(coef, cov, [1.0] + [0.0] * (len(coef) - 1)),
                      "N m", "Coulomb friction torque")]
        if len(coef) > 1:
            out.append(_param("breakaway_torque_nm", *linear_estimate(coef, cov, [1.0, 1.0]), "N m",
                              "friction torque at zero speed (Coulomb + Stribeck peak)"))
            out.append(_param("stribeck_velocity_rad_s", setting["stribeck_velocity_rad_s"],
                              setting_se.get("stribeck_velocity_rad_s"), "rad/s", "Stribeck velocity"))
        return out


@register
class ViscousFriction(MechanicalEffect):
    name = "viscous_friction"
    description = "additional viscous friction"
    equation = "tau = -b_v * omega"

    def coefficient_names(self, setting):
        return ["viscous_coefficient_nm_s_rad"]

    def terms(self, inputs, setting, options):
        return _mechanical_regressors(inputs, [-inputs.omega]), None

    def scalar_torque(self, coef, setting, options):
        b_v = float(coef[0])
        return lambda theta, omega, tau_load: -b_v * omega

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        return [_param("viscous_coefficient_nm_s_rad", *linear_estimate(coef, cov, [1.0]), "N m s/rad",
                       "additional viscous friction coefficient")]


@register
class LoadDependentFriction(MechanicalEffect):
    name = "load_dependent_friction"
    description = ("friction proportional to the load torque (ball-screw efficiency), optionally different "
                   "when applying (omega > 0) and releasing (omega < 0)")
    equation = "tau = -(mu + delta_mu * s) * |tau_load| * s, s = sign(omega)"

    def requirement(self, layout):
        if layout.tau_load is None:
            return "no load-torque input"
        return super().requirement(layout)

    def grid(self, options, layout):
        return [{"asymmetric": 0.0}, {"asymmetric": 1.0}]

    def coefficient_names(self, setting):
        if setting.get("asymmetric", 0.0):
            return ["load_friction_coefficient", "load_friction_half_difference"]
        return ["load_friction_coefficient"]

    def terms(self, inputs, setting, options):
        sign = smooth_sign(inputs.omega, options["sign_smoothing_rad_s"])
        torques = [-np.abs(inputs.tau_load) * sign]
        if setting.get("asymmetric", 0.0):
            torques.append(-np.abs(inputs.tau_load) * sign * sign)
        return _mechanical_regressors(inputs, torques), None

    def scalar_torque(self, coef, setting, options):
        eps = float(options["sign_smoothing_rad_s"])
        mean = float(coef[0])
        half = float(coef[1]) if len(coef) > 1 else 0.0

        def torque(theta: float, omega: float, tau_load: float) -> float:
            s = math.tanh(omega / eps)
            return -(mean + half * s) * abs(tau_load) * s
        return torque

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        if len(coef) == 1:
            return [_param("load_friction_coefficient", *linear_estimate(coef, cov, [1.0]), "-",
                           "friction torque per N m of load torque")]
        return [
            _param("coefficient_apply", *linear_estimate(coef, cov, [1.0, 1.0]), "-",
                   "friction per N m of load while moving towards positive theta (applying)"),
            _param("coefficient_release", *linear_estimate(coef, cov, [1.0, -1.0]), "-",
                   "friction per N m of load while moving towards negative theta (releasing)"),
            _param("load_friction_coefficient", *linear_estimate(coef, cov, [1.0, 0.0]), "-",
                   "mean of the two"),
        ]


@register
class Cogging(MechanicalEffect):
    name = "cogging"
    description = "cogging torque, harmonics of an order n per mechanical revolution"
    equation = "tau = sum_h a_h sin(h n theta) + b_h cos(h n theta)"

    def grid(self, options, layout):
        harmonics = int(options["cogging_harmonics"])
        return [{"order": float(n), "harmonics": float(harmonics)} for n in options["cogging_orders"]]

    def coefficient_names(self, setting):
        names = []
        for h in range(1, int(setting["harmonics"]) + 1):
            names += [f"sin_{h}_nm", f"cos_{h}_nm"]
        return names

    def terms(self, inputs, setting, options):
        order = setting["order"]
        torques = []
        for h in range(1, int(setting["harmonics"]) + 1):
            torques += [np.sin(h * order * inputs.theta), np.cos(h * order * inputs.theta)]
        return _mechanical_regressors(inputs, torques), None

    def scalar_torque(self, coef, setting, options):
        order = float(setting["order"])
        pairs = [(h * order, float(coef[2 * (h - 1)]), float(coef[2 * (h - 1) + 1]))
                 for h in range(1, int(setting["harmonics"]) + 1)]

        def torque(theta: float, omega: float, tau_load: float) -> float:
            total = 0.0
            for n, a, b in pairs:
                total += a * math.sin(n * theta) + b * math.cos(n * theta)
            return total
        return torque

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        order = setting["order"]
        out = [_param("order", order, None, "1/rev", "fundamental cogging order (periods per mechanical revolution)")]
        for h in range(len(coef) // 2):
            a, b = coef[2 * h], coef[2 * h + 1]
            amp = float(np.hypot(a, b))
            grad = np.zeros(len(coef))
            if amp > 0:
                grad[2 * h], grad[2 * h + 1] = a / amp, b / amp
            amp_se = float(np.sqrt(max(grad @ cov @ grad, 0.0)))
            n = int(round((h + 1) * order))
            out.append(_param(f"amplitude_{n}_nm", amp, amp_se, "N m",
                              f"amplitude of the order-{n} component (torque = amplitude sin({n} theta + phase))"))
            out.append(_param(f"phase_{n}_rad", float(np.arctan2(b, a)), amp_se / amp if amp > 0 else None,
                              "rad", f"phase of the order-{n} component"))
        return out


@register
class InertiaMismatch(MechanicalEffect):
    name = "inertia_mismatch"
    description = "rotor inertia differs from the model's"
    equation = "omega_dot_true = omega_dot_model * J / J_true, i.e. residual = k * omega_dot_model"

    def coefficient_names(self, setting):
        return ["acceleration_scale_error"]

    def terms(self, inputs, setting, options):
        lay = inputs.layout
        regressors = np.zeros((inputs.n, lay.n_x, 1))
        regressors[:, lay.omega, 0] = inputs.f[:, lay.omega]
        return regressors, None

    def scalar_rows(self, coef, setting, options, layout):
        c = layout.constants
        if "speed_a_q" not in c:
            return None
        k, lay = float(coef[0]), layout
        a_q, a_dq, a_w, a_l, a_0 = (c[f"speed_a_{n}"] for n in ("q", "dq", "w", "l", "0"))

        def rows(x: list[float], u: list[float]) -> list[tuple[int, float]]:
            i_q = x[lay.i_q]
            return [(lay.omega, k * (a_q * i_q + a_dq * x[lay.i_d] * i_q + a_w * x[lay.omega]
                                     + a_l * u[lay.tau_load] + a_0))]
        return rows

    def fast_correction(self, coef, setting, options, layout, model):
        k, row = float(coef[0]), layout.omega

        def correction(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            out = np.zeros_like(x)
            out[:, row] = k * model.derivatives(x, u)[:, row]
            return out
        return correction

    def relative_error(self, coef):
        return 1.0 / (1.0 + float(coef[0])) - 1.0

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        k = float(coef[0])
        se_k = float(np.sqrt(max(cov[0, 0], 0.0)))
        inertia = layout.inertia_kg_m2
        true_inertia = inertia / (1.0 + k)
        return [
            _param("inertia_kg_m2", true_inertia, inertia * se_k / (1.0 + k) ** 2, "kg m^2",
                   "rotor inertia implied by the data"),
            _param("inertia_relative_error", true_inertia / inertia - 1.0, se_k / (1.0 + k) ** 2, "-",
                   "(J_true - J_model) / J_model"),
        ]


@register
class TorqueConstantError(MechanicalEffect):
    name = "torque_constant_error"
    description = "torque constant (flux linkage psi) differs from the model's, in the torque equation"
    equation = "residual = k * d(omega_dot)/d(i_q) * i_q"

    def requirement(self, layout):
        if layout.i_q is None:
            return "no q-axis current state"
        return super().requirement(layout)

    def coefficient_names(self, setting):
        return ["torque_constant_relative_error"]

    def terms(self, inputs, setting, options):
        lay = inputs.layout
        delta = np.zeros_like(inputs.x)
        delta[:, lay.i_q] = inputs.x[:, lay.i_q]
        regressors = np.zeros((inputs.n, lay.n_x, 1))
        regressors[:, lay.omega, 0] = inputs.state_response(delta)[:, lay.omega]
        return regressors, None

    def scalar_rows(self, coef, setting, options, layout):
        c = layout.constants
        if "speed_a_q" not in c:
            return None
        k, lay, a_q, a_dq = float(coef[0]), layout, c["speed_a_q"], c["speed_a_dq"]
        return lambda x, u: [(lay.omega, k * (a_q + a_dq * x[lay.i_d]) * x[lay.i_q])]

    def fast_correction(self, coef, setting, options, layout, model):
        k, row, col = float(coef[0]), layout.omega, layout.i_q

        def correction(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            without = x.copy()
            without[:, col] = 0.0
            out = np.zeros_like(x)
            out[:, row] = k * (model.derivatives(x, u)[:, row] - model.derivatives(without, u)[:, row])
            return out
        return correction

    def relative_error(self, coef):
        return float(coef[0])

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        return [_param("torque_constant_relative_error", *linear_estimate(coef, cov, [1.0]), "-",
                       "(k_t,true - k_t,model) / k_t,model")]


class ElectricalEffect(Effect):
    group = "electrical"

    def requirement(self, layout: MotorLayout) -> str | None:
        if layout.i_d is None or layout.i_q is None:
            return "no dq current states"
        return None


@register
class ResistanceError(ElectricalEffect):
    name = "resistance_error"
    description = "winding resistance differs from the model's"
    equation = "residual_d,q = k * (d i_dot_d,q / d i_d,q) * i_d,q"

    def coefficient_names(self, setting):
        return ["resistance_relative_error"]

    def terms(self, inputs, setting, options):
        lay = inputs.layout
        regressors = np.zeros((inputs.n, lay.n_x, 1))
        for idx in (lay.i_d, lay.i_q):
            delta = np.zeros_like(inputs.x)
            delta[:, idx] = inputs.x[:, idx]
            regressors[:, idx, 0] = inputs.state_response(delta)[:, idx]
        return regressors, None

    def scalar_rows(self, coef, setting, options, layout):
        c = layout.constants
        if "diag_d" not in c or "diag_q" not in c:
            return None
        k, lay, g_d, g_q = float(coef[0]), layout, c["diag_d"], c["diag_q"]
        return lambda x, u: [(lay.i_d, k * g_d * x[lay.i_d]), (lay.i_q, k * g_q * x[lay.i_q])]

    def fast_correction(self, coef, setting, options, layout, model):
        k = float(coef[0])
        columns = (layout.i_d, layout.i_q)

        def correction(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            full = model.derivatives(x, u)
            out = np.zeros_like(x)
            for col in columns:
                without = x.copy()
                without[:, col] = 0.0
                out[:, col] = k * (full[:, col] - model.derivatives(without, u)[:, col])
            return out
        return correction

    def relative_error(self, coef):
        return float(coef[0])

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        return [_param("resistance_relative_error", *linear_estimate(coef, cov, [1.0]), "-",
                       "(R_true - R_model) / R_model")]


@register
class InverterDeadtime(ElectricalEffect):
    name = "inverter_deadtime"
    description = "inverter dead time: each phase loses a duty share against its current"
    equation = "delta d_k = -delta * tanh(i_k / i_0), k = a, b, c"

    def requirement(self, layout):
        if layout.duty is None:
            return "no three duty-cycle inputs"
        if layout.pole_pairs is None:
            return "pole-pair number unknown (set diagnosis.pole_pairs)"
        return super().requirement(layout)

    def grid(self, options, layout):
        return [{"current_scale_a": float(v)} for v in options["deadtime_current_scales_a"]]

    def coefficient_names(self, setting):
        return ["duty_error"]

    def terms(self, inputs, setting, options):
        lay = inputs.layout
        delta_u = np.zeros_like(inputs.u)
        delta_u[:, list(lay.duty)] = -smooth_sign(inputs.i_abc, setting["current_scale_a"])
        response = inputs.input_response(delta_u)
        regressors = np.zeros((inputs.n, lay.n_x, 1))
        for idx in lay.groups["electrical"]:
            regressors[:, idx, 0] = response[:, idx]
        return regressors, None

    def scalar_rows(self, coef, setting, options, layout):
        c = layout.constants
        if "inv_l_d" not in c or "inv_l_q" not in c:
            return None
        delta, inv_scale = float(coef[0]), 1.0 / float(setting["current_scale_a"])
        lay, p, inv_l_d, inv_l_q = layout, float(layout.pole_pairs), c["inv_l_d"], c["inv_l_q"]
        half_sqrt3 = 0.5 * math.sqrt(3.0)

        def rows(x: list[float], u: list[float]) -> list[tuple[int, float]]:
            th = p * x[lay.theta]
            cos_e, sin_e = math.cos(th), math.sin(th)
            i_d, i_q = x[lay.i_d], x[lay.i_q]
            i_al = i_d * cos_e - i_q * sin_e
            i_be = i_d * sin_e + i_q * cos_e
            d_a = -delta * math.tanh(i_al * inv_scale)
            d_b = -delta * math.tanh((-0.5 * i_al + half_sqrt3 * i_be) * inv_scale)
            d_c = -delta * math.tanh((-0.5 * i_al - half_sqrt3 * i_be) * inv_scale)
            u_dc = u[lay.u_dc]
            v_al = u_dc * (2.0 / 3.0) * (d_a - 0.5 * d_b - 0.5 * d_c)
            v_be = u_dc * (d_b - d_c) / math.sqrt(3.0)
            return [(lay.i_d, (v_al * cos_e + v_be * sin_e) * inv_l_d),
                    (lay.i_q, (-v_al * sin_e + v_be * cos_e) * inv_l_q)]
        return rows

    def fast_correction(self, coef, setting, options, layout, model):
        delta, scale = float(coef[0]), float(setting["current_scale_a"])
        duty = list(layout.duty)
        rows = list(layout.groups["electrical"])

        def correction(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            i_abc = dq_to_abc(x[:, layout.i_d], x[:, layout.i_q], layout.pole_pairs * x[:, layout.theta])
            shifted = u.copy()
            shifted[:, duty] -= delta * np.tanh(i_abc / scale)
            out = np.zeros_like(x)
            out[:, rows] = (model.derivatives(x, shifted) - model.derivatives(x, u))[:, rows]
            return out
        return correction

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        duty_error, se = linear_estimate(coef, cov, [1.0])
        out = [_param("duty_error", duty_error, se, "-", "duty lost per phase against the phase current"),
               _param("current_scale_a", setting["current_scale_a"], None, "A",
                      "current below which the loss fades (tanh scale)")]
        u_dc = context.get("u_dc_mean_v")
        if u_dc:
            out.append(_param("voltage_error_v", duty_error * u_dc, se * u_dc, "V",
                              "phase voltage error at the mean supply voltage"))
        f_pwm = float(options.get("pwm_frequency_hz") or 0.0)
        if f_pwm > 0:
            out.append(_param("dead_time_s", duty_error / f_pwm, se / f_pwm, "s",
                              "equivalent dead time at the configured PWM frequency"))
        return out


@register
class ChannelTimeOffset(ElectricalEffect):
    name = "channel_time_offset"
    description = "the logged inputs are offset in time against the logged states"
    equation = "residual = f(x, u(t + dt)) - f(x, u(t))"
    continuous = "offset_s"

    def requirement(self, layout):
        return None

    def grid(self, options, layout):
        limit = float(options["max_time_offset_s"])
        step = layout.dt_s / 2.0
        count = int(np.floor(limit / step))
        return [{"offset_s": float(k * step)} for k in range(-count, count + 1) if k != 0]

    def bounds(self, options, layout):
        limit = float(options["max_time_offset_s"])
        return (-limit, limit)

    def coefficient_names(self, setting):
        return []

    def _mask(self, options, layout):
        names = options.get("time_offset_inputs") or []
        if not names:
            return np.ones(layout.n_u, dtype=bool)
        unknown = [n for n in names if n not in layout.input_names]
        if unknown:
            raise ValueError(f"diagnosis.effects.time_offset_inputs: {unknown} are not model inputs "
                             f"{layout.input_names}")
        return np.array([n in names for n in layout.input_names])

    def terms(self, inputs, setting, options):
        if inputs.simulation_mode:
            return None, None
        lay = inputs.layout
        delta_u = inputs.shifted_inputs(setting["offset_s"]) - inputs.u
        delta_u[:, ~self._mask(options, lay)] = 0.0
        response = inputs.input_response(delta_u)
        fixed = np.zeros((inputs.n, lay.n_x))
        rows = [i for i in range(lay.n_x) if i != lay.theta]
        fixed[:, rows] = response[:, rows]
        return None, fixed

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        return [_param("offset_s", setting["offset_s"], setting_se.get("offset_s"), "s",
                       "time by which the inputs lead: the model should see u(t + offset)")]

    def input_shift_s(self, setting):
        return float(setting["offset_s"])


def _dq_voltages(x: list[float], u: list[float], layout: MotorLayout) -> tuple[float, float, float, float]:
    """(v_d, v_q, cos, sin) from the duties and the supply voltage of one state/input row."""
    th = float(layout.pole_pairs) * x[layout.theta]
    cos_e, sin_e = math.cos(th), math.sin(th)
    d_a, d_b, d_c = (u[i] for i in layout.duty)
    u_dc = u[layout.u_dc]
    v_al = u_dc * (2.0 / 3.0) * (d_a - 0.5 * d_b - 0.5 * d_c)
    v_be = u_dc * (d_b - d_c) / math.sqrt(3.0)
    return v_al * cos_e + v_be * sin_e, -v_al * sin_e + v_be * cos_e, cos_e, sin_e


@register
class InductanceError(ElectricalEffect):
    name = "inductance_error"
    description = "the inductances (both axes, by the same factor) differ from the model's"
    equation = ("residual_d = k (-i_dot_d + d(i_dot_d)/d(i_q) i_q), residual_q = k (-i_dot_q + d(i_dot_q)/d(i_d) i_d), "
                "L_true / L_model = 1 / (1 - k)")

    def coefficient_names(self, setting):
        return ["inductance_scale_error"]

    def terms(self, inputs, setting, options):
        lay = inputs.layout
        regressors = np.zeros((inputs.n, lay.n_x, 1))
        for row, other in ((lay.i_d, lay.i_q), (lay.i_q, lay.i_d)):
            delta = np.zeros_like(inputs.x)
            delta[:, other] = inputs.x[:, other]
            regressors[:, row, 0] = -inputs.f[:, row] + inputs.state_response(delta)[:, row]
        return regressors, None

    def scalar_rows(self, coef, setting, options, layout):
        c = layout.constants
        needed = ("inv_l_d", "diag_d", "inv_l_q", "diag_q", "emf_q")
        if not all(k in c for k in needed) or layout.duty is None or layout.u_dc is None:
            return None
        k, lay = float(coef[0]), layout

        def rows(x: list[float], u: list[float]) -> list[tuple[int, float]]:
            v_d, v_q, _, _ = _dq_voltages(x, u, lay)
            f_d = c["inv_l_d"] * v_d + c["diag_d"] * x[lay.i_d]
            f_q = c["inv_l_q"] * v_q + c["diag_q"] * x[lay.i_q] + c["emf_q"] * x[lay.omega]
            return [(lay.i_d, -k * f_d), (lay.i_q, -k * f_q)]
        return rows

    def relative_error(self, coef):
        return float(coef[0]) / (1.0 - float(coef[0]))

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        k = float(coef[0])
        se = float(np.sqrt(max(cov[0, 0], 0.0)))
        return [_param("inductance_relative_error", k / (1.0 - k), se / (1.0 - k) ** 2, "-",
                       "(L_true - L_model) / L_model, both axes")]


@register
class BackEmfError(ElectricalEffect):
    name = "back_emf_error"
    description = "the flux linkage psi (back-EMF constant) differs from the model's, in the q-current equation"
    equation = "residual_q = k * (d(i_dot_q)/d(omega) omega - d(i_dot_q)/d(i_d) i_d), k = (psi_true - psi) / psi"

    def coefficient_names(self, setting):
        return ["flux_linkage_relative_error"]

    def terms(self, inputs, setting, options):
        lay = inputs.layout
        by_speed = np.zeros_like(inputs.x)
        by_speed[:, lay.omega] = inputs.x[:, lay.omega]
        by_current = np.zeros_like(inputs.x)
        by_current[:, lay.i_d] = inputs.x[:, lay.i_d]
        regressors = np.zeros((inputs.n, lay.n_x, 1))
        regressors[:, lay.i_q, 0] = (inputs.state_response(by_speed)[:, lay.i_q]
                                     - inputs.state_response(by_current)[:, lay.i_q])
        return regressors, None

    def scalar_rows(self, coef, setting, options, layout):
        if "emf_q" not in layout.constants:
            return None
        k, lay, emf = float(coef[0]), layout, layout.constants["emf_q"]
        return lambda x, u: [(lay.i_q, k * emf * x[lay.omega])]

    def relative_error(self, coef):
        return float(coef[0])

    def physical(self, coef, cov, setting, setting_se, layout, options, context):
        return [_param("flux_linkage_relative_error", *linear_estimate(coef, cov, [1.0]), "-",
                       "(psi_true - psi_model) / psi_model as seen in the back-EMF")]


def effect_options(diagnosis_config: dict[str, Any]) -> dict[str, Any]:
    """The effects' options: ``DEFAULT_OPTIONS`` updated by ``diagnosis.effects`` of the case config."""
    options = dict(DEFAULT_OPTIONS)
    options.update(diagnosis_config.get("effects", {}) or {})
    return options


def candidate_effects(names: list[str] | None, layout: MotorLayout) -> tuple[list[Effect], dict[str, str]]:
    """The effects to try (all registered if ``names`` is empty) and why others were skipped."""
    names = list(names or EFFECTS)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise ValueError(f"diagnosis.candidates: unknown effects {unknown}; known: {sorted(EFFECTS)}")
    usable, skipped = [], {}
    for name in names:
        reason = EFFECTS[name].requirement(layout)
        if reason:
            skipped[name] = reason
        elif EFFECTS[name].group not in layout.groups:
            skipped[name] = f"the model has no {EFFECTS[name].group} equations"
        else:
            usable.append(EFFECTS[name])
    return usable, skipped
