"""The Runge-Kutta schemes defined once by their Butcher tableaus: consistent, of their order, and applied by every
path with the same floating-point operations."""

from __future__ import annotations

import ast
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import torch

from hybridfmu.runge_kutta import EULER, RK4, ButcherTableau, numpy_axpy, pairwise_sum, tableau
from hybridfmu.training.adjoint import torch_axpy

SOURCE = Path(__file__).resolve().parent.parent / "src" / "hybridfmu"


def test_a_tableau_that_is_not_consistent_is_refused():
    with pytest.raises(ValueError, match="weights sum"):
        ButcherTableau("bad", a=((), (Fraction(1),)), b=(Fraction(1, 2), Fraction(1, 4)), c=(Fraction(0), Fraction(1)))
    with pytest.raises(ValueError, match="node"):
        ButcherTableau("bad", a=((), (Fraction(1),)), b=(Fraction(1, 2), Fraction(1, 2)),
                       c=(Fraction(0), Fraction(1, 2)))
    with pytest.raises(ValueError, match="'rk4', 'euler'"):
        tableau("rk45")


@pytest.mark.parametrize(("scheme", "order"), [(RK4, 4), (EULER, 1)])
def test_each_scheme_converges_at_its_order(scheme, order):
    """x' = -x + sin(t) from 1 over [0, 1]: halving the step divides the error by 2**order."""
    def exact(t):
        return 1.5 * np.exp(-t) + 0.5 * (np.sin(t) - np.cos(t))

    errors = []
    for n in (40, 80):
        h, x = 1.0 / n, 1.0
        plan = scheme.plan(h)
        for k in range(n):
            x = plan.step(x, lambda state, i, t=k * h: -state + np.sin(t + float(scheme.c[i]) * h), numpy_axpy)
        errors.append(abs(x - exact(1.0)))
    assert errors[0] / errors[1] == pytest.approx(2.0 ** order, rel=0.1)


def test_the_step_is_computed_as_a_hand_written_rk4_writes_it():
    """Coefficients h/6, h/3, 0.5 h; stages grouped (k1 + k4), (k2 + k3): bit for bit in NumPy and torch."""
    rng = np.random.default_rng(0)
    matrix = rng.normal(size=(3, 3))
    x0 = rng.normal(size=(5, 3))
    h = 0.0137

    def f(x):
        return np.tanh(x @ matrix)

    k1 = f(x0)
    k2 = f(x0 + (0.5 * h) * k1)
    k3 = f(x0 + (0.5 * h) * k2)
    k4 = f(x0 + h * k3)
    expected = x0 + (h / 6.0) * (k1 + k4) + (h / 3.0) * (k2 + k3)
    np.testing.assert_array_equal(RK4.plan(h).step(x0, lambda x, _i: f(x), numpy_axpy), expected)
    t_matrix = torch.from_numpy(matrix)
    stepped = RK4.plan(h).step(torch.from_numpy(x0), lambda x, _i: torch.tanh(x @ t_matrix), torch_axpy)
    t1 = torch.tanh(torch.from_numpy(x0) @ t_matrix)
    t2 = torch.tanh(torch.add(torch.from_numpy(x0), t1, alpha=0.5 * h) @ t_matrix)
    t3 = torch.tanh(torch.add(torch.from_numpy(x0), t2, alpha=0.5 * h) @ t_matrix)
    t4 = torch.tanh(torch.add(torch.from_numpy(x0), t3, alpha=h) @ t_matrix)
    by_hand = torch.add(torch.add(torch.from_numpy(x0), t1 + t4, alpha=h / 6.0), t2 + t3, alpha=h / 3.0)
    assert torch.equal(stepped, by_hand)


def test_the_adjoint_step_is_the_transpose_of_the_step():
    """For a linear right-hand side f(x) = A x the step is x -> M x; the adjoint maps lam to M^T lam."""
    rng = np.random.default_rng(1)
    a = rng.normal(size=(4, 4))
    h = 0.05
    for scheme in (RK4, EULER):
        plan = scheme.plan(h)
        step_matrix = np.column_stack([plan.step(e, lambda x, _i: a @ x, numpy_axpy) for e in np.eye(4)])
        lam = rng.normal(size=4)
        grads = plan.adjoint_step(lam, lambda gy, _i: a.T @ gy, numpy_axpy)
        np.testing.assert_allclose(lam + pairwise_sum(grads), step_matrix.T @ lam, rtol=1e-13)


def test_the_mean_rate_is_the_increment_over_h():
    x0, h = np.array([0.3, -1.2]), 0.01
    plan, rate_plan = RK4.plan(h), RK4.plan(h, weight_scale=1.0)

    def f(x, _i):
        return np.array([x[1], -np.sin(x[0])])

    stages = []
    for i in range(RK4.stages):
        stages.append(f(rate_plan.stage_state(x0, stages, i, numpy_axpy), i))
    rate = rate_plan.combine(np.zeros(2), stages, numpy_axpy)
    np.testing.assert_allclose(rate, (plan.step(x0, f, numpy_axpy) - x0) / h, rtol=1e-12)


def test_no_module_writes_its_own_runge_kutta_step():
    """The classical weights 1/6 and 1/3 appear in one Python module only: the tableau's."""
    offenders = []
    for path in SOURCE.rglob("*.py"):
        if path.name == "runge_kutta.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and isinstance(node.right, ast.Constant)
                    and node.right.value in (6, 6.0, 3, 3.0) and isinstance(node.left, ast.Name)
                    and node.left.id in ("h", "dt_s", "h_s", "dt")):
                offenders.append(f"{path.relative_to(SOURCE)}:{node.lineno}")
    assert not offenders, offenders
