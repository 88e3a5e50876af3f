"""Rule ``export``: one trained model of a case as an FMI 2.0 Co-Simulation FMU, checked against the workflow.

:func:`export_model` reads the model the evaluation simulated (the search's ``best.json`` or, for the FMU +
diagnosed effects, the diagnosed model; the calibration), writes ``export/<case>_<model>.fmu``
(:mod:`hybridfmu.export.package`), validates it and replays the check
maneuvers with FMPy alone (:mod:`hybridfmu.export.replay`), and writes the record ``export/<model>.json``:
the file, its provenance, the output delay, and per maneuver the replay's deviation from the evaluation's
trajectory. The FMU is added to the evaluation's MLflow run (``evaluation/mlflow_run.json``) as an artifact under
``export/``. A replay off by more than the tolerance, or a validation message, fails the job: an exported model
that does not reproduce the workflow is not written as a result.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from hybridfmu.export.content import ExportContent, effects_content, hybrid_content, neural_content
from hybridfmu.export.names import EXPORT_MODELS, model_identifier
from hybridfmu.export.package import write_exported_fmu
from hybridfmu.export.replay import REPLAY_TOLERANCE, replay
from hybridfmu.io import atomic_path, read_json, write_json_atomic

LOG = logging.getLogger(__name__)


class ExportCheckError(RuntimeError):
    """An exported FMU failed its validation or did not reproduce the workflow's trajectory."""


def config_digest(config: dict[str, Any]) -> str:
    """12 hex digits of SHA-256 of the case config (keys in any order): which settings the model was made with."""
    text = json.dumps(config, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def export_provenance(case: str, model: str, config: dict[str, Any], source: dict[str, Any]) -> dict[str, Any]:
    """What an exported FMU records of where it comes from: the project's version and commit, the case, the model,
    the config's digest, and the MLflow run and trial of ``source`` (the search's ``best.json``, or for the FMU +
    effects the diagnosis' ``diagnosis.json``)."""
    from hybridfmu import __version__
    from hybridfmu.tracking.provenance import code_version

    code = code_version()
    return {"project": "hybridfmu", "version": __version__, "commit": code.get("commit"),
            "modified": code.get("modified"), "case": case, "model": model, "config_digest": config_digest(config),
            "mlflow_run_id": source.get("mlflow_run_id"), "trial": source.get("trial_id")}


def model_content(model: str, best_path: str | Path | None, fmu_path: str | Path, calibration_path: str | Path,
                  diagnosed_path: str | Path | None = None, rate_hz: float | None = None,
                  conventions: Sequence[str] | None = None, time_s: np.ndarray | None = None) -> ExportContent:
    """What the exported FMU of ``model`` carries: a neural FMU or hybrid from its search's ``best.json``, the FMU +
    diagnosed effects from the diagnosed model; the calibration's parameters; ``rate_hz`` the case's grid rate (the
    FMU + effects' grid); ``conventions`` each input's convention between samples; ``time_s`` a record's time
    stamps (T,), whose median step the FMU + effects' input changes are computed with, as the evaluation does. A
    hybrid that is its physical layer (ANN at zero) is exported as the evaluation simulates it: as the FMU + its
    diagnosed effects.

    Raises:
        ValueError: an unknown model, or an input it needs missing.
    """
    from hybridfmu.training.inference import is_its_physical_layer, load_trained_neural_fmu
    from hybridfmu.training.measured import load_calibration

    if model not in EXPORT_MODELS:
        raise ValueError(f"export: model {model!r} cannot be exported; the export writes {list(EXPORT_MODELS)}")
    parameters = dict(load_calibration(calibration_path).parameters)
    if model in ("fmu_effects", "hybrid") and diagnosed_path is None:
        raise ValueError(f"export: the {model} needs the diagnosed model (diagnosis/diagnosed_model.pkl)")
    changes_dt_s = float(np.median(np.diff(time_s))) if time_s is not None and len(time_s) > 1 else None
    if model == "fmu_effects":
        if rate_hz is None:
            raise ValueError("export: the FMU + diagnosed effects needs the case's grid rate")
        return effects_content(str(diagnosed_path), str(fmu_path), parameters, rate_hz, conventions,
                               changes_dt_s=changes_dt_s)
    if best_path is None:
        raise ValueError(f"export: the {model} needs its search's best.json")
    trained = load_trained_neural_fmu(best_path, fmu_path, parameters or None, diagnosed_path)
    if model == "hybrid":
        if is_its_physical_layer(trained):
            return effects_content(str(diagnosed_path), str(fmu_path), parameters, 1.0 / trained.spec.sample_period_s
                                   if rate_hz is None else rate_hz, conventions,
                                   description="hybrid: its physical layer, the FMU plus the diagnosed effects "
                                   "(the search chose the ANN at zero)", effects=trained.spec.physics_effects,
                                   model_kind="hybrid", changes_dt_s=changes_dt_s)
        return hybrid_content(trained, str(fmu_path), parameters, conventions=conventions)
    return neural_content(trained, str(fmu_path), parameters, model_kind=model, conventions=conventions)


def _reference(trajectory_path: str | Path, model: str, state_names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """(time_s (T,), states (T, n_x)) of ``model`` in the evaluation's trajectory file."""
    import pandas as pd

    frame = pd.read_parquet(trajectory_path)
    columns = [f"{model}_state_{name}" for name in state_names]
    missing = [column for column in ["time_s", *columns] if column not in frame.columns]
    if missing:
        raise ValueError(f"{trajectory_path}: column(s) {missing} missing (expected the evaluation's trajectories of "
                         f"{model}; rerun simulate_best)")
    return frame["time_s"].to_numpy(dtype=float), frame[columns].to_numpy(dtype=float)


def export_model(model: str, case: str, config: dict[str, Any], best_path: str | Path | None, fmu_path: str | Path,
                 calibration_path: str | Path, check_maneuvers: Sequence[str], data_paths: Sequence[str | Path],
                 trajectory_paths: Sequence[str | Path], roles: Any, fmu_out: str | Path, record_out: str | Path,
                 run_path: str | Path | None = None, diagnosed_path: str | Path | None = None,
                 grid_path: str | Path | None = None, diagnosis_path: str | Path | None = None) -> dict[str, Any]:
    """Export ``model`` of ``case`` and check it (module docstring).

    Args:
        model: ``neural_fmu``, ``fmu_effects`` or ``hybrid`` (:data:`hybridfmu.export.names.EXPORT_MODELS`).
        case, config: the case's name and its validated config (for the provenance's digest and the grid's rate).
        best_path, fmu_path, calibration_path: the search's ``best.json`` (None for ``fmu_effects``), the case's
            FMU, ``calibration.json``.
        check_maneuvers, data_paths, trajectory_paths: the maneuvers replayed, their ingested data and the
            evaluation's trajectories, in the same order.
        roles: the case's roles (``hybridfmu.data.roles.CaseRoles``).
        fmu_out, record_out: the FMU and the JSON record to write.
        run_path: the evaluation's ``mlflow_run.json`` (the FMU becomes an artifact of that run), or None.
        diagnosed_path: the diagnosed model (``diagnosis/diagnosed_model.pkl``: the FMU + effects, a hybrid's
            physical layer). grid_path: ``data/grid.json`` where the grid's rate was chosen from the logs.
        diagnosis_path: ``diagnosis/diagnosis.json`` (the FMU + effects' MLflow run, for the provenance).

    Returns:
        The record written to ``record_out``.

    Raises:
        ExportCheckError: a validation message, or a replay deviation above the tolerance (nothing is written).
    """
    import pandas as pd

    from hybridfmu import __version__
    from hybridfmu.data.between_samples import frame_conventions
    from hybridfmu.data.grid import grid_rate_hz
    from hybridfmu.data.signals import signal_array

    if not (len(check_maneuvers) == len(data_paths) == len(trajectory_paths)):
        raise ValueError(f"export: {len(check_maneuvers)} check maneuvers, {len(data_paths)} data files and "
                         f"{len(trajectory_paths)} trajectories")
    frames = [pd.read_parquet(path) for path in data_paths]
    conventions = frame_conventions(frames[0], roles.input_names) if frames else None
    rate_hz = grid_rate_hz(config, grid_path) if model != "neural_fmu" else None
    content = model_content(model, best_path, fmu_path, calibration_path, diagnosed_path, rate_hz, conventions,
                            frames[0]["time_s"].to_numpy(dtype=float) if frames else None)
    source = read_json(best_path) if best_path is not None else read_json(diagnosis_path) if diagnosis_path else {}
    identifier = model_identifier(case, model)
    provenance = export_provenance(case, model, config, source)
    fmu_out, record_out = Path(fmu_out), Path(record_out)
    with atomic_path(fmu_out, suffix=".fmu") as tmp_fmu:
        write_exported_fmu(content, identifier, fmu_path, tmp_fmu, provenance, __version__)
        state_names = list(content.inner.state_names)
        checks = []
        for maneuver, data_path, frame, trajectory_path in zip(check_maneuvers, data_paths, frames, trajectory_paths):
            time_s, reference = _reference(trajectory_path, model, state_names)
            data_time_s = frame["time_s"].to_numpy(dtype=float)
            if time_s.shape != data_time_s.shape or not np.allclose(time_s, data_time_s, rtol=0, atol=1e-9):
                raise ValueError(f"{trajectory_path}: its time grid differs from {data_path}'s; rerun simulate_best")
            if frame_conventions(frame, roles.input_names) != conventions:
                raise ValueError(f"{data_path}: its inputs' conventions between samples differ from "
                                 f"{data_paths[0]}'s; rerun ingest")
            # the inputs as sampled: the exported FMU holds each step's value by the input's convention itself
            sampled = signal_array(frame, roles.input_signals)
            LOG.info("%s: replaying %s (%d samples) with FMPy ...", identifier, maneuver, time_s.size)
            result = replay(tmp_fmu, maneuver, time_s, sampled, list(content.inner.input_names), reference,
                            state_names, content.lookahead)
            LOG.info("%s: %s replayed in %.1f s wall time, largest deviation %.3g of a state's range (%s)",
                     identifier, maneuver, result.wall_s, max(result.deviation.values()),
                     "ok" if result.ok else f"above the tolerance {REPLAY_TOLERANCE:g}")
            checks.append(result.as_dict())
        problems = sorted({problem for check in checks for problem in check["problems"]})
        failed = [check["maneuver"] for check in checks if not check["ok"]]
        if problems or failed:
            raise ExportCheckError(
                f"{fmu_out}: the exported {model} " + "; ".join(
                    ([f"fails fmpy's validation: {problems}"] if problems else [])
                    + ([f"does not reproduce the evaluation's trajectory of {failed} within {REPLAY_TOLERANCE:g} of "
                        f"a state's range: {[c['deviation'] for c in checks if not c['ok']]}"] if failed else [])))
    record = {"model": model, "fmu": str(fmu_out), "identifier": identifier, "description": content.description,
              "output_delay_s": content.output_delay_s, "sample_period_s": content.sample_period_s,
              "delays_s": content.delays.delays_s, "inner_fmu": content.inner.identifier,
              "inputs": list(content.inner.input_names), "states": state_names,
              "coefficients": list(content.coefficient_names), "conventions": conventions,
              "input_stages": [stage.kind for stage in content.input_stages], "events": content.events,
              "provenance": provenance, "checks": checks}
    if run_path is not None:
        record["mlflow_artifact"] = _log_artifact(run_path, fmu_out)
    write_json_atomic(record_out, record)
    return record


def _log_artifact(run_path: str | Path, fmu_path: Path) -> str | None:
    """Add the FMU to the evaluation's MLflow run under ``export/``; its artifact path, or None if not logged."""
    from hybridfmu.tracking import Tracker

    info = read_json(run_path)
    if not info.get("tracking_uri") or not info.get("run_id"):
        LOG.warning("%s: no MLflow run recorded; the exported FMU is not logged", run_path)
        return None
    Tracker(info["tracking_uri"]).log_artifact(info["run_id"], str(fmu_path), artifact_path="export")
    LOG.info("added %s to MLflow run %s", fmu_path, info["run_id"])
    return f"export/{fmu_path.name}"
