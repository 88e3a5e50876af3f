"""A hybrid's changes of the logged inputs as the sample-by-sample stages an exported FMU evaluates in C.

The diagnosed model changes whole logged input sequences before the model sees them
(``hybridfmu.diagnosis.corrected_model.CorrectedModel.inputs``): per input, its time shifts, then its lags, then
its transforms in rank order, then its gains and offsets. :func:`input_stages` lists the same operations, in the
same order, as :class:`InputStage` records that ``c/cs_wrapper.c`` applies to each new sample; a stage that
interpolates towards later samples reads ``lookahead`` samples ahead (the exported FMU's outputs then lag by that
much more). A change without a C form (a lag of a smoothed rate, a transform without a stated form) is refused,
naming the input and the effect.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

#: Stage kind -> its code in ``cs_wrapper.c`` (what each computes of the samples v of one input, k the sample):
#: ``shift`` (r0 = s/dt): lerp of v at index k + r0 (the first sample before the start);
#: ``shift_mix`` (r0 = c, r1 = s/dt): v + c (shift(v) - v); ``actuator_lag`` (r0 = c, r1 = a = exp(-dt/T),
#: r2 = T/dt, r3 = 1 - a): v + c (lag(v) - v), lag(v) the interval mean of a first-order lag started at v[0];
#: ``lag`` (r0 = T, r1 = dt): v + T (v[k+1] - v[k]) / dt (the rate over the interval, no smoothing);
#: ``deadzone`` (c, d): v - c clip(v, -d, d); ``saturation_above`` (c, level): v - c max(v - level, 0);
#: ``saturation_below`` (c, level): v + c max(level - v, 0); ``gain`` (g): (1 + g) v; ``offset`` (o): v + o.
#: ``linear``: (v[k] + v[k+1]) / 2, the value a step holds of an input sampled from a continuous signal
#: (``hybridfmu.data.between_samples``; it comes first, before the diagnosed changes).
STAGE_CODES = {"shift": 1, "shift_mix": 2, "actuator_lag": 3, "lag": 4, "deadzone": 5, "saturation_above": 6,
               "saturation_below": 7, "gain": 8, "offset": 9, "linear": 10}


@dataclass(frozen=True)
class InputStage:
    """One operation on the samples of input ``column``: ``kind`` (:data:`STAGE_CODES`), its reals, and how far
    it reads ahead of and behind the sample it computes (samples)."""

    column: int
    kind: str
    reals: tuple[float, float, float, float]
    lookahead: int
    lookback: int


def _shift_reach(offset_samples: float) -> tuple[int, int]:
    """(lookahead, lookback) of an interpolation at k + offset_samples (its lower sample and the one after)."""
    lower = math.floor(offset_samples)
    return max(0, lower + 2), max(0, 1 - lower)


def _stage(column: int, kind: str, *reals: float, lookahead: int = 0, lookback: int = 0) -> InputStage:
    values = tuple(float(r) for r in reals) + (0.0,) * (4 - len(reals))
    return InputStage(column, kind, values, lookahead, lookback)  # type: ignore[arg-type]


def _transform_stage(column: int, form: tuple[str, float, float], dt_s: float) -> InputStage:
    kind, a, b = form
    if kind == "shift_mix":
        offset = b / dt_s  # as shift_samples computes the index: k + offset_s / dt_s
        ahead, behind = _shift_reach(offset)
        return _stage(column, kind, a, offset, lookahead=ahead, lookback=behind)
    if kind == "actuator_lag":
        decay = math.exp(-dt_s / b)  # as first_order_lag computes it
        return _stage(column, kind, a, decay, b / dt_s, 1.0 - decay)
    return _stage(column, kind, a, b)


def input_stages(input_changes: dict[int, list[tuple[str, dict[str, Any]]]], input_names: Sequence[str],
                 dt_s: float, lag_window_samples: int, conventions: Sequence[str] | None = None) -> list[InputStage]:
    """The stages of the inputs as a model sees them: per input, the value a step holds by its convention between
    samples (``linear``), then the diagnosed ``input_changes`` (``CorrectedModel.input_changes``: column ->
    [(effect kind, change)]) in the order :meth:`CorrectedModel.inputs` applies them; columns in ascending order.

    Args:
        input_names: the inputs' names (for messages); dt_s: the sampling interval (s).
        lag_window_samples: the smoothing window of a lag's input rate (samples; only 3, no smoothing, has a C form).
        conventions: each input's convention between samples (``hold`` or ``linear``, FMU order); None: all held.

    Raises:
        ValueError: a change without a C form, naming the input and the effect.
    """
    stages: list[InputStage] = []
    for column in range(len(input_names)):
        name = input_names[column]
        if conventions is not None and conventions[column] == "linear":
            stages.append(_stage(column, "linear", lookahead=1))
        changes = input_changes.get(column, [])
        for _, change in changes:
            if change.get("shift_s", 0.0):
                offset = change["shift_s"] / dt_s  # shift_inputs' index: k + offset_s / dt_s
                ahead, behind = _shift_reach(offset)
                stages.append(_stage(column, "shift", offset, lookahead=ahead, lookback=behind))
        for kind, change in changes:
            if change.get("lag_s", 0.0):
                if lag_window_samples != 3:
                    raise ValueError(f"export: the {kind} change of input {name!r} is a lag of its rate smoothed over "
                                     f"{lag_window_samples} samples, which has no C form (only 3 samples, no "
                                     "smoothing); set diagnosis.effects.lag_derivative_window_s to 3 samples or "
                                     "leave the effect out of the hybrid")
                stages.append(_stage(column, "lag", change["lag_s"], dt_s, lookahead=1))
        for kind, change in changes:
            if change.get("transform") is not None:
                form = change.get("form")
                if form is None:
                    raise ValueError(f"export: the {kind} change of input {name!r} is a transform without a stated "
                                     "form (make_input_change(form=...)); it cannot be evaluated in C")
                stages.append(_transform_stage(column, form, dt_s))
        for _, change in changes:
            if change.get("gain", 0.0):
                stages.append(_stage(column, "gain", change["gain"]))
        for _, change in changes:
            if change.get("offset", 0.0):
                stages.append(_stage(column, "offset", change["offset"]))
    return stages


def column_lookahead(stages: Sequence[InputStage], column: int) -> int:
    """Samples the stages of ``column`` read ahead of the sample they finish, together."""
    return sum(stage.lookahead for stage in stages if stage.column == column)
