"""Case plugin for three-phase motors: effects that need machine knowledge (Park transform, phase duties).

Loaded only when a case config lists it (``diagnosis.plugins: [hybridfmu.diagnosis.effects_motor]``);
the diagnosis core never imports it. Options (``diagnosis.plugin_options["hybridfmu.diagnosis.effects_motor"]``):

- ``duty_inputs``: the three phase duty inputs [a, b, c] (model input names);
- ``current_states``: the rotor-frame current states [d, q];
- ``angle_state``: the mechanical angle state; ``pole_pairs`` (number) or ``pole_pairs_parameter`` (model
  parameter name): electrical angle = pole pairs x angle;
- ``current_scales_a``: grid of the current scale below which the dead-time loss fades (A);
- ``pwm_frequency_hz``: converts the fitted duty loss into a dead time (0 leaves it out).

Effect: ``deadtime(<duties>)`` in each examined current equation: every phase loses a duty share
``delta * tanh(i_k / i_0)`` against its phase current (amplitude-invariant inverse Park with the angle);
its term is the model's response to that duty change (input Jacobian along the data; a helper model
instance in the corrected simulation).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hybridfmu.config import ConfigError
from hybridfmu.diagnosis.effects import Effect, EffectInputs, linear_estimate, param

WHERE = "config.diagnosis.plugin_options.hybridfmu.diagnosis.effects_motor"


def dq_to_abc(i_d: np.ndarray, i_q: np.ndarray, theta_e: np.ndarray) -> np.ndarray:
    """Phase currents (M, 3) from rotor-frame currents (amplitude-invariant inverse Park and Clarke)."""
    cos_e, sin_e = np.cos(theta_e), np.sin(theta_e)
    alpha = i_d * cos_e - i_q * sin_e
    beta = i_d * sin_e + i_q * cos_e
    half_sqrt3 = 0.5 * math.sqrt(3.0)
    return np.stack([alpha, -0.5 * alpha + half_sqrt3 * beta, -0.5 * alpha - half_sqrt3 * beta], axis=1)


class InverterDeadtime(Effect):
    kind = "deadtime"

    def __init__(self, problem: Any, equation: int, duties: list[int], currents: tuple[int, int], angle: int,
                 pole_pairs: float, scales: list[float], pwm_frequency_hz: float):
        names = [problem.input_names[j] for j in duties]
        super().__init__(f"deadtime({','.join(names)})", equation,
                         "inverter dead time: each phase loses a duty share against its phase current",
                         "delta d_k = -delta * tanh(i_k / i_0), k = a, b, c", "-")
        self.duties, self.currents, self.angle = list(duties), currents, angle
        self.pole_pairs, self.scales, self.pwm = float(pole_pairs), [float(s) for s in scales], float(pwm_frequency_hz)

    def grid(self):
        return [{"current_scale_a": s} for s in self.scales]

    def coefficient_names(self, setting):
        return ["duty_error"]

    def duty_change(self, x: np.ndarray, u: np.ndarray, scale: float) -> np.ndarray:
        """(M, n_u) input change of a unit duty loss against the phase currents."""
        i_abc = dq_to_abc(x[:, self.currents[0]], x[:, self.currents[1]], self.pole_pairs * x[:, self.angle])
        delta = np.zeros_like(u)
        delta[:, self.duties] = -np.tanh(i_abc / scale)
        return delta

    def regressors(self, inputs: EffectInputs, setting):
        delta = self.duty_change(inputs.x_smooth, inputs.u, setting["current_scale_a"])
        return inputs.input_response(delta)[:, [self.equation]]

    def batch_function(self, coef, setting, helper):
        if helper is None:
            return None
        size, scale, row = float(coef[0]), setting["current_scale_a"], self.equation

        def term(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            changed = u + size * self.duty_change(x, u, scale)
            return (np.asarray(helper.derivatives(x, changed)) - np.asarray(helper.derivatives(x, u)))[:, row]
        return term

    def physical(self, coef, cov, setting, setting_se):
        duty_error, se = linear_estimate(coef, cov, [1.0])
        out = [param("duty_error", duty_error, se, "-", "duty lost per phase against the phase current"),
               param("current_scale_a", setting["current_scale_a"], None, "A", "current below which the loss fades")]
        if self.pwm > 0:
            out.append(param("dead_time_s", duty_error / self.pwm, se / self.pwm, "s",
                             "equivalent dead time at the configured PWM frequency"))
        return out


def plugin_effects(problem: Any, equation: int, options: dict[str, Any], inputs: EffectInputs) -> list[Effect]:
    """The motor effects for the equation of state ``equation`` (only the current equations get one)."""
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
    return [InverterDeadtime(problem, equation, duties, currents, angle, float(pole_pairs),
                             options.get("current_scales_a", [0.5, 2.0, 5.0]),
                             float(options.get("pwm_frequency_hz", 0.0)))]
