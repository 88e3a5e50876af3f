"""Every check of a case that needs no job to run, before the workflow starts.

The case's roles against the FMU (:func:`hybridfmu.data.roles.case_roles`), every FMU variable another section
names, the search's Hyperband budget and search space, the training's gradient engine against the model, and
the maneuvers' raw logs (no data in two roles). Each failure is a :class:`hybridfmu.config.ConfigError` that
names the config file and field.

API::

    check_case(config, config_file="") -> CaseRoles    # every check, ConfigError naming file and field
    case_warnings(config, config_file="") -> list[str] # what a valid config leaves out (no test maneuver)
"""

from __future__ import annotations

import math
import os
from typing import Any

from hybridfmu.config import ConfigError
from hybridfmu.data.errors import DataError
from hybridfmu.data.roles import (NO_TEST_MANEUVER, CaseRoles, ModelInterface, case_roles, maneuver_source,
                                  model_interface)
from hybridfmu.io import file_sha256
from hybridfmu.units import UnitError, parse_quantity


def check_case(config: dict[str, Any], config_file: str = "") -> CaseRoles:
    """Every check of a case that needs no job to run (module docstring), before the workflow starts.

    Raises:
        ConfigError: the message starts with the config file (when given) and names the field.
    """
    try:
        check_hpo(config)
        check_gradients(config)
        interface = model_interface(config)
        roles = case_roles(config, interface)
        check_names(config, interface, roles)
        check_maneuvers(config, roles)
        return roles
    except ConfigError as err:
        prefix = f"{config_file}: " if config_file else ""
        raise ConfigError(f"{prefix}{err}") from None


def check_gradients(config: dict[str, Any]) -> None:
    """``training.gradients`` fits the model: torchdiffeq's fixed-grid solvers have no end stop.

    Raises:
        ConfigError: naming ``config.training.gradients`` and ``config.model.end_stop``.
    """
    gradients = (config.get("training") or {}).get("gradients", "adjoint")
    if str(gradients).startswith("torchdiffeq") and (config.get("model") or {}).get("end_stop"):
        raise ConfigError(f"config.training.gradients: {gradients!r} has no end stop, but config.model.end_stop is "
                          "set; expected adjoint or adjoint_numpy, or no model.end_stop")


def check_hpo(config: dict[str, Any]) -> None:
    """The Hyperband budget of a validated config is a real search (:func:`hybridfmu.training.hyperband.check_budget`),
    for the section and for every search that sets its own (``config.hpo.searches.<search>``).

    Raises:
        ConfigError: naming ``config.hpo.R`` and ``config.hpo.eta`` (or ``config.hpo.searches.<search>.R``, ...)
            and what is expected.
    """
    from hybridfmu.training.hyperband import check_budget

    hpo = config.get("hpo") or {}
    budgets = [("config.hpo", hpo.get("R", 81), hpo.get("eta", 3))]
    for search, own in (hpo.get("searches") or {}).items():
        own = own or {}
        if "R" in own or "eta" in own:
            budgets.append((f"config.hpo.searches.{search}", own.get("R", hpo.get("R", 81)),
                            own.get("eta", hpo.get("eta", 3))))
    for where, R, eta in budgets:
        try:
            check_budget(R, eta, names=(f"{where}.R", f"{where}.eta"))
        except ValueError as err:
            raise ConfigError(str(err)) from None
    spaces = [("config.hpo.search_space", hpo.get("search_space") or {})]
    spaces += [(f"config.hpo.searches.{search}.search_space", (own or {})["search_space"])
               for search, own in (hpo.get("searches") or {}).items() if "search_space" in (own or {})]
    for where, space in spaces:
        for name, distribution in space.items():
            low, high = distribution.get("low"), distribution.get("high")
            if low is not None and high is not None and not float(low) <= float(high):
                raise ConfigError(f"{where}.{name}: low = {low} is above high = {high}; expected low <= high")


def check_names(config: dict[str, Any], interface: ModelInterface, roles: CaseRoles) -> None:
    """Every FMU variable a config section names exists, before any job runs (not only when the stage that reads
    it starts, after the search): ``fmu.parameters`` (names and finite values), ``roles.between_samples``, the
    states and inputs of
    ``model`` (corrected states, ANN inputs, end stop, input-delay groups) and of ``diagnosis`` (equations,
    states from derivatives, one-step states, input lags).

    Raises:
        ConfigError: naming the field, the FMU and the names it has.
    """
    source = interface.source
    states, inputs, parameters = interface.state_names, interface.input_names, interface.parameter_names

    def known(where: str, names: Any, available: list[str], kind: str) -> None:
        if names == "all":
            return
        unknown = [name for name in ([names] if isinstance(names, str) else names or []) if name not in available]
        if unknown:
            raise ConfigError(f"{where}: {unknown} {'is' if len(unknown) == 1 else 'are'} not {kind} of the FMU "
                              f"({source}); expected some of {available}")

    for name, value in ((config.get("fmu") or {}).get("parameters") or {}).items():
        known(f"config.fmu.parameters.{name}", [name], parameters, "a parameter")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"config.fmu.parameters.{name}: {value!r}; expected a finite number")
    known("config.roles.between_samples", list((config.get("roles") or {}).get("between_samples") or {}), inputs,
          "an input")
    model = config.get("model") or {}
    known("config.model.corrected_states", model.get("corrected_states"), states, "a state")
    ann = model.get("ann_inputs") or {}
    known("config.model.ann_inputs.states", ann.get("states"), states, "a state")
    known("config.model.ann_inputs.derivatives", ann.get("derivatives"), states, "a state")
    known("config.model.ann_inputs.inputs", ann.get("inputs"), inputs, "an input")
    stop = model.get("end_stop") or {}
    for field in ("state", "rate_state"):
        if field in stop:
            known(f"config.model.end_stop.{field}", [stop[field]], states, "a state")
    for field in ("min_parameter", "max_parameter"):
        if field in stop:
            known(f"config.model.end_stop.{field}", [stop[field]], parameters, "a parameter")
    for group, names in ((model.get("input_delay") or {}).get("groups") or {}).items():
        known(f"config.model.input_delay.groups.{group}", names, inputs, "an input")
    diagnosis = config.get("diagnosis") or {}
    measured, kind = list(roles.measured_states), "a measured state (config.roles.states)"
    known("config.diagnosis.equations", diagnosis.get("equations"), measured, kind)
    known("config.diagnosis.one_step_states", diagnosis.get("one_step_states"), states, "a state")
    derived = diagnosis.get("state_from_derivative") or {}
    known("config.diagnosis.state_from_derivative", [*derived, *derived.values()], measured, kind)
    known("config.diagnosis.input_lag_compensation_s", list(diagnosis.get("input_lag_compensation_s") or {}),
          inputs, "an input")
    scales = diagnosis.get("report_scale") or {}
    known("config.diagnosis.report_scale", list(scales), states, "a state")
    for state, text in scales.items():
        try:
            parse_quantity(text)
        except UnitError as err:
            raise ConfigError(f"config.diagnosis.report_scale.{state}: {err}") from None


def check_maneuvers(config: dict[str, Any], roles: CaseRoles) -> None:
    """Each maneuver's source in its raw log, and no log data in two roles (the same file, or a copy of it under
    another name).

    A maneuver's data are its raw file, the raw channel of each logged signal (``config.signals`` with the
    maneuver's ``channels`` overrides) and its slice ``t_start_s``..``t_end_s``. Two maneuvers of different
    roles (train, validation, test) must not read the same data: the same file with the same channels over
    overlapping slices would make e.g. the test maneuver a copy of the validation data. Slices that do not
    overlap, or different channels (records side by side in one log), are different data.

    Raises:
        ConfigError: a channel override of a signal that is not logged, a slice that ends before it starts,
            or the same data in two roles; naming the ``config.maneuvers`` fields.
    """
    maneuvers = config.get("maneuvers") or {}
    sources = {}
    for name in maneuvers:
        try:
            sources[name] = maneuver_source(config, roles, name)
        except DataError as err:
            raise ConfigError(str(err)) from None
    names = list(maneuvers)
    for k, first in enumerate(names):
        for second in names[k + 1:]:
            a, b = maneuvers[first], maneuvers[second]
            if a["role"] == b["role"] or not _same_log(a["raw"], b["raw"]):
                continue
            sa, sb = sources[first], sources[second]
            if sa.channels != sb.channels:
                continue
            start = max(_bound(sa.t_start_s, 0.0), _bound(sb.t_start_s, 0.0))
            end = min(_bound(sa.t_end_s, math.inf), _bound(sb.t_end_s, math.inf))
            if start < end:
                log = f"the same raw log {b['raw']!r}" if _raw_key(a["raw"]) == _raw_key(b["raw"]) else \
                    f"{b['raw']!r}, a byte-identical copy of {a['raw']!r},"
                raise ConfigError(
                    f"config.maneuvers.{second}: role {b['role']} reads {log} with the same "
                    f"channels as config.maneuvers.{first} (role {a['role']}) over an overlapping time span "
                    f"({_span(sa)} and {_span(sb)}), so its data would be {a['role']} data too; expected another "
                    "raw file, t_start_s/t_end_s slices that do not overlap, or other channels")


def _raw_key(raw: str) -> str:
    """The raw file a path names (relative paths from the working directory, links resolved)."""
    return os.path.realpath(os.path.expanduser(str(raw)))


def _same_log(first: str, second: str) -> bool:
    """Whether two raw paths hold the same log: the same file, or two existing files with the same bytes (a copy
    under another name). Files that do not exist yet (logs a rule writes) are compared by path only."""
    a, b = _raw_key(first), _raw_key(second)
    if a == b:
        return True
    if not (os.path.isfile(a) and os.path.isfile(b)) or os.path.getsize(a) != os.path.getsize(b):
        return False
    return file_sha256(a) == file_sha256(b)


def _bound(value: float | None, default: float) -> float:
    return default if value is None else float(value)


def _span(source: Any) -> str:
    start = "start" if source.t_start_s is None else f"{source.t_start_s:g} s"
    end = "end" if source.t_end_s is None else f"{source.t_end_s:g} s"
    return f"{start} to {end}"


def case_warnings(config: dict[str, Any], config_file: str = "") -> list[str]:
    """What a valid config leaves out that the user probably wants (one line each, naming file and field).

    Without a test maneuver the held-out check (the diagnosis' "how far" on data no fit saw) is not run.
    """
    prefix = f"{config_file}: " if config_file else ""
    warnings = []
    maneuvers = config.get("maneuvers") or {}
    if not any(entry.get("role") == "test" for entry in maneuvers.values()):
        warnings.append(f"{prefix}config.maneuvers: {NO_TEST_MANEUVER}")
    return warnings
