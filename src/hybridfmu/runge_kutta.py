"""The fixed-grid explicit Runge-Kutta schemes, each defined once by its Butcher tableau, for every Python path.

A step of size h from x with stages k_i = f(x + h sum_j a_ij k_j, u(t + c_i h)) is

    x_next = x + h sum_i b_i k_i.

Every Python integrator of the package takes its coefficients from here: the training rollouts and their
discrete adjoints (``training.solver``, ``training.adjoint``, ``training.numpy_adjoint``) and the diagnosis'
simulations (``diagnosis.corrected_model``, ``diagnosis.residual``, ``diagnosis.library``). They differ in the
array library (torch, NumPy, Python floats), in how a stage gets its inputs, and in what they record, so each
passes its own ``axpy(y, k, c) -> y + c k``; the order of the floating-point operations is fixed here, so two
paths with the same arrays give the same numbers to the bit:

- a stage's state adds its terms ``(h a_ij) k_j`` to x one by one, in the order of j;
- the step adds the stages in groups of equal weight, in the order of each group's first stage: for the
  classical RK4, ``x + (h/6) (k1 + k4) + (h/3) (k2 + k3)``;
- a coefficient ``h w`` of a rational weight ``w = p/q`` is computed as ``h * p / q`` (``h/6`` for 1/6, ``0.5 h``
  for 1/2), the way a hand-written step writes it.

The integrators in C (``hybridfmu/fmu/shim.c``: the FMU's open loop, the neural FMU's rollout and adjoint)
implement the classical RK4 and the explicit Euler step of the tableaus below.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from functools import cached_property, lru_cache
from typing import Any, Callable, Sequence

#: ``axpy(y, k, c) -> y + c * k``: the one array operation a step needs, in the caller's array library.
Axpy = Callable[[Any, Any, float], Any]


@dataclass(frozen=True, eq=False)  # compared and hashed as the object: each scheme exists once
class ButcherTableau:
    """An explicit Runge-Kutta scheme.

    Attributes:
        name: the name ``model.solver`` uses for it.
        a: the stage matrix, strictly lower triangular: row i holds a_i0 .. a_i(i-1) (i entries).
        b: the weights, one per stage, summing to 1.
        c: the nodes (fractions of the step at which each stage takes its inputs); c_i = sum_j a_ij.
    """

    name: str
    a: tuple[tuple[Fraction, ...], ...]
    b: tuple[Fraction, ...]
    c: tuple[Fraction, ...]

    def __post_init__(self) -> None:
        n = len(self.b)
        if len(self.a) != n or len(self.c) != n or any(len(row) != i for i, row in enumerate(self.a)):
            raise ValueError(f"tableau {self.name}: expected {n} rows of a (row i with i entries) and {n} nodes")
        if sum(self.b) != 1:
            raise ValueError(f"tableau {self.name}: the weights sum to {sum(self.b)}, expected 1")
        if any(sum(row) != node for row, node in zip(self.a, self.c)):
            raise ValueError(f"tableau {self.name}: each node c_i must equal the sum of row i of a")

    @property
    def stages(self) -> int:
        return len(self.b)

    @cached_property
    def _structure(self) -> tuple:
        """The tableau as integers, computed once: per stage its nonzero (j, numerator, denominator) of a_ij; the
        weight groups ((numerator, denominator), stages) in the order of their first stage; every weight's
        (numerator, denominator)."""
        stage_terms = tuple(tuple((j, a_ij.numerator, a_ij.denominator) for j, a_ij in enumerate(row) if a_ij != 0)
                            for row in self.a)
        groups: dict[Fraction, list[int]] = {}
        for i, weight in enumerate(self.b):
            if weight != 0:
                groups.setdefault(weight, []).append(i)
        weight_groups = tuple(((w.numerator, w.denominator), tuple(members)) for w, members in groups.items())
        weights = tuple((w.numerator, w.denominator) for w in self.b)
        return stage_terms, weight_groups, weights

    def plan(self, h: Any, weight_scale: Any = None) -> "StepPlan":
        """The step's coefficients for the step size ``h`` (a float, or an array broadcasting against the
        states, e.g. (W, 1) for windows of different steps). ``weight_scale`` (default ``h``) multiplies the
        weights instead: 1.0 gives the step's mean rate, sum_i b_i k_i, instead of its increment.

        A coefficient ``h w`` of a weight ``w = p/q`` is computed as ``h * p / q``, the way a hand-written step
        writes it (h/6 for 1/6, 0.5 h for 1/2, h for 1)."""
        if isinstance(h, float) and (weight_scale is None or isinstance(weight_scale, float)):
            return _cached_plan(self, h, weight_scale)  # a step size of a uniform grid: the same plan every step
        return self._make_plan(h, weight_scale)

    def _make_plan(self, h: Any, weight_scale: Any) -> "StepPlan":
        scale = h if weight_scale is None else weight_scale
        stage_terms, weight_groups, _ = self._structure
        return StepPlan(self, tuple(tuple((j, h * p / q) for j, p, q in row) for row in stage_terms),
                        tuple((scale * p / q, members) for (p, q), members in weight_groups), scale)


@lru_cache(maxsize=64)
def _cached_plan(tableau: ButcherTableau, h: float, weight_scale: float | None) -> "StepPlan":
    return tableau._make_plan(h, weight_scale)


@dataclass(frozen=True)
class StepPlan:
    """A tableau's coefficients for one step size, in the order every path applies them.

    Attributes:
        tableau: the scheme.
        stage_terms: per stage i, the terms (j, h a_ij) of its state, nonzero a_ij only, in the order of j.
        weight_groups: (h b, the stages with that weight), in the order of each group's first stage.
        weight_scale: what the weights are multiplied by (h, or 1 for a mean rate).
    """

    tableau: ButcherTableau
    stage_terms: tuple[tuple[tuple[int, Any], ...], ...]
    weight_groups: tuple[tuple[Any, tuple[int, ...]], ...]
    weight_scale: Any

    def weight(self, i: int) -> Any:
        """h b_i: the adjoint's seed of stage i."""
        p, q = self.tableau._structure[2][i]
        return self.weight_scale * p / q

    def stage_state(self, x: Any, stages: Sequence[Any], i: int, axpy: Axpy) -> Any:
        """The state at which stage i is evaluated: x + sum_j (h a_ij) k_j, from the stages k_0..k_(i-1)."""
        state = x
        for j, coefficient in self.stage_terms[i]:
            state = axpy(state, stages[j], coefficient)
        return state

    def combine(self, x: Any, stages: Sequence[Any], axpy: Axpy) -> Any:
        """x + sum over the weight groups of (h b) (sum of the group's stages): the step's new state (or, from
        x = 0 with the weights unscaled, its mean rate)."""
        for coefficient, members in self.weight_groups:
            total = stages[members[0]]
            for i in members[1:]:
                total = total + stages[i]
            x = axpy(x, total, coefficient)
        return x

    def step(self, x: Any, derivative: Callable[[Any, int], Any], axpy: Axpy) -> Any:
        """One step from x: stage i is ``derivative(state_i, i)`` (the caller picks the inputs of node c_i)."""
        stages: list[Any] = []
        for i in range(self.tableau.stages):
            stages.append(derivative(self.stage_state(x, stages, i, axpy), i))
        return self.combine(x, stages, axpy)

    def adjoint_step(self, lam: Any, stage_backward: Callable[[Any, int], Any], axpy: Axpy) -> list[Any]:
        """The reverse sweep of one step: the state gradient of each stage, in stage order.

        ``lam`` is the gradient of the step's new state. Stage i, last first, gets the output gradient
        ``(h b_i) lam + sum_{l > i} (h a_li) g_l`` and ``stage_backward(gy_i, i)`` returns g_i, the gradient
        with respect to its state. The gradient of the step's old state is ``lam + pairwise_sum(g)``.
        """
        n = self.tableau.stages
        grads: list[Any] = [None] * n
        for i in range(n - 1, -1, -1):
            gy = lam * self.weight(i)
            for l in range(i + 1, n):
                for j, coefficient in self.stage_terms[l]:
                    if j == i:
                        gy = axpy(gy, grads[l], coefficient)
            grads[i] = stage_backward(gy, i)
        return grads


def pairwise_sum(values: Sequence[Any]) -> Any:
    """Sum by pairs of neighbours, level by level: ((v0 + v1) + (v2 + v3)) for four values."""
    values = list(values)
    while len(values) > 1:
        values = [values[i] + values[i + 1] if i + 1 < len(values) else values[i] for i in range(0, len(values), 2)]
    return values[0]


def numpy_axpy(y: Any, k: Any, c: Any) -> Any:
    """y + c k with the arithmetic operators (NumPy arrays, Python floats)."""
    return y + c * k


_HALF = Fraction(1, 2)

#: The nodes of the schemes below: a stage takes the inputs at the step's start, its middle or its end (the
#: rollouts hold the inputs of these three instants per step).
NODE_START, NODE_MIDDLE, NODE_END = Fraction(0), _HALF, Fraction(1)


def node_inputs(grid: Sequence[Any], middle: Sequence[Any] | None, k: int) -> dict[Fraction, Any]:
    """What a stage of step k takes at each node: ``grid[k]`` at the step's start, ``middle[k]`` half a step in
    (None for a scheme without that node), ``grid[k + 1]`` at its end."""
    inputs = {NODE_START: grid[k], NODE_END: grid[k + 1]}
    if middle is not None:
        inputs[NODE_MIDDLE] = middle[k]
    return inputs


#: The classical fourth-order Runge-Kutta scheme.
RK4 = ButcherTableau(
    name="rk4",
    a=((), (_HALF,), (Fraction(0), _HALF), (Fraction(0), Fraction(0), Fraction(1))),
    b=(Fraction(1, 6), Fraction(1, 3), Fraction(1, 3), Fraction(1, 6)),
    c=(Fraction(0), _HALF, _HALF, Fraction(1)),
)

#: The explicit Euler step.
EULER = ButcherTableau(name="euler", a=((),), b=(Fraction(1),), c=(Fraction(0),))

#: ``model.solver`` -> its tableau.
TABLEAUS: dict[str, ButcherTableau] = {tableau.name: tableau for tableau in (RK4, EULER)}


def tableau(name: str) -> ButcherTableau:
    """The tableau of ``model.solver`` ``name``; an unknown name is an error that lists the known ones."""
    try:
        return TABLEAUS[name]
    except KeyError:
        raise ValueError(f"solver: expected one of {', '.join(map(repr, TABLEAUS))}, got {name!r}") from None
