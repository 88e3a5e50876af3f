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
``hold``              j, friction term numbers t_1, ..     band, rate (1/s)
====================  ===================================  =========================================

``hold`` holds the velocity x_j at rest by the friction terms it lists (terms earlier in the program): within
|x_j| < band the equation's rate becomes -rate x_j where that friction can hold it, else the rate without the
friction plus the friction at the band's edge (a Karnopp stick band; ``effects.c``). It reads the rate the
terms before it have summed, so it comes last.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np


class TermKind(NamedTuple):
    """How ``effects.c`` reads a term kind: its ``code``, the index space of each of its ints (``"x"``: a state,
    ``"u"``: an input), the number of its reals (for the kinds of ``_REPEATED_REALS``: any positive multiple of it)
    and whether it evaluates the model with changed inputs."""

    code: int
    ints: str
    reals: int
    evaluates_model: bool = False


#: term kind -> how ``effects.c`` reads it (mirrors the enum there)
TERM_KINDS: dict[str, TermKind] = {
    "viscous": TermKind(1, "x", 1),
    "quadratic": TermKind(2, "x", 1),
    "polynomial": TermKind(3, "x", 1),
    "coulomb": TermKind(4, "x", 4),
    "scaled_coulomb": TermKind(5, "xu", 3),
    "periodic": TermKind(6, "x", 3),
    "saturation_above": TermKind(7, "x", 2),
    "saturation_below": TermKind(8, "x", 2),
    "limit_above": TermKind(9, "x", 2),
    "limit_below": TermKind(10, "x", 2),
    "spill": TermKind(11, "x", 2),
    "phase_deadtime": TermKind(12, "uuuxxx", 3, evaluates_model=True),
    "hold": TermKind(13, "x", 2),
}
#: kinds with any positive number of reals that is a multiple of TermKind.reals (one per coefficient or harmonic)
_REPEATED_REALS = ("polynomial", "periodic")


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
            code += [TERM_KINDS[term.kind].code, len(term.equations), *term.equations, len(term.ints), *term.ints,
                     len(term.reals)]
            reals += [float(r) for r in term.reals]
        self.code = np.array(code, dtype=np.int64)
        self.reals = np.array(reals if reals else [0.0], dtype=np.float64)
        self.evaluates_model = any(TERM_KINDS[term.kind].evaluates_model for term in self.terms)

    def _check(self, number: int, term: EffectTerm) -> None:
        where = f"effect term {number} ({term.kind})"
        if term.kind not in TERM_KINDS:
            raise ValueError(f"{where}: unknown kind; expected one of {sorted(TERM_KINDS)}")
        if not term.equations or any(not 0 <= e < self.n_states for e in term.equations):
            raise ValueError(f"{where}: equations {list(term.equations)}: expected state indices in "
                             f"0..{self.n_states - 1}")
        kind = TERM_KINDS[term.kind]
        if term.kind == "hold":
            self._check_hold(number, term)
            return
        if len(term.ints) != len(kind.ints):
            raise ValueError(f"{where}: expected {len(kind.ints)} indices, got {len(term.ints)}")
        for position, (index, space) in enumerate(zip(term.ints, kind.ints)):
            size = self.n_inputs if space == "u" else self.n_states
            if not 0 <= index < size:
                raise ValueError(f"{where}: index {index} at position {position}: expected 0..{size - 1}")
        n_reals = len(term.reals)
        fits = n_reals > 0 and n_reals % kind.reals == 0 if term.kind in _REPEATED_REALS else n_reals == kind.reals
        if not fits:
            raise ValueError(f"{where}: {n_reals} real arguments do not fit the kind")

    def _check_hold(self, number: int, term: EffectTerm) -> None:
        where = f"effect term {number} (hold)"
        if len(term.equations) != 1 or len(term.reals) != 2 or len(term.ints) < 2:
            raise ValueError(f"{where}: expected one equation, a state and at least one friction term, and the "
                             "band and rate")
        if not 0 <= term.ints[0] < self.n_states:
            raise ValueError(f"{where}: state {term.ints[0]}: expected 0..{self.n_states - 1}")
        for friction in term.ints[1:]:
            if not 0 <= friction < number or self.terms[friction].kind in ("hold", "phase_deadtime"):
                raise ValueError(f"{where}: friction term {friction}: expected an earlier term of one value")
        if number != len(self.terms) - 1:
            raise ValueError(f"{where}: expected the program's last term (it reads the rate the others sum)")

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
