"""Small models and synthetic maneuvers for the diagnosis tests (no FMU, pure NumPy)."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from hybridfmu.data.roles import CaseRoles, Signal
from hybridfmu.diagnosis.prepare import MeasuredManeuver
from hybridfmu.diagnosis.problem import build_problem, diagnosis_settings


class ParameterStore:
    """``get_parameters`` / ``set_parameters`` over ``self.values`` (name -> value) as a model offers them;
    ``positive`` names the parameters that must stay above 0."""

    parameter_names: list[str] = []
    positive: tuple[str, ...] = ()

    def get_parameters(self, names=None):
        return {n: self.values[n] for n in (names or self.parameter_names)}

    def set_parameters(self, values):
        for name, value in values.items():
            if name not in self.values:
                raise ValueError(f"unknown parameter {name}")
            if name in self.positive and value <= 0:
                raise ValueError(f"{name} must be positive")
            self.values[name] = float(value)


class MassSpringDamper(ParameterStore):
    """m dv/dt = F - k x - c v, dx/dt = v; states [x, v] (m, m/s), input [F] (N), parameters m, k, c."""

    state_names = ["x", "v"]
    input_names = ["F"]
    parameter_names = ["m", "k", "c"]
    positive = ("m",)

    def __init__(self, m: float = 1.0, k: float = 4.0, c: float = 0.4):
        self.values = {"m": m, "k": k, "c": c}

    def derivatives(self, x, u=None):
        x = np.atleast_2d(np.asarray(x, dtype=float))
        u = np.atleast_2d(np.asarray(u, dtype=float)).reshape(len(x), -1)
        m, k, c = self.values["m"], self.values["k"], self.values["c"]
        return np.stack([x[:, 1], (u[:, 0] - k * x[:, 0] - c * x[:, 1]) / m], axis=1)

    def jacobians(self, x, u=None):
        x = np.atleast_2d(np.asarray(x, dtype=float))
        n = len(x)
        m, k, c = self.values["m"], self.values["k"], self.values["c"]
        dfdx = np.zeros((n, 2, 2))
        dfdx[:, 0, 1] = 1.0
        dfdx[:, 1, 0] = -k / m
        dfdx[:, 1, 1] = -c / m
        dfdu = np.zeros((n, 2, 1))
        dfdu[:, 1, 0] = 1.0 / m
        return dfdx, dfdu


def msd_roles() -> CaseRoles:
    signals = {"position": Signal("position", "m", "m", "position"), "velocity": Signal("velocity", "m/s", "m/s",
                                                                                         "velocity"),
               "force": Signal("force", "N", "N", "force")}
    return CaseRoles(signals=signals, transforms=[], state_names=["x", "v"], input_names=["F"], inputs={"F": "force"},
                     states={"x": "position", "v": "velocity"}, target_weights={"x": 0.5, "v": 0.5})


def force_profile(time_s: np.ndarray, seed: int) -> np.ndarray:
    """A rich force input: a chirp, steps and noise (N)."""
    rng = np.random.default_rng(seed)
    chirp = 3.0 * np.sin(2 * np.pi * (0.1 + 0.05 * time_s) * time_s + rng.uniform(0, 6))
    steps = np.repeat(rng.uniform(-3, 3, len(time_s) // 400 + 1), 400)[:len(time_s)]
    return chirp + steps


def simulate_truth(model, extra: Callable[[np.ndarray, np.ndarray], np.ndarray] | None, time_s: np.ndarray,
                   u: np.ndarray, x0, substeps: int = 4, input_delay_s: float = 0.0) -> np.ndarray:
    """The 'real' system: the model plus ``extra(x, u) -> (1, n_x)``, RK4 with sub-steps, held inputs
    (seen ``input_delay_s`` earlier than logged when positive: the logged channel lags)."""
    dt = time_s[1] - time_s[0]
    x = np.asarray(x0, dtype=float).reshape(1, -1)
    out = np.empty((len(time_s), x.shape[1]))
    out[0] = x
    if input_delay_s:
        index = np.arange(len(u)) + input_delay_s / dt
        u = np.interp(index, np.arange(len(u)), u[:, 0])[:, None]

    def rhs(xs, us):
        f = model.derivatives(xs, us)
        return f + extra(xs, us) if extra is not None else f

    h = dt / substeps
    for k in range(len(time_s) - 1):
        uk = u[k:k + 1]
        for _ in range(substeps):
            k1 = rhs(x, uk)
            k2 = rhs(x + 0.5 * h * k1, uk)
            k3 = rhs(x + 0.5 * h * k2, uk)
            k4 = rhs(x + h * k3, uk)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out[k + 1] = x
    return out


def msd_maneuvers(extra=None, noise=(1e-4, 0.0), duration_s: float = 40.0, dt: float = 0.01,
                  truth_model=None, input_delay_s: float = 0.0) -> dict[str, MeasuredManeuver]:
    """Train, validation and test maneuvers of the mass-spring-damper with an added effect."""
    truth_model = truth_model or MassSpringDamper()
    time_s = np.arange(0.0, duration_s, dt)
    out = {}
    for seed, role in enumerate(("train", "validation", "test")):
        u = force_profile(time_s, seed)[:, None]
        x = simulate_truth(truth_model, extra, time_s, u, [0.0, 0.0], input_delay_s=input_delay_s)
        rng = np.random.default_rng(100 + seed)
        x = x + rng.standard_normal(x.shape) * np.asarray(noise)
        # the velocity is measured as the derivative of the position (state_from_derivative) when noise[1] == 0
        out[role] = MeasuredManeuver(name=role, role=role, time_s=time_s, x=x, u=u,
                                     spans_s=[[0.0, float(time_s[-1])]])
    return out


def msd_problem(model=None, **diagnosis):
    model = model or MassSpringDamper()
    config = {"seed": 3, "diagnosis": {"kernel_s": 0.09, "equations": ["v"],
                                       "selection": {"bootstrap_samples": 20}, **diagnosis}}
    settings = diagnosis_settings(config)
    return build_problem(msd_roles(), model, settings, model.get_parameters()), model


def simulate_lagged_input(time_s: np.ndarray, u_cmd: np.ndarray, lag_s: float, sensor: bool,
                          substeps: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The mass-spring-damper with a first-order lag (time constant ``lag_s``) on its force channel.

    The command ``u_cmd`` (T,) is held per sample; z follows it with lag_s dz/dt = u_cmd - z (from z = u_cmd[0]).
    ``sensor``: the plant feels the command and the log records z (a sensor lag); else the plant feels z
    and the log records the command (a slow actuator). Returns (states (T, 2), z (T,)).
    """
    model = MassSpringDamper()
    dt = time_s[1] - time_s[0]
    h = dt / substeps
    s = np.array([0.0, 0.0, u_cmd[0]])
    states, lagged = np.empty((len(time_s), 2)), np.empty(len(time_s))

    def rhs(s, u):
        force = u if sensor else s[2]
        f = model.derivatives(s[None, :2], np.array([[force]]))[0]
        return np.array([f[0], f[1], (u - s[2]) / lag_s])

    for k in range(len(time_s)):
        states[k], lagged[k] = s[:2], s[2]
        if k == len(time_s) - 1:
            break
        for _ in range(substeps):
            k1 = rhs(s, u_cmd[k])
            k2 = rhs(s + 0.5 * h * k1, u_cmd[k])
            k3 = rhs(s + 0.5 * h * k2, u_cmd[k])
            k4 = rhs(s + h * k3, u_cmd[k])
            s = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return states, lagged


def msd_input_maneuvers(duration_s: float = 20.0, dt: float = 0.01, *, lag_s: float = 0.0, sensor: bool = True,
                        plant_input: Callable[[np.ndarray], np.ndarray] | None = None,
                        input_noise: float = 0.0) -> dict[str, MeasuredManeuver]:
    """Train, validation and test maneuvers whose force channel differs from what the plant feels.

    Either a first-order lag ``lag_s`` (``sensor``: the logged force lags the true one; else the plant feels a
    lagged force, a slow actuator), or a static map ``plant_input`` (logged force (T,) -> felt force (T,), e.g.
    a dead zone). ``input_noise``: white noise (N) on the logged force. Position noise 1e-4 m.
    """
    time_s = np.arange(0.0, duration_s, dt)
    out = {}
    for seed, role in enumerate(("train", "validation", "test")):
        command = force_profile(time_s, seed)
        if lag_s:
            x, lagged = simulate_lagged_input(time_s, command, lag_s, sensor)
            logged = lagged if sensor else command
        else:
            felt = plant_input(command) if plant_input is not None else command
            x = simulate_truth(MassSpringDamper(), None, time_s, felt[:, None], [0.0, 0.0])
            logged = command
        rng = np.random.default_rng(100 + seed)
        x = x + rng.standard_normal(x.shape) * np.array([1e-4, 0.0])
        logged = logged + rng.standard_normal(logged.shape) * input_noise
        out[role] = MeasuredManeuver(name=role, role=role, time_s=time_s, x=x, u=logged[:, None],
                                     spans_s=[[0.0, float(time_s[-1])]])
    return out
