"""One selection over all examined equations: changes of the whole model compete with local terms.

A change of an input (gain, offset, time offset, lag, dead zone, saturation) or of a model parameter acts on
every state equation the input or parameter enters, with ONE value: a supply-voltage gain error changes both
current equations by the same factor, a flux-linkage error the back-EMF and the torque together. Fitted
equation by equation, such a change takes a different value in each equation and can stand in for something
else in each (a speed-proportional term in a current equation looks like a flux error there, a torque
proportional to the current like one in the speed equation). Here the equations are stacked:

- every examined equation is a block of rows, each row divided by its maneuver's noise floor
  (``ManeuverFitData.noise_std``), so all blocks are in units of their noise and comparable;
- a model-wide effect (``Effect.model_wide``) is a :class:`JointEffect`: its per-equation members side by side
  in their blocks, with one set of coefficients and one nonlinear setting;
- a local effect (a friction, a periodic torque ...) fills its own equation's block and is zero elsewhere.

The forward selection (:func:`hybridfmu.diagnosis.selection.select_equation`) then runs once over the stacked
rows with the pseudo equation :data:`JOINT`; its thresholds are measured on the blocks a candidate acts on, and
its information criterion is the sum of the blocks' Gaussian log-likelihoods (each block its own variance).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hybridfmu.diagnosis.effects import Effect
from hybridfmu.diagnosis.memo import DesignMemo, LruMemo, setting_key

#: Pseudo equation index of the stacked problem (all examined equations at once).
JOINT = -1


class JointEffect(Effect):
    """A model-wide effect: its per-equation members with one set of coefficients and one setting.

    Args:
        members: the same effect (same name, kind, grid and coefficients) in each equation it acts on, in the
            order of the examined equations.
    """

    def __init__(self, members: list[Effect]) -> None:
        if not members:
            raise ValueError("JointEffect: no member effect")
        first = members[0]
        super().__init__(first.name, JOINT, first.description, first.formula, first.coefficient_unit)
        self.kind = first.kind
        self.continuous = first.continuous
        self.log_scale = first.log_scale
        self.model_wide = True
        self.members = list(members)

    @property
    def first(self) -> Effect:
        return self.members[0]

    def equations(self) -> list[int]:
        """The equations the effect acts on (indices of states)."""
        return [m.equation for m in self.members]

    def member(self, equation: int) -> Effect | None:
        return next((m for m in self.members if m.equation == equation), None)

    def grid(self):
        return self.first.grid()

    def bounds(self):
        return self.first.bounds()

    def refine_bounds(self, name):
        return self.first.refine_bounds(name)

    def continuous_parameters(self):
        return self.first.continuous_parameters()

    def coefficient_names(self, setting):
        return self.first.coefficient_names(setting)

    def coefficient_bounds(self, setting):
        return self.first.coefficient_bounds(setting)

    def regressors(self, inputs, setting):
        raise TypeError(f"{self.name}: a joint effect has regressors per member equation; use its members")

    def physical(self, coef, cov, setting, setting_se):
        return self.first.physical(coef, cov, setting, setting_se)

    def relative_error(self, coef):
        return self.first.relative_error(coef)

    def input_change(self, coef, setting):
        return self.first.input_change(coef, setting)

    def parameter_change(self, coef, setting):
        return self.first.parameter_change(coef, setting)


def effect_equations(effect: Effect) -> list[int]:
    """The equations an effect (local or joint) acts on."""
    return effect.equations() if isinstance(effect, JointEffect) else [effect.equation]


def effect_key(effect: Effect) -> tuple[str, int]:
    """What tells candidates apart in a selection: the same local effect exists in several equations."""
    return effect.name, effect.equation


def joint_candidates(library: dict[int, list[Effect]], equations: list[int]) -> list[Effect]:
    """The candidates of the stacked selection: every local effect as it is, the model-wide ones of the same
    name grouped into one :class:`JointEffect` (in the order they first appear)."""
    out: list[Effect] = []
    groups: dict[str, list[Effect]] = {}
    order: list[str] = []
    for eq in equations:
        for effect in library.get(eq, []):
            if getattr(effect, "model_wide", False):
                if effect.name not in groups:
                    groups[effect.name] = []
                    order.append(effect.name)
                groups[effect.name].append(effect)
            else:
                out.append(effect)
    return [JointEffect(groups[name]) for name in order] + out


@dataclass(frozen=True)
class Block:
    """The rows of one equation in a (stacked) design: ``rows`` a slice, ``noise_variance`` per row."""

    equation: int
    rows: slice
    noise_variance: float


class StackedCache:
    """All examined equations as one regression, each row divided by its maneuver's noise floor.

    Offers the interface of :class:`hybridfmu.diagnosis.selection.DesignCache` for the pseudo equation
    :data:`JOINT`. Rows: equation by equation (in ``equations`` order), within each the maneuvers ``names``
    in order, within each its fitting centres.
    """

    def __init__(self, base: Any, equations: list[int]) -> None:
        self.base = base
        self.equations = list(equations)
        self.maneuvers = base.maneuvers
        self._designs = DesignMemo()
        #: the latest fits of :func:`hybridfmu.diagnosis.selection.fit_terms`
        self.fits = LruMemo()

    def row_weight(self, equation: int, name: str) -> float:
        """The factor every row of ``equation`` from maneuver ``name`` is multiplied by: 1 / its noise floor (1
        where that is not a positive finite number)."""
        std = float(self.maneuvers[name].noise_std[equation])
        return 1.0 / std if std > 0 and np.isfinite(std) else 1.0

    def _rows(self, name: str) -> int:
        return len(self.maneuvers[name].centres)

    def accepts(self, effect: Effect, equation: int) -> bool:
        return equation == JOINT and all(eq in self.equations for eq in effect_equations(effect))

    def target(self, equation: int, names: list[str]) -> np.ndarray:
        """(n,) the weighted equation errors of all blocks."""
        parts = [self.row_weight(eq, n) * self.maneuvers[n].target[:, eq] for eq in self.equations for n in names]
        return np.concatenate(parts) if parts else np.zeros(0)

    def design(self, effect: Effect, setting: dict[str, float], names: list[str]) -> np.ndarray:
        """(n, n_coef) weighted regressors: a joint effect's members in their blocks, a local effect in its own,
        zeros elsewhere (read-only; built once per effect, setting and maneuvers)."""
        return self._designs.get((effect_key(effect), setting_key(setting), tuple(names)),
                                 lambda: self._build_design(effect, setting, names))

    def _build_design(self, effect: Effect, setting: dict[str, float], names: list[str]) -> np.ndarray:
        width = len(effect.coefficient_names(setting))
        parts = []
        for eq in self.equations:
            member = effect.member(eq) if isinstance(effect, JointEffect) else (effect if effect.equation == eq
                                                                                 else None)
            for n in names:
                if member is None:
                    parts.append(np.zeros((self._rows(n), width)))
                else:
                    parts.append(self.row_weight(eq, n) * self.base.design(member, setting, [n]))
        return np.concatenate(parts, axis=0) if parts else np.zeros((0, width))

    def blocks(self, equation: int, names: list[str]) -> list[Block]:
        out, start = [], 0
        for eq in self.equations:
            count = sum(self._rows(n) for n in names)
            out.append(Block(eq, slice(start, start + count), 1.0))
            start += count
        return out

    def noise_variance(self, equation: int, names: list[str]) -> float:
        """Mean noise variance per weighted row: 1."""
        return 1.0

    def groups_of_rows(self, names: list[str]) -> np.ndarray:
        """Bootstrap group of every row: a segment block of a maneuver, the same in every equation (a resample
        draws a segment in all equations together)."""
        groups = self.base.groups_of_rows(names)
        return np.concatenate([groups for _ in self.equations]) if self.equations else groups

    def weights(self, equation: int, names: list[str]) -> np.ndarray:
        """(rows of ``equation``'s block,) the weights of its rows (1 / noise floor)."""
        return np.concatenate([np.full(self._rows(n), self.row_weight(equation, n)) for n in names])
