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
        self.stages = 4 if method == "rk4" else 1
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
        h = self.h
        states = np.empty((n_steps + 1, batch, n_x))
        states[0] = x0
        x = states[0]
        stage, isfinite = self._stage, np.isfinite
        for k in range(n_steps):
            if self.stages == 4:
                j = 4 * k
                k1 = stage(j, x, u_grid[k], z_grid[k])
                k2 = stage(j + 1, x + (0.5 * h) * k1, u_half[k], z_half[k])
                k3 = stage(j + 2, x + (0.5 * h) * k2, u_half[k], z_half[k])
                k4 = stage(j + 3, x + h * k3, u_grid[k + 1], z_grid[k + 1])
                k1 += k4
                k2 += k3
                nxt = states[k + 1]
                np.multiply(k1, h / 6.0, out=nxt)
                nxt += x
                nxt += (h / 3.0) * k2
            else:
                nxt = states[k + 1]
                np.multiply(stage(k, x, u_grid[k], z_grid[k]), h, out=nxt)
                nxt += x
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
        w, h = self.w, self.h
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
            if self.stages == 4:
                j = 4 * k
                lam_sixth, lam_third = lam * (h / 6.0), lam * (h / 3.0)
                gx4 = back(j + 3, lam_sixth)
                gx3 = back(j + 2, lam_third + h * gx4)
                gx2 = back(j + 1, lam_third + (0.5 * h) * gx3)
                gx1 = back(j, lam_sixth + (0.5 * h) * gx2)
                gx1 += gx2
                gx3 += gx4
                gx1 += gx3
                lam += gx1
            else:
                lam += back(k, lam * h)
            lam += grad_states[k]
        if self.coefficients:  # sum over stages and rows of g_F^T df/dc
            self.coefficient_gradient = np.einsum("jbi,jbic->c", self.g_fmu, self.sensitivity)
        return (lam, *self._input_gradients(n_steps), *self._weight_gradients())

    def _input_gradients(self, n_steps: int):
        """Gradients of u_grid (n+1, B, n_u), u_half, z_grid (n+1, B, H0), z_half from the stages'."""
        gu, gz = self.gu, self.ga[0]
        g_u_grid = np.zeros((n_steps + 1,) + gu.shape[1:])
        g_z_grid = np.zeros((n_steps + 1,) + gz.shape[1:])
        if self.stages == 4:
            g_u_grid[1:] += gu[3::4]
            g_u_grid[:-1] += gu[0::4]
            g_z_grid[1:] += gz[3::4]
            g_z_grid[:-1] += gz[0::4]
            return g_u_grid, gu[1::4] + gu[2::4], g_z_grid, gz[1::4] + gz[2::4]
        g_u_grid[:-1] = gu
        g_z_grid[:-1] = gz
        return g_u_grid, None, g_z_grid, None

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
