"""Where the motor's quantities sit in the model: state/input indices and constants.

The candidate effects need to know which state is the rotor angle or speed, which inputs
are the PWM duties, the supply voltage and the load torque, the pole-pair number and the
rotor inertia. ``resolve_layout`` finds them from the model's variable names, the case's
``signals``/``diagnosis`` config and the model itself (inertia from the load-torque
Jacobian), so a case with other names only has to configure them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: The two equation groups the diagnosis distinguishes.
GROUPS = ("electrical", "mechanical")


@dataclass
class MotorLayout:
    """Indices (into the model's state/input vectors) and constants used by the effects.

    ``groups`` maps an equation group to the state indices whose equations it holds.
    ``inertia_kg_m2`` converts torques (N m) to accelerations (rad/s^2). ``constants`` holds
    model coefficients calibrated along the data (see ``calibrate_constants``) that let the
    corrections run in scalar arithmetic.
    """

    state_names: list[str]
    input_names: list[str]
    theta: int
    omega: int
    i_d: int | None = None
    i_q: int | None = None
    duty: tuple[int, int, int] | None = None
    u_dc: int | None = None
    tau_load: int | None = None
    pole_pairs: float | None = None
    inertia_kg_m2: float | None = None
    groups: dict[str, list[int]] = field(default_factory=dict)
    dt_s: float = 1e-4
    constants: dict[str, float] = field(default_factory=dict)

    @property
    def n_x(self) -> int:
        return len(self.state_names)

    @property
    def n_u(self) -> int:
        return len(self.input_names)


def _index(names: list[str], name: str | None, what: str, required: bool) -> int | None:
    if not name:
        if required:
            raise ValueError(f"diagnosis: no {what} configured")
        return None
    if name not in names:
        if required:
            raise ValueError(f"diagnosis: {what} {name!r} is not among the model's variables {names}")
        return None
    return names.index(name)


def resolve_layout(model: Any, diagnosis_config: dict[str, Any], signals_config: dict[str, Any] | None,
                   x_sample: np.ndarray, u_sample: np.ndarray, dt_s: float,
                   parameter_values: dict[str, float] | None = None) -> MotorLayout:
    """Build the layout of ``model`` for the diagnosis.

    Args:
        model: model with ``state_names``, ``input_names``, ``jacobians``.
        diagnosis_config: the case's ``diagnosis`` section (``variables`` sub-section names the
            model variables, ``pole_pairs``/``inertia_kg_m2`` override the model's values).
        signals_config: the case's ``signals`` section (angle/speed states), may be None.
        x_sample, u_sample: a few measured states/inputs (K, n_x), (K, n_u) at which the inertia
            is read from the model's load-torque Jacobian (-1 / (d omega_dot / d tau_load)).
        dt_s: sampling interval of the data (s).
        parameter_values: the model's parameter values by name (e.g. start values), optional.
    """
    names = diagnosis_config.get("variables", {})
    signals_config = signals_config or {}
    states = list(model.state_names)
    inputs = list(model.input_names)
    theta = _index(states, signals_config.get("angle_state") or names.get("theta", "theta"), "angle state", True)
    omega = _index(states, signals_config.get("speed_state") or names.get("omega", "omega"), "speed state", True)
    i_d = _index(states, names.get("i_d", "i_d"), "d-axis current state", False)
    i_q = _index(states, names.get("i_q", "i_q"), "q-axis current state", False)
    duty_names = names.get("duties", ["d_a", "d_b", "d_c"])
    duty_idx = [_index(inputs, n, "duty input", False) for n in duty_names]
    duty = tuple(duty_idx) if len(duty_idx) == 3 and all(i is not None for i in duty_idx) else None
    u_dc = _index(inputs, names.get("u_dc", "u_dc"), "supply voltage input", False)
    tau_load = _index(inputs, names.get("tau_load", "tau_load"), "load torque input", False)
    parameter_values = parameter_values or {}
    pole_pairs = diagnosis_config.get("pole_pairs") or parameter_values.get(names.get("pole_pairs", "p"))
    inertia = diagnosis_config.get("inertia_kg_m2")
    if not inertia and tau_load is not None:
        _, dfdu = model.jacobians(np.asarray(x_sample, dtype=float), np.asarray(u_sample, dtype=float))
        slope = float(np.median(dfdu[:, omega, tau_load]))
        if slope < 0 and np.isfinite(slope):
            inertia = -1.0 / slope
    if not inertia:
        inertia = parameter_values.get(names.get("inertia", "J"))
    groups = {"mechanical": [omega]}
    if i_d is not None and i_q is not None:
        groups["electrical"] = [i_d, i_q]
    return MotorLayout(
        state_names=states, input_names=inputs, theta=theta, omega=omega, i_d=i_d, i_q=i_q,
        duty=duty, u_dc=u_dc, tau_load=tau_load,
        pole_pairs=float(pole_pairs) if pole_pairs else None,
        inertia_kg_m2=float(inertia) if inertia else None, groups=groups, dt_s=float(dt_s),
    )


def _exact_fit(design: np.ndarray, target: np.ndarray, tolerance: float = 1e-6) -> np.ndarray | None:
    """Least-squares coefficients if they reproduce ``target`` to ``tolerance`` (relative), else None."""
    keep = np.all(np.isfinite(design), axis=1) & np.isfinite(target)
    design, target = design[keep], target[keep]
    if len(target) < 4 * design.shape[1]:
        return None
    coef, *_ = np.linalg.lstsq(design, target, rcond=None)
    scale = max(float(np.max(np.abs(target))), 1e-12)
    return coef if float(np.max(np.abs(design @ coef - target))) <= tolerance * scale else None


def calibrate_constants(layout: MotorLayout, x: np.ndarray, u: np.ndarray, f: np.ndarray,
                        dfdx: np.ndarray | None, dfdu: np.ndarray | None) -> dict[str, float]:
    """Coefficients of the model found along the data, kept only where they reproduce it exactly.

    - ``speed_*``: omega_dot = a_q i_q + a_dq i_d i_q + a_w omega + a_l tau_load + a_0 (the speed
      equation is affine in these for a PMSM);
    - current equations: i_dot_d = inv_l_d v_d + diag_d i_d + cross_d omega i_q and
      i_dot_q = inv_l_q v_q + diag_q i_q + cross_q omega i_d + emf_q omega, with v_dq =
      Park(Clarke(u_dc (d - mean d))) (amplitude-invariant, theta_e = p theta): 1/L, -R/L, the
      cross coupling p L_q/L_d and -p L_d/L_q, and the back-EMF constant -p psi/L_q.
    Arguments: ``x`` (M, n_x), ``u`` (M, n_u), ``f`` = model derivatives at (x, u) (M, n_x),
    Jacobians at (x, u) (unused by the fits, kept for models without inputs of these kinds). Returns the constants found (also stored in ``layout.constants``).
    """
    from hybridfmu.diagnosis.synthetic import abc_to_dq

    found: dict[str, float] = {}
    lay = layout
    step = max(1, len(x) // 20000)
    xs, us, fs = x[::step], u[::step], f[::step]
    if lay.i_d is not None and lay.i_q is not None and lay.tau_load is not None:
        design = np.stack([xs[:, lay.i_q], xs[:, lay.i_d] * xs[:, lay.i_q], xs[:, lay.omega], us[:, lay.tau_load],
                           np.ones(len(xs))], axis=1)
        coef = _exact_fit(design, fs[:, lay.omega])
        if coef is not None:
            found.update(zip(("speed_a_q", "speed_a_dq", "speed_a_w", "speed_a_l", "speed_a_0"), map(float, coef)))
    if lay.duty is not None and lay.u_dc is not None and lay.pole_pairs and lay.i_d is not None and lay.i_q is not None:
        duty = us[:, list(lay.duty)]
        v_d, v_q = abc_to_dq((duty - duty.mean(axis=1, keepdims=True)) * us[:, [lay.u_dc]],
                             lay.pole_pairs * xs[:, lay.theta])
        i_d, i_q, omega = xs[:, lay.i_d], xs[:, lay.i_q], xs[:, lay.omega]
        coef = _exact_fit(np.stack([v_d, i_d, omega * i_q], axis=1), fs[:, lay.i_d], tolerance=1e-5)
        if coef is not None:
            found.update(zip(("inv_l_d", "diag_d", "cross_d"), map(float, coef)))
        coef = _exact_fit(np.stack([v_q, i_q, omega * i_d, omega], axis=1), fs[:, lay.i_q], tolerance=1e-5)
        if coef is not None:
            found.update(zip(("inv_l_q", "diag_q", "cross_q", "emf_q"), map(float, coef)))
    layout.constants.update(found)
    return found
