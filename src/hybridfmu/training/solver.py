"""Fixed-step integration of the neural FMU on the sample grid, many windows side by side in the batch."""

from __future__ import annotations

import numpy as np
import torch

from hybridfmu import runge_kutta
from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.runge_kutta import NODE_MIDDLE, node_inputs
from hybridfmu.training.adjoint import ENGINES, fixed_model_c_rollout, rollout_adjoint, torch_axpy

#: ``rollout``'s gradients options that name one engine of the adjoint.
GRADIENT_ENGINES = {f"adjoint_{engine}": engine for engine in ENGINES}


def rollout(model: NeuralFmu, u_seq: torch.Tensor, start_index: int, x0: torch.Tensor, n_steps: int,
            gradients: str = "adjoint", row_steps: torch.Tensor | None = None) -> torch.Tensor:
    """Simulate ``n_steps`` solver steps of size h (the sample period) from ``x0``.

    Args:
        model: the neural FMU (solver method and end stop from ``model.spec``).
        u_seq: sampled inputs (B, T, n_u) on the data grid; the window starts at ``start_index`` and the
            sequence must reach far enough around the window for the input delay (ends are held).
        start_index: index in ``u_seq`` of the window's first instant (where ``x0`` applies).
        x0: initial states (B, n_x).
        n_steps: number of steps.
        gradients: "adjoint" (the solver's discrete adjoint, ``training.adjoint``, with the fastest engine the
            right-hand side allows: in C for an FMU behind the bridge), "adjoint_c", "adjoint_numpy",
            "adjoint_torch" (that engine of the adjoint) or "autograd" (the reference: every operation recorded
            by autograd). All give the same values and gradients to rounding. "torchdiffeq" and
            "torchdiffeq_adjoint": the library's fixed-grid solver (``torchdiffeq.odeint``, backpropagation
            through its steps, or ``odeint_adjoint``), for comparison (``benchmarks/train_step.py``); its RK4 is
            the 3/8 rule, so its states differ from the classical RK4's at the order of the truncation error,
            and it has no end stop.
        row_steps: optional (B,) steps each row needs (e.g. segments of different lengths side by side), for
            gradient-free rollouts through the adjoint: a row's states after its own steps are not meaningful
            (an FMU's loop in C holds them and saves the work).

    Returns:
        states (B, n_steps + 1, n_x) at t_start + k h, k = 0..n_steps (row 0 is ``x0``).

    Inputs at the stage times are the delayed, linearly interpolated samples ``model.delay``; all of them
    (and their first-layer contributions) are computed before the time loop.
    """
    if gradients in ("torchdiffeq", "torchdiffeq_adjoint"):
        return _rollout_torchdiffeq(model, u_seq, start_index, x0, n_steps, gradients == "torchdiffeq_adjoint")
    spec = model.spec
    h = spec.sample_period_s
    stage = model.fused()
    tableau = runge_kutta.tableau(spec.solver)
    middle = NODE_MIDDLE in tableau.c  # inputs half a sample into each step
    u_grid_t = model.delay(u_seq, start_index, n_steps + 1, 0.0).transpose(0, 1).contiguous()  # (n+1, B, n_u)
    z_grid_t = stage.input_term(u_grid_t)  # (n+1, B, H)
    u_half_t = model.delay(u_seq, start_index, n_steps if middle else 0, 0.5).transpose(0, 1).contiguous()
    z_half_t = stage.input_term(u_half_t)
    if gradients == "adjoint" or gradients in GRADIENT_ENGINES:
        states_t = rollout_adjoint(stage, h, spec.solver, _end_stop_indices(model), x0,
                                   u_grid_t, u_half_t, z_grid_t, z_half_t,
                                   engine=GRADIENT_ENGINES.get(gradients, "auto"),
                                   row_steps=None if row_steps is None else row_steps.numpy())
        return states_t.transpose(0, 1)
    if gradients != "autograd":
        raise ValueError(f"rollout: gradients must be 'adjoint', {', '.join(repr(g) for g in GRADIENT_ENGINES)}, "
                         f"'autograd', 'torchdiffeq' or 'torchdiffeq_adjoint', got {gradients!r}")
    # Time-major sequences split once (one backward node each instead of one per step).
    u_grid, z_grid = u_grid_t.unbind(0), z_grid_t.unbind(0)
    u_half, z_half = u_half_t.unbind(0), z_half_t.unbind(0)
    clamp = _end_stop(model)
    plan = tableau.plan(h)

    grid = list(zip(u_grid, z_grid))
    half = list(zip(u_half, z_half)) if middle else None
    x = x0
    states = [x0]
    for k in range(n_steps):
        x = plan.step(x, lambda state, i, inputs=node_inputs(grid, half, k): stage(state, *inputs[tableau.c[i]]),
                      torch_axpy)
        if clamp is not None:
            x = clamp(x)
        states.append(x)
    return torch.stack(states, dim=1)


def held_input_stepper(model: NeuralFmu):
    """``rollout`` of one step with each row's inputs held over it, for many calls on a model that does not change
    between them (a closed loop): the fused derivative is made once (without gradients, also the C engine's
    flattened weights and the physical layer's coefficients: :func:`hybridfmu.training.adjoint.fixed_model_c_rollout`)
    and the held inputs go to the solver as they are (the delays of a constant sequence give its value exactly, so
    the states equal ``rollout``'s bit for bit).

    Returns:
        ``step(u (B, n_u), x (B, n_x)) -> (B, n_x)`` (float64 tensors): the states one sample period later.
    """
    spec = model.spec
    stage = model.fused()
    middle = NODE_MIDDLE in runge_kutta.tableau(spec.solver).c
    clamp = _end_stop_indices(model)
    with torch.no_grad():
        c_run = fixed_model_c_rollout(stage, spec.sample_period_s, spec.solver, clamp)

    def step(u: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        if c_run is not None and not torch.is_grad_enabled():  # the C engine without its per-call set-up
            # every sample of the step holds the same inputs: their first-layer term once, as NumPy arrays
            u_np = u.numpy()
            z_np = stage.input_term(u).numpy()  # (B, H)
            n_half = 1 if middle else 0
            states = c_run(x.numpy(), np.stack((u_np, u_np)), np.repeat(u_np[None], n_half, axis=0),
                           np.stack((z_np, z_np)), np.repeat(z_np[None], n_half, axis=0))
            return torch.from_numpy(states[1])
        u_grid_t = u[None].expand(2, -1, -1).contiguous()  # (2, B, n_u): both ends of the step
        u_half_t = u[None].contiguous() if middle else u[None, :0].contiguous()
        states_t = rollout_adjoint(stage, spec.sample_period_s, spec.solver, clamp, x, u_grid_t, u_half_t,
                                   stage.input_term(u_grid_t), stage.input_term(u_half_t), engine="auto")
        return states_t[1]

    return step


class _DelayedDerivative(torch.nn.Module):
    """The neural FMU's derivative as a function of (t, x) for torchdiffeq: the inputs at t come from the
    model's input delay (linear interpolation of the window's samples, shifted by the learned offset)."""

    def __init__(self, model: NeuralFmu, u_seq: torch.Tensor, start_index: int) -> None:
        super().__init__()
        self.model, self.u_seq, self.start_index = model, u_seq, start_index

    def forward(self, t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        offset = float(t.detach()) / self.model.spec.sample_period_s  # the grid is fixed: t carries no gradient
        u = self.model.delay(self.u_seq, self.start_index, 1, offset)[:, 0]
        return self.model.derivative(x, u)


def _rollout_torchdiffeq(model: NeuralFmu, u_seq: torch.Tensor, start_index: int, x0: torch.Tensor,
                         n_steps: int, adjoint: bool) -> torch.Tensor:
    """``rollout`` with torchdiffeq's fixed-grid solver on the sample grid: (B, n_steps + 1, n_x)."""
    import torchdiffeq

    spec = model.spec
    if spec.end_stop is not None:
        raise ValueError("rollout: torchdiffeq's fixed-grid solvers have no end stop; use gradients='adjoint' for a "
                         "model with model.end_stop")
    h = spec.sample_period_s
    func = _DelayedDerivative(model, u_seq, start_index)
    times = torch.arange(n_steps + 1, dtype=torch.float64) * h
    options = {"method": "rk4" if spec.solver == "rk4" else "euler", "options": {"step_size": h}}
    if adjoint:
        states = torchdiffeq.odeint_adjoint(func, x0, times, adjoint_params=tuple(model.parameters()), **options)
    else:
        states = torchdiffeq.odeint(func, x0, times, **options)
    return states.transpose(0, 1)


def _end_stop_indices(model: NeuralFmu) -> tuple[int, int, float, float] | None:
    stop = model.spec.end_stop
    if stop is None:
        return None
    names = model.spec.state_names
    return names.index(stop.state), names.index(stop.rate_state), float(stop.min), float(stop.max)


def _end_stop(model: NeuralFmu):
    stop = model.spec.end_stop
    if stop is None:
        return None
    names = model.spec.state_names
    i_pos, i_rate = names.index(stop.state), names.index(stop.rate_state)
    lower, upper = float(stop.min), float(stop.max)

    def clamp(x: torch.Tensor) -> torch.Tensor:
        position = x[:, i_pos]
        outside = (position <= lower) | (position >= upper)
        if not bool(outside.any()):
            return x
        rate_kept = torch.where(outside, torch.zeros_like(position), x[:, i_rate])
        columns = list(x.unbind(dim=1))
        columns[i_pos] = position.clamp(lower, upper)
        columns[i_rate] = rate_kept
        return torch.stack(columns, dim=1)

    return clamp
