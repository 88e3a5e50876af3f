"""How each FMU input passes between the grid's samples in every simulation: held, or linear.

Every simulator of the workflow (the FMU's open loop in C, the neural FMU and hybrid in training and
evaluation, the calibration, the diagnosis) steps from grid sample to grid sample with one value of each input
held over the step (the neural FMU's input delay places that value at the step's centre, ``hold_center``).
Which value is held depends on the input's convention:

- ``hold``: a sampled command (a PWM duty, a setpoint written by control software) that really is constant
  between its samples: the step holds the sample at its start, ``u[k]`` over ``[t_k, t_k+1)``;
- ``linear``: a continuous measurement (a force, a pressure, a supply voltage) sampled on the grid: the step
  holds the signal's mean over the step, ``(u[k] + u[k+1]) / 2`` for the line through the samples. Holding the
  sample at the start would delay the signal by half a sample, which a time-offset estimate or a learned
  input delay then reports as a channel offset that is not there. The mean leaves no delay; what it drops,
  the signal's change within one step, moves the states by O(h^2) of it.

The convention of each input is declared in ``config.roles.between_samples`` (FMU input -> hold | linear);
an input whose signal is resampled with ``resample: hold`` is held. Every other input's convention is
chosen from the raw logs of the train and validation maneuvers (rule ``choose_grid``; a test maneuver informs
no choice): a channel that repeats its previous sample in at least ``REPEAT_SHARE_HOLD`` of its raw samples
moves in steps and is held, any other is linear. A derived input (a transform's output) is held only when
every logged channel it is computed from is held.

The ingest stage records the conventions in each ingested frame's ``attrs[ATTRS_KEY]`` (kept in its Parquet
file), and :func:`hybridfmu.data.signals.input_array` applies them: every reader of an FMU input gets the
values the simulation holds.

API::

    declared_conventions(config, roles) -> {input: convention or None}   # None: to be chosen from the data
    repeat_share(values) -> float
    choose_conventions(undeclared, samples, roles) -> {input: {"convention", "repeat_share", "text"}}
    held_values(u, conventions) -> (T, n_u)
    frame_conventions(frame, input_names) -> [convention]
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from hybridfmu.data.errors import DataError

#: The conventions an FMU input can have.
CONVENTIONS = ("hold", "linear")
#: Key of the conventions (FMU input -> convention) in an ingested frame's ``attrs``.
ATTRS_KEY = "between_samples"
#: A raw channel that repeats its previous sample at least this often (share of its sample-to-sample
#: increments that are exactly zero) moves in steps: held.
REPEAT_SHARE_HOLD = 0.5
#: The convention of an input an ingested frame does not record (a frame built by hand): as the simulators
#: did before conventions existed.
DEFAULT_CONVENTION = "hold"


def declared_conventions(config: Mapping[str, Any], roles: Any) -> dict[str, str | None]:
    """Each FMU input's convention as the config declares it, in FMU order: ``config.roles.between_samples``,
    else ``hold`` for an input whose signal is resampled with ``resample: hold``, else None (chosen from the data).

    Raises:
        DataError: ``config.roles.between_samples`` names something that is not an FMU input, or a convention
            other than hold or linear (names the field).
    """
    declared = dict((config.get("roles") or {}).get("between_samples") or {})
    unknown = [name for name in declared if name not in roles.input_names]
    if unknown:
        raise DataError(f"config.roles.between_samples: {unknown} are not FMU inputs; expected some of "
                        f"{list(roles.input_names)}")
    for name, convention in declared.items():
        if convention not in CONVENTIONS:
            raise DataError(f"config.roles.between_samples.{name}: {convention!r}; expected one of {list(CONVENTIONS)}")
    result: dict[str, str | None] = {}
    for name in roles.input_names:
        signal = roles.signals[roles.inputs[name]]
        result[name] = declared.get(name) or ("hold" if signal.resample == "hold" else None)
    return result


def repeat_share(values: np.ndarray) -> float:
    """Share of a raw channel's sample-to-sample increments that are exactly zero, over its finite samples.

    Args:
        values: (n,) raw samples in time order.

    Returns:
        A share in [0, 1]; 1.0 for fewer than two finite samples (nothing moves).
    """
    repeats, increments = _repeats(values)
    return repeats / increments if increments else 1.0


def _repeats(values: np.ndarray) -> tuple[int, int]:
    """(zero increments, increments) between a channel's consecutive finite samples."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    steps = np.diff(values)
    return int(np.count_nonzero(steps == 0.0)), int(steps.size)


def logged_sources(signal: str, roles: Any) -> list[str]:
    """The logged signals a signal is computed from: itself when logged, else the logged inputs of the
    transforms that derive it (recursively), in first-seen order."""
    from hybridfmu.data.transforms import transform_of

    if not roles.signals[signal].derived:
        return [signal]
    for index, spec in enumerate(roles.transforms):
        transform = transform_of(spec, index)
        if signal in transform.outputs(spec):
            sources: list[str] = []
            for name in transform.inputs(spec):
                sources += [s for s in logged_sources(name, roles) if s not in sources]
            return sources
    raise DataError(f"signal {signal!r}: neither logged nor derived by config.transforms")


def choose_conventions(undeclared: Sequence[str], samples: Mapping[str, Sequence[np.ndarray]], roles: Any
                       ) -> dict[str, dict[str, Any]]:
    """The conventions of the inputs the config leaves out, from the raw samples of their logged channels.

    Args:
        undeclared: FMU inputs to choose for.
        samples: logged signal -> its raw channel's (n,) samples, one array per maneuver (train and
            validation maneuvers only).
        roles: the case's roles (which signal feeds each input, the transforms).

    Returns:
        FMU input -> ``{"convention", "repeat_share", "text"}``: the lowest repeat share over the input's
        logged sources (pooled over the maneuvers), and a sentence for the report.
    """
    chosen = {}
    for name in undeclared:
        signal = roles.inputs[name]
        shares = {}
        for source in logged_sources(signal, roles):
            counts = [_repeats(a) for a in samples.get(source) or []]
            increments = sum(n for _, n in counts)
            shares[source] = sum(r for r, _ in counts) / increments if increments else 1.0
        share = min(shares.values())
        convention = "hold" if share >= REPEAT_SHARE_HOLD else "linear"
        what = ("moves in steps: held over each sample" if convention == "hold"
                else "moves continuously: each step holds its mean over the step (no half-sample delay)")
        via = "" if list(shares) == [signal] else f" (computed from {', '.join(shares)})"
        chosen[name] = {"convention": convention, "repeat_share": share,
                        "text": (f"{convention}: {signal}{via} repeats its previous raw sample in {share:.0%} of "
                                 f"its samples (held from {REPEAT_SHARE_HOLD:.0%}), it {what}")}
    return chosen


def held_values(u: np.ndarray, conventions: Sequence[str]) -> np.ndarray:
    """The value each simulation step holds, from the inputs sampled on the grid.

    Args:
        u: (T, n_u) input samples at the grid times t_k (FMU order).
        conventions: n_u conventions (``CONVENTIONS``), FMU order.

    Returns:
        (T, n_u) float64: row k is held over [t_k, t_k+1). A ``hold`` column is returned as sampled; a ``linear``
        column holds the mean of the line through its samples over each step, (u[k] + u[k+1]) / 2, and in the
        last row the line's value half a step after the last sample (so that the value at the last sample,
        interpolated between the step centres, is the sample itself).
    """
    u = np.asarray(u, dtype=np.float64)
    if u.ndim != 2 or u.shape[1] != len(conventions):
        raise ValueError(f"held_values: expected u of shape (T, {len(conventions)}), got {u.shape}")
    unknown = [c for c in conventions if c not in CONVENTIONS]
    if unknown:
        raise ValueError(f"held_values: conventions {unknown}; expected {list(CONVENTIONS)}")
    linear = [j for j, c in enumerate(conventions) if c == "linear"]
    if not linear or u.shape[0] < 2:
        return u
    held = u.copy()
    held[:-1, linear] = 0.5 * (u[:-1, linear] + u[1:, linear])
    held[-1, linear] = 1.5 * u[-1, linear] - 0.5 * u[-2, linear]
    return held


def frame_conventions(frame: Any, input_names: Sequence[str]) -> list[str]:
    """The conventions an ingested frame records for the FMU inputs (``frame.attrs[ATTRS_KEY]``), in the given
    order; ``DEFAULT_CONVENTION`` for an input it does not record."""
    recorded = dict(getattr(frame, "attrs", {}).get(ATTRS_KEY) or {})
    return [str(recorded.get(name, DEFAULT_CONVENTION)) for name in input_names]
