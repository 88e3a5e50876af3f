"""What one diagnosis found (:func:`hybridfmu.diagnosis.run.run_diagnosis`), before it is written.

:func:`hybridfmu.diagnosis.report.diagnosis_record` is the one place that turns it into ``diagnosis.json``; the
report, the figures and :func:`hybridfmu.api.diagnose` read its fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from hybridfmu.diagnosis.export import DiagnosedModel
    from hybridfmu.diagnosis.prepare import PreparedManeuver
    from hybridfmu.diagnosis.problem import Problem
    from hybridfmu.diagnosis.selection import DesignCache, Term


def is_finding(item: dict[str, Any]) -> bool:
    """Whether a record of ``EffectSelection.chosen`` is a named finding (not an adjustment, not unconfirmed; a record
    without a role, from before roles, is one)."""
    return item.get("role", "finding") == "finding"


@dataclass
class EffectSelection:
    """Which effects: one selection over all examined equations on the fitting maneuvers
    (:func:`hybridfmu.diagnosis.run.select_effects`).

    Attributes:
        chosen: per named effect, in rank order (by drop-one score): ``effect``, ``kind``, ``equation`` (the one
            it explains most), ``equations`` (all it acts on), ``equation_unit``, ``description``, ``formula``,
            ``setting``, ``coefficients``, ``parameters`` (physical values with their standard errors, 90 %
            intervals and identification), ``stability`` (per-maneuver refits), ``rivals`` (the left-out terms
            that move its estimates), ``role`` (``finding``; ``adjustment``: fitted beside the findings so that
            their estimates are not biased, not named; ``unconfirmed``: in the model, not named, since none of its
            sizes is identified, :func:`hybridfmu.diagnosis.identification.confirmed`), ``score``, ``rank``.
        equations: per examined state, its equation error before and after the chosen effects (the equation's
            unit), the effects acting there and the selection's steps restricted to it.
        steps: the selection's steps (candidates with the equations they act on, the one chosen, why).
        calibration: per parameter error calibrated from the start: its relative error and what became of it.
        skipped: library entries left out -> why.
        terms: the chosen terms, in the rank order of ``chosen``.
        cache: the per-equation designs the selection worked on (for the figures).
        n_candidates: how many candidates were examined.
        groups: effects the data cannot tell apart (correlated estimates), each with its pairs.
        periodic_orders: per periodic effect whose orders were searched in the data (``<effect> in d<state>/dt``):
            the highest order resolved, the orders searched and their explained shares.
    """

    chosen: list[dict[str, Any]]
    equations: dict[str, dict[str, Any]]
    steps: list[dict[str, Any]]
    calibration: list[dict[str, Any]]
    skipped: dict[str, str]
    terms: list[Term]
    cache: DesignCache
    n_candidates: int
    groups: list[dict[str, Any]]
    periodic_orders: dict[str, dict[str, Any]] = field(default_factory=dict)

    @property
    def found_effects(self) -> list[str]:
        """The names of the named effects (the chosen findings: not the adjustments, not the unconfirmed), rank
        order, each once."""
        return list(dict.fromkeys(item["effect"] for item in self.chosen if is_finding(item)))

    @property
    def adjustments(self) -> list[str]:
        """The names of the adjustments: terms fitted beside the named effects because leaving them out would move a
        named estimate (a rival, :class:`hybridfmu.diagnosis.selection.Rival`), not named themselves."""
        return [item["effect"] for item in self.chosen if item.get("role") == "adjustment"]

    @property
    def unconfirmed(self) -> list[str]:
        """The names of the unconfirmed terms: in the model, not named, since the data identify none of their sizes."""
        return [item["effect"] for item in self.chosen if item.get("role") == "unconfirmed"]


@dataclass
class HeldOutCheck:
    """How far: the FMU and every cumulative variant with the chosen effects, open loop on the test maneuvers
    (:func:`hybridfmu.diagnosis.open_loop.how_far`). Gaps are the target-weighted errors normalised by each
    target's spread (dimensionless); errors are in the signals' units.

    Attributes:
        steps: per variant (the FMU first, then one more effect each, rank order): ``model``, ``effects``,
            ``per_maneuver`` errors, their means (``<signal>_rmse``, ``<signal>_mae``, ``gap``, with windows
            ``window_gap``) and, when recalibrated, its ``refit`` record.
        before, after: the FMU's and the diagnosed model's mean errors.
        gap_before, gap_after: their normalised gaps; shrink_factor: gap_before / gap_after.
        notes: what the corrected model's evaluation noted (e.g. effects it could not apply).
        trajectories: maneuver -> variant label -> (T, n_x) whole-maneuver states (figures only; not written).
        diagnosed: the model the check ends with (recalibrated with its effects when the refit is on).
        parameters_only: the step record of the model with only its parameter errors corrected.
        parameter_shrink_factor: the FMU's gap over ``parameters_only``'s; effect_shrink_factor: that gap over the
            diagnosed model's (what the named effects add; 1 when every chosen term is a parameter error).
        window_gap_before, window_gap_after, window_parameter_shrink_factor, window_effect_shrink_factor: the
            same over windows restarted from the measured state (None without windows).
        window: the windows' length ``window_s`` and how it was chosen
            (:func:`hybridfmu.diagnosis.open_loop.window_setting`), or None without windows.
        standstill_hold: how the standstill hold was chosen on the fitting maneuvers
            (:func:`hybridfmu.diagnosis.open_loop.standstill_hold`; the last step is the model with it when one
            was), or None without a configured standstill.
    """

    steps: list[dict[str, Any]]
    before: dict[str, float]
    after: dict[str, float]
    gap_before: float
    gap_after: float
    shrink_factor: float
    notes: list[str]
    trajectories: dict[str, dict[str, np.ndarray]]
    diagnosed: DiagnosedModel
    parameters_only: dict[str, Any]
    parameter_shrink_factor: float | None
    effect_shrink_factor: float | None
    window_gap_before: float | None = None
    window_gap_after: float | None = None
    window_parameter_shrink_factor: float | None = None
    window_effect_shrink_factor: float | None = None
    window: dict[str, Any] | None = None
    standstill_hold: dict[str, Any] | None = None

    @property
    def windowed(self) -> bool:
        """Whether the check also ran over restarted windows."""
        return self.window_gap_before is not None


@dataclass
class DiagnosisResult:
    """Where, which and how far, with what they were computed from.

    Attributes:
        settings: the diagnosis settings (config section with defaults).
        problem: the problem (states, inputs, equations, units, targets).
        prepared: maneuver -> its equation error and smoothed data.
        fit_names: maneuvers the effects are fitted on (train, validation); test_names: the held-out check's.
        diagnosed: the model the held-out check ends with (the FMU plus the named effects, recalibrated when
            ``diagnosis.open_loop.refit`` is on).
        where: per equation the equation error against its noise floor, and the carrier of the gap.
        regions: equation -> where in the operating range the gap lies (table, statements, time bins).
        which: the named effects and how they were selected (:class:`EffectSelection`).
        how_far: the held-out check (:class:`HeldOutCheck`), or None when it was not run; how_far_not_run: why
            not.
        growth: where the open-loop error took off, per maneuver and target, or None.
        calibration: where the calibration was read (None: the FMU with the config's parameters).
        model_parameters: the model parameters the diagnosis simulated with.
    """

    settings: dict[str, Any]
    problem: Problem
    prepared: dict[str, PreparedManeuver]
    fit_names: list[str]
    test_names: list[str]
    diagnosed: DiagnosedModel
    where: dict[str, Any]
    regions: dict[str, Any]
    which: EffectSelection
    how_far: HeldOutCheck | None
    how_far_not_run: str | None
    growth: list[dict[str, Any]] | None
    calibration: str | None = None
    model_parameters: dict[str, float] = field(default_factory=dict)
