"""A case's diagnosis inputs: the problem, the calibrated FMU and the measured maneuvers, from files
(:func:`load_inputs`, as rule ``diagnose`` has them) or from frames in memory (:func:`case_inputs`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hybridfmu.diagnosis.prepare import MeasuredManeuver, maneuver_from_frame
from hybridfmu.diagnosis.problem import Problem, build_problem, diagnosis_settings


@dataclass
class CaseInputs:
    """A case's diagnosis inputs, loaded (:func:`load_inputs`): the problem, the calibrated model and a helper
    instance, the measured maneuvers, the model's parameters, the calibration (or None), the settings."""

    problem: Problem
    model: Any
    helper: Any
    measured: dict[str, MeasuredManeuver]
    parameters: dict[str, float]
    calibration: Any
    settings: dict[str, Any]


def load_inputs(config: dict[str, Any], fmu_path: str | Path, data_paths: dict[str, str | Path],
                segments_paths: dict[str, str | Path], calibration_path: str | Path | None = None) -> CaseInputs:
    """Load a case's FMU (with the calibrated parameters), maneuvers and segments (arguments: :func:`analyse`;
    :func:`case_inputs` does the rest)."""
    import pandas as pd

    from hybridfmu.data.segments import read_segments

    calibration = None
    if calibration_path is not None:
        from hybridfmu.calibration.result import Calibration

        calibration = Calibration.load(calibration_path)
    frames, spans = {}, {}
    for name in [name for name in config["maneuvers"] if name in data_paths]:  # a missing one: case_inputs says so
        data_path = Path(data_paths[name])
        if not data_path.is_file():
            raise FileNotFoundError(f"{data_path}: ingested data of maneuver {name!r} does not exist")
        frames[name] = pd.read_parquet(data_path)
        if segments_paths.get(name):
            spans[name] = read_segments(segments_paths[name])["spans_s"]
    return case_inputs(config, fmu_path, frames, spans, calibration,
                       sources={name: str(data_paths[name]) for name in frames})


def case_inputs(config: dict[str, Any], fmu_path: str | Path, frames: dict[str, Any],
                spans_s: dict[str, list[list[float]]] | None = None, calibration: Any = None,
                sources: dict[str, str] | None = None) -> CaseInputs:
    """A case's diagnosis inputs from maneuvers in memory.

    Args:
        config: validated case config (its ``maneuvers`` name each maneuver's role).
        fmu_path: the case's FMU.
        frames: maneuver name -> ingested frame (``time_s`` (s) and one column per signal, in model units;
            :func:`hybridfmu.data.ingest.ingest_log`), one for every maneuver of the config.
        spans_s: maneuver name -> informative segments [[t_start_s, t_end_s], ...] (s); a maneuver not
            listed is used whole.
        calibration: :class:`hybridfmu.calibration.result.Calibration` (its parameters and unmeasured initial
            states), or None for the FMU with ``config.fmu.parameters``.
        sources: maneuver name -> where its frame comes from, for messages.
    """
    from hybridfmu.data.roles import case_roles, model_interface
    from hybridfmu.fmu import load_fmu

    maneuver_roles = {name: m["role"] for name, m in config["maneuvers"].items()}
    missing = [n for n in maneuver_roles if n not in frames]
    if missing:
        raise ValueError(f"diagnosis: no ingested data given for maneuver(s) {missing}")
    settings = diagnosis_settings(config)
    parameters = dict(config.get("fmu", {}).get("parameters", {}) or {})
    if calibration is not None:
        parameters.update(calibration.parameters)
    model = load_fmu(fmu_path, parameters=parameters or None)
    helper = load_fmu(fmu_path, parameters=parameters or None)
    case_config = dict(config)
    case_config["fmu"] = {**config.get("fmu", {}), "source": "path", "path": str(fmu_path)}
    interface = model_interface(case_config)
    roles = case_roles(case_config, interface)
    problem = build_problem(roles, model, settings, model.get_parameters(), (config.get("model") or {}).get("end_stop"))
    measured = {}
    for name, role in maneuver_roles.items():
        unmeasured = [problem.state_names[i] for i in problem.unmeasured]
        x0 = calibration.unmeasured_initial_states(name, config, interface.start_values, unmeasured) \
            if calibration is not None else {s: float(interface.start_values.get(s, 0.0)) for s in unmeasured}
        measured[name] = maneuver_from_frame(name, role, frames[name], (spans_s or {}).get(name), problem, x0,
                                             (sources or {}).get(name, ""))
    return CaseInputs(problem=problem, model=model, helper=helper, measured=measured, parameters=parameters,
                      calibration=calibration, settings=settings)
