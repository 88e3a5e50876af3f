"""Fast rollout of the neural FMU with a hand-written discrete adjoint (reverse sweep) of the solver.

Same result and gradients as ``solver.rollout`` with autograd, with far fewer operations: the forward pass
runs without building an autograd graph and records the stage values; the reverse sweep propagates the
adjoint through the solver stages, the MLP and the FMU Jacobians. Three engines (:data:`ENGINES`) do this:
in C next to the FMU shim (``hybridfmu.fmu.neural``, for an FMU behind the bridge), in NumPy
(``training.numpy_adjoint``, for a right-hand side with the bridge's derivatives-and-Jacobians kernel) and
as torch operations (``SolverEngine``, any right-hand side; the weight gradients of all stages summed in one
matrix product per layer at the end). Gradient-free rollouts (validation, inference) run in C, NumPy or torch
the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from hybridfmu import runge_kutta
from hybridfmu.fmu.neural import NeuralWeights
from hybridfmu.model.fmu_layer import (coefficient_kernel, jacobian_function, jacobian_kernel, neural_recorder_function,
                                       neural_rollout_function, numpy_function, numpy_kernel, value_function)
from hybridfmu.model.neural_fmu import FusedDerivative
from hybridfmu.runge_kutta import NODE_END, NODE_MIDDLE, NODE_START, node_inputs, numpy_axpy, pairwise_sum
from hybridfmu.training.numpy_adjoint import NumpyRollout, NumpyWeights


def torch_axpy(y: torch.Tensor, k: torch.Tensor, c: float) -> torch.Tensor:
    """y + c k in one torch operation (``hybridfmu.runge_kutta.Axpy``)."""
    return torch.add(y, k, alpha=c)


@dataclass
class _Weights:
    w_xd_t: torch.Tensor
    w_out: torch.Tensor
    b_out: torch.Tensor
    g_fmu: torch.Tensor
    hidden: list[tuple[torch.Tensor, torch.Tensor]]

    def transposed(self) -> "_Weights":
        """Transposes for the reverse sweep (``hidden`` holds the transposed weights only)."""
        return _Weights(self.w_xd_t.t().contiguous(), self.w_out.t().contiguous(), self.b_out, self.g_fmu,
                        [(w.t().contiguous(), b) for w, b in self.hidden])


class SolverEngine:
    """Solver stages of one rollout on plain (graph-free) tensors.

    Args:
        stage: the fused derivative (its rhs is used; the weights are passed to ``run``).
        h: step size (s). method: "rk4" or "euler". clamp: optional end stop (position index,
            rate index, lower, upper).
    """

    def __init__(self, stage: FusedDerivative, h: float, method: str,
                 clamp: tuple[int, int, float, float] | None) -> None:
        self.rhs = stage.rhs
        self.jacobians = jacobian_function(stage.rhs)
        self.value = value_function(stage.rhs)
        self.numpy_rhs = numpy_function(stage.rhs)
        self.c_rollout = neural_rollout_function(stage.rhs)
        self.h = h
        self.method = method
        self.tableau = runge_kutta.tableau(method)
        self.clamp = clamp

    # ------------------------------------------------------------------ forward
    def _stage(self, wts: _Weights, x, u, z, record: list | None):
        if record is None:
            xdot_f = self.value(x, u)
            rhs_record = None
        elif self.jacobians is not None:
            xdot_f, dfdx, dfdu = self.jacobians(x, u)
            rhs_record = (torch.cat([dfdx, dfdu], dim=2),)
        else:
            with torch.enable_grad():
                x_leaf = x.detach().requires_grad_(True)
                u_leaf = u.detach().requires_grad_(True)
                xdot_graph = self.rhs(x_leaf, u_leaf)
            xdot_f = xdot_graph.detach()
            rhs_record = (x_leaf, u_leaf, xdot_graph)
        xf = torch.cat([x, xdot_f], dim=1)
        h = torch.tanh(torch.addmm(z, xf, wts.w_xd_t))
        activations = [h]
        for weight_t, bias in wts.hidden:
            h = torch.tanh(torch.addmm(bias, h, weight_t))
            activations.append(h)
        y = torch.addmm(torch.addcmul(wts.b_out, xdot_f, wts.g_fmu), h, wts.w_out)
        if record is not None:
            record.append((xf, xdot_f, activations, rhs_record))
        return y

    def _apply_clamp(self, x):
        if self.clamp is None:
            return x, None
        i_pos, i_rate, lower, upper = self.clamp
        position = x[:, i_pos]
        outside = (position <= lower) | (position >= upper)
        if not bool(outside.any()):
            return x, None
        x = x.clone()
        x[:, i_pos] = position.clamp(lower, upper)
        x[:, i_rate] = torch.where(outside, torch.zeros_like(position), x[:, i_rate])
        mask = torch.ones_like(x)
        mask[:, i_pos] = (~outside).to(x.dtype)
        mask[:, i_rate] = (~outside).to(x.dtype)
        return x, mask

    def run(self, wts: _Weights, x0, u_grid, u_half, z_grid, z_half, records: list | None, row_steps=None,
            engine: str = "auto"):
        """Integrate; returns states (n+1, B, n_x). ``records`` (a list) receives per step
        (stage records, clamp mask) for the reverse sweep; None runs without them (and, for an FMU, in
        C or NumPy, as ``engine`` allows: "auto" the fastest, "c", "numpy" or "torch" that one where the
        right-hand side offers it; rows from the first non-finite state on are NaN). ``row_steps`` (B,),
        gradient-free only: the steps each row needs; the loop in C holds a row's state after them, the others
        integrate on.

        Raises:
            FloatingPointError: a state became non-finite while recording (training).
        """
        if records is None and self.c_rollout is not None and engine in ("auto", "c"):
            return self._run_c(wts, x0, u_grid, u_half, z_grid, z_half, row_steps)
        if records is None and self.numpy_rhs is not None and engine in ("auto", "numpy"):
            return self._run_numpy(wts, x0, u_grid, u_half, z_grid, z_half)
        n_steps = u_grid.shape[0] - 1
        plan, nodes = self.tableau.plan(self.h), self.tableau.c
        middle = NODE_MIDDLE in nodes
        grid, half = list(zip(u_grid, z_grid)), list(zip(u_half, z_half)) if middle else None
        states = [x0]
        x = x0
        for k in range(n_steps):
            stage_records = [] if records is not None else None

            def derivative(state, i, inputs=node_inputs(grid, half, k), stage_records=stage_records):
                return self._stage(wts, state, *inputs[nodes[i]], stage_records)

            x = plan.step(x, derivative, torch_axpy)
            x, mask = self._apply_clamp(x)
            if records is not None:
                if not bool(torch.isfinite(x).all()):
                    raise FloatingPointError(f"non-finite state after step {k + 1} of {n_steps}")
                records.append((stage_records, mask))
            states.append(x)
        return torch.stack(states, dim=0)

    def _run_c(self, wts: _Weights, x0, u_grid, u_half, z_grid, z_half, row_steps=None) -> torch.Tensor:
        """Gradient-free integration with the whole loop in C (the bridge's ``neural_rollout``); the same
        stages as ``_run_numpy`` (values equal to rounding), without Python per stage."""
        states = self.c_rollout(x0.detach().numpy(), u_grid.detach().numpy(), u_half.detach().numpy(),
                                z_grid.detach().numpy(), z_half.detach().numpy(), _c_weights(wts), self.h,
                                self.method, self.clamp, row_steps)
        return torch.from_numpy(states)

    def _run_numpy(self, wts: _Weights, x0, u_grid, u_half, z_grid, z_half) -> torch.Tensor:
        """Gradient-free integration in NumPy with the FMU's batched derivatives (fewer, cheaper calls).

        The stages reuse preallocated buffers (``out=``); every value is computed by the same operations in
        the same order as with fresh arrays, so the states are the same to the bit.
        """
        n_steps = u_grid.shape[0] - 1
        h = self.h
        batch = x0.shape[0]
        f = numpy_kernel(self.rhs, batch)
        as_np = lambda t: t.detach().numpy()  # noqa: E731
        w_xd, w_out, b_out, g_fmu = as_np(wts.w_xd_t), as_np(wts.w_out), as_np(wts.b_out), as_np(wts.g_fmu)
        hidden = [(as_np(w), as_np(b)) for w, b in wts.hidden]
        u_grid, z_grid = as_np(u_grid), as_np(z_grid)
        u_half, z_half = as_np(u_half), as_np(z_half)
        n_x = x0.shape[1]
        xf = np.empty((batch, 2 * n_x))
        first = np.empty((batch, w_xd.shape[1]))
        layers = [(weight_t, bias, np.empty((batch, weight_t.shape[1]))) for weight_t, bias in hidden]
        matmul, add, tanh = np.matmul, np.add, np.tanh

        def stage(x, u, z):
            xdot_f = f(x, u)
            xf[:, :n_x] = x
            xf[:, n_x:] = xdot_f
            a = tanh(add(matmul(xf, w_xd, out=first), z, out=first), out=first)
            for weight_t, bias, out in layers:
                a = tanh(add(matmul(a, weight_t, out=out), bias, out=out), out=out)
            y = xdot_f * g_fmu
            y += b_out
            y += a @ w_out
            return y

        states = np.full((n_steps + 1,) + tuple(x0.shape), np.nan)
        x = x0.detach().numpy().copy()
        states[0] = x
        plan, nodes = self.tableau.plan(h), self.tableau.c
        grid = list(zip(u_grid, z_grid))
        half = list(zip(u_half, z_half)) if NODE_MIDDLE in nodes else None
        for k in range(n_steps):
            x = plan.step(x, lambda state, i, inputs=node_inputs(grid, half, k): stage(state, *inputs[nodes[i]]),
                          numpy_axpy)
            if self.clamp is not None:
                i_pos, i_rate, lower, upper = self.clamp
                outside = (x[:, i_pos] <= lower) | (x[:, i_pos] >= upper)
                if outside.any():
                    x[:, i_pos] = np.clip(x[:, i_pos], lower, upper)
                    x[outside, i_rate] = 0.0
            if not np.isfinite(x).all():
                break
            states[k + 1] = x
        return torch.from_numpy(states)

    # ------------------------------------------------------------------ reverse sweep
    def _stage_backward(self, wts_t: _Weights, gy, record, acc: "_Accumulator"):
        """Adjoint of one stage; ``wts_t`` holds the transposed weights (``_Weights.transposed``)."""
        xf, xdot_f, activations, rhs_record = record
        n_x = xdot_f.shape[1]
        acc.out_inputs.append(activations[-1])
        acc.out_grads.append(gy)
        acc.fmu_values.append(xdot_f)
        g_h = torch.mm(gy, wts_t.w_out)
        for layer in range(len(activations) - 1, 0, -1):
            h = activations[layer]
            g_a = torch.addcmul(g_h, g_h * h, h, value=-1.0)
            acc.hidden_inputs[layer - 1].append(activations[layer - 1])
            acc.hidden_grads[layer - 1].append(g_a)
            g_h = torch.mm(g_a, wts_t.hidden[layer - 1][0])
        h = activations[0]
        g_a1 = torch.addcmul(g_h, g_h * h, h, value=-1.0)
        acc.first_inputs.append(xf)
        acc.first_grads.append(g_a1)
        g_xf = torch.mm(g_a1, wts_t.w_xd_t)
        g_fmu_out = torch.addcmul(g_xf[:, n_x:], gy, wts_t.g_fmu)
        if len(rhs_record) == 1:
            g_xu = torch.bmm(g_fmu_out.unsqueeze(1), rhs_record[0]).squeeze(1)
            g_x_rhs, g_u = g_xu[:, :n_x], g_xu[:, n_x:]
        else:
            x_leaf, u_leaf, xdot_graph = rhs_record
            g_x_rhs, g_u = torch.autograd.grad(xdot_graph, (x_leaf, u_leaf), g_fmu_out)
        return g_xf[:, :n_x] + g_x_rhs, g_u, g_a1

    def backward(self, wts: _Weights, records, grad_states, n_hidden: int):
        """Reverse sweep. grad_states (n+1, B, n_x) -> grads of x0, u_grid, u_half, z_grid, z_half and
        the weights (w_xd_t, w_out, b_out, g_fmu, hidden...)."""
        n_steps = len(records)
        h = self.h
        acc = _Accumulator(n_hidden)
        wts_t = wts.transposed()
        g_u_grid = grad_states.new_zeros((n_steps + 1,) + tuple(self._u_shape))
        g_z_grid = grad_states.new_zeros((n_steps + 1,) + tuple(self._z_shape))
        nodes = self.tableau.c
        middle = NODE_MIDDLE in nodes
        g_u_half = g_u_grid.new_zeros((n_steps,) + tuple(self._u_shape)) if middle else None
        g_z_half = g_z_grid.new_zeros((n_steps,) + tuple(self._z_shape)) if middle else None
        plan = self.tableau.plan(h)
        lam = grad_states[n_steps].clone()
        for k in range(n_steps - 1, -1, -1):
            stage_records, mask = records[k]
            if mask is not None:
                lam = lam * mask
            input_grads: list = [None] * len(nodes)

            def stage_backward(gy, i, stage_records=stage_records, input_grads=input_grads):
                g_x, g_u, g_z = self._stage_backward(wts_t, gy, stage_records[i], acc)
                input_grads[i] = (g_u, g_z)
                return g_x

            state_grads = plan.adjoint_step(lam, stage_backward, torch_axpy)
            for node, grads_u, grads_z, index in ((NODE_START, g_u_grid, g_z_grid, k),
                                                  (NODE_END, g_u_grid, g_z_grid, k + 1),
                                                  (NODE_MIDDLE, g_u_half, g_z_half, k)):
                at_node = [input_grads[i] for i in range(len(nodes)) if nodes[i] == node]
                if at_node:
                    grads_u[index] += pairwise_sum([g for g, _ in at_node])
                    grads_z[index] += pairwise_sum([g for _, g in at_node])
            lam = lam + pairwise_sum(state_grads) + grad_states[k]
        weight_grads = acc.weight_grads(wts)
        return lam, g_u_grid, g_u_half, g_z_grid, g_z_half, weight_grads


class _Accumulator:
    """Per-stage inputs and output gradients of every layer; summed into weight gradients at the end."""

    def __init__(self, n_hidden: int) -> None:
        self.first_inputs, self.first_grads = [], []
        self.hidden_inputs = [[] for _ in range(n_hidden)]
        self.hidden_grads = [[] for _ in range(n_hidden)]
        self.out_inputs, self.out_grads, self.fmu_values = [], [], []

    @staticmethod
    def _outer(inputs, grads):
        return torch.mm(torch.cat(inputs).t(), torch.cat(grads))

    def weight_grads(self, wts: _Weights):
        gy = torch.cat(self.out_grads)
        g_w_xd_t = self._outer(self.first_inputs, self.first_grads)
        g_w_out = torch.mm(torch.cat(self.out_inputs).t(), gy)
        g_b_out = gy.sum(0)
        g_g_fmu = (torch.cat(self.fmu_values) * gy).sum(0)
        hidden = []
        for inputs, grads in zip(self.hidden_inputs, self.hidden_grads):
            g_a = torch.cat(grads)
            hidden.extend([self._outer(inputs, grads), g_a.sum(0)])
        return [g_w_xd_t, g_w_out, g_b_out, g_g_fmu] + hidden


class _Rollout(torch.autograd.Function):
    @staticmethod
    def forward(ctx, engine: SolverEngine, x0, u_grid, u_half, z_grid, z_half, w_xd_t, w_out, b_out, g_fmu,
                *hidden_flat):
        wts = _Weights(w_xd_t, w_out, b_out, g_fmu, list(zip(hidden_flat[0::2], hidden_flat[1::2])))
        records: list = []
        states = engine.run(wts, x0, u_grid, u_half, z_grid, z_half, records)
        engine._u_shape = u_grid.shape[1:]
        engine._z_shape = z_grid.shape[1:]
        ctx.engine, ctx.wts, ctx.records = engine, wts, records
        ctx.has_half = u_half.numel() > 0
        return states

    @staticmethod
    def backward(ctx, grad_states):
        engine, wts, records = ctx.engine, ctx.wts, ctx.records
        g_x0, g_u_grid, g_u_half, g_z_grid, g_z_half, weight_grads = engine.backward(
            wts, records, grad_states.contiguous(), len(wts.hidden))
        ctx.records = None
        if not ctx.has_half:
            g_u_half = g_z_half = None
        return (None, g_x0, g_u_grid, g_u_half, g_z_grid, g_z_half, *weight_grads)


def _c_weights(wts: _Weights) -> NeuralWeights:
    as_np = lambda t: t.detach().numpy()  # noqa: E731
    return NeuralWeights.from_arrays(as_np(wts.w_xd_t), [(as_np(w), as_np(b)) for w, b in wts.hidden],
                                     as_np(wts.w_out), as_np(wts.b_out), as_np(wts.g_fmu))


def fixed_model_c_rollout(stage: FusedDerivative, h: float, method: str, clamp):
    """The C engine's gradient-free rollout for many calls on a model that does not change between them (a
    closed loop's one-sample steps), or None where the right-hand side has no C rollout or a weight is not float64.

    What ``rollout_adjoint`` does per call on the C engine (the weights flattened, the physical layer's
    coefficients set) is done once here, so a call costs the C loop and the argument checks only; the states
    are the same to the bit.

    Returns:
        ``run(x0 (B, n_x), u_grid (n+1, B, n_u), u_half (n, B, n_u), z_grid (n+1, B, H), z_half (n, B, H))
        -> states (n+1, B, n_x)``, all float64 NumPy arrays.
    """
    c_rollout = neural_rollout_function(stage.rhs)
    hidden_flat = [t for pair in stage.hidden for t in pair]
    weights = (stage.w_xd_t, stage.w_out, stage.b_out, stage.g_fmu, *hidden_flat)
    if c_rollout is None or any(t.dtype != torch.float64 for t in weights):
        return None
    if hasattr(stage.rhs, "apply_coefficients"):
        stage.rhs.apply_coefficients()
    c_weights = _c_weights(_Weights(stage.w_xd_t, stage.w_out, stage.b_out, stage.g_fmu, list(stage.hidden)))

    def run(x0, u_grid, u_half, z_grid, z_half):
        return c_rollout(x0, u_grid, u_half, z_grid, z_half, c_weights, h, method, clamp, None)

    return run


class _ArrayRollout(torch.autograd.Function):
    """``_Rollout`` with an engine working on NumPy arrays. ``make(w_xd_t, hidden, w_out, b_out, g_fmu)`` (the
    fused derivative's weights as arrays, ``hidden`` a list of (weight_t, bias)) returns an object whose
    ``forward(x0, u_grid, u_half, z_grid, z_half)`` integrates and records, and whose ``backward(grad_states)``
    returns (g_x0, g_u_grid, g_u_half, g_z_grid, g_z_half, then the gradients of w_xd_t, w_out, b_out, g_fmu
    and of weight_t and bias per hidden layer). ``coefficients``: the right-hand side's trainable coefficients
    (n_c,) (empty when they are fixed; the object's ``coefficient_gradient`` is their gradient)."""

    @staticmethod
    def forward(ctx, make, x0, u_grid, u_half, z_grid, z_half, coefficients, w_xd_t, w_out, b_out, g_fmu,
                *hidden_flat):
        as_np = lambda t: t.detach().numpy()  # noqa: E731
        hidden = [(as_np(w), as_np(b)) for w, b in zip(hidden_flat[0::2], hidden_flat[1::2])]
        rollout = make(as_np(w_xd_t), hidden, as_np(w_out), as_np(b_out), as_np(g_fmu))
        states = rollout.forward(as_np(x0), as_np(u_grid), as_np(u_half), as_np(z_grid), as_np(z_half))
        ctx.rollout = rollout
        ctx.has_half = u_half.numel() > 0
        ctx.has_coefficients = coefficients.numel() > 0
        return torch.from_numpy(states)

    @staticmethod
    def backward(ctx, grad_states):
        rollout, ctx.rollout = ctx.rollout, None
        g_x0, g_u_grid, g_u_half, g_z_grid, g_z_half, *weight_grads = rollout.backward(
            grad_states.detach().to(torch.float64).contiguous().numpy())
        as_tensor = lambda a: None if a is None else torch.from_numpy(np.ascontiguousarray(a))  # noqa: E731
        if not ctx.has_half:
            g_u_half = g_z_half = None
        g_coefficients = getattr(rollout, "coefficient_gradient", None) if ctx.has_coefficients else None
        return (None, as_tensor(g_x0), as_tensor(g_u_grid), as_tensor(g_u_half), as_tensor(g_z_grid),
                as_tensor(g_z_half), as_tensor(g_coefficients), *(as_tensor(g) for g in weight_grads))


#: Engines of the reverse sweep, fastest first: "c" (forward pass and sweep in C, for an FMU behind the
#: bridge), "numpy" (stages in NumPy through the bridge's derivatives-and-Jacobians kernel), "torch" (stages as
#: torch operations, any right-hand side).
ENGINES = ("c", "numpy", "torch")


def rollout_adjoint(stage: FusedDerivative, h: float, method: str, clamp, x0, u_grid, u_half, z_grid, z_half,
                    engine: str = "auto", row_steps=None):
    """Time-major rollout: inputs u_grid (n+1, B, n_u), u_half (n, B, n_u) (empty for Euler), their first-layer
    terms z_grid, z_half (…, H), x0 (B, n_x) -> states (n+1, B, n_x), differentiable w.r.t. all tensors.

    ``engine``: one of :data:`ENGINES`, or "auto" (the fastest the right-hand side allows). All give the same
    values and gradients to rounding. ``row_steps`` (B,), gradient-free rollouts only: the steps each row needs
    (its states after them are not meaningful). A hybrid whose physical layer's coefficients train
    (``FmuLayer.coefficient_change``) gets their gradients from the NumPy engine.

    Raises:
        ValueError: an unknown engine, or one the right-hand side does not offer (the C and torch engines do not
            train a physical layer's coefficients).
    """
    if engine not in ("auto",) + ENGINES:
        raise ValueError(f"rollout_adjoint: engine must be 'auto' or one of {ENGINES}, got {engine!r}")
    coefficients = stage.rhs.apply_coefficients() if hasattr(stage.rhs, "apply_coefficients") else None
    solver = SolverEngine(stage, h, method, clamp)
    hidden_flat = [t for pair in stage.hidden for t in pair]
    tensors = (x0, u_grid, u_half, z_grid, z_half, stage.w_xd_t, stage.w_out, stage.b_out, stage.g_fmu, *hidden_flat)
    train_coefficients = coefficients is not None and coefficients.requires_grad and torch.is_grad_enabled()
    if not torch.is_grad_enabled() or not (train_coefficients or any(t.requires_grad for t in tensors)):
        wts = _Weights(stage.w_xd_t, stage.w_out, stage.b_out, stage.g_fmu, list(stage.hidden))
        with torch.no_grad():
            return solver.run(wts, x0, u_grid, u_half, z_grid, z_half, None, row_steps, engine)
    float64 = all(t.dtype == torch.float64 for t in tensors)
    if train_coefficients:
        kernel = coefficient_kernel(stage.rhs, x0.shape[0]) if float64 else None
        if engine not in ("auto", "numpy") or kernel is None:
            raise ValueError(f"rollout_adjoint: the physical layer's coefficients train only with the NumPy engine "
                             f"in float64 (engine {engine!r}, float64 {float64})")

        def make_hybrid(w_xd_t, hidden, w_out, b_out, g_fmu):
            weights = NumpyWeights(w_xd_t, w_out, b_out, g_fmu, hidden)
            return NumpyRollout(kernel, weights, solver.h, solver.method, solver.clamp, coefficients=True)
        return _ArrayRollout.apply(make_hybrid, *tensors[:5], coefficients, *tensors[5:])
    no_coefficients = x0.new_zeros(0)
    if engine in ("auto", "c"):
        recorder = neural_recorder_function(stage.rhs) if float64 else None
        if recorder is not None:
            def make_c(w_xd_t, hidden, w_out, b_out, g_fmu):
                weights = NeuralWeights.from_arrays(w_xd_t, hidden, w_out, b_out, g_fmu)
                return recorder(weights, solver.h, solver.method, solver.clamp)
            return _ArrayRollout.apply(make_c, *tensors[:5], no_coefficients, *tensors[5:])
    if engine in ("auto", "numpy"):
        kernel = jacobian_kernel(stage.rhs, x0.shape[0]) if float64 else None
        if kernel is not None:
            def make_numpy(w_xd_t, hidden, w_out, b_out, g_fmu):
                weights = NumpyWeights(w_xd_t, w_out, b_out, g_fmu, hidden)
                return NumpyRollout(kernel, weights, solver.h, solver.method, solver.clamp)
            return _ArrayRollout.apply(make_numpy, *tensors[:5], no_coefficients, *tensors[5:])
    if engine != "auto" and engine != "torch":
        raise ValueError(f"rollout_adjoint: engine {engine!r} needs an FMU-backed right-hand side in float64 "
                         "(the bridge's neural_recorder or derivatives_and_jacobians_kernel)")
    return _Rollout.apply(solver, *tensors)
