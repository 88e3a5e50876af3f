"""Additive effect terms evaluated in C at every solver stage of an FMU simulation (``effects.c``).

A diagnosed model adds some of its effects as terms to the state derivatives. Handed to
:func:`hybridfmu.fmu.simulate_open_loop` as an :class:`EffectProgram`, those terms are evaluated by the C
step loop itself, without a call into Python per Runge-Kutta stage. Each term kind computes the same
floating-point operations in the same order as its Python form in :mod:`hybridfmu.diagnosis.library`, so a
simulation gives the same states either way.

Term kinds (x: the stage's states, u: the held inputs, f: the FMU's derivatives there; see ``effects.c``):

====================  ===================================  =========================================
kind                  ints                                 reals
====================  ===================================  =========================================
``viscous``           j                                    c
``quadratic``         j                                    c
``polynomial``        j                                    c_2, c_3, ..
``coulomb``           j                                    c, c_s, 1/v_s (0: none), eps
``scaled_coulomb``    j, k (input)                         c, c_a, eps
``periodic``          j                                    (w, a, b) per harmonic
``saturation_above``  j                                    c, x_c
``saturation_below``  j                                    c, x_c
``limit_above``       i                                    c, x_c
``limit_below``       i                                    c, x_c
``spill``             j                                    s, x_c
``phase_deadtime``    duty a, b, c (inputs), i_d, i_q,     delta, i_0, pole pairs
                      angle (states)
====================  ===================================  =========================================
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Callable

import numpy as np

#: term kind -> its code in ``effects.c`` and the number of ints it takes
TERM_KINDS: dict[str, tuple[int, int]] = {
    "viscous": (1, 1),
    "quadratic": (2, 1),
    "polynomial": (3, 1),
    "coulomb": (4, 1),
    "scaled_coulomb": (5, 2),
    "periodic": (6, 1),
    "saturation_above": (7, 1),
    "saturation_below": (8, 1),
    "limit_above": (9, 1),
    "limit_below": (10, 1),
    "spill": (11, 1),
    "phase_deadtime": (12, 6),
}
#: kinds whose ints index inputs (position -> input) rather than states
_INPUT_INTS = {"scaled_coulomb": (1,), "phase_deadtime": (0, 1, 2)}
#: number of reals each kind takes (None: any; "periodic" a multiple of 3)
_REAL_COUNTS = {"viscous": 1, "quadratic": 1, "coulomb": 4, "scaled_coulomb": 3, "saturation_above": 2,
                "saturation_below": 2, "limit_above": 2, "limit_below": 2, "spill": 2, "phase_deadtime": 3}


@dataclass(frozen=True)
class EffectTerm:
    """One additive term: its ``kind`` (:data:`TERM_KINDS`), the ``equations`` (state indices) its value is
    added to, and its integer and real arguments (module docstring)."""

    kind: str
    equations: tuple[int, ...]
    ints: tuple[int, ...]
    reals: tuple[float, ...]


class EffectProgram:
    """The terms of a diagnosed model, encoded for ``effects.c``; evaluated in order, each added to its equations.

    Args:
        terms: the terms in the order their values are summed.
        n_states, n_inputs: the model's sizes (every index is checked against them).
        python: the same terms as a Python callable ``(x (N, n_x), u (N, n_u)) -> (N, n_x)``, called where no
            FMU simulates the program (e.g. a vectorised simulation of many windows); None: none.

    Raises:
        ValueError: an unknown kind, an index out of range or a wrong number of arguments (naming the term).
    """

    def __init__(self, terms: list[EffectTerm], n_states: int, n_inputs: int,
                 python: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> None:
        self.terms = list(terms)
        self.n_states, self.n_inputs = int(n_states), int(n_inputs)
        self.python = python
        code: list[int] = []
        reals: list[float] = []
        for number, term in enumerate(self.terms):
            self._check(number, term)
            code += [TERM_KINDS[term.kind][0], len(term.equations), *term.equations, len(term.ints), *term.ints,
                     len(term.reals)]
            reals += [float(r) for r in term.reals]
        self.code = np.array(code, dtype=np.int64)
        self.reals = np.array(reals if reals else [0.0], dtype=np.float64)
        self.evaluates_model = any(term.kind == "phase_deadtime" for term in self.terms)

    def _check(self, number: int, term: EffectTerm) -> None:
        where = f"effect term {number} ({term.kind})"
        if term.kind not in TERM_KINDS:
            raise ValueError(f"{where}: unknown kind; expected one of {sorted(TERM_KINDS)}")
        if not term.equations or any(not 0 <= e < self.n_states for e in term.equations):
            raise ValueError(f"{where}: equations {list(term.equations)}: expected state indices in "
                             f"0..{self.n_states - 1}")
        n_ints = TERM_KINDS[term.kind][1]
        if len(term.ints) != n_ints:
            raise ValueError(f"{where}: expected {n_ints} indices, got {len(term.ints)}")
        for position, index in enumerate(term.ints):
            size = self.n_inputs if position in _INPUT_INTS.get(term.kind, ()) else self.n_states
            if not 0 <= index < size:
                raise ValueError(f"{where}: index {index} at position {position}: expected 0..{size - 1}")
        count = _REAL_COUNTS.get(term.kind)
        if (count is not None and len(term.reals) != count) or (term.kind == "periodic" and len(term.reals) % 3) \
                or not term.reals:
            raise ValueError(f"{where}: {len(term.reals)} real arguments do not fit the kind")

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The terms in Python (:attr:`python`): (N, n_x), (N, n_u) -> (N, n_x)."""
        if self.python is None:
            raise ValueError("this effect program has no Python form; simulate it with an FMU")
        return self.python(x, u)

    def evaluate(self, x: np.ndarray, u: np.ndarray, f: np.ndarray) -> np.ndarray:
        """The terms evaluated in C row by row: states ``x`` (N, n_x), inputs ``u`` (N, n_u) and the model's
        derivatives ``f`` (N, n_x) there -> (N, n_x). For programs that do not evaluate the model (a check of
        the C forms against the Python ones).

        Raises:
            ValueError: the program evaluates the model (it needs an FMU simulation).
        """
        from hybridfmu.fmu.shim import load_shim

        if self.evaluates_model:
            raise ValueError("this effect program evaluates the model; simulate it with an FMU")
        x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, self.n_states)
        u = np.ascontiguousarray(u, dtype=np.float64).reshape(len(x), self.n_inputs)
        f = np.ascontiguousarray(f, dtype=np.float64).reshape(len(x), self.n_states)
        out = np.empty_like(x)
        work = np.empty(self.n_inputs + self.n_states + 1)
        call = load_shim().hf_effects_add
        for row in range(len(x)):
            status = call(self.code.ctypes.data, self.code.size, self.reals.ctypes.data, self.n_states,
                          self.n_inputs, x[row].ctypes.data, u[row].ctypes.data, f[row].ctypes.data,
                          out[row].ctypes.data, work.ctypes.data, None, None)
            if status:
                raise ValueError(f"the effect program failed with status {status}")
        return out

    def install(self, shim_model: ctypes.Structure) -> tuple[np.ndarray, ...]:
        """Point the C record of an FMU (``ShimModel``) at this program; returns the buffers it uses (keep them
        alive while it is installed)."""
        if (shim_model.nx, shim_model.nu) != (self.n_states, self.n_inputs):
            raise ValueError(f"effect program for {self.n_states} states and {self.n_inputs} inputs, the FMU has "
                             f"{shim_model.nx} and {shim_model.nu}")
        out = np.zeros(max(self.n_states, 1))
        work = np.zeros(self.n_inputs + self.n_states + 1)
        shim_model.effect_code = self.code.ctypes.data
        shim_model.effect_n_code = self.code.size
        shim_model.effect_reals = self.reals.ctypes.data
        shim_model.effect_out = out.ctypes.data
        shim_model.effect_work = work.ctypes.data
        shim_model.effect_sets_inputs = int(self.evaluates_model)
        return self.code, self.reals, out, work

    @staticmethod
    def remove(shim_model: ctypes.Structure) -> None:
        """Detach any program from the C record of an FMU."""
        shim_model.effect_code = None
        shim_model.effect_n_code = 0
        shim_model.effect_reals = None
        shim_model.effect_out = None
        shim_model.effect_work = None
        shim_model.effect_sets_inputs = 0
