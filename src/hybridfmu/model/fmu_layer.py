"""FMU layer: the physical model's state derivative xdot_F = f(x, u) inside the neural FMU."""

from __future__ import annotations

from typing import Callable

import torch
from torch import nn

Rhs = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


class FmuLayer(nn.Module):
    """Wraps a differentiable right-hand side ``rhs(x (N, n_x), u (N, n_u)) -> (N, n_x)``.

    Typically ``hybridfmu.fmu.FmuRhs(model)``; any callable with that signature works (e.g. a small
    pure-torch right-hand side in the tests). The layer has no parameters of its own, except with
    ``train_coefficients``: the model behind ``rhs`` is a hybrid's physical layer
    (``hybridfmu.model.physics.PhysicsModel``) whose additive terms are linear in their coefficients, and the
    layer trains them as ``coefficients = start + scale * coefficient_change`` (``start``: the diagnosed values,
    ``scale``: their magnitudes, 1 for a zero; ``coefficient_change`` (n_c,) starts at zero, so an Adam step of
    size s changes a coefficient by about s of itself).
    """

    def __init__(self, rhs: Rhs, n_states: int, n_inputs: int, train_coefficients: bool = False) -> None:
        super().__init__()
        if not callable(rhs):
            raise TypeError(f"FmuLayer: rhs must be callable, got {type(rhs).__name__}")
        self.rhs = rhs
        self.n_states = int(n_states)
        self.n_inputs = int(n_inputs)
        self.coefficient_change: nn.Parameter | None = None
        if train_coefficients:
            model = getattr(rhs, "model", None)
            if not callable(getattr(model, "set_coefficients", None)):
                raise ValueError(f"FmuLayer: trainable coefficients need a hybrid's physical layer behind rhs, got "
                                 f"{type(model).__name__}")
            start = torch.as_tensor(model.coefficients, dtype=torch.float64)
            self.register_buffer("coefficient_start", start)
            self.register_buffer("coefficient_scale", torch.where(start != 0, start.abs(), torch.ones_like(start)))
            self.coefficient_change = nn.Parameter(torch.zeros_like(start))

    @property
    def physics(self):
        """The model behind ``rhs`` (None for a plain callable)."""
        return getattr(self.rhs, "model", None)

    def coefficients(self) -> torch.Tensor | None:
        """(n_c,) the physical layer's trainable coefficients (differentiable), or None when they are fixed."""
        if self.coefficient_change is None:
            return None
        return self.coefficient_start + self.coefficient_scale * self.coefficient_change

    def apply_coefficients(self) -> torch.Tensor | None:
        """Set the current coefficients on the physical layer (every evaluation path calls this before it
        integrates); returns them (differentiable), or None when they are fixed."""
        values = self.coefficients()
        if values is not None:
            self.physics.set_coefficients(values.detach().to(torch.float64).numpy())
        return values

    def forward(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """x (N, n_x), u (N, n_u) -> xdot_F (N, n_x)."""
        values = self.apply_coefficients()
        xdot = self.rhs(x, u)
        if xdot.shape != x.shape:
            raise ValueError(f"FmuLayer: rhs returned shape {tuple(xdot.shape)}, expected {tuple(x.shape)}")
        if values is not None and values.requires_grad and torch.is_grad_enabled():
            # the terms are linear in the coefficients: adding R (values - values) changes no value and gives
            # the coefficients their gradient R^T g (R = df/dc, detached)
            sensitivity = torch.from_numpy(self.physics.coefficient_jacobian(
                x.detach().to(torch.float64).contiguous().numpy(), u.detach().to(torch.float64).contiguous().numpy()))
            xdot = xdot + torch.einsum("nik,k->ni", sensitivity.to(xdot.dtype), values - values.detach())
        return xdot


JacobianFn = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]


def jacobian_function(rhs: Rhs) -> JacobianFn | None:
    """A function ``(x (N, n_x), u (N, n_u)) -> (xdot (N, n_x), dfdx (N, n_x, n_x), dfdu (N, n_x, n_u))``
    evaluating ``rhs`` and its Jacobians in one go, if ``rhs`` offers them; else None.

    Recognised: an object with ``value_and_jacobians(x, u)``, or one with an attribute ``model`` that has
    the bridge's batched ``derivatives(x, u)`` and ``jacobians(x, u)`` (e.g. ``hybridfmu.fmu.FmuRhs``).
    Without it, gradients through ``rhs`` come from autograd.
    """
    if isinstance(rhs, FmuLayer):
        rhs = rhs.rhs
    method = getattr(rhs, "value_and_jacobians", None)
    if callable(method):
        return method
    model = getattr(rhs, "model", None)
    if model is not None and callable(getattr(model, "derivatives", None)) and callable(
            getattr(model, "jacobians", None)):
        both = getattr(model, "derivatives_and_jacobians", None)  # the bridge's: the arguments checked once

        def value_and_jacobians(x: torch.Tensor, u: torch.Tensor):
            x_np = x.detach().to(torch.float64).contiguous().numpy()
            u_np = u.detach().to(torch.float64).contiguous().numpy()
            if callable(both):
                xdot, dfdx, dfdu = both(x_np, u_np)
            else:
                xdot = model.derivatives(x_np, u_np)
                dfdx, dfdu = model.jacobians(x_np, u_np)
            return torch.from_numpy(xdot), torch.from_numpy(dfdx), torch.from_numpy(dfdu)
        return value_and_jacobians
    return None


def numpy_function(rhs: Rhs):
    """The batched NumPy evaluation ``(x (N, n_x), u (N, n_u)) -> (N, n_x)`` of an FMU-backed ``rhs``
    (the bridge's ``derivatives``), or None for other right-hand sides."""
    if isinstance(rhs, FmuLayer):
        rhs = rhs.rhs
    model = getattr(rhs, "model", None)
    if model is not None and callable(getattr(model, "derivatives", None)):
        return model.derivatives
    return None


def numpy_kernel(rhs: Rhs, n: int):
    """Like :func:`numpy_function` for many calls on batches of ``n`` rows: the bridge's
    ``derivatives_kernel(n)`` when it has one (its result is overwritten by the next call), else its
    ``derivatives``; None for right-hand sides that are not FMU-backed."""
    if isinstance(rhs, FmuLayer):
        rhs = rhs.rhs
    model = getattr(rhs, "model", None)
    kernel = getattr(model, "derivatives_kernel", None)
    if callable(kernel):
        return kernel(n)
    return numpy_function(rhs)


def value_function(rhs: Rhs) -> Rhs:
    """A gradient-free evaluation of ``rhs`` (the bridge's batched ``derivatives`` when available)."""
    if isinstance(rhs, FmuLayer):
        rhs = rhs.rhs
    model = getattr(rhs, "model", None)
    if model is not None and callable(getattr(model, "derivatives", None)):
        return lambda x, u: torch.from_numpy(model.derivatives(
            x.to(torch.float64).contiguous().numpy(), u.to(torch.float64).contiguous().numpy()))
    return rhs


def coefficient_kernel(rhs: Rhs, n: int):
    """The physical layer's ``coefficient_kernel(n)`` behind ``rhs`` (an :class:`FmuLayer` whose coefficients
    train): ``(x, u) -> (xdot, dfdx, dfdu, df/dc (n, n_x, n_c))``; None otherwise."""
    if not isinstance(rhs, FmuLayer) or rhs.coefficient_change is None:
        return None
    kernel = getattr(rhs.physics, "coefficient_kernel", None)
    return kernel(n) if callable(kernel) else None


def jacobian_kernel(rhs: Rhs, n: int):
    """The bridge's ``derivatives_and_jacobians_kernel(n)`` behind an FMU-backed ``rhs``: a NumPy function
    ``(x (n, n_x), u (n, n_u)) -> (xdot (n, n_x), dfdx (n, n_x, n_x), dfdu (n, n_x, n_u))`` whose results are
    overwritten by its next call; None for right-hand sides without one (they take the torch path)."""
    if isinstance(rhs, FmuLayer):
        rhs = rhs.rhs
    kernel = getattr(getattr(rhs, "model", None), "derivatives_and_jacobians_kernel", None)
    return kernel(n) if callable(kernel) else None


def neural_rollout_function(rhs: Rhs):
    """The bridge's ``neural_rollout`` (a neural FMU's gradient-free rollout in C) behind an FMU-backed ``rhs``,
    or None for other right-hand sides."""
    if isinstance(rhs, FmuLayer):
        rhs = rhs.rhs
    method = getattr(getattr(rhs, "model", None), "neural_rollout", None)
    return method if callable(method) else None


def neural_recorder_function(rhs: Rhs):
    """The bridge's ``neural_recorder`` (a neural FMU's training rollout and reverse sweep in C) behind an
    FMU-backed ``rhs``, or None for other right-hand sides."""
    if isinstance(rhs, FmuLayer):
        rhs = rhs.rhs
    method = getattr(getattr(rhs, "model", None), "neural_recorder", None)
    return method if callable(method) else None
