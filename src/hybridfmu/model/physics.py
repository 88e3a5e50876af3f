"""The physical layer of a hybrid model: the FMU plus the effects the diagnosis identified.

A hybrid model (``model.physics_terms``) is a neural FMU whose FMU layer is :class:`PhysicsModel`: the
calibrated FMU with the diagnosed model's parameters (recalibrated with the effects), its additive terms in
the state equations (friction, periodic terms, limits, ...) and its changes of the logged inputs (dead
zones, gains, offsets, time offsets), all fitted by the diagnosis (:mod:`hybridfmu.diagnosis.export`). The
ANN then learns only what remains.

:class:`PhysicsModel` has the batched interface of the FMU bridge (``derivatives``, ``jacobians``,
``derivatives_and_jacobians``, ``event_indicators``), so ``hybridfmu.fmu.FmuRhs`` makes it differentiable and
the solvers use it like an FMU. The additive terms' Jacobians come from central differences of their
vectorised evaluation (all perturbed rows in one call); the FMU's own Jacobians from the FMU. The input changes
act on whole logged input sequences (:meth:`PhysicsModel.inputs`) before the model sees them: the training
data and every simulation's inputs pass through them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from hybridfmu.diagnosis.export import DiagnosedModel, load_diagnosed
from hybridfmu.fmu.effect_program import EffectProgram

#: Values of ``model.physics_terms`` that are no list of effect names.
PHYSICS_TERMS_CHOICES = ("none", "from_diagnosis")


class PhysicsModel:
    """The FMU plus the diagnosed effects, with the FMU bridge's batched interface.

    Args:
        fmu: the calibrated FMU instance the derivatives come from (the diagnosed parameters are set on it).
        helper: a second instance (same FMU and parameters) for effects that evaluate the model's derivatives.
        diagnosed: the diagnosed model (its effects, parameters and problem).
        relative_step: step of the additive terms' central differences, relative to 1 + |value|.
        terms_in_c: the training's terms and their Jacobians in C where the FMU and every term allow it (False:
            always in NumPy, e.g. to compare the two).

    Raises:
        ValueError: the diagnosed model's states or inputs differ from the FMU's.
    """

    def __init__(self, fmu: Any, helper: Any, diagnosed: DiagnosedModel, relative_step: float = 1e-6,
                 terms_in_c: bool = True) -> None:
        if list(fmu.state_names) != diagnosed.state_names or list(fmu.input_names) != diagnosed.input_names:
            raise ValueError(f"diagnosed model: states {diagnosed.state_names} / inputs {diagnosed.input_names} "
                             f"differ from the FMU's {list(fmu.state_names)} / {list(fmu.input_names)}")
        self.fmu = fmu
        self.helper = helper
        self.diagnosed = diagnosed
        self.corrected = diagnosed.corrected(helper)
        self.relative_step = float(relative_step)
        self.terms_in_c = bool(terms_in_c)
        self._programs_cache: tuple[tuple[bytes, bool], Any] | None = None
        self._effect_program_cache: tuple[bytes, EffectProgram | None] | None = None
        # the refit's parameters, then the parameter errors the effects name (they are not refitted ones)
        self.parameters = {**diagnosed.parameters, **self.corrected.parameters}
        for instance in (fmu, helper):
            if self.parameters:
                instance.set_parameters(self.parameters)
        self.state_names = list(fmu.state_names)
        self.input_names = list(fmu.input_names)
        self.n_states = int(fmu.n_states)
        self.n_inputs = int(fmu.n_inputs)
        self.n_event_indicators = int(getattr(fmu, "n_event_indicators", 0))
        self.model_name = f"{fmu.model_name} + {len(diagnosed.terms)} diagnosed effect(s)"

    @property
    def effects(self) -> list[str]:
        return list(self.diagnosed.effects)

    @property
    def notes(self) -> list[str]:
        """Effects the corrected model could not apply (e.g. a second change of one input), in words."""
        return list(self.corrected.notes)

    # ------------------------------------------------------------------ trainable coefficients
    @property
    def coefficient_names(self) -> list[str]:
        """Names of the additive terms' coefficients, ``"<effect>[i]"`` (the order of :attr:`coefficients`)."""
        return [f"{name}[{i}]" for name, array in self.corrected.row_coefficients for i in range(array.size)]

    @property
    def coefficients(self) -> np.ndarray:
        """(n_c,) the additive terms' coefficients as the model uses them now (a copy); the diagnosis' fitted
        values until :meth:`set_coefficients`. The terms are linear in them, so a hybrid can train them."""
        arrays = [array for _, array in self.corrected.row_coefficients]
        return np.concatenate(arrays) if arrays else np.zeros(0)

    def set_coefficients(self, values: np.ndarray) -> None:
        """Use ``values`` (n_c,) as the additive terms' coefficients (in the order of :attr:`coefficients`).

        Raises:
            ValueError: a different count, or non-finite values.
        """
        values = np.asarray(values, dtype=float).reshape(-1)
        arrays = [array for _, array in self.corrected.row_coefficients]
        n_c = sum(array.size for array in arrays)
        if values.size != n_c or not np.isfinite(values).all():
            raise ValueError(f"physical layer: expected {n_c} finite coefficients ({self.coefficient_names}), "
                             f"got {values.tolist()}")
        start = 0
        for array in arrays:
            array[:] = values[start:start + array.size]
            start += array.size

    def coefficient_jacobian(self, x: np.ndarray, u: np.ndarray, t_s: Any = 0.0) -> np.ndarray:
        """df/d(coefficients): (N, n_x), (N, n_u) -> (N, n_x, n_c) (the terms' regressors; independent of the
        coefficients' values)."""
        x = np.asarray(x, dtype=float).reshape(-1, self.n_states)
        return self.corrected.coefficient_regressors(x, np.asarray(u, dtype=float).reshape(x.shape[0], -1))

    def derivatives_jacobians_and_coefficient_jacobian(self, x: np.ndarray, u: np.ndarray, t_s: Any = 0.0):
        """(f, df/dx, df/du, df/d(coefficients)) at (x (N, n_x), u (N, n_u)): :meth:`derivatives_and_jacobians`
        and :meth:`coefficient_jacobian` (the training engine's call when the coefficients train)."""
        return self._derivatives_and_jacobians(x, u, t_s, regressors=True)

    # ------------------------------------------------------------------ inputs
    def inputs(self, u: np.ndarray, dt_s: float) -> np.ndarray:
        """The logged inputs (T, n_u) of one maneuver as the model sees them (the diagnosed input changes);
        ``dt_s`` the sampling interval (s)."""
        u = np.asarray(u, dtype=float)
        if not self.corrected.input_changes:
            return np.array(u)
        return self.corrected.inputs(u, float(dt_s))

    def held_inputs(self, u: np.ndarray, dt_s: float) -> np.ndarray:
        """Each row of ``u`` (B, n_u) held constant, as the model sees it (the diagnosed input changes,
        :meth:`CorrectedModel.held_inputs`) -> (B, n_u); ``dt_s`` the sampling interval (s)."""
        u = np.asarray(u, dtype=float)
        if not self.corrected.input_changes:
            return np.array(u)
        return self.corrected.held_inputs(u, float(dt_s))

    # ------------------------------------------------------------------ derivatives
    def derivatives(self, x: np.ndarray, u: np.ndarray, t_s: Any = 0.0) -> np.ndarray:
        """(N, n_x), (N, n_u) -> (N, n_x): the FMU's derivatives plus the additive terms."""
        f = np.asarray(self.fmu.derivatives(x, u, t_s), dtype=float)
        if not self.corrected.has_correction:
            return f
        return f + self.corrected.additive_batch(np.reshape(x, f.shape), np.reshape(u, (f.shape[0], self.n_inputs)))

    def _terms_and_jacobians(self, x: np.ndarray, u: np.ndarray, regressors: bool = False):
        """The additive terms (N, n_x) and their central-difference Jacobians (N, n_x, n_x), (N, n_x, n_u); with
        ``regressors`` also :meth:`coefficient_jacobian` (N, n_x, n_c). In C where every term has a C form and the
        FMU runs behind the shim (``FmuModel.effect_jacobians_kernel``, one call per solver stage), else in NumPy.

        In C the regressors are each row term's program with a unit coefficient; within the standstill hold's band
        (where the hold makes the terms depend on the coefficients in pieces) they are the central differences of
        the whole program in each coefficient, which :meth:`CorrectedModel.coefficient_regressors` states in
        closed form (held: none; sliding: the friction at the band's edge)."""
        programs = self._c_programs(regressors)
        if programs is None:
            terms, term_x, term_u = self._terms_and_jacobians_numpy(x, u)
            return (terms, term_x, term_u, self.coefficient_jacobian(x, u)) if regressors else (terms, term_x, term_u)
        terms, term_x, term_u, unit_values, pair_values, in_band = programs.kernel(x, u)
        if not regressors:
            return terms, term_x, term_u
        jacobian = np.zeros((terms.shape[0], self.n_states, self.coefficients.size))
        np.add.at(jacobian, (slice(None), slice(None), programs.columns), unit_values)
        jacobian[in_band] = pair_values[in_band]
        return terms, term_x, term_u, jacobian

    def _c_programs(self, regressors: bool) -> "_TermPrograms | None":
        """The terms as effect programs for :meth:`FmuModel.effect_jacobians_kernel` with the coefficients as they are
        now; None where the FMU has no C interface or some term no C form. Rebuilt when the coefficients change (a
        hybrid trains them); the regressors' programs only when asked for."""
        if (not self.terms_in_c or not callable(getattr(self.fmu, "effect_jacobians_kernel", None))
                or not self.corrected.has_correction):
            return None
        key = (self.coefficients.tobytes(), regressors)
        cached = self._programs_cache
        if cached is not None and (cached[0] == key or (not regressors and cached[0][0] == key[0])):
            return cached[1]
        programs = _term_programs(self.corrected, self.fmu, self.relative_step, regressors)
        self._programs_cache = (key, programs)
        return programs

    def _terms_and_jacobians_numpy(self, x: np.ndarray, u: np.ndarray
                                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The additive terms (N, n_x) and their central-difference Jacobians (N, n_x, n_x), (N, n_x, n_u), from one
        vectorised evaluation of all rows: the unperturbed ones and each variable perturbed up and down."""
        n, n_x = x.shape[0], self.n_states
        z = np.concatenate([x, u], axis=1)  # (N, m)
        m = z.shape[1]
        step = self.relative_step * (1.0 + np.abs(z))  # (N, m)
        rows = np.repeat(z[None], 2 * m + 1, axis=0)  # (2m + 1, N, m): unperturbed, up, down
        columns = np.arange(m)
        rows[1 + columns, :, columns] += step.T
        rows[1 + m + columns, :, columns] -= step.T
        flat = rows.reshape(-1, m)
        values = self.corrected.additive_batch(flat[:, :n_x], flat[:, n_x:]).reshape(2 * m + 1, n, n_x)
        jac = (values[1:m + 1] - values[m + 1:]) / (2.0 * step.T[:, :, None])  # (m, N, n_x)
        jac = np.transpose(jac, (1, 2, 0))  # (N, n_x, m)
        return values[0], np.ascontiguousarray(jac[:, :, :n_x]), np.ascontiguousarray(jac[:, :, n_x:])

    def derivatives_and_jacobians(self, x: np.ndarray, u: np.ndarray,
                                  t_s: Any = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f (N, n_x), df/dx (N, n_x, n_x), df/du (N, n_x, n_u)) of :meth:`derivatives`, with one FMU call and one
        evaluation of the terms (the training engine calls this once per solver stage)."""
        return self._derivatives_and_jacobians(x, u, t_s, regressors=False)

    def _derivatives_and_jacobians(self, x: np.ndarray, u: np.ndarray, t_s: Any, regressors: bool):
        """:meth:`derivatives_and_jacobians`, and with ``regressors`` also :meth:`coefficient_jacobian`."""
        both = getattr(self.fmu, "derivatives_and_jacobians", None)
        if callable(both):
            f, dfdx, dfdu = both(x, u, t_s)
        else:
            f = self.fmu.derivatives(x, u, t_s)
            dfdx, dfdu = self.fmu.jacobians(x, u, t_s)
        f, dfdx, dfdu = (np.array(a, dtype=float) for a in (f, dfdx, dfdu))
        x = np.asarray(x, dtype=float).reshape(f.shape)
        u = np.asarray(u, dtype=float).reshape(f.shape[0], -1)
        if not self.corrected.has_correction:
            return (f, dfdx, dfdu, self.coefficient_jacobian(x, u)) if regressors else (f, dfdx, dfdu)
        parts = self._terms_and_jacobians(x, u, regressors)
        f += parts[0]
        dfdx += parts[1]
        dfdu += parts[2]
        return (f, dfdx, dfdu, parts[3]) if regressors else (f, dfdx, dfdu)

    def jacobians(self, x: np.ndarray, u: np.ndarray, t_s: Any = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(df/dx (N, n_x, n_x), df/du (N, n_x, n_u)) of :meth:`derivatives`."""
        _, dfdx, dfdu = self.derivatives_and_jacobians(x, u, t_s)
        return dfdx, dfdu

    def event_indicators(self, x: np.ndarray, u: np.ndarray, t_s: Any = 0.0) -> np.ndarray:
        return self.fmu.event_indicators(x, u, t_s)

    def get_parameters(self, names: list[str] | None = None) -> dict[str, float]:
        return self.fmu.get_parameters(names)

    @property
    def initial_states(self) -> np.ndarray:
        """(n_x,) the FMU's states after initialisation (its start values)."""
        return self.fmu.initial_states

    @property
    def parameter_names(self) -> list[str]:
        return list(self.fmu.parameter_names)

    # ------------------------------------------------------------------ the training engines' kernels
    def derivatives_kernel(self, n: int):
        """``(x (n, n_x), u (n, n_u)) -> (n, n_x)`` (the bridge's kernel interface; fresh arrays per call): the
        FMU's own low-overhead kernel (when it has one) plus the additive terms. Same values as
        :meth:`derivatives`; the gradient-free rollouts (validation, evaluation) call it once per solver stage."""
        fmu_kernel = getattr(self.fmu, "derivatives_kernel", None)
        if not callable(fmu_kernel):
            return self.derivatives
        fmu_derivatives = fmu_kernel(n)
        if not self.corrected.has_correction:
            return lambda x, u: np.array(fmu_derivatives(x, u))
        additive = self.corrected.additive_batch

        def kernel(x: np.ndarray, u: np.ndarray) -> np.ndarray:
            f = fmu_derivatives(x, u)  # the kernel's buffer: the sum below is a fresh array
            return f + additive(x, u)

        return kernel

    @property
    def neural_rollout(self):
        """A neural FMU's gradient-free rollout around this layer with the whole loop in C, or None.

        The FMU's own C rollout (``FmuModel.neural_rollout``) with the additive terms installed as an effect
        program (``effects.c``, the coefficients as they are at the call), so the effects add to the FMU's
        derivatives inside the C loop. None where the FMU has no C rollout or some term has no C form (the NumPy
        engine then evaluates the terms per stage). Same arguments and result as ``FmuModel.neural_rollout``.
        """
        fmu_rollout = getattr(self.fmu, "neural_rollout", None)
        if not callable(fmu_rollout) or not hasattr(self.fmu, "_shim_model"):
            return None
        if not self.corrected.has_correction:
            return fmu_rollout
        if self._effect_program() is None:
            return None

        def rollout(*args, **kwargs):
            program = self._effect_program()
            buffers = program.install(self.fmu._shim_model)
            try:
                return fmu_rollout(*args, **kwargs)
            finally:
                EffectProgram.remove(self.fmu._shim_model)
                del buffers

        return rollout

    def _effect_program(self) -> EffectProgram | None:
        """``self.corrected.effect_program()`` with the coefficients as they are now, made again only when they
        have changed since the last call (a closed loop's rollouts of one sample each all use one)."""
        key = self.coefficients.tobytes()
        if self._effect_program_cache is None or self._effect_program_cache[0] != key:
            self._effect_program_cache = (key, self.corrected.effect_program())
        return self._effect_program_cache[1]

    def derivatives_and_jacobians_kernel(self, n: int):
        """``(x (n, n_x), u (n, n_u)) -> (xdot, dfdx, dfdu)`` (the bridge's kernel interface, for the NumPy
        engine of the training adjoint; fresh arrays per call)."""
        return self.derivatives_and_jacobians

    def coefficient_kernel(self, n: int):
        """``(x (n, n_x), u (n, n_u)) -> (xdot, dfdx, dfdu, df/d(coefficients) (n, n_x, n_c))``, for the NumPy
        engine of the training adjoint when the coefficients train (fresh arrays per call)."""
        return self.derivatives_jacobians_and_coefficient_jacobian


def physics_model(fmu_path: str | Path, fmu_parameters: dict[str, float] | None, diagnosed_path: str | Path,
                  effects: list[str] | None = None, without_kinds: tuple[str, ...] = ()) -> PhysicsModel:
    """The physical layer of a hybrid: the FMU at ``fmu_path`` with ``fmu_parameters`` (the calibrated ones)
    plus the diagnosed model at ``diagnosed_path``, restricted to ``effects`` (None: all of them), less the
    effects of the kinds ``without_kinds`` (e.g. ``("time_offset",)``)."""
    from hybridfmu.fmu import load_fmu

    diagnosed = load_diagnosed(diagnosed_path).selected(effects, without_kinds)
    fmu = load_fmu(fmu_path, parameters=fmu_parameters or None)
    helper = load_fmu(fmu_path, parameters=fmu_parameters or None)
    return PhysicsModel(fmu, helper, diagnosed)


def physics_effects(physics_terms: Any) -> list[str] | None:
    """The effects a hybrid takes from ``model.physics_terms``: None for all (``from_diagnosis``), the names of
    a list; ValueError for ``none`` (no physical layer) or anything else."""
    if physics_terms == "from_diagnosis":
        return None
    if isinstance(physics_terms, (list, tuple)) and all(isinstance(n, str) for n in physics_terms):
        return list(physics_terms)
    raise ValueError(f"config.model.physics_terms: expected 'from_diagnosis' or a list of effect names for a "
                     f"hybrid, got {physics_terms!r}")


#: Each coefficient's step in the central differences of the whole effect program (regressors within the
#: standstill hold's band), relative to 1 + |coefficient|: the terms are linear in pieces in the coefficients.
PAIR_RELATIVE_STEP = 1e-5


class _TermPrograms(NamedTuple):
    """A physical layer's terms in C: the FMU's ``effect_jacobians_kernel`` of the whole program, the programs of
    each row term with one unit coefficient (its regressors) and the pairs of the whole program with coefficient k
    moved up and down; ``columns`` each unit program's coefficient (a coefficient array two terms share has one
    column each)."""

    kernel: Any
    columns: np.ndarray


def _term_programs(corrected: Any, fmu: Any, relative_step: float, regressors: bool) -> _TermPrograms | None:
    """The :class:`_TermPrograms` of a corrected model's terms as they are now, on ``fmu`` (without regressors:
    the whole program only); None when some term has no C form."""
    program = corrected.effect_program()
    if program is None:
        return None
    if not regressors:
        return _TermPrograms(fmu.effect_jacobians_kernel(program, relative_step), np.zeros(0, dtype=int))
    n_states, n_inputs = corrected.n_x, corrected.n_u
    starts, n_c = {}, 0
    for _, array in corrected.row_coefficients:
        starts[id(array)] = n_c
        n_c += array.size
    units, columns = [], []
    for _, member, coefficients, setting in corrected.row_terms:
        for i in range(coefficients.size):
            unit = np.zeros(coefficients.size)
            unit[i] = 1.0
            term = member.stage_term(unit, setting)
            if term is None:
                return None
            units.append(EffectProgram([term], n_states, n_inputs))
            columns.append(starts[id(coefficients)] + i)
    pairs, steps = [], []
    for _, array in corrected.row_coefficients:
        for i in range(array.size):
            value = float(array[i])
            step = PAIR_RELATIVE_STEP * (1.0 + abs(value))
            try:
                for moved in (value + step, value - step):
                    array[i] = moved
                    pairs.append(corrected.effect_program())
            finally:
                array[i] = value
            steps.append(step)
    hold = corrected.hold
    kernel = fmu.effect_jacobians_kernel(program, relative_step, units, corrected.hold_state if hold else -1,
                                         hold.band if hold else 0.0, pairs, steps)
    return _TermPrograms(kernel, np.array(columns, dtype=int))
