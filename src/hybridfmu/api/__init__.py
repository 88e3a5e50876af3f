"""A small Python API for notebook work beside the workflow: a case, its logs, its FMU, a diagnosis, a run.

Each function does what one stage of the workflow does, on objects in memory instead of files between rules,
through the same functions the workflow's scripts call. Frames are pandas DataFrames
as the ingestion writes them: ``time_s`` (s, from 0 on a uniform grid) and one float64 column per signal of
the case, in its model unit. States come back under the FMU's names.

Example, after a run of the tiny case (``snakemake -j2 --configfile config/cases/tiny.yaml``), from the
directory it ran in (``docs/api.md`` has it step by step)::

    from hybridfmu import api

    case = api.load_case("config/cases/tiny.yaml")
    frame = api.read_log(case, "test")             # a raw log through the case's signals -> DataFrame
    run = api.load_run(case)                       # what the run wrote: metrics, chosen models, calibration
    fmu = api.simulate_fmu(case, frame, "test", run.calibration_path)   # the FMU open loop
    neural = api.simulate_trained(case, frame, "hpo", "test", run)      # the trained neural FMU
    diagnosis = api.diagnose(case, {name: api.read_log(case, name) for name in case.maneuvers})
    print(diagnosis.verdict)

Functions:

- :func:`load_case`: a case config, validated and checked against its FMU (:class:`Case`);
- :func:`fmu_file`: the case's FMU file (built from its C sources when the case says so);
- :func:`read_log`: a maneuver's raw log (MDF4, CSV, Parquet) ingested into a frame;
- :func:`simulate_fmu`: the FMU open loop over a frame's logged inputs;
- :func:`diagnose`: the diagnosis of the sim-to-real gap on frames in memory;
- :func:`load_run`: what a workflow run wrote for a case (metrics, best models, calibration) (:class:`Run`);
- :func:`simulate_trained`: a run's trained neural FMU or hybrid open loop over a frame;
- :func:`export_fmu`: a run's trained model as an FMI 2.0 Co-Simulation FMU (what rule ``export`` writes).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hybridfmu.config import ConfigError, case_fmu_path, case_results_dir, load_case_config
from hybridfmu.data.roles import CaseRoles

#: The searches a run can have: the paper's neural FMU and the hybrid (FMU + diagnosed effects + ANN).
SEARCHES = ("hpo", "hybrid")


@dataclass(frozen=True)
class Case:
    """A validated case config with its roles.

    Attributes:
        config: the config with the schema's defaults filled in.
        source: the config file.
        roles: the case's signals, inputs, measured states and targets (:class:`hybridfmu.data.roles.CaseRoles`).
    """

    config: dict[str, Any]
    source: Path
    roles: CaseRoles

    @property
    def name(self) -> str:
        return str(self.config["case"])

    @property
    def results_dir(self) -> Path:
        """Where the workflow writes this case's outputs (``<results_dir>/<case>``, relative to the working
        directory the workflow runs in)."""
        return case_results_dir(self.config)

    @property
    def maneuvers(self) -> dict[str, str]:
        """Maneuver name -> role (train, validation, test)."""
        return {name: entry["role"] for name, entry in self.config["maneuvers"].items()}


@dataclass(frozen=True)
class Run:
    """What a workflow run wrote for a case (:func:`load_run`).

    Attributes:
        case: the case.
        results_dir: the run's case folder.
        metrics: role (validation, test) -> the evaluation's metrics of that role (``metrics/<role>.json``:
            per model and signal the errors, and the improvement factors against the FMU).
        best: search (``hpo``, ``hybrid``) -> the search's chosen model (``<search>/best.json``).
        calibration_path: the calibration (``calibration/calibration.json``), or None when absent.
        diagnosed_path: the diagnosed model (``diagnosis/diagnosed_model.pkl``), or None when absent.
    """

    case: Case
    results_dir: Path
    metrics: dict[str, dict[str, Any]] = field(default_factory=dict)
    best: dict[str, dict[str, Any]] = field(default_factory=dict)
    calibration_path: Path | None = None
    diagnosed_path: Path | None = None


@dataclass(frozen=True)
class Diagnosis:
    """A diagnosis computed by :func:`diagnose`.

    Attributes:
        record: what rule ``diagnose`` writes to ``diagnosis.json`` (JSON types): the equation errors and
            regions (``where``), the chosen effects with their coefficients and uncertainties (``which``), the
            held-out open-loop check (``how_far``) and the one-paragraph ``verdict``.
        model: the FMU plus the chosen effects (:class:`hybridfmu.diagnosis.export.DiagnosedModel`), as the
            later stages load it from ``diagnosed_model.pkl``.
    """

    record: dict[str, Any]
    model: Any

    @property
    def verdict(self) -> str:
        return str(self.record["verdict"])

    @property
    def effects(self) -> list[str]:
        """The named effects and parameter errors, in rank order (as the verdict lists them)."""
        return list(self.record["which"]["found_effects"])


def load_case(path: str | Path) -> Case:
    """Read the case config at ``path``, validate it (schema defaults filled in) and check it against its FMU
    (roles, units, maneuvers; :func:`hybridfmu.case_checks.check_case`).

    Raises:
        ConfigError: naming the file and the field, and what was expected.
    """
    from hybridfmu.case_checks import check_case

    path = Path(path)
    config = load_case_config(path)
    return Case(config=config, source=path, roles=check_case(config, str(path)))


def fmu_file(case: Case, build: bool = True) -> Path:
    """The case's FMU: ``fmu.path``, or for ``fmu.source: build`` the FMU the workflow builds
    (``<results>/fmu/<model_name>.fmu``), built here when it is missing and ``build`` is set.

    Raises:
        FileNotFoundError: the FMU does not exist (and is not to be built).
    """
    path = case_fmu_path(case.config)
    if not path.is_file():
        if case.config["fmu"]["source"] != "build" or not build:
            raise FileNotFoundError(f"{path}: the case's FMU does not exist ({case.source}: config.fmu)")
        from hybridfmu.fmu.build import build_fmu

        build_fmu(case.config["fmu"]["model_name"], path)
    return path


def read_log(case: Case, maneuver: str, raw_path: str | Path | None = None) -> pd.DataFrame:
    """A maneuver's raw log ingested as the workflow ingests it (checks, resampling, transforms, model units).

    Args:
        case: the case.
        maneuver: a name of ``config.maneuvers`` (its channel overrides and time slice apply).
        raw_path: the log to read; None: the maneuver's ``raw`` file.

    Returns:
        (T rows) ``time_s`` (s) and one column per signal of the case, in its model unit; ``attrs`` records how
        each FMU input passes between samples. What the config leaves out of the grid's rate and those
        conventions comes, as in the workflow, from the run's choice (``<results_dir>/data/grid.json``, rule
        ``choose_grid``, from the train and validation logs) where the case has run, else from this log.

    Raises:
        ConfigError: an unknown maneuver. DataError: naming the file, the channel and what was expected.
    """
    from hybridfmu.data.grid import chosen_conventions
    from hybridfmu.data.ingest import ingest_log
    from hybridfmu.io import read_json

    entry = _maneuver(case, maneuver)
    grid = case.results_dir / "data" / "grid.json"
    chosen = read_json(grid) if grid.is_file() else {}
    return ingest_log(raw_path if raw_path is not None else entry["raw"], case.config, maneuver,
                      chosen.get("rate_hz"), chosen_conventions(grid if grid.is_file() else None))


def simulate_fmu(case: Case, frame: pd.DataFrame, maneuver: str | None = None,
                 calibration: str | Path | None = None) -> pd.DataFrame:
    """The FMU open loop over a frame's logged inputs (each held over its sample, a continuous input at its mean
    over the sample: the conventions the frame records, :mod:`hybridfmu.data.between_samples`), from the measured
    first sample
    (unmeasured states: the calibration's values for ``maneuver``, else the FMU's start values).

    Args:
        case: the case; frame: as :func:`read_log` returns it.
        maneuver: the maneuver the frame is (for its calibrated unmeasured initial states), or None.
        calibration: ``calibration/calibration.json`` of a run (its parameters are set on the FMU), or None
            for the FMU with ``config.fmu.parameters``.

    Returns:
        (T rows) ``time_s`` (s) and one column per FMU state, in the FMU's units.
    """
    from hybridfmu.evaluation.baseline import simulate_fmu_open_loop
    from hybridfmu.training.measured import (initial_state, load_calibrated_fmu, load_calibration,
                                             measured_from_frame)

    measured = measured_from_frame(frame, case.roles)
    calibrated = load_calibration(calibration)
    with load_calibrated_fmu(fmu_file(case), calibrated) as fmu:
        x0 = initial_state(fmu, measured.x[0], case.roles, calibrated, maneuver or "", case.config["maneuvers"])
        states, _ = simulate_fmu_open_loop(fmu, measured.time_s, measured.u, x0, label=maneuver or "frame")
    return _states_frame(measured.time_s, states, case.roles.state_names)


def diagnose(case: Case, frames: dict[str, pd.DataFrame], spans_s: dict[str, list[list[float]]] | None = None,
             calibration: str | Path | None = None, open_loop: bool = True) -> Diagnosis:
    """The diagnosis of the sim-to-real gap (where it lies, which effect causes it, how far it shrinks) on
    maneuvers in memory, as rule ``diagnose`` computes it.

    Args:
        case: the case; frames: maneuver -> its frame (:func:`read_log`), for every maneuver the diagnosis
            reads (the train and validation maneuvers and the held-out test maneuvers,
            :func:`hybridfmu.diagnosis.settings.diagnosis_maneuvers`; others are left out).
        spans_s: maneuver -> its informative segments [[t_start_s, t_end_s], ...] (s); a maneuver not given is
            used whole.
        calibration: ``calibration/calibration.json`` of a run, or None for the FMU as configured.
        open_loop: also the open-loop checks (the held-out "how far" and the error growth).

    Returns:
        :class:`Diagnosis`: the record rule ``diagnose`` writes to ``diagnosis.json`` and the diagnosed model.
    """
    from hybridfmu.calibration.result import Calibration
    from hybridfmu.diagnosis.report import diagnosis_record
    from hybridfmu.diagnosis.inputs import case_inputs
    from hybridfmu.diagnosis.run import analyse_inputs
    from hybridfmu.diagnosis.settings import diagnosis_maneuvers

    names = diagnosis_maneuvers(case.config, str(case.source))
    unknown = sorted(set(frames) - set(case.maneuvers))
    missing = [name for name in names if name not in frames]
    if unknown or missing:
        raise ConfigError(f"{case.source}: config.maneuvers: expected a frame of each maneuver the diagnosis reads "
                          f"{names}; missing {missing}, not maneuvers of the case {unknown}")
    config = {**case.config, "maneuvers": {name: case.config["maneuvers"][name] for name in names}}
    settings = None if calibration is None else Calibration.load(calibration)
    inputs = case_inputs(config, fmu_file(case), {name: frames[name] for name in names}, spans_s, settings)
    result = analyse_inputs(config, inputs, None if calibration is None else str(calibration), open_loop)
    return Diagnosis(record=diagnosis_record(result, config), model=result.diagnosed)


def load_run(case: Case, results_dir: str | Path | None = None) -> Run:
    """What a workflow run wrote for ``case``: its metrics per role, the chosen model of each search, the
    calibration and the diagnosed model (whatever of them exists).

    Args:
        results_dir: the run's case folder; None: the case's (``<results_dir>/<case>`` from the working directory).

    Raises:
        FileNotFoundError: the folder does not exist (run the workflow first).
    """
    from hybridfmu.io import read_json

    folder = Path(results_dir) if results_dir is not None else case.results_dir
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no results of case {case.name!r}; run the workflow first "
                                f"(snakemake -j2 --configfile {case.source})")
    metrics = {path.stem: read_json(path) for path in sorted((folder / "metrics").glob("*.json"))}
    best = {search: read_json(folder / search / "best.json") for search in SEARCHES
            if (folder / search / "best.json").is_file()}
    calibration = folder / "calibration" / "calibration.json"
    diagnosed = folder / "diagnosis" / "diagnosed_model.pkl"
    return Run(case=case, results_dir=folder, metrics=metrics, best=best,
               calibration_path=calibration if calibration.is_file() else None,
               diagnosed_path=diagnosed if diagnosed.is_file() else None)


def simulate_trained(case: Case, frame: pd.DataFrame, search: str = "hpo", maneuver: str | None = None,
                     run: Run | None = None) -> pd.DataFrame:
    """A run's trained model open loop over a frame's logged inputs, as the evaluation simulates it.

    Args:
        case: the case; frame: as :func:`read_log` returns it.
        search: ``hpo`` (the neural FMU) or ``hybrid`` (the FMU + diagnosed effects + ANN).
        maneuver: the maneuver the frame is (its calibrated unmeasured initial states), or None.
        run: the run (:func:`load_run`); None: the case's own results folder.

    Returns:
        (T rows) ``time_s`` (s) and one column per FMU state.

    Raises:
        FileNotFoundError: the run has no chosen model of ``search``.
    """
    from hybridfmu.training.inference import load_trained_neural_fmu, physical_layer, simulate_neural_fmu
    from hybridfmu.training.measured import initial_state, load_calibration, measured_from_frame

    if search not in SEARCHES:
        raise ValueError(f"search: expected one of {list(SEARCHES)}, got {search!r}")
    run = run or load_run(case)
    best_path = run.results_dir / search / "best.json"
    if search not in run.best:
        raise FileNotFoundError(f"{best_path}: the run has no chosen model of search {search!r}")
    calibration = load_calibration(run.calibration_path)
    diagnosed = run.diagnosed_path if search == "hybrid" else None
    model = load_trained_neural_fmu(best_path, fmu_file(case), dict(calibration.parameters) or None, diagnosed)
    measured = measured_from_frame(frame, case.roles)
    x0 = initial_state(model.fmu.rhs.model, measured.x[0], case.roles, calibration, maneuver or "",
                       case.config["maneuvers"])
    if search == "hybrid":
        x0 = physical_layer(model).diagnosed.initial_state(x0, maneuver or "")
    states = np.asarray(simulate_neural_fmu(model, measured.time_s, measured.u, x0), dtype=float)
    return _states_frame(measured.time_s, states, case.roles.state_names)


def export_fmu(case: Case, model: str, path: str | Path, run: Run | None = None) -> Path:
    """A run's trained model as an FMI 2.0 Co-Simulation FMU at ``path``, as rule ``export`` writes it (without the
    rule's replay check; ``docs/export.md``).

    Args:
        case: the case; model: ``neural_fmu``, ``fmu_effects`` or ``hybrid``.
        path: the ``.fmu`` to write (atomically).
        run: the run (:func:`load_run`); None: the case's own results folder.

    Raises:
        FileNotFoundError: the run lacks what the model needs (its search's best model, the diagnosed model, the
            calibration, an ingested maneuver).
        ValueError: an unknown model, or a part of it without a C form (the message names it).
    """
    from hybridfmu import __version__
    from hybridfmu.data.between_samples import frame_conventions
    from hybridfmu.data.grid import grid_rate_hz
    from hybridfmu.export.names import model_identifier
    from hybridfmu.export.package import write_exported_fmu
    from hybridfmu.export.stage import export_provenance, model_content
    from hybridfmu.io import read_json

    run = run or load_run(case)
    search = {"neural_fmu": "hpo", "hybrid": "hybrid"}.get(model)
    if search is not None and search not in run.best:
        raise FileNotFoundError(f"{run.results_dir / search / 'best.json'}: the run has no chosen model of search "
                                f"{search!r}")
    if run.calibration_path is None:
        raise FileNotFoundError(f"{run.results_dir / 'calibration'}: the run has no calibration")
    data = sorted((run.results_dir / "data").glob("*.parquet"))
    if not data:
        raise FileNotFoundError(f"{run.results_dir / 'data'}: the run has no ingested maneuver")
    grid = run.results_dir / "data" / "grid.json"
    best = run.results_dir / search / "best.json" if search else None
    diagnosis = run.results_dir / "diagnosis" / "diagnosis.json"
    frame = pd.read_parquet(data[0])
    content = model_content(model, best, fmu_file(case), run.calibration_path, run.diagnosed_path,
                            grid_rate_hz(case.config, grid if grid.is_file() else None),
                            frame_conventions(frame, case.roles.input_names), frame["time_s"].to_numpy(dtype=float))
    source = read_json(best) if best else read_json(diagnosis) if diagnosis.is_file() else {}
    return write_exported_fmu(content, model_identifier(case.name, model), fmu_file(case), path,
                              export_provenance(case.name, model, case.config, source), __version__)


def _maneuver(case: Case, maneuver: str) -> dict[str, Any]:
    entry = case.config["maneuvers"].get(maneuver)
    if entry is None:
        raise ConfigError(f"{case.source}: config.maneuvers: no maneuver {maneuver!r}; expected one of "
                          f"{sorted(case.maneuvers)}")
    return entry


def _states_frame(time_s: np.ndarray, states: np.ndarray, state_names: list[str]) -> pd.DataFrame:
    return pd.DataFrame({"time_s": np.asarray(time_s, dtype=float),
                         **{name: states[:, i] for i, name in enumerate(state_names)}})
