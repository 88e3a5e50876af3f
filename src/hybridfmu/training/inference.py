"""Using a trained neural FMU: load the best model of a search and simulate it open loop."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from hybridfmu.io import read_json
from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.model.spec import NeuralFmuSpec
from hybridfmu.training.data import check_uniform_grid
from hybridfmu.training.multiple_shooting import batched_window_rows, windowed_trajectory
from hybridfmu.training.solver import held_input_stepper, rollout
from hybridfmu.training.windows import delay_padding


def load_trained_neural_fmu(best_json_path: str | Path, fmu_path: str | Path,
                            fmu_parameters: dict[str, float] | None = None,
                            diagnosed_path: str | Path | None = None) -> NeuralFmu:
    """The neural FMU named by ``hpo/best.json`` (its ``checkpoint``), around the FMU at ``fmu_path``.

    A hybrid (its spec names ``physics_effects``) is built around the FMU plus those effects of the diagnosed
    model at ``diagnosed_path`` (``diagnosis/diagnosed_model.pkl``). The learned delays are
    ``model.delay_s()`` ({group: s}), the gates ``model.gate_values()``.
    """
    best = read_json(best_json_path)
    if "checkpoint" not in best:
        raise ValueError(f"{best_json_path}: field 'checkpoint' missing (expected the best.json of a search)")
    checkpoint_path = Path(best["checkpoint"])
    if not checkpoint_path.is_absolute() and not checkpoint_path.exists():
        # paths are relative to the workflow's folder; the copy also lies beside best.json
        beside = Path(best_json_path).parent / checkpoint_path.name
        checkpoint_path = beside if beside.exists() else checkpoint_path
    return load_checkpoint_model(checkpoint_path, fmu_path, fmu_parameters, diagnosed_path)


def load_checkpoint_model(checkpoint_path: str | Path, fmu_path: str | Path,
                          fmu_parameters: dict[str, float] | None = None,
                          diagnosed_path: str | Path | None = None) -> NeuralFmu:
    """The trained neural FMU (or hybrid) of one trial's ``checkpoint.pt``, around the FMU at ``fmu_path``
    (see :func:`load_trained_neural_fmu`), in evaluation mode."""
    from hybridfmu.fmu import FmuRhs, load_fmu
    from hybridfmu.training.checkpoint import load_checkpoint

    checkpoint = load_checkpoint(checkpoint_path)
    spec = NeuralFmuSpec.from_dict(checkpoint["spec"])
    fmu_model = load_fmu(fmu_path, parameters=fmu_parameters or None)
    if list(fmu_model.state_names) != spec.state_names or list(fmu_model.input_names) != spec.input_names:
        raise ValueError(f"{fmu_path}: FMU states {fmu_model.state_names} / inputs {fmu_model.input_names} differ "
                         f"from the trained model's {spec.state_names} / {spec.input_names}")
    rhs_model = fmu_model
    if spec.physics_effects is not None:
        from hybridfmu.diagnosis.export import load_diagnosed
        from hybridfmu.model.physics import PhysicsModel

        if diagnosed_path is None:
            raise ValueError(f"{checkpoint_path}: a hybrid (spec field 'physics_effects' "
                             f"{spec.physics_effects}) needs the diagnosed model (diagnosis/diagnosed_model.pkl)")
        helper = load_fmu(fmu_path, parameters=fmu_parameters or None)
        rhs_model = PhysicsModel(fmu_model, helper, load_diagnosed(diagnosed_path).selected(spec.physics_effects))
    model = NeuralFmu(FmuRhs(rhs_model), spec, None)
    model.load_state_dict(checkpoint["model"])
    model.eval()
    return model


def simulate_neural_fmu(model: NeuralFmu, time_s: Any, u: Any, x0: Any, engine: str = "adjoint") -> np.ndarray:
    """Open-loop simulation from ``x0`` over the whole grid.

    Args:
        model: a trained neural FMU.
        time_s: (T,) uniform sample times (s) with the model's sample period.
        u: (T, n_u) inputs in FMU order.
        x0: (n_x,) initial state at ``time_s[0]``.
        engine: the rollout's engine (``gradients`` of :func:`hybridfmu.training.solver.rollout`; the default:
            the fastest the model allows, in C for an FMU behind the bridge). The same states to rounding.

    Returns:
        states (T, n_x), float64 (non-finite rows if the simulation diverged).
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    x0 = np.asarray(x0, dtype=np.float64).reshape(-1)
    spec = model.spec
    step = check_uniform_grid(time_s, "simulate_neural_fmu")
    if abs(step - spec.sample_period_s) > 1e-6 * spec.sample_period_s:
        raise ValueError(f"simulate_neural_fmu: time_s has step {step:.6g} s, the model was trained with "
                         f"{spec.sample_period_s:.6g} s")
    if u.shape != (time_s.size, len(spec.input_names)):
        raise ValueError(f"simulate_neural_fmu: u has shape {u.shape}, expected {(time_s.size, len(spec.input_names))}")
    if x0.shape != (len(spec.state_names),):
        raise ValueError(f"simulate_neural_fmu: x0 has shape {x0.shape}, expected ({len(spec.state_names)},)")
    diagnosed = diagnosed_simulator(model)
    if diagnosed is not None:  # a hybrid that is its physical layer: the FMU + effects' own simulation
        return diagnosed(time_s, u, x0)
    physics = physical_layer(model)
    if physics is not None:  # a hybrid sees the inputs through the diagnosed input changes
        u = physics.inputs(u, spec.sample_period_s)
    pad = delay_padding(spec.sample_period_s, spec.delay_min_s, spec.delay_max_s)
    index = np.clip(np.arange(-pad, time_s.size + pad), 0, time_s.size - 1)
    u_seq = torch.from_numpy(np.ascontiguousarray(u[index]))[None]
    with torch.no_grad():
        states = rollout(model, u_seq, pad, torch.from_numpy(x0)[None], time_s.size - 1, gradients=engine)
    return states[0].numpy()


def simulate_neural_fmu_windows(model: NeuralFmu, time_s: Any, u: Any, x_start: Any, steps: int,
                                batch: int = 64) -> np.ndarray:
    """Multiple shooting: the model over consecutive windows of ``steps`` steps, each from ``x_start`` at its first
    sample, side by side in batches of ``batch`` windows (:mod:`hybridfmu.training.multiple_shooting`).

    The inputs are those of the whole record (a hybrid's diagnosed input changes and the learned delays see the
    samples before a window's start), so a window is the whole-record simulation restarted, nothing else.

    Args:
        model: a trained neural FMU; time_s: (T,) uniform grid with the model's sample period (s); u: (T, n_u)
            inputs in FMU order; x_start: (T, n_x) the state a window started at sample k starts from.

    Returns:
        (T, n_x) float64: each window's states on its samples (its first sample: its start state).
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    x_start = np.asarray(x_start, dtype=np.float64)
    spec = model.spec
    check_uniform_grid(time_s, "simulate_neural_fmu_windows")
    if u.shape != (time_s.size, len(spec.input_names)) or x_start.shape != (time_s.size, len(spec.state_names)):
        raise ValueError(f"simulate_neural_fmu_windows: u {u.shape} and x_start {x_start.shape} must have "
                         f"{time_s.size} rows of {len(spec.input_names)} inputs / {len(spec.state_names)} states")
    diagnosed = diagnosed_simulator(model)
    if diagnosed is not None:  # a hybrid that is its physical layer: windowed as the FMU + effects
        return windowed_trajectory(diagnosed, time_s, u, x_start, steps)
    physics = physical_layer(model)
    if physics is not None:
        u = physics.inputs(u, spec.sample_period_s)
    pad = delay_padding(spec.sample_period_s, spec.delay_min_s, spec.delay_max_s)
    u_padded = u[np.clip(np.arange(-pad, time_s.size + pad), 0, time_s.size - 1)]  # record sample j at pad + j
    out = np.full(x_start.shape, np.nan)
    full, last_steps = batched_window_rows(time_s.size, steps)
    groups = [(full[i:i + batch], steps) for i in range(0, full.size, batch)]
    if last_steps:
        groups.append((np.array([time_s.size - 1 - last_steps]), last_steps))
    with torch.no_grad():
        for starts, n_steps in groups:
            u_seq = np.stack([u_padded[s:s + n_steps + 1 + 2 * pad] for s in starts])
            states = rollout(model, torch.from_numpy(u_seq), pad, torch.from_numpy(x_start[starts]), n_steps)
            for row, start in zip(states.numpy(), starts):  # in order: a window's first sample overwrites the
                out[start:start + n_steps + 1] = row          # last one of the window before (its start state)
    return out


def make_held_input_step(model: NeuralFmu):
    """One solver step of the model's sample period with the inputs held over the step, for many calls on a model
    that does not change between them.

    The closed loop's step (:mod:`hybridfmu.evaluation.closed_loop`): a controller's outputs are applied as it
    writes them, held over the period, so the learned input delays see constant inputs (no delay acts) and a
    hybrid's diagnosed input changes act on the held values (time shifts and lags vanish, dead zones and gains
    stay).

    Args:
        model: a trained neural FMU or hybrid (not changed while the step is used).

    Returns:
        ``step(u (B, n_u) inputs in FMU order, x (B, n_x) states) -> (B, n_x)`` float64 states one sample period
        later (the solver and end stop of ``model.spec``; :func:`hybridfmu.training.solver.held_input_stepper`).
    """
    spec = model.spec
    physics = physical_layer(model)
    stepper = held_input_stepper(model)

    def step(u: Any, x: Any) -> np.ndarray:
        u = np.asarray(u, dtype=np.float64)
        x = np.asarray(x, dtype=np.float64)
        if physics is not None:  # each row held on its own (rows are different records)
            u = physics.held_inputs(u, spec.sample_period_s)
        with torch.no_grad():
            states = stepper(torch.from_numpy(np.ascontiguousarray(u)), torch.from_numpy(np.ascontiguousarray(x)))
        return states.numpy()

    return step


def without_ann(model: NeuralFmu) -> NeuralFmu:
    """``model`` with its ANN gates closed and its FMU gates at 1 (in place; returned): what is left is the model's
    physics (the FMU with the model's calibration, or a hybrid's physical layer with its trained coefficients)."""
    with torch.no_grad():
        model.gates.g_A.zero_()
        model.gates.g_F.fill_(1.0)
    return model


def is_its_physical_layer(model: NeuralFmu) -> bool:
    """True when ``model`` is a hybrid that is exactly its physical layer, the FMU plus its diagnosed effects: ANN
    output at zero and FMU gates at 1, input delays fixed at zero, effect coefficients at the diagnosed values (the
    candidate of :func:`hybridfmu.training.finalists.write_physical_layer_checkpoint`)."""
    from hybridfmu.training.physical_layer_rollout import untrained_is_physical_layer

    physics = physical_layer(model)
    if physics is None or not untrained_is_physical_layer(model):
        return False
    spec = model.spec
    if not (float(spec.delay_min_s) == float(spec.delay_max_s) == 0.0):
        return False
    diagnosed = [array for _, array in physics.diagnosed.corrected(physics.helper).row_coefficients]
    return bool(np.array_equal(physics.coefficients, np.concatenate(diagnosed) if diagnosed else np.zeros(0)))


def diagnosed_simulator(model: NeuralFmu):
    """For a hybrid that is its physical layer (:func:`is_its_physical_layer`): ``(time_s (T,), u (T, n_u), x0
    (n_x,)) -> states (T, n_x)``, the diagnosed model's own open-loop simulation
    (:meth:`hybridfmu.diagnosis.export.DiagnosedModel.simulate`, the logged inputs held between samples as the FMU
    + effects is evaluated), so that model and this hybrid give one trajectory; else None. ``x0`` is the physical
    layer's start (already through ``diagnosed.initial_state``)."""
    if not is_its_physical_layer(model):
        return None
    physics = physical_layer(model)

    def simulate(time_s: np.ndarray, u: np.ndarray, x0: np.ndarray) -> np.ndarray:
        return np.asarray(physics.diagnosed.simulate(physics.fmu, physics.helper, time_s, u, x0), dtype=float)

    return simulate


def physical_layer(model: NeuralFmu):
    """The physical layer of a hybrid (``hybridfmu.model.physics.PhysicsModel``), or None for a neural FMU
    around a plain FMU."""
    from hybridfmu.model.physics import PhysicsModel

    inner = getattr(model.fmu.rhs, "model", None)
    return inner if isinstance(inner, PhysicsModel) else None
