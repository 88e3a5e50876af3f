"""The calibration stage (rule ``calibrate``) and what later stages read from its result.

API::

    run_calibration(config, fmu_path, data_paths, calibration_path, figure_path, track=True) -> Calibration
    calibrated_parameters(config, calibration_path) -> {parameter: value}   # for load_fmu(path, parameters=...)
    open_loop_rmse(config, fmu_path, calibration_path, data_path, maneuver) -> {"<signal>_rmse": value}
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from hybridfmu.calibration.data import ManeuverArrays, load_maneuver, maneuvers_with_role
from hybridfmu.calibration.figure import Panel, calibration_figure
from hybridfmu.calibration.fit import (FitSettings, TargetSimulator, check_settings, fit_case, fit_settings,
                                       fitted_states, needs_fit, target_rmse)
from hybridfmu.calibration.result import Calibration
from hybridfmu.data.roles import CaseRoles, case_roles

LOG = logging.getLogger(__name__)


def _config_parameters(config: dict[str, Any]) -> dict[str, float]:
    return {str(k): float(v) for k, v in (config["fmu"].get("parameters") or {}).items()}


def _load_maneuvers(config: dict[str, Any], roles: CaseRoles, data_paths: Mapping[str, str | Path],
                    role: str) -> list[ManeuverArrays]:
    names = maneuvers_with_role(config, role)
    missing = [name for name in names if name not in data_paths]
    if missing:
        raise ValueError(f"calibration: no ingested data given for the {role} maneuver(s) {missing}; "
                         f"expected a path for each of {names}")
    return [load_maneuver(data_paths[name], roles, name) for name in names]


def _nothing_to_fit(config: dict[str, Any], roles: CaseRoles, maneuvers: list[tuple[str, ManeuverArrays]],
                    calibration_path: Path, figure_path: Path) -> Calibration:
    """Write the config's parameters and no initial states (no FMU simulation); draw the measured targets."""
    calibration = Calibration(parameters=_config_parameters(config), fitted=[], initial_states={},
                              metrics={"fitted": False, "reason": "no parameter and no unmeasured initial "
                                       "state to fit (config.calibration)"})
    calibration.save(calibration_path)
    panels = [Panel(m.name, role, m.time_s, np.stack([m.state(s) for s in roles.target_states], axis=1))
              for role, m in maneuvers]
    calibration_figure(figure_path, panels, roles, f"{config['case']}: nothing to calibrate (measured targets)")
    LOG.info("nothing to calibrate: wrote the config's parameters %s to %s", calibration.parameters, calibration_path)
    return calibration


def _simulate_all(simulator: TargetSimulator, maneuvers: list[ManeuverArrays], parameters: dict[str, float],
                  states: Mapping[str, dict[str, float]]) -> dict[str, np.ndarray]:
    return {m.name: simulator.simulate(m, parameters, states.get(m.name, {})) for m in maneuvers}


def _rmse_by_maneuver(simulator: TargetSimulator, maneuvers: list[ManeuverArrays],
                      trajectories: dict[str, np.ndarray], roles: CaseRoles) -> dict[str, dict[str, float]]:
    return {m.name: target_rmse(trajectories[m.name], simulator.measured_targets(m), roles.target_signals)
            for m in maneuvers}


def _start_values(model, settings: FitSettings, roles: CaseRoles,
                  config_parameters: dict[str, float]) -> tuple[dict[str, float], dict[str, float]]:
    """(every parameter to set incl. the start of the fitted ones, FMU start values of the unmeasured states)."""
    parameters = dict(config_parameters)
    missing = [name for name in settings.parameter_bounds if name not in parameters]
    if missing:
        parameters.update(model.get_parameters(missing))
    states = {name: float(model.initial_states[roles.state_names.index(name)])
              for name in fitted_states(settings, roles)}
    return parameters, states


def run_calibration(config: dict[str, Any], fmu_path: str | Path, data_paths: Mapping[str, str | Path],
                    calibration_path: str | Path, figure_path: str | Path, track: bool = True) -> Calibration:
    """Fit the case's FMU (``hybridfmu.calibration.fit``) and write the record, the figure and the MLflow run.

    Args:
        config: validated case config (sections calibration, fmu, roles, maneuvers, signals).
        fmu_path: the case's FMU.
        data_paths: maneuver -> ingested Parquet file, for every train and validation maneuver.
        calibration_path: the :class:`Calibration` record (JSON, written atomically).
        figure_path: PNG of measured against simulated targets before/after (written atomically).
        track: log the run ``calibration`` to MLflow.

    Returns:
        The record written. When nothing is to be fitted (no parameter, no unmeasured state to fit), the
        record holds the config's parameters and no initial states, and the FMU is not simulated.

    Raises:
        ConfigError: a parameter to fit is unknown, bounds are inconsistent, no train maneuver.
        ValueError / FileNotFoundError: missing or malformed ingested data (names the file and column).
    """
    started = time.perf_counter()
    calibration_path, figure_path = Path(calibration_path), Path(figure_path)
    roles = case_roles(config)
    settings = fit_settings(config)
    train = _load_maneuvers(config, roles, data_paths, "train")
    validation = _load_maneuvers(config, roles, data_paths, "validation")
    labelled = [("train", m) for m in train] + [("validation", m) for m in validation]
    if not needs_fit(settings, roles):
        calibration = _nothing_to_fit(config, roles, labelled, calibration_path, figure_path)
    else:
        calibration, panels = _fit(config, fmu_path, roles, settings, train, validation)
        calibration.metrics["elapsed_s"] = round(time.perf_counter() - started, 3)
        calibration.save(calibration_path)
        calibration_figure(figure_path, panels, roles, f"{config['case']}: calibration of "
                           f"{', '.join(calibration.fitted) or 'the initial states'}")
        for maneuver, values in calibration.metrics["after"].items():
            LOG.info("%s: RMS error before %s, after %s", maneuver, calibration.metrics["before"][maneuver], values)
    if track:
        from hybridfmu.calibration.tracking import log_calibration_run

        log_calibration_run(config, calibration, [calibration_path, figure_path])
    LOG.info("calibration written to %s and %s in %.1f s", calibration_path, figure_path,
             time.perf_counter() - started)
    return calibration


def _fit(config: dict[str, Any], fmu_path: str | Path, roles: CaseRoles, settings: FitSettings,
         train: list[ManeuverArrays], validation: list[ManeuverArrays]) -> tuple[Calibration, list[Panel]]:
    from hybridfmu.fmu import load_fmu

    config_parameters = _config_parameters(config)
    model = load_fmu(fmu_path, parameters=config_parameters)
    try:
        check_settings(settings, model.parameter_names, roles, str(fmu_path))
        start_parameters, start_states = _start_values(model, settings, roles, config_parameters)
        simulator = TargetSimulator(model, roles)
        maneuvers = train + validation
        start_by_maneuver = {m.name: dict(start_states) for m in maneuvers}
        before = _simulate_all(simulator, maneuvers, start_parameters, start_by_maneuver)
        outcome = fit_case(model, roles, settings, start_parameters, start_states, train, validation)
        after = _simulate_all(simulator, maneuvers, outcome.parameters, outcome.initial_states)
    finally:
        model.close()
    metrics = {
        "fitted": True,
        "before": _rmse_by_maneuver(simulator, maneuvers, before, roles),
        "after": _rmse_by_maneuver(simulator, maneuvers, after, roles),
        "start_parameters": {name: start_parameters[name] for name in outcome.fitted},
        "start_initial_states": start_states,
        "phases": {name: phase.summary() for name, phase in outcome.phases.items()},
    }
    parameters = {**config_parameters, **outcome.parameters}
    calibration = Calibration(parameters=parameters, fitted=outcome.fitted, initial_states=outcome.initial_states,
                              metrics=metrics)
    roles_of = {m.name: "train" for m in train} | {m.name: "validation" for m in validation}
    panels = [Panel(m.name, roles_of[m.name], m.time_s, simulator.measured_targets(m), before[m.name], after[m.name])
              for m in maneuvers]
    return calibration, panels


def calibrated_parameters(config: dict[str, Any], calibration_path: str | Path | None) -> dict[str, float]:
    """Parameters to load the case's FMU with: ``config.fmu.parameters`` overridden by the calibration's.

    Args:
        config: validated case config.
        calibration_path: the calibration record; None: the config's parameters only.

    Raises:
        FileNotFoundError: ``calibration_path`` is given but does not exist.
        ValueError: the record is malformed (names the file and field).
    """
    parameters = _config_parameters(config)
    if calibration_path is None:
        return parameters
    path = Path(calibration_path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: calibration record not found (rule calibrate writes it)")
    parameters.update(Calibration.load(path).parameters)
    return parameters


def open_loop_rmse(config: dict[str, Any], fmu_path: str | Path, calibration_path: str | Path | None,
                   data_path: str | Path, maneuver: str) -> dict[str, float]:
    """RMS error per target (``<signal>_rmse``, signal units) of the calibrated FMU, open loop over the whole
    maneuver: measured states from the data at its start, unmeasured ones from the calibration
    (:meth:`Calibration.unmeasured_initial_states`: the maneuver's own, its ``initial_states_from``, the
    FMU's start values)."""
    from hybridfmu.data.roles import model_interface
    from hybridfmu.fmu import load_fmu

    interface = model_interface(config)
    roles = case_roles(config, interface)
    calibration = Calibration.load(calibration_path) if calibration_path is not None else Calibration()
    data = load_maneuver(data_path, roles, maneuver)
    with load_fmu(fmu_path, parameters=calibrated_parameters(config, calibration_path)) as model:
        start = {name: float(model.initial_states[roles.state_names.index(name)]) for name in roles.unmeasured_states}
        states = calibration.unmeasured_initial_states(maneuver, config, start, roles.unmeasured_states)
        simulator = TargetSimulator(model, roles)
        simulated = simulator.simulate(data, {}, states)
        return target_rmse(simulated, simulator.measured_targets(data), roles.target_signals)
