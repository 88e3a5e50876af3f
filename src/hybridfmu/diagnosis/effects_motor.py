"""Case plugin for three-phase motors: effects that need machine knowledge (Park transform, phase duties).

Loaded only when a case config lists it (``diagnosis.plugins: [hybridfmu.diagnosis.effects_motor]``);
the diagnosis core never imports it. Options (``diagnosis.plugin_options["hybridfmu.diagnosis.effects_motor"]``):

- ``duty_inputs``: the three phase duty inputs [a, b, c] (model input names);
- ``current_states``: the rotor-frame current states [d, q];
- ``angle_state``: the mechanical angle state; ``pole_pairs`` (number) or ``pole_pairs_parameter`` (model
  parameter name): electrical angle = pole pairs x angle;
- ``current_scale_relative``: grid of the current scale i_0 below which the dead-time loss fades, relative
  to the RMS of the phase currents along the data (default ``DEFAULT_CURRENT_SCALE_RELATIVE``); the best
  grid value is refined continuously on a log scale;
- ``current_scales_a``: instead, an explicit grid of i_0 in A (refined the same way; a single value fixes it);
- ``pwm_frequency_hz``: converts the fitted duty loss into a dead time (default 0: the dead time in s is
  not reported, the duty loss is).

Effect: ``deadtime(<duties>)`` in each examined current equation: every phase loses a duty share
``delta * tanh(i_k / i_0)`` against its phase current (amplitude-invariant inverse Park with the angle);
its term is the model's response to that duty change (input Jacobian along the data; a helper model
instance in the corrected simulation, both evaluations of one stage in one batch).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from hybridfmu.config import ConfigError
from hybridfmu.diagnosis.effects import Effect, EffectInputs, linear_estimate, param
from hybridfmu.diagnosis.library import log_grid_bounds
from hybridfmu.diagnosis.problem import positive_grid
from hybridfmu.fmu.effect_program import EffectTerm

WHERE = "config.diagnosis.plugin_options.hybridfmu.diagnosis.effects_motor"

#: Grid of the dead-time current scale relative to the RMS phase current along the data.
DEFAULT_CURRENT_SCALE_RELATIVE = [0.003, 0.01, 0.03, 0.1, 0.3]


def dq_to_abc(i_d: np.ndarray, i_q: np.ndarray, theta_e: np.ndarray) -> np.ndarray:
    """Phase currents (M, 3) from rotor-frame currents (amplitude-invariant inverse Park and Clarke)."""
    cos_e, sin_e = np.cos(theta_e), np.sin(theta_e)
    alpha = i_d * cos_e - i_q * sin_e
    beta = i_d * sin_e + i_q * cos_e
    half_sqrt3 = 0.5 * math.sqrt(3.0)
    return np.stack([alpha, -0.5 * alpha + half_sqrt3 * beta, -0.5 * alpha - half_sqrt3 * beta], axis=1)


def phase_current_rms(x: np.ndarray, currents: tuple[int, int], angle: int, pole_pairs: float) -> float:
    """RMS (A) over samples and phases of the phase currents of states ``x`` (M, n_x)."""
    x = np.asarray(x, dtype=float)
    i_abc = dq_to_abc(x[:, currents[0]], x[:, currents[1]], pole_pairs * x[:, angle])
    i_abc = i_abc[np.all(np.isfinite(i_abc), axis=1)]
    return float(np.sqrt(np.mean(i_abc ** 2))) if i_abc.size else 0.0


class InverterDeadtime(Effect):
    """Inverter dead time: every phase loses a duty share against its phase current, fading below i_0."""

    kind = "deadtime"
    continuous = "current_scale_a"
    log_scale = True
    model_wide = True

    def __init__(self, problem: Any, equation: int, duties: list[int], currents: tuple[int, int], angle: int,
                 pole_pairs: float, scales: list[float], pwm_frequency_hz: float):
        """``scales``: grid of i_0 (A), refined on a log scale (a single value fixes it); ``pwm_frequency_hz``:
        0 leaves the dead time in s out of the report."""
        names = [problem.input_names[j] for j in duties]
        super().__init__(f"deadtime({','.join(names)})", equation,
                         "inverter dead time: each phase loses a duty share against its phase current",
                         "delta d_k = -delta * tanh(i_k / i_0), k = a, b, c", "-")
        self.duties, self.currents, self.angle = list(duties), currents, angle
        self.pole_pairs, self.scales, self.pwm = float(pole_pairs), sorted(float(s) for s in scales), \
            float(pwm_frequency_hz)

    def grid(self):
        return [{"current_scale_a": s} for s in self.scales]

    def bounds(self):
        return log_grid_bounds(self.scales)

    def coefficient_names(self, setting):
        return ["duty_error"]

    def duty_change(self, x: np.ndarray, u: np.ndarray, scale: float) -> np.ndarray:
        """(M, n_u) input change of a unit duty loss against the phase currents (x (M, n_x), u (M, n_u))."""
        i_abc = dq_to_abc(x[:, self.currents[0]], x[:, self.currents[1]], self.pole_pairs * x[:, self.angle])
        delta = np.zeros_like(u)
        delta[:, self.duties] = -np.tanh(i_abc / scale)
        return delta

    def regressors(self, inputs: EffectInputs, setting):
        delta = self.duty_change(inputs.x_smooth, inputs.u, setting["current_scale_a"])
        return inputs.input_response(delta)[:, [self.equation]]

    def _duty_change_row(self, x_row: np.ndarray, scale: float) -> tuple[float, float, float]:
        """The three phase duty changes of a unit loss for one state row (plain floats, the RK-stage case)."""
        i_d, i_q = float(x_row[self.currents[0]]), float(x_row[self.currents[1]])
        theta_e = self.pole_pairs * float(x_row[self.angle])
        cos_e, sin_e = math.cos(theta_e), math.sin(theta_e)
        alpha, beta = i_d * cos_e - i_q * sin_e, i_d * sin_e + i_q * cos_e
        half_sqrt3 = 0.5 * math.sqrt(3.0)
        return (-math.tanh(alpha / scale), -math.tanh((-0.5 * alpha + half_sqrt3 * beta) / scale),
                -math.tanh((-0.5 * alpha - half_sqrt3 * beta) / scale))

    def batch_function(self, coef, setting, helper):
        """f_row(x, u + delta) - f_row(x, u) with the helper model, x (N, n_x), u (N, n_u) -> (N,).

        Both evaluations go to the helper as one batch of 2N rows (the helper's fast fixed-size kernel when it
        has one); a single row (one RK stage of a simulation) computes its duty change with plain floats.
        """
        joint = self.joint_batch_function([self], coef, setting, helper)
        return None if joint is None else (lambda x, u: joint(x, u)[:, 0])

    @staticmethod
    def joint_batch_function(members: list["InverterDeadtime"], coef, setting, helper):
        """:meth:`batch_function` of all ``members`` (the effect in each equation it acts on) at once:
        x (N, n_x), u (N, n_u) -> (N, len(members)), the members' equations in order, from one evaluation of
        the helper (the members of one term share the duty change and the model's response to it)."""
        if helper is None:
            return None
        first = members[0]
        size, scale = float(coef[0]), float(setting["current_scale_a"])
        rows = [member.equation for member in members]
        duties = first.duties
        kernels: dict[int, Any] = {}
        make_kernel = getattr(helper, "derivatives_kernel", None)

        def evaluate(x2: np.ndarray, u2: np.ndarray) -> np.ndarray:
            if make_kernel is None:
                return np.asarray(helper.derivatives(x2, u2))
            n2 = x2.shape[0]
            if n2 not in kernels:
                kernels[n2] = make_kernel(n2)
            return kernels[n2](x2, u2)

        def term(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            x = np.asarray(x, dtype=float)
            u = np.asarray(u, dtype=float)
            n = x.shape[0]
            stacked_x = np.concatenate([x, x])
            stacked_u = np.concatenate([u, u])
            if n == 1:
                for j, change in zip(duties, first._duty_change_row(x[0], scale)):
                    stacked_u[0, j] += size * change
            else:
                stacked_u[:n] += size * first.duty_change(x, u, scale)
            f = evaluate(stacked_x, stacked_u)
            return f[:n, rows] - f[n:, rows]
        return term

    def stage_term(self, coef, setting):
        return self.joint_stage_term([self], coef, setting)

    @staticmethod
    def joint_stage_term(members: list["InverterDeadtime"], coef, setting) -> EffectTerm:
        """:meth:`joint_batch_function` as a :meth:`stage_term` (one model evaluation for all ``members``)."""
        first = members[0]
        return EffectTerm("phase_deadtime", tuple(member.equation for member in members),
                          (*first.duties, *first.currents, first.angle),
                          (float(coef[0]), float(setting["current_scale_a"]), first.pole_pairs))

    def physical(self, coef, cov, setting, setting_se):
        duty_error, se = linear_estimate(coef, cov, [1.0])
        fixed = len(self.scales) < 2
        out = [param("duty_error", duty_error, se, "-", "duty lost per phase against the phase current"),
               param("current_scale_a", setting["current_scale_a"], setting_se.get("current_scale_a"), "A",
                     "current below which the loss fades" + (" (fixed)" if fixed else " (searched, refined)"))]
        if self.pwm > 0:
            out.append(param("dead_time_s", duty_error / self.pwm, se / self.pwm, "s",
                             "equivalent dead time at the configured PWM frequency"))
        return out


def current_scales(options: dict[str, Any], inputs: EffectInputs | None, currents: tuple[int, int], angle: int,
                   pole_pairs: float) -> list[float]:
    """The grid of i_0 (A): ``current_scales_a``, else ``current_scale_relative`` times the RMS phase current
    along the data (``inputs.x_smooth``); [] when the data carry no current.

    Raises:
        ConfigError: both options given, or one that is no positive number / list of them.
    """
    if options.get("current_scales_a") is not None:
        if options.get("current_scale_relative") is not None:
            raise ConfigError(f"{WHERE}: expected one of current_scales_a (an explicit grid in A) or "
                              "current_scale_relative (relative to the RMS phase current), not both")
        return positive_grid(options["current_scales_a"], f"{WHERE}.current_scales_a")
    relative = options.get("current_scale_relative")
    relative = positive_grid(DEFAULT_CURRENT_SCALE_RELATIVE if relative is None else relative,
                             f"{WHERE}.current_scale_relative")
    if inputs is None:
        raise ValueError("deadtime: a current scale relative to the phase currents needs the data (effect inputs)")
    rms = phase_current_rms(inputs.x_smooth, currents, angle, pole_pairs)
    return [r * rms for r in relative] if rms > 0 else []


def plugin_effects(problem: Any, equation: int, options: dict[str, Any], inputs: EffectInputs) -> list[Effect]:
    """The motor effects for the equation of state ``equation`` (only the current equations get one).

    ``inputs``: effect inputs along a fitting maneuver (the RMS phase current of the relative current grid).
    """
    try:
        duties = [problem.input_names.index(n) for n in options.get("duty_inputs", [])]
        currents = tuple(problem.state_names.index(n) for n in options.get("current_states", []))
        angle = problem.state_names.index(options["angle_state"])
    except (ValueError, KeyError) as err:
        raise ConfigError(f"{WHERE}: expected duty_inputs (3 model inputs), current_states (2 states) and "
                          f"angle_state naming the model's variables ({err})") from None
    if len(duties) != 3 or len(currents) != 2:
        raise ConfigError(f"{WHERE}: expected 3 duty_inputs and 2 current_states")
    if equation not in currents:
        return []
    pole_pairs = options.get("pole_pairs")
    if pole_pairs is None:
        name = options.get("pole_pairs_parameter")
        if name not in problem.parameter_values:
            raise ConfigError(f"{WHERE}: expected pole_pairs or pole_pairs_parameter naming a model parameter")
        pole_pairs = problem.parameter_values[name]
    pwm = options.get("pwm_frequency_hz")
    if pwm is None:
        pwm = 0.0
    if isinstance(pwm, bool) or not isinstance(pwm, (int, float)) or not pwm >= 0:
        raise ConfigError(f"{WHERE}.pwm_frequency_hz: expected a frequency >= 0 in Hz (0: no dead time in s), "
                          f"got {pwm!r}")
    scales = current_scales(options, inputs, currents, angle, float(pole_pairs))
    return [InverterDeadtime(problem, equation, duties, currents, angle, float(pole_pairs), scales, float(pwm))]
