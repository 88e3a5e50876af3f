"""Derived signals: transforms a case declares (config section ``transforms``), each implemented once.

A transform reads signals already on the case's grid (logged or derived before it) and adds new
ones. Kinds:

- ``scale``: ``output = input * factor`` with ``factor`` a quantity string (``"0.0125 N*m/bar"``);
  the output's unit follows from the input's unit times the factor's.
- ``derivative``: ``output = d input / dt`` by a Savitzky-Golay differentiator over ``window_s``
  (local polynomial of degree ``polyorder``, zero phase); unit: input unit per second.
- ``park`` (:mod:`hybridfmu.data.transforms.motor`): phase quantities of a three-phase machine to
  the rotor frame with a measured angle.

Every transform answers two questions: which units its outputs have (checked before any job
runs, :func:`output_units`) and what their values are (:func:`apply_transforms`, at ingest).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hybridfmu.data.transforms.base import Transform, TransformError
from hybridfmu.data.transforms.calculus import Derivative, Scale
from hybridfmu.data.transforms.motor import Park

#: Transform kinds by the name a config uses.
TRANSFORMS: dict[str, Transform] = {transform.kind: transform for transform in (Scale(), Derivative(), Park())}


def transform_of(spec: dict[str, Any], index: int) -> Transform:
    """The transform a config entry names (``config.transforms[index].kind``).

    Raises:
        TransformError: unknown kind (the message lists the known ones).
    """
    kind = spec.get("kind")
    if kind not in TRANSFORMS:
        raise TransformError(f"config.transforms[{index}].kind: {kind!r} is not a known transform; "
                             f"expected one of {sorted(TRANSFORMS)}")
    return TRANSFORMS[kind]


def output_units(specs: list[dict[str, Any]], units: dict[str, str]) -> dict[str, str]:
    """Units of every signal after the transforms, in order.

    Args:
        specs: the config's ``transforms`` entries.
        units: unit of every logged signal (on the model side).

    Returns:
        ``units`` extended by the transforms' outputs.

    Raises:
        TransformError: naming ``config.transforms[i]`` and the field: an input that no signal or earlier
            transform provides, an output that already exists, a unit of the wrong dimension.
    """
    known = dict(units)
    for index, spec in enumerate(specs):
        transform = transform_of(spec, index)
        where = f"config.transforms[{index}] ({spec['kind']})"
        missing = [name for name in transform.inputs(spec) if name not in known]
        if missing:
            raise TransformError(f"{where}: input signal(s) {missing} are neither logged signals nor outputs of "
                                 f"an earlier transform; known: {sorted(known)}")
        clashes = [name for name in transform.outputs(spec) if name in known]
        if clashes:
            raise TransformError(f"{where}: output signal(s) {clashes} already exist; expected new names")
        known.update(transform.output_units(spec, known, where))
    return known


def apply_transforms(specs: list[dict[str, Any]], columns: dict[str, np.ndarray], units: dict[str, str],
                     rate_hz: float) -> dict[str, np.ndarray]:
    """Add the transforms' outputs to ``columns`` (in place, in config order) and return it.

    Args:
        specs: the config's ``transforms`` entries.
        columns: signal name -> (T,) values on the uniform grid, in the signal's unit ``units[name]``.
        units: unit of every signal, transforms' outputs included (:func:`output_units`).
        rate_hz: sample rate of the grid (Hz).
    """
    for index, spec in enumerate(specs):
        transform = transform_of(spec, index)
        columns.update(transform.apply(spec, columns, units, rate_hz))
    return columns


__all__ = ["TRANSFORMS", "Transform", "TransformError", "apply_transforms", "output_units", "transform_of"]

