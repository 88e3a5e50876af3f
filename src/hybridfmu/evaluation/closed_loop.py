"""Closed loop: the case's control software drives each model, as in a software-in-the-loop test.

Open loop, a model is driven by the logged actuator commands; a small error in the rotor angle then turns the
logged phase voltages against the rotor and the model slips out of step where the hardware, with its controller
closing the loop, did not. In software-in-the-loop tests the control software closes the loop around the model.
A case declares its controller (config ``closed_loop``): a Python callable ``module:attribute`` that, called with
the case config and the sample period, returns an object with

- ``reset(states, signals)``: start of a record (the model's initial ``states`` by FMU state name, the logged
  ``signals`` at the first sample by the controller's signal names);
- ``step(states, signals) -> {output: value}``: one sample period; the outputs (by the controller's output names,
  mapped to FMU inputs by ``closed_loop.outputs``) apply from the next sample on (one sample of computation delay,
  as a control unit applies them).

Every other FMU input stays as logged. Per sample k: the controller reads the model's states at t_k and the
logged signals at t_k; the model steps [t_k, t_k+1) with the outputs of the step before, held over the period
(:func:`hybridfmu.training.inference.make_held_input_step`). The record's first sample applies the logged commands.
The models' trajectories are then judged against the measurement like the open-loop ones.
"""

from __future__ import annotations

import importlib
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import pandas as pd

from hybridfmu.io import write_parquet_atomic
from hybridfmu.progress import Progress

LOG = logging.getLogger(__name__)

#: The models the closed loop simulates: the FMU (the neural FMU's model with its ANN gates closed), the neural
#: FMU, the FMU + diagnosed effects (the hybrid's physical layer, ANN at zero) and the hybrid.
CLOSED_LOOP_MODELS = ("fmu", "neural_fmu", "fmu_effects", "hybrid")


@dataclass(frozen=True)
class ClosedLoopSettings:
    """Config ``closed_loop``.

    Attributes:
        controller: ``module:attribute`` of the controller factory.
        signals: the controller's signal name -> the case signal it reads (logged, model units).
        outputs: the controller's output name -> the FMU input it writes.
        options: keyword arguments of the factory.
    """

    controller: str
    signals: dict[str, str]
    outputs: dict[str, str]
    options: dict[str, Any] = field(default_factory=dict)


def closed_loop_settings(config: Mapping[str, Any], roles: Any) -> ClosedLoopSettings | None:
    """The case's closed-loop settings, checked against its signals and FMU inputs (``roles``:
    :class:`hybridfmu.data.roles.CaseRoles`); None when the case declares no controller.

    Raises:
        ValueError: naming the field of ``config.closed_loop`` and what was expected.
    """
    section = config.get("closed_loop") or {}
    if not section.get("controller"):
        return None
    controller = str(section["controller"])
    if controller.count(":") != 1 or not all(controller.split(":")):
        raise ValueError(f"config.closed_loop.controller: expected 'module:attribute' (e.g. "
                         f"'my_package.ecu:Controller'), got {controller!r}")
    signals = {str(k): str(v) for k, v in (section.get("signals") or {}).items()}
    unknown = sorted(v for v in signals.values() if v not in roles.signals)
    if unknown:
        raise ValueError(f"config.closed_loop.signals: signal(s) {unknown} are not signals of the case; expected "
                         f"some of {sorted(roles.signals)}")
    outputs = {str(k): str(v) for k, v in (section.get("outputs") or {}).items()}
    if not outputs:
        raise ValueError("config.closed_loop.outputs: expected at least one 'controller output: FMU input' pair")
    bad = sorted(v for v in outputs.values() if v not in roles.input_names)
    if bad or len(set(outputs.values())) != len(outputs):
        raise ValueError(f"config.closed_loop.outputs: FMU input(s) {bad or list(outputs.values())} are not distinct "
                         f"inputs of the FMU; expected some of {list(roles.input_names)}")
    return ClosedLoopSettings(controller, signals, outputs, dict(section.get("options") or {}))


def controller_factory(settings: ClosedLoopSettings) -> Callable[..., Any]:
    """Import the factory ``module:attribute`` of ``config.closed_loop.controller``.

    Raises:
        ValueError: the module or attribute cannot be imported (naming the field and the error).
    """
    module_name, attribute = settings.controller.split(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ValueError(f"config.closed_loop.controller: cannot import module {module_name!r} ({err}); expected "
                         "an importable module (installed, or on PYTHONPATH)") from None
    factory = getattr(module, attribute, None)
    if not callable(factory):
        raise ValueError(f"config.closed_loop.controller: module {module_name!r} has no callable {attribute!r}")
    return factory


def make_controller(settings: ClosedLoopSettings, config: Mapping[str, Any], period_s: float) -> Any:
    """A new controller instance: ``factory(config, period_s, **options)``, checked to have ``reset`` and ``step``."""
    controller = controller_factory(settings)(config, period_s, **settings.options)
    missing = [name for name in ("reset", "step") if not callable(getattr(controller, name, None))]
    if missing:
        raise ValueError(f"config.closed_loop.controller: {settings.controller} returned a "
                         f"{type(controller).__name__} without method(s) {missing}; expected reset(states, signals) "
                         "and step(states, signals) -> {output: value}")
    return controller


@dataclass
class ClosedLoopRecord:
    """One record driven in closed loop.

    Attributes:
        name: the maneuver.
        u: (T, n_u) logged FMU inputs (FMU order); the controller's outputs replace their columns from sample 1 on.
        signals: the controller's signal name -> (T,) logged values (model units).
        x0: (n_x,) the model's initial state.
        controller: a fresh controller instance.
    """

    name: str
    u: np.ndarray
    signals: dict[str, np.ndarray]
    x0: np.ndarray
    controller: Any


def simulate_closed_loop(step: Callable[[np.ndarray, np.ndarray], np.ndarray], records: Sequence[ClosedLoopRecord],
                         state_names: Sequence[str], input_names: Sequence[str], outputs: Mapping[str, str],
                         period_s: float, label: str = "closed loop") -> list[np.ndarray]:
    """Drive the model by each record's controller, all records side by side in one batch.

    Args:
        step: ``step(u (B, n_u), x (B, n_x)) -> (B, n_x)``: the model over one sample period with ``u`` held.
        records: the records (different lengths allowed; a finished record's row idles until the longest ends).
        state_names, input_names: the FMU's, in order.
        outputs: the controller's output name -> FMU input (config ``closed_loop.outputs``).
        period_s: the sample period (s), for the progress lines.
        label: names the run in the progress lines.

    Returns:
        Per record, its (T, n_x) states (NaN from the first non-finite state on).

    Raises:
        ValueError: a controller returns something else than its declared outputs as finite numbers.
    """
    columns = {output: list(input_names).index(name) for output, name in outputs.items()}
    commanded = np.array(list(columns.values()), dtype=int)
    lengths = [record.u.shape[0] for record in records]
    # per record its signals' names and (T, n_signals) values, a sample's row read as Python floats at once
    signal_names = [list(record.signals) for record in records]
    signal_rows = [np.column_stack([np.asarray(values, dtype=float) for values in record.signals.values()])
                   if record.signals else np.zeros((record.u.shape[0], 0)) for record in records]
    n_max = max(lengths)
    x = np.stack([np.asarray(record.x0, dtype=float) for record in records])
    trajectories = [np.full((n, len(state_names)), np.nan) for n in lengths]
    applied = np.stack([record.u[0] for record in records])  # the first sample: the logged commands
    u_now = applied.copy()
    for b, record in enumerate(records):
        record.controller.reset(dict(zip(state_names, x[b].tolist())),
                                {name: float(values[0]) for name, values in record.signals.items()})
    progress = Progress((n_max - 1) * period_s, label, unit="simulated s", logger=LOG, interval_s=10.0)
    chunk = max(int(round(0.1 / period_s)), 1)
    for k in range(n_max):
        for b, record in enumerate(records):
            if k < lengths[b]:
                trajectories[b][k] = x[b]
        if k == n_max - 1:
            break
        for b, record in enumerate(records):
            u_now[b] = record.u[min(k, lengths[b] - 1)]
        u_now[:, commanded] = applied[:, commanded]  # the commands of the step before (row b's are set below)
        finite_rows = np.isfinite(x).all(axis=1).tolist()
        state_rows = x.tolist()
        for b, record in enumerate(records):
            kk = min(k, lengths[b] - 1)
            if k >= lengths[b] - 1 or not finite_rows[b]:
                continue
            command = record.controller.step(dict(zip(state_names, state_rows[b])),
                                             dict(zip(signal_names[b], signal_rows[b][kk].tolist())))
            is_mapping = isinstance(command, (dict, Mapping))
            for output, column in columns.items():
                value = command.get(output) if is_mapping else None
                if value is None or not math.isfinite(value):
                    raise ValueError(f"{record.name}: at sample {k} the controller returned {command!r}; expected "
                                     f"finite values of its outputs {list(columns)}")
                applied[b, column] = float(value)
        x = np.asarray(step(u_now, x), dtype=float)
        if (k + 1) % chunk == 0:
            progress.update(chunk * period_s)
    progress.finish()
    return trajectories


def write_closed_loop(model_kind: str, model: Any, fmu_start: Callable[[str, np.ndarray], np.ndarray],
                      data_paths: Mapping[str, str | Path], output_paths: Mapping[str, str | Path], roles: Any,
                      settings: ClosedLoopSettings, config: Mapping[str, Any]) -> dict[str, float]:
    """Rule ``simulate_closed_loop``: one model in closed loop over the evaluated maneuvers.

    Args:
        model_kind: one of :data:`CLOSED_LOOP_MODELS` (names the columns).
        model: the trained neural FMU (or its physics, :func:`hybridfmu.training.inference.without_ann`).
        fmu_start: ``fmu_start(maneuver, measured x at the first sample (n_x,)) -> x0 (n_x,)``: the model's
            initial state (measured states, unmeasured ones as the open-loop evaluation starts them).
        data_paths, output_paths: maneuver -> its ingested frame / the Parquet written: ``time_s``,
            ``closed_loop_<model>_<signal>`` per target signal and ``closed_loop_<model>_state_<state>`` per FMU
            state (model units).
        roles: :class:`hybridfmu.data.roles.CaseRoles`; settings: :func:`closed_loop_settings`; config: the case config
            (for the controller factory).

    Returns:
        Wall time per simulated second.
    """
    from hybridfmu.training.inference import make_held_input_step
    from hybridfmu.training.measured import read_measured

    period_s = float(model.spec.sample_period_s)
    records, measured = [], {}
    for name, path in data_paths.items():
        data = read_measured(path, roles)
        step_s = float(np.median(np.diff(data.time_s)))
        if abs(step_s - period_s) > 1e-6 * period_s:
            raise ValueError(f"{path}: sample period {step_s:.6g} s, the model's is {period_s:.6g} s")
        frame = pd.read_parquet(path, columns=sorted(set(settings.signals.values())))
        signals = {controller_name: frame[signal].to_numpy(dtype=float)
                   for controller_name, signal in settings.signals.items()}
        records.append(ClosedLoopRecord(name, data.u, signals, fmu_start(name, data.x[0]),
                                        make_controller(settings, config, period_s)))
        measured[name] = data
    wall = time.perf_counter()
    trajectories = simulate_closed_loop(make_held_input_step(model), records, roles.state_names,
                                        roles.input_names, settings.outputs, period_s,
                                        f"closed loop {model_kind} ({len(records)} maneuvers)")
    wall_s = time.perf_counter() - wall
    simulated_s = max(r.u.shape[0] for r in records) * period_s
    for record, states in zip(records, trajectories):
        data = measured[record.name]
        columns: dict[str, np.ndarray] = {"time_s": data.time_s}
        for state, signal in zip(data.target_states, data.target_signals):
            columns[f"closed_loop_{model_kind}_{signal}"] = states[:, list(roles.state_names).index(state)]
        for i, state in enumerate(roles.state_names):
            columns[f"closed_loop_{model_kind}_state_{state}"] = states[:, i]
        write_parquet_atomic(output_paths[record.name], pd.DataFrame(columns))
        errors = ", ".join(f"{signal} MAE {np.nanmean(np.abs(columns[f'closed_loop_{model_kind}_{signal}'] - data.targets[:, k])):.4g}"
                           for k, signal in enumerate(data.target_signals))
        LOG.info("closed loop %s, %s: %s", model_kind, record.name, errors)
    LOG.info("closed loop %s: %d maneuvers side by side, %.2f simulated s in %.1f s wall (%.3g s per simulated s)",
             model_kind, len(records), simulated_s, wall_s, wall_s / max(simulated_s, 1e-12))
    return {"wall_s_per_simulated_s": wall_s / max(simulated_s, 1e-12)}


def closed_loop_model(model_kind: str, *, best_path: str | Path, fmu_path: str | Path,
                      calibration_path: str | Path | None, roles: Any, maneuvers: Mapping[str, Any] | None,
                      diagnosed_path: str | Path | None = None, hybrid_best_path: str | Path | None = None,
                      physical_layer_path: str | Path | None = None) -> tuple[Any, Callable]:
    """The model of ``model_kind`` and its start-state function for :func:`write_closed_loop`.

    ``fmu``: the neural FMU of ``best_path`` without its ANN (the FMU with the calibration, stepped by the same
    solver as the others); ``neural_fmu``: that neural FMU; ``fmu_effects``: the hybrid search's physical layer
    (``physical_layer_path``: the diagnosed effects at their fitted coefficients, ANN at zero); ``hybrid``: the
    hybrid of ``hybrid_best_path``. Initial states as in the open-loop evaluation.

    Raises:
        ValueError: an unknown kind, or a file the kind needs is not given.
    """
    from hybridfmu.training.inference import (load_checkpoint_model, load_trained_neural_fmu, physical_layer,
                                              without_ann)
    from hybridfmu.training.measured import initial_state, load_calibration

    if model_kind not in CLOSED_LOOP_MODELS:
        raise ValueError(f"closed loop: model {model_kind!r} unknown; expected one of {list(CLOSED_LOOP_MODELS)}")
    calibration = load_calibration(calibration_path)
    parameters = dict(calibration.parameters) or None
    if model_kind in ("fmu", "neural_fmu"):
        model = load_trained_neural_fmu(best_path, fmu_path, parameters)
        if model_kind == "fmu":
            without_ann(model)
    elif model_kind == "hybrid":
        if hybrid_best_path is None or diagnosed_path is None:
            raise ValueError("closed loop hybrid: needs hybrid/best.json and the diagnosed model")
        model = load_trained_neural_fmu(hybrid_best_path, fmu_path, parameters, diagnosed_path)
    else:
        if physical_layer_path is None or diagnosed_path is None:
            raise ValueError("closed loop fmu_effects: needs the hybrid search's physical_layer.pt and the diagnosed "
                             "model")
        model = load_checkpoint_model(physical_layer_path, fmu_path, parameters, diagnosed_path)
    physics = physical_layer(model)

    def start(maneuver: str, measured_x0: np.ndarray) -> np.ndarray:
        fmu = physics.fmu if physics is not None else model.fmu.rhs.model
        x0 = initial_state(fmu, measured_x0, roles, calibration, maneuver, dict(maneuvers or {}))
        return physics.diagnosed.initial_state(x0, maneuver) if physics is not None else x0

    return model, start
