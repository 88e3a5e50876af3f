"""The roles of a case: its signals, how they feed the FMU, which states are measured and compared.

A case config declares (sections ``signals``, ``transforms``, ``roles``):

- **signals**: name -> raw channel, raw unit, resampling, optional label; any physical unit pint
  knows (:mod:`hybridfmu.units`);
- **transforms**: derived signals (:mod:`hybridfmu.data.transforms`), e.g. a load torque from a
  pressure, rotor-frame currents from phase currents;
- **roles**: FMU input -> signal (``inputs``), FMU state -> signal (``states``: the measured states;
  every other state of the FMU is unmeasured), and the ``targets``: measured states compared in
  the loss, the validation objective and the metrics, with their weights.

Nothing in the core knows a particular machine: every stage asks this module for names, units
and labels.

Units. Each signal's column in the ingested data is in its *model unit*: the declared unit of the
FMU variable it feeds (inputs, states), else ``to_unit`` from the config, else the unit the
signal arrives in (the raw unit, or the unit a transform gives). A signal whose dimension differs
from the FMU variable's declared dimension is a config error.

API::

    model_interface(config) -> ModelInterface          # FMU names and units, without loading it
    case_roles(config, interface=None) -> CaseRoles
    maneuver_source(config, roles, maneuver) -> ManeuverSource  # a maneuver's raw log, channels and slice

The checks of a whole case before the workflow starts (roles, search budget, maneuvers) are in
:mod:`hybridfmu.case_checks`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hybridfmu.config import ConfigError
from hybridfmu.data.errors import DataError
from hybridfmu.units import UnitError, converter, dimension, parse_unit, unit_string


@dataclass(frozen=True)
class ModelInterface:
    """Names and declared units of an FMU's states, inputs and parameters (from its modelDescription.xml).

    Attributes:
        source: the FMU file or modelDescription.xml the facts come from (for messages).
        state_names, input_names: in FMU order (states: order of ModelStructure/Derivatives).
        parameter_names: tunable and fixed parameters.
        units: variable name -> declared unit ("" when none is declared).
        start_values: variable name -> start value where the FMU declares one.
    """

    source: str
    state_names: list[str]
    input_names: list[str]
    parameter_names: list[str]
    units: dict[str, str]
    start_values: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Signal:
    """One signal of the case.

    Attributes:
        name: the signal's name (column of the ingested data).
        unit: model unit (module docstring), canonical spelling ("" = dimensionless).
        natural_unit: unit the signal arrives in (raw unit of a logged channel, or a transform's output).
        label: display name for figures and reports.
        channel: raw channel name (None for a derived signal).
        resample: "linear" or "hold" (zero-order hold) onto the grid; derived signals: "derived".
        gain, offset: value = gain * raw + offset, in the raw unit, before the unit conversion.
        wrap_period: period (raw unit) of a wrapping channel, unwrapped on ingest, or None.
    """

    name: str
    unit: str
    natural_unit: str
    label: str
    channel: str | None = None
    resample: str = "linear"
    gain: float = 1.0
    offset: float = 0.0
    wrap_period: float | None = None

    @property
    def derived(self) -> bool:
        return self.channel is None

    def display(self) -> str:
        """``label [unit]`` for axis labels and tables."""
        return f"{self.label} [{self.unit}]" if self.unit else f"{self.label} [-]"


@dataclass(frozen=True)
class CaseRoles:
    """What every stage needs to know of a case (module docstring).

    Attributes:
        signals: name -> Signal, logged signals first, then derived ones in transform order.
        transforms: the config's transform entries (validated).
        state_names, input_names: the FMU's states and inputs in FMU order.
        inputs: FMU input -> signal, for every FMU input, in FMU order.
        states: measured FMU state -> signal, in FMU order.
        target_weights: target state -> weight (positive, summing to 1), in FMU order.
    """

    signals: dict[str, Signal]
    transforms: list[dict[str, Any]]
    state_names: list[str]
    input_names: list[str]
    inputs: dict[str, str]
    states: dict[str, str]
    target_weights: dict[str, float]

    @property
    def measured_states(self) -> list[str]:
        return list(self.states)

    @property
    def unmeasured_states(self) -> list[str]:
        return [name for name in self.state_names if name not in self.states]

    @property
    def target_states(self) -> list[str]:
        return list(self.target_weights)

    @property
    def target_signals(self) -> list[str]:
        """Signal of each target state (same order as ``target_states``): names metrics ``<signal>_mae``."""
        return [self.states[name] for name in self.target_weights]

    @property
    def input_signals(self) -> list[str]:
        """Signal of each FMU input, FMU order."""
        return [self.inputs[name] for name in self.input_names]

    def signal_of_state(self, state: str) -> Signal:
        return self.signals[self.states[state]]

    def weights_with(self, overrides: dict[str, float] | None) -> dict[str, float]:
        """Target weights with some set explicitly (e.g. by a hyperparameter ``w_<state>``).

        The given weights (each in [0, 1]) are kept; the other targets share ``1 - sum(given)`` in
        proportion to their configured weights. With two targets and one given weight ``w`` this is the
        paper's ``(1 - w, w)``.

        Raises:
            ValueError: an unknown target, a weight outside [0, 1], or given weights summing above 1.
        """
        overrides = dict(overrides or {})
        unknown = [name for name in overrides if name not in self.target_weights]
        if unknown:
            raise ValueError(f"target weight(s) for {unknown}: not target states {self.target_states}")
        if any(not 0.0 <= float(w) <= 1.0 for w in overrides.values()):
            raise ValueError(f"target weights {overrides}: expected values in [0, 1]")
        given = sum(float(w) for w in overrides.values())
        if given > 1.0 + 1e-12:
            raise ValueError(f"target weights {overrides} sum to {given:g}; expected at most 1")
        rest = {name: w for name, w in self.target_weights.items() if name not in overrides}
        rest_total = sum(rest.values())
        weights = {}
        for name, weight in self.target_weights.items():
            if name in overrides:
                weights[name] = float(overrides[name])
            else:
                weights[name] = (1.0 - given) * weight / rest_total if rest_total > 0 else 0.0
        return weights

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable summary (stored beside results, logged to MLflow)."""
        return {
            "signals": {name: {"unit": s.unit, "label": s.label, "channel": s.channel} for name, s in self.signals.items()},
            "state_names": self.state_names, "input_names": self.input_names, "inputs": self.inputs,
            "states": self.states, "target_weights": self.target_weights,
        }


@dataclass(frozen=True)
class ManeuverSource:
    """Where a maneuver's samples come from in its raw log.

    Attributes:
        channels: logged signal -> raw channel name (config.signals, with the maneuver's overrides).
        t_start_s, t_end_s: slice of the log (s, relative to its first sample); None = unbounded.
    """

    channels: dict[str, str]
    t_start_s: float | None = None
    t_end_s: float | None = None


def maneuver_source(config: dict[str, Any], roles: CaseRoles, maneuver: str | None) -> ManeuverSource:
    """The raw channel of every logged signal and the slice of the log for ``maneuver``.

    Raises:
        DataError: an unknown maneuver, an override for a signal that is not logged, or a slice whose
            end is not after its start (naming the ``config.maneuvers`` field).
    """
    channels = {name: signal.channel for name, signal in roles.signals.items() if not signal.derived}
    if maneuver is None:
        return ManeuverSource(channels)
    maneuvers = config.get("maneuvers") or {}
    if maneuver not in maneuvers:
        raise DataError(f"config.maneuvers: no maneuver {maneuver!r}; expected one of {sorted(maneuvers)}")
    entry = maneuvers[maneuver] or {}
    for name, channel in (entry.get("channels") or {}).items():
        if name not in channels:
            raise DataError(f"config.maneuvers.{maneuver}.channels.{name}: not a logged signal; expected one of "
                            f"config.signals {sorted(channels)}")
        channels[name] = str(channel)
    t_start_s, t_end_s = entry.get("t_start_s"), entry.get("t_end_s")
    if t_start_s is not None and t_end_s is not None and not float(t_end_s) > float(t_start_s):
        raise DataError(f"config.maneuvers.{maneuver}: t_end_s = {t_end_s} is not after t_start_s = {t_start_s}; "
                        "expected a slice of positive length")
    return ManeuverSource(channels, None if t_start_s is None else float(t_start_s),
                          None if t_end_s is None else float(t_end_s))


def model_description_path(config: dict[str, Any]) -> Path:
    """Where the FMU's interface is read from without building it: the FMU file, or the C model's XML."""
    fmu = config["fmu"]
    if fmu["source"] == "build":
        from hybridfmu.fmu.build import C_SOURCE_DIR, model_source

        try:
            return model_source(fmu["model_name"]).directory / "modelDescription.xml"
        except Exception as err:  # FmuBuildError: unknown model
            raise ConfigError(f"config.fmu.model_name: {err}; models with C sources live in {C_SOURCE_DIR}") from None
    return Path(fmu["path"])


def model_interface(config: dict[str, Any]) -> ModelInterface:
    """States, inputs, parameters and declared units of the case's FMU (read from its modelDescription.xml).

    Raises:
        ConfigError: the FMU (or its model description) cannot be read; names the file.
    """
    from fmpy import read_model_description

    path = model_description_path(config)
    if not path.is_file():
        raise ConfigError(f"config.fmu.path: {str(path)!r} is not an existing file; expected an FMI 2.0 FMU")
    try:
        description = read_model_description(str(path), validate=False)
    except Exception as err:
        raise ConfigError(f"{path}: cannot read the model description: {err}") from None
    _check_model_name(config, path, description)
    states = [unknown.variable.derivative for unknown in description.derivatives]
    if any(state is None for state in states):
        raise ConfigError(f"{path}: a derivative in ModelStructure names no state; expected a Model-Exchange FMU")
    variables = description.modelVariables
    units, starts = {}, {}
    for variable in variables:
        declared = variable.unit or (variable.declaredType.unit if variable.declaredType is not None else None)
        units[variable.name] = declared or ""
        if variable.start is not None and variable.type == "Real":
            try:
                starts[variable.name] = float(variable.start)
            except (TypeError, ValueError):
                pass
    inputs = [v.name for v in variables
              if v.causality == "input" and v.type == "Real" and v.variability in (None, "continuous")]
    parameters = [v.name for v in variables if v.causality == "parameter"]
    return ModelInterface(str(path), [s.name for s in states], inputs, parameters, units, starts)


def _check_model_name(config: dict[str, Any], path: Path, description: Any) -> None:
    """A user FMU (``fmu.source: path``) whose ``fmu.model_name`` is set must be that model."""
    fmu = config.get("fmu") or {}
    wanted = fmu.get("model_name")
    if fmu.get("source") != "path" or not wanted:
        return
    identifiers = [kind.modelIdentifier for kind in (description.modelExchange, description.coSimulation)
                   if kind is not None and kind.modelIdentifier]
    names = list(dict.fromkeys([description.modelName, *identifiers]))
    if wanted not in names:
        actual = f"modelName {description.modelName!r}" + "".join(
            f", modelIdentifier {identifier!r}" for identifier in dict.fromkeys(identifiers))
        raise ConfigError(f"config.fmu.model_name: {wanted!r} does not match the FMU {path} ({actual}); expected "
                          f"one of {names} or no config.fmu.model_name")


def _natural_units(config: dict[str, Any]) -> dict[str, str]:
    """Unit each logged signal arrives in (its raw unit), checked to be known to pint."""
    units = {}
    for name, entry in config.get("signals", {}).items():
        try:
            parse_unit(entry["unit"])
        except UnitError as err:
            raise ConfigError(f"config.signals.{name}.unit: {err}; expected a physical unit") from None
        units[name] = entry["unit"]
    return units


def case_roles(config: dict[str, Any], interface: ModelInterface | None = None) -> CaseRoles:
    """The roles of a validated case config, checked against the FMU's interface.

    Args:
        config: validated case config (sections ``signals``, ``transforms``, ``roles``).
        interface: the FMU's interface; read from the config's FMU when None.

    Raises:
        ConfigError: naming the config field and what was expected: an FMU variable that does not exist,
            an FMU input without a signal, a signal or transform input that does not exist, a unit pint
            does not know, a signal whose dimension differs from the FMU variable's declared unit.
    """
    from hybridfmu.data.transforms import TransformError, output_units

    interface = interface or model_interface(config)
    signal_entries = config.get("signals", {})
    transforms = list(config.get("transforms", []))
    roles = config.get("roles", {})
    natural = _natural_units(config)
    try:
        natural = output_units(transforms, natural)
    except TransformError as err:
        raise ConfigError(str(err)) from None

    inputs_cfg: dict[str, str] = dict(roles.get("inputs", {}))
    states_cfg: dict[str, str] = dict(roles.get("states", {}))
    for group, mapping, names in (("inputs", inputs_cfg, interface.input_names),
                                  ("states", states_cfg, interface.state_names)):
        kind = "input" if group == "inputs" else "state"
        for variable, signal in mapping.items():
            if variable not in names:
                raise ConfigError(f"config.roles.{group}.{variable}: the FMU ({interface.source}) has no {kind} "
                                  f"{variable!r}; expected one of {names}")
            if signal not in natural:
                raise ConfigError(f"config.roles.{group}.{variable}: signal {signal!r} is not declared; expected one "
                                  f"of config.signals or a transform output: {sorted(natural)}")
    missing_inputs = [name for name in interface.input_names if name not in inputs_cfg]
    if missing_inputs:
        raise ConfigError(f"config.roles.inputs: no signal for FMU input(s) {missing_inputs} "
                          f"({interface.source}); expected every input of the FMU to be fed")

    model_units: dict[str, str] = {}
    feeds: dict[str, str] = {}
    for group, mapping in (("inputs", inputs_cfg), ("states", states_cfg)):
        for variable, signal in mapping.items():
            declared = interface.units.get(variable, "")
            where = f"config.roles.{group}.{variable}"
            if declared:
                try:
                    parse_unit(declared)
                except UnitError:
                    continue  # an FMU unit pint cannot read: the signal keeps its own unit
                if not _convertible(natural[signal], declared):
                    raise ConfigError(
                        f"{where}: signal {signal!r} is in {natural[signal]!r} ({dimension(natural[signal])}) but "
                        f"the FMU variable {variable!r} is declared in {declared!r} ({dimension(declared)}) in "
                        f"{interface.source}; expected a unit of the same dimension")
                if signal in model_units and not _same_unit(model_units[signal], declared):
                    raise ConfigError(f"{where}: signal {signal!r} feeds {feeds[signal]} in {model_units[signal]!r} "
                                      f"and {variable!r} in {declared!r}; expected one unit per signal")
                model_units[signal], feeds[signal] = declared, variable

    signals: dict[str, Signal] = {}
    for name, unit in natural.items():
        entry = signal_entries.get(name, {})
        to_unit = entry.get("to_unit") or next((t.get("to_unit") for t in transforms if name in _outputs(t)), None)
        target = model_units.get(name) or to_unit or unit
        if to_unit and not _convertible(unit, to_unit):
            raise ConfigError(f"config.signals.{name}.to_unit: {to_unit!r} is not a unit of {dimension(unit)} "
                              f"(the signal arrives in {unit!r})")
        label = entry.get("label") or next((t.get("label") for t in transforms if name in _outputs(t)
                                            and isinstance(t.get("label"), str)), None) or name
        signals[name] = Signal(
            name=name, unit=unit_string(target), natural_unit=unit, label=str(label),
            channel=entry.get("channel"), resample=entry.get("resample", "linear") if name in signal_entries else
            "derived", gain=float(entry.get("gain", 1.0)), offset=float(entry.get("offset", 0.0)),
            wrap_period=entry.get("wrap_period"))

    targets_cfg = roles.get("targets")
    if not targets_cfg:
        targets_cfg = {name: 1.0 for name in states_cfg}
    for state, weight in targets_cfg.items():
        if state not in states_cfg:
            raise ConfigError(f"config.roles.targets.{state}: not a measured state; expected one of "
                              f"config.roles.states {list(states_cfg)}")
        if not float(weight) > 0:
            raise ConfigError(f"config.roles.targets.{state}: weight {weight}; expected a positive number")
    if not targets_cfg:
        raise ConfigError("config.roles.targets: no target state (and no measured state in config.roles.states); "
                          "expected at least one measured state to compare")
    total = sum(float(w) for w in targets_cfg.values())
    target_weights = {name: float(targets_cfg[name]) / total for name in interface.state_names if name in targets_cfg}
    return CaseRoles(
        signals=signals, transforms=transforms, state_names=list(interface.state_names),
        input_names=list(interface.input_names),
        inputs={name: inputs_cfg[name] for name in interface.input_names},
        states={name: states_cfg[name] for name in interface.state_names if name in states_cfg},
        target_weights=target_weights)


#: Why the held-out check is missing when a case has no test maneuver, and how to add one.
NO_TEST_MANEUVER = ("no maneuver has role: test, so the held-out check (how far the gap shrinks on data no fit "
                    "saw) is not run; to run it, add a maneuver with role: test to config.maneuvers, e.g. "
                    "`test: {role: test, raw: logs/test.csv}`")


def _outputs(transform: dict[str, Any]) -> list[str]:
    outputs = transform.get("outputs", transform.get("output", []))
    return [outputs] if isinstance(outputs, str) else list(outputs)


def _convertible(a: str, b: str) -> bool:
    try:
        converter(a, b)
        return True
    except UnitError:
        return False


def _same_unit(a: str, b: str) -> bool:
    try:
        return converter(a, b) == (1.0, 0.0)
    except UnitError:
        return False
