"""What one diagnosis found (:func:`hybridfmu.diagnosis.run.run_diagnosis`), before it is written.

:func:`hybridfmu.diagnosis.report.diagnosis_record` is the one place that turns it into ``diagnosis.json``; the
report, the figures and :func:`hybridfmu.api.diagnose` read its fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hybridfmu.diagnosis.export import DiagnosedModel
    from hybridfmu.diagnosis.prepare import PreparedManeuver
    from hybridfmu.diagnosis.problem import Problem


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
        which: the named effects (``chosen``, rank order, with parameters and uncertainty), per equation the
            selection's steps, the calibration records, the skipped candidates.
        how_far: the held-out check (before, after, per variant), or None when it was not run;
            how_far_not_run: why not.
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
    which: dict[str, Any]
    how_far: dict[str, Any] | None
    how_far_not_run: str | None
    growth: list[dict[str, Any]] | None
    calibration: str | None = None
    model_parameters: dict[str, float] = field(default_factory=dict)
