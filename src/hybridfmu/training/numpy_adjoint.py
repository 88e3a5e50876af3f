"""The training rollout of an FMU-backed neural FMU and its discrete adjoint, in NumPy.

Same stages, values and gradients as ``adjoint.SolverEngine`` (to rounding), for right-hand sides that are
an FMU behind the bridge: each solver stage calls the bridge's ``derivatives_and_jacobians_kernel`` once
(values and Jacobians at once, buffers reused) and the MLP runs on preallocated NumPy arrays, so a stage
costs a few microseconds of Python per operation instead of a torch dispatch per operation.
``benchmarks/train_step.py`` prints both engines side by side.

Records are kept per stage ``j = k * S + s`` (step k, stage s of S = 4 for RK4, 1 for Euler); the weight
gradients are summed over all stages with one matrix product per layer at the end.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybridfmu import runge_kutta
from hybridfmu.runge_kutta import NODE_END, NODE_MIDDLE, NODE_START, node_inputs, numpy_axpy, pairwise_sum


@dataclass(frozen=True)
class NumpyWeights:
    """The fused derivative's weights as float64 arrays (``FusedDerivative``'s layout):
    w_xd_t (2 n_x, H0), w_out (H_L, n_x), b_out (n_x,), g_fmu (n_x,), hidden [(weight_t (H_i, H_i+1), bias)]."""

    w_xd_t: np.ndarray
    w_out: np.ndarray
    b_out: np.ndarray
    g_fmu: np.ndarray
    hidden: list[tuple[np.ndarray, np.ndarray]]


class NumpyRollout:
    """One recorded rollout (``forward``) and its reverse sweep (``backward``).

    Args:
        kernel: the bridge's ``derivatives_and_jacobians_kernel(B)``; with ``coefficients``, a kernel that also
            returns df/dc (B, n_x, n_c) (a hybrid's physical layer's ``coefficient_kernel(B)``).
        weights: the fused derivative's weights (:class:`NumpyWeights`).
        h: step size (s). method: "rk4" or "euler".
        clamp: optional end stop (position index, rate index, lower, upper).
        coefficients: whether the right-hand side's coefficients train (then ``backward`` also sets
            :attr:`coefficient_gradient`, (n_c,)).
    """

    def __init__(self, kernel, weights: NumpyWeights, h: float, method: str,
                 clamp: tuple[int, int, float, float] | None, coefficients: bool = False) -> None:
        self.kernel, self.w, self.h, self.clamp = kernel, weights, float(h), clamp
        self.tableau = runge_kutta.tableau(method)
        self.stages = self.tableau.stages
        self.masks: dict[int, np.ndarray] = {}
        self.coefficients = bool(coefficients)
        self.sensitivity: np.ndarray | None = None
        self.coefficient_gradient: np.ndarray | None = None

    # ------------------------------------------------------------------ forward
    def _allocate(self, n_steps: int, batch: int, n_x: int, n_u: int) -> None:
        n_records = n_steps * self.stages
        widths = [self.w.w_xd_t.shape[1]] + [weight_t.shape[1] for weight_t, _ in self.w.hidden]
        self.xf = np.empty((n_records, batch, 2 * n_x))
        self.jac = np.empty((n_records, batch, n_x, n_x + n_u))
        self.sensitivity = None
        self.act = [np.empty((n_records, batch, width)) for width in widths]
        self.n_x, self.n_u = n_x, n_u

    def _stage(self, j: int, x: np.ndarray, u: np.ndarray, z: np.ndarray) -> np.ndarray:
        n_x, w = self.n_x, self.w
        if self.coefficients:
            xdot, dfdx, dfdu, dfdc = self.kernel(x, u)
            if self.sensitivity is None:
                self.sensitivity = np.empty((self.xf.shape[0],) + dfdc.shape)
            self.sensitivity[j] = dfdc
        else:
            xdot, dfdx, dfdu = self.kernel(x, u)
        xf = self.xf[j]
        xf[:, :n_x] = x
        xf[:, n_x:] = xdot
        jac = self.jac[j]
        jac[:, :, :n_x] = dfdx
        jac[:, :, n_x:] = dfdu
        a = self.act[0][j]
        np.matmul(xf, w.w_xd_t, out=a)
        a += z
        np.tanh(a, out=a)
        for layer, (weight_t, bias) in enumerate(w.hidden, start=1):
            out = self.act[layer][j]
            np.matmul(a, weight_t, out=out)
            out += bias
            np.tanh(out, out=out)
            a = out
        y = xf[:, n_x:] * w.g_fmu
        y += w.b_out
        y += a @ w.w_out
        return y

    def _apply_clamp(self, k: int, x: np.ndarray) -> None:
        i_pos, i_rate, lower, upper = self.clamp
        outside = (x[:, i_pos] <= lower) | (x[:, i_pos] >= upper)
        if not outside.any():
            return
        x[:, i_pos] = np.clip(x[:, i_pos], lower, upper)
        x[outside, i_rate] = 0.0
        mask = np.ones_like(x)
        mask[:, i_pos] = ~outside
        mask[:, i_rate] = ~outside
        self.masks[k] = mask

    def forward(self, x0: np.ndarray, u_grid: np.ndarray, u_half: np.ndarray, z_grid: np.ndarray,
                z_half: np.ndarray) -> np.ndarray:
        """Integrate from x0 (B, n_x) with inputs u_grid (n+1, B, n_u), u_half (n, B, n_u) (RK4) and their
        first-layer terms z_grid, z_half (..., H0); returns states (n+1, B, n_x).

        Raises:
            FloatingPointError: a state became non-finite.
        """
        n_steps = u_grid.shape[0] - 1
        batch, n_x = x0.shape
        self._allocate(n_steps, batch, n_x, u_grid.shape[2])
        plan, nodes, n_stages = self.tableau.plan(self.h), self.tableau.c, self.stages
        grid = list(zip(u_grid, z_grid))
        half = list(zip(u_half, z_half)) if NODE_MIDDLE in nodes else None
        states = np.empty((n_steps + 1, batch, n_x))
        states[0] = x0
        x = states[0]
        stage, isfinite = self._stage, np.isfinite
        for k in range(n_steps):
            states[k + 1] = plan.step(x, lambda state, i, first=n_stages * k, inputs=node_inputs(grid, half, k):
                                      stage(first + i, state, *inputs[nodes[i]]), numpy_axpy)
            nxt = states[k + 1]
            if self.clamp is not None:
                self._apply_clamp(k, nxt)
            if not isfinite(nxt).all():
                raise FloatingPointError(f"non-finite state after step {k + 1} of {n_steps}")
            x = nxt
        return states

    # ------------------------------------------------------------------ reverse sweep
    def _stage_backward(self, j: int, gy: np.ndarray) -> np.ndarray:
        """Adjoint of stage j for the output gradient gy (B, n_x); returns the state gradient (B, n_x) and
        stores the layers' gradients and the input gradient of the stage."""
        n_x, w = self.n_x, self.w
        self.gy[j] = gy
        g_h = gy @ self.w_out_t
        for layer in range(len(w.hidden), 0, -1):
            a = self.act[layer][j]
            g_a = self.ga[layer][j]
            np.multiply(g_h, a, out=g_a)
            g_a *= a
            np.subtract(g_h, g_a, out=g_a)
            g_h = g_a @ self.hidden_t[layer - 1]
        a = self.act[0][j]
        g_a = self.ga[0][j]
        np.multiply(g_h, a, out=g_a)
        g_a *= a
        np.subtract(g_h, g_a, out=g_a)
        g_xf = g_a @ self.w_xd
        g_fmu_out = gy * self.w.g_fmu
        g_fmu_out += g_xf[:, n_x:]
        if self.coefficients:
            self.g_fmu[j] = g_fmu_out
        g_xu = np.matmul(g_fmu_out[:, None, :], self.jac[j])[:, 0, :]
        self.gu[j] = g_xu[:, n_x:]
        g_x = g_xf[:, :n_x]
        g_x += g_xu[:, :n_x]
        return g_x

    def backward(self, grad_states: np.ndarray):
        """Reverse sweep for grad_states (n+1, B, n_x) = dL/dstates. Returns (g_x0 (B, n_x), g_u_grid,
        g_u_half (None for Euler), g_z_grid, g_z_half (None for Euler), weight gradients in the order
        w_xd_t, w_out, b_out, g_fmu, then weight_t and bias of each hidden layer)."""
        n_records = self.xf.shape[0]
        n_steps = n_records // self.stages
        batch = self.xf.shape[1]
        w, plan, n_stages = self.w, self.tableau.plan(self.h), self.stages
        self.w_out_t = np.ascontiguousarray(w.w_out.T)
        self.w_xd = np.ascontiguousarray(w.w_xd_t.T)
        self.hidden_t = [np.ascontiguousarray(weight_t.T) for weight_t, _ in w.hidden]
        self.gy = np.empty((n_records, batch, self.n_x))
        self.gu = np.empty((n_records, batch, self.n_u))
        self.ga = [np.empty_like(a) for a in self.act]
        self.g_fmu = np.empty((n_records, batch, self.n_x)) if self.coefficients else None
        lam = grad_states[n_steps].copy()
        back = self._stage_backward
        for k in range(n_steps - 1, -1, -1):
            mask = self.masks.get(k)
            if mask is not None:
                lam *= mask
            lam += pairwise_sum(plan.adjoint_step(lam, lambda gy, i, first=n_stages * k: back(first + i, gy),
                                                  numpy_axpy))
            lam += grad_states[k]
        if self.coefficients:  # sum over stages and rows of g_F^T df/dc
            self.coefficient_gradient = np.einsum("jbi,jbic->c", self.g_fmu, self.sensitivity)
        return (lam, *self._input_gradients(n_steps), *self._weight_gradients())

    def _input_gradients(self, n_steps: int):
        """Gradients of u_grid (n+1, B, n_u), u_half, z_grid (n+1, B, H0), z_half from the stages'."""
        gu, gz = self.gu, self.ga[0]
        nodes, n_stages = self.tableau.c, self.stages
        g_u_grid = np.zeros((n_steps + 1,) + gu.shape[1:])
        g_z_grid = np.zeros((n_steps + 1,) + gz.shape[1:])
        half = {}
        for node, grid_steps in ((NODE_START, slice(None, -1)), (NODE_END, slice(1, None)), (NODE_MIDDLE, None)):
            members = [i for i in range(n_stages) if nodes[i] == node]
            if not members:
                continue
            node_u = pairwise_sum([gu[i::n_stages] for i in members])
            node_z = pairwise_sum([gz[i::n_stages] for i in members])
            if grid_steps is None:
                half = {"u": node_u, "z": node_z}
            else:
                g_u_grid[grid_steps] += node_u
                g_z_grid[grid_steps] += node_z
        return g_u_grid, half.get("u"), g_z_grid, half.get("z")

    def _weight_gradients(self) -> list[np.ndarray]:
        def flat(array: np.ndarray) -> np.ndarray:
            return array.reshape(-1, array.shape[-1])

        n_x = self.n_x
        gy = flat(self.gy)
        grads = [flat(self.xf).T @ flat(self.ga[0]), flat(self.act[-1]).T @ gy, gy.sum(0),
                 (flat(self.xf)[:, n_x:] * gy).sum(0)]
        for layer in range(1, len(self.act)):
            g_a = flat(self.ga[layer])
            grads.extend([flat(self.act[layer - 1]).T @ g_a, g_a.sum(0)])
        return grads
