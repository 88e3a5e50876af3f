"""The FMU's right-hand side as a differentiable PyTorch operation.

``FmuRhs(model)(x, u)`` evaluates the batched derivatives in the FMU (float64 inside, the
result cast back to the dtype of ``x``). Its backward pass forms vector-Jacobian products
with the batched Jacobians (directional derivatives, or finite differences for FMUs without
them), which are computed only when a gradient is actually requested.
"""

from __future__ import annotations

import numpy as np
import torch

from hybridfmu.fmu.bridge import FmuModel


def _to_numpy64(tensor: torch.Tensor) -> np.ndarray:
    """A C-contiguous float64 NumPy view of ``tensor`` (copied only when dtype/layout/device demand)."""
    return tensor.detach().to(device="cpu", dtype=torch.float64).contiguous().numpy()


def _time_argument(t_s):
    if isinstance(t_s, torch.Tensor):
        if t_s.requires_grad:
            raise ValueError("t_s: gradients with respect to time are not supported; pass a detached tensor")
        t_s = _to_numpy64(t_s).reshape(-1) if t_s.ndim else float(t_s)
    return t_s


class _FmuRhsFunction(torch.autograd.Function):
    """dx = f(x, u) through the FMU; backward: g^T df/dx and g^T df/du."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, u: torch.Tensor, model: FmuModel, t_s):
        x64, u64 = _to_numpy64(x), _to_numpy64(u)
        dx = model.derivatives(x64, u64, t_s)
        ctx.model, ctx.t_s = model, t_s
        ctx.save_for_backward(x, u)
        return torch.from_numpy(dx).to(device=x.device, dtype=x.dtype)

    @staticmethod
    def backward(ctx, grad_dx: torch.Tensor):
        x, u = ctx.saved_tensors
        need_x, need_u = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        if not (need_x or need_u):
            return None, None, None, None
        dfdx, dfdu = ctx.model.jacobians(_to_numpy64(x), _to_numpy64(u), ctx.t_s)
        g = _to_numpy64(grad_dx)
        grad_x = grad_u = None
        if need_x:
            grad_x = torch.from_numpy(np.einsum("ni,nij->nj", g, dfdx)).to(device=x.device, dtype=x.dtype)
        if need_u:
            grad_u = torch.from_numpy(np.einsum("ni,nik->nk", g, dfdu)).to(device=u.device, dtype=u.dtype)
        return grad_x, grad_u, None, None


#: What a model other than an FmuModel must offer to stand behind :class:`FmuRhs` (e.g. the physical layer
#: of a hybrid, ``hybridfmu.model.physics.PhysicsModel``).
MODEL_INTERFACE = ("state_names", "input_names", "n_states", "n_inputs", "model_name", "derivatives", "jacobians")


class FmuRhs(torch.nn.Module):
    """Differentiable right-hand side of an FMU: ``rhs(x, u, t_s=0.0) -> dx``.

    x: (..., n_x) states, u: (..., n_u) inputs with the same leading dimensions (None for an
    FMU without inputs), t_s: time in s (scalar, or one per row of the flattened batch).
    Returns dx/dt with the shape, dtype and device of ``x``. float32 inputs are evaluated in
    float64 inside. Gradients flow to x and u through the FMU's Jacobians. The module holds no
    parameters; the FMU's parameters are set on the model (``model.set_parameters``).
    """

    def __init__(self, model: FmuModel):
        super().__init__()
        if not isinstance(model, FmuModel) and not all(hasattr(model, name) for name in MODEL_INTERFACE):
            raise ValueError(f"model: expected an FmuModel (from load_fmu) or a model with its batched interface "
                             f"({', '.join(MODEL_INTERFACE)}), got {type(model).__name__}")
        self.model = model

    def forward(self, x: torch.Tensor, u: torch.Tensor | None = None, t_s=0.0) -> torch.Tensor:
        model = self.model
        if not isinstance(x, torch.Tensor):
            raise ValueError(f"x: expected a torch.Tensor of shape (..., {model.n_states}), got {type(x).__name__}")
        if not (x.is_floating_point() and x.shape and x.shape[-1] == model.n_states):
            raise ValueError(
                f"x: expected a floating-point tensor of shape (..., {model.n_states}) "
                f"({model.state_names}), got shape {tuple(x.shape)}, dtype {x.dtype}"
            )
        lead = x.shape[:-1]
        if u is None:
            if model.n_inputs:
                raise ValueError(f"u: the FMU has inputs {model.input_names}; expected a tensor of shape "
                                 f"{(*lead, model.n_inputs)}, got None")
            u = x.new_zeros((*lead, 0))
        if not isinstance(u, torch.Tensor):
            raise ValueError(f"u: expected a torch.Tensor of shape {(*lead, model.n_inputs)}, got {type(u).__name__}")
        if not u.is_floating_point() or tuple(u.shape) != (*lead, model.n_inputs):
            raise ValueError(f"u: expected a floating-point tensor of shape {(*lead, model.n_inputs)} "
                             f"({model.input_names}), got shape {tuple(u.shape)}, dtype {u.dtype}")
        x2 = x.reshape(-1, model.n_states)
        u2 = u.reshape(x2.shape[0], model.n_inputs)
        dx = _FmuRhsFunction.apply(x2, u2, model, _time_argument(t_s))
        return dx.reshape(x.shape)

    def extra_repr(self) -> str:
        return f"model={self.model.model_name!r}, states={self.model.state_names}, inputs={self.model.input_names}"
