"""Least-squares calibration of FMU parameters and unmeasured initial states on measured maneuvers.

Objective. Each maneuver is simulated open loop over its whole length (``simulate_open_loop``:
RK4, one step per sample, inputs held per sample) from its initial state: the measured states
from the data at its first sample, the unmeasured states from the fitted values. The residual of
target state ``t`` at sample ``k`` of maneuver ``m`` is::

    r = sqrt(w_t) * (x_sim[k, t] - x_meas[k, t]) / std_t / sqrt(N)

with ``w_t`` the target weights (``roles.target_weights``, summing to 1), ``std_t`` the standard
deviation of the measured target over the fitted maneuvers (1 where it is 0) and ``N`` the number
of samples of all fitted maneuvers, so the cost ``0.5 * sum r^2`` is half the weighted mean of the
normalised squared errors.

Phases. (1) The parameters of ``config.calibration.parameters`` jointly with the unmeasured initial
states of every train maneuver (when ``calibration.initial_states``); (2) with the parameters fixed,
the unmeasured initial states of each validation maneuver on its own.

Fitter: :mod:`hybridfmu.output_error` (the one the diagnosis' recalibration uses too):
``scipy.optimize.least_squares``, trust-region reflective (``trf``) with the bounds of the config, in
variables normalised by their start values. Sensitivities: forward finite differences of the simulation (one
extra simulation per variable, relative step :data:`FD_RELATIVE_STEP` of the normalised variable, the steps
scipy's ``jac="2-point"`` takes); a column of a maneuver's initial state re-simulates that maneuver only (the
others do not depend on it). The FMU's directional derivatives are not used: they give the Jacobian of the right-hand
side, not of the simulated trajectory with respect to parameters.

API::

    fit_settings(config) -> FitSettings
    needs_fit(settings, roles) -> bool
    fit_case(model, roles, settings, start_parameters, start_states, train, validation) -> FitOutcome
    target_rmse(simulated, measured, signals) -> {"<signal>_rmse": value}
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from hybridfmu.calibration.data import ManeuverArrays
from hybridfmu.config import ConfigError
from hybridfmu.data.roles import CaseRoles
from hybridfmu.output_error import Variable, fit_output_error, target_spread

LOG = logging.getLogger(__name__)

#: Forward-difference step, relative to |z| of a normalised variable z (hybridfmu.output_error.forward_step).
FD_RELATIVE_STEP = 1e-6


@dataclass(frozen=True)
class FitSettings:
    """What to fit (from ``config.calibration``).

    Attributes:
        parameter_bounds: FMU parameter -> (min, max), -inf/inf where unbounded; config order.
        initial_states: fit the unmeasured states' initial values of train and validation maneuvers.
        state_bounds: unmeasured state -> (min, max) of its fitted initial value.
        max_iterations: most trust-region iterations per phase (least_squares' max_nfev: evaluations of
            the objective at trial points; the Jacobian's simulations are not counted).
        duration_s: fit on the first duration_s of each train maneuver (None: all of it).
    """

    parameter_bounds: dict[str, tuple[float, float]]
    initial_states: bool = True
    state_bounds: dict[str, tuple[float, float]] = field(default_factory=dict)
    max_iterations: int = 50
    duration_s: float | None = None


def _bounds(entry: dict[str, Any] | None, where: str) -> tuple[float, float]:
    entry = entry or {}
    low = -math.inf if entry.get("min") is None else float(entry["min"])
    high = math.inf if entry.get("max") is None else float(entry["max"])
    if not low < high:
        raise ConfigError(f"{where}: min {low:g} is not below max {high:g}; expected min < max")
    return low, high


def fit_settings(config: dict[str, Any]) -> FitSettings:
    """The calibration settings of a validated case config (section ``calibration``, schema defaults).

    Raises:
        ConfigError: bounds with min >= max (names the field).
    """
    section = config.get("calibration") or {}
    parameters = {name: _bounds(entry, f"config.calibration.parameters.{name}")
                  for name, entry in (section.get("parameters") or {}).items()}
    states = {name: _bounds(entry, f"config.calibration.initial_state_bounds.{name}")
              for name, entry in (section.get("initial_state_bounds") or {}).items()}
    return FitSettings(parameter_bounds=parameters, initial_states=bool(section.get("initial_states", True)),
                       state_bounds=states, max_iterations=int(section.get("max_iterations", 50)),
                       duration_s=section.get("duration_s"))


def fitted_states(settings: FitSettings, roles: CaseRoles) -> list[str]:
    """The unmeasured states whose initial values are fitted (none unless ``initial_states``)."""
    return list(roles.unmeasured_states) if settings.initial_states else []


def needs_fit(settings: FitSettings, roles: CaseRoles) -> bool:
    """True when there is a parameter or an unmeasured initial state to fit."""
    return bool(settings.parameter_bounds) or bool(fitted_states(settings, roles))


def target_rmse(simulated: np.ndarray, measured: np.ndarray, signals: Sequence[str]) -> dict[str, float]:
    """RMS error per target: ``{"<signal>_rmse": value}`` in the signal's unit.

    simulated, measured: (T, n_targets), columns in the order of ``signals``.
    """
    error = np.asarray(simulated, float) - np.asarray(measured, float)
    return {f"{signal}_rmse": float(np.sqrt(np.mean(error[:, j] ** 2))) for j, signal in enumerate(signals)}


class TargetSimulator:
    """Open-loop simulations of one FMU over maneuvers, returning the target states.

    Args:
        model: an FmuModel (``hybridfmu.fmu.load_fmu``); its parameters are changed by ``simulate``.
        roles: the case's roles (state order, measured and target states).
    """

    def __init__(self, model, roles: CaseRoles):
        self.model = model
        self.roles = roles
        self.target_index = [roles.state_names.index(name) for name in roles.target_states]
        self._parameters: dict[str, float] | None = None

    def initial_state(self, maneuver: ManeuverArrays, unmeasured: dict[str, float]) -> np.ndarray:
        """(n_x,) initial state: measured states at the first sample, the others from ``unmeasured``
        (else the FMU's start values)."""
        x0 = np.array(self.model.initial_states, dtype=float)
        for i, name in enumerate(self.roles.state_names):
            if name in maneuver.measured_names:
                x0[i] = maneuver.state(name)[0]
            elif name in unmeasured:
                x0[i] = float(unmeasured[name])
        return x0

    def set_parameters(self, parameters: dict[str, float]) -> None:
        if parameters and parameters != self._parameters:
            self.model.set_parameters(parameters)
            self._parameters = dict(parameters)

    def forget_parameters(self) -> None:
        """Set every parameter again at the next simulation (after the FMU failed with a trial value)."""
        self._parameters = None

    def simulate(self, maneuver: ManeuverArrays, parameters: dict[str, float],
                 unmeasured: dict[str, float]) -> np.ndarray:
        """(T, n_targets) simulated target states (order ``roles.target_states``).

        Raises:
            FmuError: the FMU failed (e.g. rejected a parameter value).
        """
        from hybridfmu.fmu import simulate_open_loop

        self.set_parameters(parameters)
        inputs = maneuver.inputs if self.model.n_inputs else None
        result = simulate_open_loop(self.model, maneuver.time_s, inputs, self.initial_state(maneuver, unmeasured))
        return result.states[:, self.target_index]

    def measured_targets(self, maneuver: ManeuverArrays) -> np.ndarray:
        """(T, n_targets) measured target states."""
        return np.stack([maneuver.state(name) for name in self.roles.target_states], axis=1)


@dataclass
class PhaseResult:
    """Outcome of one least-squares phase.

    Attributes:
        parameters: fitted parameter values (empty in a states-only phase).
        states: maneuver -> unmeasured state -> fitted initial value.
        cost_start, cost: objective (module docstring) at the start and at the optimum.
        iterations, evaluations: Jacobian evaluations and simulations of all maneuvers (n_fev).
        status, message: of least_squares.
        elapsed_s: wall time.
    """

    parameters: dict[str, float]
    states: dict[str, dict[str, float]]
    cost_start: float
    cost: float
    iterations: int
    evaluations: int
    status: int
    message: str
    elapsed_s: float

    def summary(self) -> dict[str, Any]:
        return {"cost_start": self.cost_start, "cost": self.cost, "iterations": self.iterations,
                "evaluations": self.evaluations, "status": self.status, "message": self.message,
                "elapsed_s": round(self.elapsed_s, 3)}


def _clip_start(name: str, value: float, bounds: tuple[float, float], kind: str) -> float:
    low, high = bounds
    if low <= value <= high:
        return value
    clipped = float(min(max(value, low), high))
    LOG.warning("start value %s = %g of %s lies outside its bounds [%g, %g]; starting from %g",
                name, value, kind, low, high, clipped)
    return clipped


def least_squares_phase(simulator: TargetSimulator, maneuvers: list[ManeuverArrays], fixed: dict[str, float],
                        parameter_start: dict[str, float], parameter_bounds: dict[str, tuple[float, float]],
                        state_start: dict[str, dict[str, float]], state_bounds: dict[str, tuple[float, float]],
                        state_names: list[str], target_std: np.ndarray, weights: np.ndarray,
                        max_iterations: int, label: str) -> PhaseResult:
    """One least-squares fit (module docstring) of parameters and per-maneuver unmeasured initial states, by the
    output-error fitter (:func:`hybridfmu.output_error.fit_output_error`).

    Args:
        simulator: simulates the FMU's targets.
        maneuvers: the maneuvers fitted jointly.
        fixed: parameters set but not fitted (FMU name -> value).
        parameter_start, parameter_bounds: fitted parameters: start value and (min, max).
        state_start: maneuver -> unmeasured state -> start value; state_bounds: state -> (min, max).
        state_names: the unmeasured states fitted for each maneuver.
        target_std: (n_targets,) scale of each target's residual; weights: (n_targets,) target weights.
        max_iterations: most evaluations of the objective at trial points (least_squares' max_nfev).
        label: prefix of the progress lines.
    """
    from hybridfmu.fmu import FmuError

    names = list(parameter_start)
    variables = [Variable(name, parameter_start[name], *parameter_bounds[name]) for name in names]
    for m, maneuver in enumerate(maneuvers):
        for name in state_names:
            low, high = state_bounds.get(name, (-math.inf, math.inf))
            start = _clip_start(name, state_start[maneuver.name][name], (low, high), f"maneuver {maneuver.name!r}")
            variables.append(Variable(f"{name}@{maneuver.name}", start, low, high, maneuver=m))

    def simulate(values: dict[str, float], m: int) -> np.ndarray:
        parameters = {**fixed, **{name: values[name] for name in names}}
        states = {name: values[f"{name}@{maneuvers[m].name}"] for name in state_names}
        try:
            return simulator.simulate(maneuvers[m], parameters, states)
        except FmuError:
            simulator.forget_parameters()  # the FMU may hold a rejected value: set every parameter again
            raise

    fit = fit_output_error(variables, simulate, [simulator.measured_targets(m) for m in maneuvers], weights,
                           target_std, relative_step=FD_RELATIVE_STEP, tolerance=1e-10,
                           max_evaluations=max_iterations, label=label, failures=(FmuError,), shown=names)
    values = fit.values or {v.name: v.start for v in variables}
    return PhaseResult(parameters={name: values[name] for name in names},
                       states={m.name: {s: values[f"{s}@{m.name}"] for s in state_names} for m in maneuvers},
                       cost_start=fit.cost_start, cost=fit.cost, iterations=fit.iterations,
                       evaluations=fit.evaluations, status=fit.status, message=fit.message, elapsed_s=fit.elapsed_s)


@dataclass
class FitOutcome:
    """Result of :func:`fit_case`.

    Attributes:
        parameters: every parameter set on the FMU (start ones + fitted), name -> value.
        fitted: names of the fitted parameters.
        initial_states: maneuver -> fitted unmeasured initial states (train and validation).
        start_states: maneuver -> unmeasured initial states before the fit (FMU start values).
        phases: "train" / "validation:<maneuver>" -> PhaseResult.
    """

    parameters: dict[str, float]
    fitted: list[str]
    initial_states: dict[str, dict[str, float]]
    start_states: dict[str, dict[str, float]]
    phases: dict[str, PhaseResult]


def check_settings(settings: FitSettings, parameter_names: Sequence[str], roles: CaseRoles, source: str) -> None:
    """Raise ConfigError unless every parameter to fit is one of the FMU's (``source`` names it) and every
    state with bounds is an unmeasured state."""
    for name in settings.parameter_bounds:
        if name not in parameter_names:
            raise ConfigError(f"config.calibration.parameters.{name}: the FMU ({source}) has no parameter "
                              f"{name!r}; expected one of {list(parameter_names)}")
    for name in settings.state_bounds:
        if name not in roles.unmeasured_states:
            raise ConfigError(f"config.calibration.initial_state_bounds.{name}: not an unmeasured state of the "
                              f"FMU ({source}); expected one of {roles.unmeasured_states}")


def target_std(simulator: TargetSimulator, maneuvers: list[ManeuverArrays]) -> np.ndarray:
    """(n_targets,) standard deviation of each measured target over ``maneuvers`` (1 where it is 0)."""
    return target_spread([simulator.measured_targets(m) for m in maneuvers])


def fit_case(model, roles: CaseRoles, settings: FitSettings, start_parameters: dict[str, float],
             start_states: dict[str, float], train: list[ManeuverArrays],
             validation: list[ManeuverArrays]) -> FitOutcome:
    """Fit parameters and unmeasured initial states (module docstring: phases, objective, optimiser).

    Args:
        model: the FMU (``load_fmu``), loaded with ``start_parameters``.
        roles: the case's roles.
        settings: what to fit (:func:`fit_settings`).
        start_parameters: every parameter value to set (config values, and the start of the fitted ones).
        start_states: unmeasured state -> start value of its fitted initial value (FMU start values).
        train, validation: the maneuvers of phase 1 and 2 (train ones truncated to settings.duration_s).

    Raises:
        ConfigError: a parameter to fit is not one of the FMU's; no train maneuver while something is fitted.
    """
    check_settings(settings, model.parameter_names, roles, str(model.path))
    if not train:
        raise ConfigError("config.maneuvers: no maneuver with role 'train'; expected at least one to calibrate on")
    simulator = TargetSimulator(model, roles)
    weights = np.array([roles.target_weights[name] for name in roles.target_states])
    train = [m.truncated(settings.duration_s) for m in train]
    std = target_std(simulator, train)
    states = fitted_states(settings, roles)
    fitted = list(settings.parameter_bounds)
    fixed = {k: v for k, v in start_parameters.items() if k not in settings.parameter_bounds}
    parameter_start = {name: _clip_start(name, float(start_parameters[name]), settings.parameter_bounds[name],
                                         "the FMU") for name in fitted}
    start_by_maneuver = {m.name: {s: float(start_states[s]) for s in states} for m in [*train, *validation]}
    phases: dict[str, PhaseResult] = {}
    phases["train"] = least_squares_phase(
        simulator, train, fixed, parameter_start, settings.parameter_bounds, start_by_maneuver,
        settings.state_bounds, states, std, weights, settings.max_iterations, "calibration train")
    parameters = {**fixed, **phases["train"].parameters}
    initial_states = dict(phases["train"].states)
    if states:
        for maneuver in validation:
            label = f"validation:{maneuver.name}"
            phases[label] = least_squares_phase(
                simulator, [maneuver], parameters, {}, {}, start_by_maneuver, settings.state_bounds, states,
                std, weights, settings.max_iterations, f"calibration {label}")
            initial_states.update(phases[label].states)
    return FitOutcome(parameters=parameters, fitted=fitted, initial_states=initial_states,
                      start_states=start_by_maneuver, phases=phases)
