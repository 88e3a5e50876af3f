"""What the diagnosis works on, in roles: states, inputs, examined equations, units and labels.

Nothing here knows a machine. A :class:`Problem` is built from the case's roles
(:func:`hybridfmu.data.roles.case_roles`), the ``diagnosis`` section of the case config and the model
(an FMU or any object with ``state_names``, ``input_names``, ``derivatives`` and ``jacobians``):

- measured states: those the roles map to a signal; their derivatives can be estimated from the
  data, so their equations can be examined (all of them, or ``diagnosis.equations``);
- unmeasured states: taken from an open-loop simulation of the calibrated model wherever an
  examined equation depends on them;
- units and labels of every state and input come from the signals they are mapped to.

API::

    diagnosis_settings(config) -> dict              # the diagnosis section with defaults
    build_problem(roles, model, settings, parameter_values, end_stop=None) -> Problem
    positive_grid(value, where) -> list[float]     # a grid option (a number or a list of numbers > 0)
    quantile_grid(value, where) -> list[float]     # a list of quantiles in (0, 1)
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hybridfmu.config import ConfigError

#: Defaults of the ``diagnosis`` section (the schema fills the same for validated configs).
DEFAULT_SETTINGS: dict[str, Any] = {
    "kernel_s": None,                 # None: from the model's time scale (hybridfmu.diagnosis.kernel_choice)
    "smoothing_s": None,              # None: half the kernel (at least 5 samples)
    "equations": [],                  # empty: every measured state
    "state_from_derivative": {},      # state -> measured state whose time derivative replaces it
    "one_step_states": [],            # states whose model rate is one RK4 step (fast states)
    "input_lag_compensation_s": {},   # input -> known first-order sensor lag (s) undone before everything
                                      # (the input_lag effect finds unknown lags from the data)
    "lag_compensation_window_s": None,
    "standstill": None,               # {state, below}: windows where |state| stays below are not fitted
    "end_stop_margin": None,          # state units; None: 1 % of the end-stop state's spread
    "bootstrap_block_s": None,        # None: 20 kernel lengths
    "periodic": {},                   # state -> period (state units)
    "parameters": None,               # None: every model parameter with a nonzero sensitivity
    "candidates": [],                 # fnmatch patterns of effect names to try; empty: all
    "exclude": [],                    # fnmatch patterns of effect names ("<state>:<pattern>": one equation)
    "effects": {},
    "plugins": [],
    "plugin_options": {},
    "selection": {},
    "regions": {},
    "open_loop": {},
    "neural_fmu": True,
    "figures_dpi": 120,
}

DEFAULT_EFFECT_OPTIONS: dict[str, Any] = {
    "kinds": ["viscous", "quadratic", "polynomial", "coulomb", "scaled_coulomb", "periodic", "saturation", "limit",
              "overflow", "input_gain", "input_offset", "time_offset", "input_lag", "input_deadzone", "input_saturation",
              "parameter"],
    # grid of the tanh smoothing of friction signs relative to the state's spread (refined on a log
    # scale after the grid; a single number fixes it)
    "coulomb_smoothing_relative": [0.001, 0.003, 0.01, 0.03, 0.1],
    "stribeck_relative": [0.005, 0.01, 0.02, 0.05, 0.1, 0.2],
    # orders 1..N per period searched, each with 1..periodic_harmonics harmonics; None: the orders are found in
    # the data (the periodic_orders strongest peaks of the spectrum up to the order the kernel resolves)
    "periodic_max_order": None,
    "periodic_harmonics": 3,
    "periodic_orders": 3,
    "saturation_quantiles": [0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95],
    # quantiles q of a state searched as its upper limit (1 - q as its lower one); refined after the grid
    "limit_quantiles": [0.8, 0.9, 0.95, 0.98, 0.99],
    # quantiles of an unmeasured state (its simulation without the effect) searched as its overflow level
    "overflow_quantiles": [0.2, 0.4, 0.6, 0.8, 0.9, 0.95, 0.99],
    # quantiles q of the inputs: dead-zone half widths at the q-quantiles of |u|, saturation levels at the
    # (1 - q)- (above) and q-quantiles (below) of u; refined after the grid
    "input_quantiles": [0.05, 0.1, 0.2, 0.3, 0.4, 0.5],
    "lag_derivative_window_s": None,  # Savitzky-Golay window of the input derivative of input lags; None: 5 samples
    "actuator_lag_samples": [1, 2, 4, 8, 16, 32, 64],  # time constants (sampling intervals) of slow-actuator lags
    "polynomial_degrees": [2, 3],
    "parameter_relative_step": 1.0e-5,
    "max_time_offset_s": None,        # None: one kernel length
}

DEFAULT_REGION_SETTINGS: dict[str, Any] = {
    "value_quantiles": [0.1, 0.5, 0.9],
    "rate_quantiles": [0.5, 0.9],
    "input_quantiles": [0.25, 0.75],
    "reversal_window_s": None,        # None: 5 kernel lengths
    "time_bin_s": None,               # None: 1/40 of the longest maneuver
    "top_statements": 6,
}

DEFAULT_OPEN_LOOP: dict[str, Any] = {"window_s": "auto", "growth_threshold_relative": 0.1, "refit": False,
                                     "refit_max_evaluations": 160}


def diagnosis_settings(config: dict[str, Any]) -> dict[str, Any]:
    """The ``diagnosis`` section of a case config with every default filled in, plus the master seed."""
    settings = copy.deepcopy(DEFAULT_SETTINGS)
    for key, value in (config.get("diagnosis") or {}).items():
        settings[key] = copy.deepcopy(value)
    for key, defaults in (("effects", DEFAULT_EFFECT_OPTIONS), ("regions", DEFAULT_REGION_SETTINGS),
                          ("open_loop", DEFAULT_OPEN_LOOP)):
        merged = copy.deepcopy(defaults)
        merged.update(settings.get(key) or {})
        settings[key] = merged
    settings["seed"] = int(config.get("seed", 0))
    return settings


@dataclass
class Problem:
    """The diagnosis' view of a case (module docstring).

    Attributes:
        state_names, input_names: the model's, in model order (n_x, n_u).
        measured: indices of the measured states.
        equations: indices of the examined state equations (a subset of ``measured``).
        state_signal: state name -> signal name (measured states only).
        input_signal: input name -> signal name.
        units: variable name -> unit (states and inputs; "" dimensionless or unknown).
        labels: variable name -> display label.
        target_weights: target state -> weight (sum 1).
        parameter_values: model parameter -> value (the calibrated model's).
        dt_s: sampling interval of the data (s), set when data is loaded.
        spread: (n_x,) std of each state over the fitting maneuvers (state units), set when data is loaded.
        quantiles: state name -> sorted sample quantiles of its values (for grids), set with ``spread``.
        rate_quantiles, rate_spread, input_quantiles: band edges of |rates| and inputs (regions), set with the data.
        end_stop: {"state": index, "min": value or None, "max": value or None} or None.
        periodic: state index -> period (state units).
        settings: the diagnosis settings.
        kernel_choice: how the kernel length was chosen along the data when ``settings["kernel_s"]`` was null
            (:meth:`hybridfmu.diagnosis.kernel_choice.KernelChoice.record`; the chosen length is then in
            ``settings["kernel_s"]``), else None.
    """

    state_names: list[str]
    input_names: list[str]
    measured: list[int]
    equations: list[int]
    state_signal: dict[str, str]
    input_signal: dict[str, str]
    units: dict[str, str]
    labels: dict[str, str]
    target_weights: dict[str, float]
    parameter_values: dict[str, float]
    settings: dict[str, Any]
    dt_s: float = 0.0
    spread: np.ndarray = field(default_factory=lambda: np.zeros(0))
    quantiles: dict[str, np.ndarray] = field(default_factory=dict)
    rate_quantiles: dict[str, list[float]] = field(default_factory=dict)
    rate_spread: dict[str, float] = field(default_factory=dict)
    input_quantiles: dict[str, list[float]] = field(default_factory=dict)
    end_stop: dict[str, Any] | None = None
    periodic: dict[int, float] = field(default_factory=dict)
    kernel_choice: dict[str, Any] | None = None

    @property
    def n_x(self) -> int:
        return len(self.state_names)

    @property
    def n_u(self) -> int:
        return len(self.input_names)

    @property
    def unmeasured(self) -> list[int]:
        return [i for i in range(self.n_x) if i not in self.measured]

    def state_index(self, name: str, where: str) -> int:
        """Index of state ``name``; ConfigError naming ``where`` if it is no state."""
        if name not in self.state_names:
            raise ConfigError(f"{where}: {name!r} is not a state of the model; expected one of {self.state_names}")
        return self.state_names.index(name)

    def input_index(self, name: str, where: str) -> int:
        if name not in self.input_names:
            raise ConfigError(f"{where}: {name!r} is not an input of the model; expected one of {self.input_names}")
        return self.input_names.index(name)

    def unit(self, name: str) -> str:
        return self.units.get(name, "")

    def rate_unit(self, state: int) -> str:
        """Unit of the derivative of state ``state`` (its equation's unit)."""
        unit = self.unit(self.state_names[state])
        if not unit or unit in ("1", "dimensionless"):
            return "1/s"
        return f"{unit}/s" if " " not in unit and "/" not in unit else f"({unit})/s"

    def display(self, name: str) -> str:
        """``label [unit]`` of a state or input."""
        unit = self.unit(name) or "-"
        label = self.labels.get(name, name)
        return f"{label} ({name}) [{unit}]" if label != name else f"{name} [{unit}]"

    def equation_display(self, state: int) -> str:
        name = self.state_names[state]
        return f"d{name}/dt ({self.labels.get(name, name)}) [{self.rate_unit(state)}]"


def build_problem(roles: Any, model: Any, settings: dict[str, Any], parameter_values: dict[str, float],
                  end_stop: dict[str, Any] | None = None) -> Problem:
    """The :class:`Problem` of a case.

    Args:
        roles: :class:`hybridfmu.data.roles.CaseRoles` of the case.
        model: the model (its ``state_names`` and ``input_names`` must match the roles').
        settings: ``diagnosis_settings(config)``.
        parameter_values: the calibrated model's parameters.
        end_stop: the case's ``model.end_stop`` section ({state, min_parameter, max_parameter}) or None.

    Raises:
        ConfigError: a name in ``diagnosis`` that is not a state/input of the model or not measured.
    """
    state_names = list(model.state_names)
    input_names = list(model.input_names)
    if list(roles.state_names) != state_names or list(roles.input_names) != input_names:
        raise ConfigError(f"config.roles: the roles name states {roles.state_names} and inputs {roles.input_names}, "
                          f"the model has {state_names} and {input_names}")
    measured = [state_names.index(s) for s in roles.states]
    if not measured:
        raise ConfigError("config.roles.states: no measured state; the diagnosis needs at least one")
    units, labels = {}, {}
    for state, signal in roles.states.items():
        units[state] = roles.signals[signal].unit
        labels[state] = roles.signals[signal].label
    for name, signal in roles.inputs.items():
        units[name] = roles.signals[signal].unit
        labels[name] = roles.signals[signal].label
    problem = Problem(state_names=state_names, input_names=input_names, measured=measured, equations=[],
                      state_signal=dict(roles.states), input_signal=dict(roles.inputs), units=units, labels=labels,
                      target_weights=dict(roles.target_weights), parameter_values=dict(parameter_values),
                      settings=settings)
    names = settings.get("equations") or [state_names[i] for i in measured]
    for name in names:
        index = problem.state_index(name, "config.diagnosis.equations")
        if index not in measured:
            raise ConfigError(f"config.diagnosis.equations: state {name!r} is not measured (config.roles.states "
                              f"{list(roles.states)}); its derivative cannot be estimated from the data")
        problem.equations.append(index)
    for state, source in (settings.get("state_from_derivative") or {}).items():
        where = f"config.diagnosis.state_from_derivative.{state}"
        if problem.state_index(state, where) not in measured or problem.state_index(source, where) not in measured:
            raise ConfigError(f"{where}: both {state!r} and {source!r} must be measured states")
    for name in settings.get("one_step_states") or []:
        problem.state_index(name, "config.diagnosis.one_step_states")
    for name in settings.get("input_lag_compensation_s") or {}:
        problem.input_index(name, "config.diagnosis.input_lag_compensation_s")
    check_effect_options(settings.get("effects") or {})
    for name, period in (settings.get("periodic") or {}).items():
        index = problem.state_index(name, "config.diagnosis.periodic")
        if index not in measured or not float(period) > 0:
            raise ConfigError(f"config.diagnosis.periodic.{name}: expected a measured state and a positive period, "
                              f"got {period!r}")
        problem.periodic[index] = float(period)
    standstill = settings.get("standstill")
    if standstill:
        if problem.state_index(standstill.get("state", ""), "config.diagnosis.standstill.state") not in measured:
            raise ConfigError("config.diagnosis.standstill.state: expected a measured state")
    if end_stop and end_stop.get("state"):
        index = problem.state_index(end_stop["state"], "config.model.end_stop.state")
        lower = parameter_values.get(end_stop.get("min_parameter") or "")
        upper = parameter_values.get(end_stop.get("max_parameter") or "")
        if index in measured and (lower is not None or upper is not None):
            problem.end_stop = {"state": index, "min": lower, "max": upper}
    return problem


def _numbers(value: Any, where: str, expected: str) -> list[float]:
    values = list(value) if isinstance(value, (list, tuple)) else [value]
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise ConfigError(f"{where}: expected {expected}, got {value!r}")
        out.append(float(v))
    return out


def positive_grid(value: Any, where: str, allow_empty: bool = False) -> list[float]:
    """A grid option: a positive number or a list of them -> the sorted distinct values.

    Raises:
        ConfigError: naming ``where`` for a value that is no positive number, or an empty list unless
            ``allow_empty``.
    """
    expected = "a positive number or a " + ("" if allow_empty else "non-empty ") + "list of positive numbers"
    values = _numbers(value, where, expected)
    if any(v <= 0 for v in values) or (not values and not allow_empty):
        raise ConfigError(f"{where}: expected {expected}, got {value!r}")
    return sorted(set(values))


def quantile_grid(value: Any, where: str) -> list[float]:
    """A non-empty list of quantiles strictly between 0 and 1 -> the sorted distinct values.

    Raises:
        ConfigError: naming ``where`` otherwise.
    """
    expected = "a non-empty list of quantiles between 0 and 1 (exclusive)"
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{where}: expected {expected}, got {value!r}")
    values = _numbers(value, where, expected)
    if not values or any(not 0.0 < v < 1.0 for v in values):
        raise ConfigError(f"{where}: expected {expected}, got {value!r}")
    return sorted(set(values))


def check_effect_options(options: dict[str, Any]) -> None:
    """Check the grid options of ``diagnosis.effects`` (the schema checks validated configs too).

    Raises:
        ConfigError: naming the field (``config.diagnosis.effects.<option>``) and what is expected.
    """
    where = "config.diagnosis.effects"
    if options.get("coulomb_smoothing_relative") is not None:
        positive_grid(options["coulomb_smoothing_relative"], f"{where}.coulomb_smoothing_relative")
    if options.get("stribeck_relative") is not None:
        positive_grid(options["stribeck_relative"], f"{where}.stribeck_relative", allow_empty=True)
    if options.get("actuator_lag_samples") is not None:
        positive_grid(options["actuator_lag_samples"], f"{where}.actuator_lag_samples", allow_empty=True)
    if options.get("limit_quantiles") is not None:
        quantile_grid(options["limit_quantiles"], f"{where}.limit_quantiles")
    if options.get("input_quantiles") is not None:
        quantile_grid(options["input_quantiles"], f"{where}.input_quantiles")
    window = options.get("lag_derivative_window_s")
    if window is not None and (isinstance(window, bool) or not isinstance(window, (int, float)) or not window > 0):
        raise ConfigError(f"{where}.lag_derivative_window_s: expected a positive window in s or null (5 samples), "
                          f"got {window!r}")
    for key in ("periodic_max_order", "periodic_harmonics", "periodic_orders"):
        value = options.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise ConfigError(f"{where}.{key}: expected an integer of at least 1, got {value!r}")


def set_data_statistics(problem: Problem, x_fit: list[np.ndarray], dt_s: float) -> None:
    """Store the sampling interval, each state's spread and quantiles over the fitting maneuvers.

    ``x_fit``: list of (N_k, n_x) state arrays (measured, unmeasured from simulation).
    """
    stacked = np.concatenate(x_fit, axis=0)
    problem.dt_s = float(dt_s)
    problem.spread = np.std(stacked, axis=0)
    levels = np.linspace(0.0, 1.0, 101)
    problem.quantiles = {name: np.quantile(stacked[:, i], levels) for i, name in enumerate(problem.state_names)}
