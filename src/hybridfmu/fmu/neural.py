"""A neural FMU's rollout on the sample grid with the whole loop in C (``shim.c``: ``hf_neural_*``).

The neural FMU is given in its fused form (``hybridfmu.model.neural_fmu.FusedDerivative``): per solver stage,
with f = the FMU's derivatives at (x, u) and t = 0,

    a_0 = tanh(z + [x, f] W_xd),   a_l = tanh(b_l + a_(l-1) W_l),   dx/dt = f * g + b_out + a_L W_out,

where z = u W_u + b_0 is the first layer's input term, computed outside for all samples at once. Inputs are
time-major: x0 (B, n_x), u_grid (n + 1, B, n_u) at the sample instants, u_half (n, B, n_u) at the steps'
middles (RK4 only), z_grid (n + 1, B, H_0), z_half (n, B, H_0). An optional end stop (position index, rate
index, lower, upper) clamps the position after a step and zeroes its rate.

:func:`rollout` integrates without gradients (validation, inference); :class:`RecordedRollout` records each
stage (the states and FMU derivatives entering the MLP, the FMU's Jacobians, the activations) and runs the
discrete adjoint of the solver over them (training). ``benchmarks/train_step.py`` compares them with the
NumPy and torch stages of ``hybridfmu.training``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

#: hf_neural_forward_record's Jacobian methods.
_JACOBIAN_METHODS = {"directional": 1, "fd": 2}


@dataclass(frozen=True)
class NeuralWeights:
    """The fused derivative's weights as one float64 vector (the C layout) and the layer widths H_0..H_L.

    ``params``: W_xd (2 n_x, H_0), per hidden layer W_l (H_(l-1), H_l) and b_l (H_l), W_out (H_L, n_x),
    b_out (n_x,), g (n_x,), each row-major.
    """

    widths: tuple[int, ...]
    params: np.ndarray

    @classmethod
    def from_arrays(cls, w_xd_t: np.ndarray, hidden: Sequence[tuple[np.ndarray, np.ndarray]], w_out: np.ndarray,
                    b_out: np.ndarray, g_fmu: np.ndarray) -> "NeuralWeights":
        """From the fused derivative's arrays: w_xd_t (2 n_x, H_0), hidden [(weight_t (H_(l-1), H_l), bias)],
        w_out (H_L, n_x), b_out (n_x,), g_fmu (n_x,)."""
        parts = [w_xd_t]
        for weight_t, bias in hidden:
            parts.extend([weight_t, bias])
        parts.extend([w_out, b_out, g_fmu])
        params = np.concatenate([np.asarray(part, dtype=np.float64).reshape(-1) for part in parts])
        widths = (int(w_xd_t.shape[1]),) + tuple(int(weight_t.shape[1]) for weight_t, _ in hidden)
        return cls(widths, params)

    def size(self, n_x: int) -> int:
        """The length ``params`` must have for n_x states."""
        widths = self.widths
        hidden = sum(a * b + b for a, b in zip(widths[:-1], widths[1:]))
        return 2 * n_x * widths[0] + hidden + widths[-1] * n_x + 2 * n_x

    def split(self, vector: np.ndarray, n_x: int) -> list[np.ndarray]:
        """``vector`` (the layout of ``params``, e.g. its gradient) as arrays in the order w_xd_t, w_out, b_out,
        g_fmu, then weight_t and bias of each hidden layer."""
        widths, offset = self.widths, 0

        def take(*shape: int) -> np.ndarray:
            nonlocal offset
            count = int(np.prod(shape))
            part = vector[offset:offset + count].reshape(shape)
            offset += count
            return part

        w_xd_t = take(2 * n_x, widths[0])
        hidden = []
        for a, b in zip(widths[:-1], widths[1:]):
            hidden.extend([take(a, b), take(b)])
        w_out, b_out, g_fmu = take(widths[-1], n_x), take(n_x), take(n_x)
        return [w_xd_t, w_out, b_out, g_fmu, *hidden]


def _checked(model, x0, u_grid, u_half, z_grid, z_half, weights: NeuralWeights, method: str):
    """The arguments as C-contiguous float64 arrays, checked against the FMU's sizes and each other."""
    model._require_open()
    if method not in ("rk4", "euler"):
        raise ValueError(f"neural rollout: method must be 'rk4' or 'euler', got {method!r}")
    nx, nu = model.n_states, model.n_inputs
    if not weights.widths or len(weights.widths) > 64:
        raise ValueError(f"neural rollout: 1 to 64 layers expected, got widths {list(weights.widths)}")
    x0 = np.ascontiguousarray(x0, dtype=np.float64)
    if x0.ndim != 2 or x0.shape[1] != nx:
        raise ValueError(f"neural rollout: x0 has shape {x0.shape}, expected (B, {nx})")
    batch = x0.shape[0]
    u_grid = np.ascontiguousarray(u_grid, dtype=np.float64)
    if u_grid.ndim != 3 or u_grid.shape[1:] != (batch, nu) or u_grid.shape[0] < 1:
        raise ValueError(f"neural rollout: u_grid has shape {u_grid.shape}, expected (n + 1, {batch}, {nu})")
    n_steps, h0 = u_grid.shape[0] - 1, weights.widths[0]
    z_grid = np.ascontiguousarray(z_grid, dtype=np.float64)
    if z_grid.shape != (n_steps + 1, batch, h0):
        raise ValueError(f"neural rollout: z_grid has shape {z_grid.shape}, expected {(n_steps + 1, batch, h0)}")
    if method == "rk4":
        u_half = np.ascontiguousarray(u_half, dtype=np.float64)
        z_half = np.ascontiguousarray(z_half, dtype=np.float64)
        if u_half.shape != (n_steps, batch, nu) or z_half.shape != (n_steps, batch, h0):
            raise ValueError(f"neural rollout: u_half/z_half have shapes {u_half.shape}/{z_half.shape}, "
                             f"expected {(n_steps, batch, nu)}/{(n_steps, batch, h0)}")
    else:
        u_half = z_half = np.empty(1)
    if weights.params.shape != (weights.size(nx),):
        raise ValueError(f"neural rollout: params has shape {weights.params.shape}, expected "
                         f"({weights.size(nx)},) for widths {list(weights.widths)}")
    for name, array in (("x0", x0), ("u_grid", u_grid)) + ((("u_half", u_half),) if method == "rk4" else ()):
        if not np.isfinite(array).all():
            raise ValueError(f"neural rollout: {name} has non-finite values")
    return x0, u_grid, u_half, z_grid, z_half, n_steps, batch


def _address(array: np.ndarray) -> int:
    return array.ctypes.data if array.size else 0


def _clamp_arguments(clamp) -> tuple[int, int, float, float]:
    if clamp is None:
        return -1, -1, 0.0, 0.0
    i_pos, i_rate, lower, upper = clamp
    return int(i_pos), int(i_rate), float(lower), float(upper)


def rollout(model, x0, u_grid, u_half, z_grid, z_half, weights: NeuralWeights, h_s: float, method: str,
            clamp: tuple[int, int, float, float] | None = None, row_steps=None) -> np.ndarray:
    """Gradient-free rollout around ``model`` (an open ``hybridfmu.fmu.FmuModel``).

    ``row_steps``: optional (B,) number of steps each row needs (at most n); a row's state is held after them
    (e.g. segments of different lengths side by side).

    Returns:
        states (n + 1, B, n_x); the rows from the first step with a non-finite state on are NaN.

    Raises:
        ValueError: a shape does not fit, or x0 or an input is not finite.
        FmuNonFiniteError, FmuError: the FMU returned a non-finite derivative or failed.
    """
    x0, u_grid, u_half, z_grid, z_half, n_steps, batch = _checked(model, x0, u_grid, u_half, z_grid, z_half,
                                                                  weights, method)
    nx = model.n_states
    steps = None
    if row_steps is not None:
        steps = np.ascontiguousarray(row_steps, dtype=np.int64)
        if steps.shape != (batch,) or (steps < 0).any() or (steps > n_steps).any():
            raise ValueError(f"neural rollout: row_steps must be {batch} integers in [0, {n_steps}], got {row_steps}")
        steps = steps.astype(np.uintp)
    widths = np.asarray(weights.widths, dtype=np.uintp)
    states = np.full((n_steps + 1, batch, nx), np.nan)
    work = np.empty(6 * nx + batch * nx + sum(weights.widths))
    done = np.zeros(1, dtype=np.uintp)
    status = model._lib.hf_neural_rollout(
        model._m, n_steps, batch, float(h_s), int(method == "rk4"), x0.ctypes.data, u_grid.ctypes.data,
        _address(u_half), _address(z_grid), _address(z_half), len(weights.widths), widths.ctypes.data,
        weights.params.ctypes.data, *_clamp_arguments(clamp), states.ctypes.data, work.ctypes.data,
        done.ctypes.data, steps.ctypes.data if steps is not None and batch else 0)
    if status:
        model._raise_shim_error(status, "neural FMU rollout")
    states[int(done[0]) + 1:] = np.nan
    return states


class RecordedRollout:
    """A training rollout around ``model`` that keeps what its reverse sweep needs.

    Args:
        model: an open ``hybridfmu.fmu.FmuModel``; its Jacobians come from directional derivatives where it
            provides them, else from central finite differences (its ``jacobian_method``).
        weights: the fused derivative's weights. h_s: step size (s). method: "rk4" or "euler".
        clamp: optional end stop (position index, rate index, lower, upper).
    """

    def __init__(self, model, weights: NeuralWeights, h_s: float, method: str,
                 clamp: tuple[int, int, float, float] | None = None) -> None:
        self.model, self.weights, self.h_s, self.method, self.clamp = model, weights, float(h_s), method, clamp
        self.jacobian_method = model._resolved_jacobian_method()

    def forward(self, x0, u_grid, u_half, z_grid, z_half) -> np.ndarray:
        """Integrate and record; returns states (n + 1, B, n_x).

        Raises:
            FloatingPointError: a state became non-finite (``FmuNonFiniteError`` if the FMU's derivative did).
        """
        model, weights = self.model, self.weights
        x0, u_grid, u_half, z_grid, z_half, n_steps, batch = _checked(model, x0, u_grid, u_half, z_grid, z_half,
                                                                      weights, self.method)
        nx, nu = model.n_states, model.n_inputs
        n_records = n_steps * (4 if self.method == "rk4" else 1)
        self.shape = (n_steps, batch, nx, nu)
        self.xf = np.empty((n_records, batch, 2 * nx))
        self.jac = np.empty((n_records, batch, nx, nx + nu))
        self.act = np.empty((n_records, batch, sum(weights.widths)))
        self.clamped = np.zeros((n_steps, batch), dtype=np.uint8)
        self.widths = np.asarray(weights.widths, dtype=np.uintp)
        states = np.empty((n_steps + 1, batch, nx))
        work = np.empty(7 * nx + nx * (nx + nu) + batch * nx + sum(weights.widths))
        done = np.zeros(1, dtype=np.uintp)
        rel = float(model.fd_relative_step)
        if self.jacobian_method == "fd" and not (np.isfinite(rel) and 0 < rel < 1):
            raise ValueError(f"fd_relative_step: expected a number in (0, 1), got {model.fd_relative_step}")
        status = model._lib.hf_neural_forward_record(
            model._m, n_steps, batch, self.h_s, int(self.method == "rk4"), x0.ctypes.data, u_grid.ctypes.data,
            _address(u_half), _address(z_grid), _address(z_half), len(weights.widths), self.widths.ctypes.data,
            weights.params.ctypes.data, *_clamp_arguments(self.clamp), states.ctypes.data, work.ctypes.data,
            done.ctypes.data, _JACOBIAN_METHODS[self.jacobian_method], model.state_nominals.ctypes.data,
            _address(model.input_nominals) or model._empty.ctypes.data, rel, _address(self.xf), _address(self.jac),
            _address(self.act), _address(self.clamped))
        if status:
            model._raise_shim_error(status, "neural FMU rollout (training)")
        if int(done[0]) < n_steps:
            raise FloatingPointError(f"non-finite state after step {int(done[0]) + 1} of {n_steps}")
        return states

    def backward(self, grad_states: np.ndarray):
        """Reverse sweep for grad_states (n + 1, B, n_x) = dL/dstates.

        Returns:
            (g_x0 (B, n_x), g_u_grid (n + 1, B, n_u), g_u_half (n, B, n_u) or None for Euler,
            g_z_grid (n + 1, B, H_0), g_z_half or None, then the weight gradients in the order of
            :meth:`NeuralWeights.split`).
        """
        n_steps, batch, nx, nu = self.shape
        grad_states = np.ascontiguousarray(grad_states, dtype=np.float64)
        if grad_states.shape != (n_steps + 1, batch, nx):
            raise ValueError(f"neural rollout backward: grad_states has shape {grad_states.shape}, expected "
                             f"{(n_steps + 1, batch, nx)}")
        rk4 = self.method == "rk4"
        h0 = self.weights.widths[0]
        g_x0 = np.empty((batch, nx))
        g_u_grid, g_z_grid = np.zeros((n_steps + 1, batch, nu)), np.zeros((n_steps + 1, batch, h0))
        g_u_half = np.zeros((n_steps, batch, nu)) if rk4 else None
        g_z_half = np.zeros((n_steps, batch, h0)) if rk4 else None
        g_params = np.zeros_like(self.weights.params)
        work = np.empty(10 * nx + 2 * max(self.weights.widths))
        i_pos, i_rate, _, _ = _clamp_arguments(self.clamp)
        status = self.model._lib.hf_neural_backward(
            nx, nu, n_steps, batch, self.h_s, int(rk4), len(self.weights.widths), self.widths.ctypes.data,
            self.weights.params.ctypes.data, _address(self.xf), _address(self.jac), _address(self.act),
            _address(self.clamped), i_pos, i_rate, grad_states.ctypes.data, g_x0.ctypes.data, _address(g_u_grid),
            _address(g_u_half) if rk4 else 0, _address(g_z_grid), _address(g_z_half) if rk4 else 0,
            g_params.ctypes.data, work.ctypes.data)
        if status:
            raise MemoryError(f"neural rollout backward: status {status}")
        self.xf = self.jac = self.act = None
        return (g_x0, g_u_grid, g_u_half, g_z_grid, g_z_half, *self.weights.split(g_params, nx))
