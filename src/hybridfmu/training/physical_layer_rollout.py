"""The open-loop rollout of a hybrid's untrained state over the validation segments, shared by its search.

An untrained hybrid is its physical layer: its ANN's output layer and post-processing shift start at zero and
its FMU gates at 1, so its derivative is the physical layer's to the bit, whatever the configuration's width,
depth or gate opening. Every rung-0 trial of the hybrid's search validates that state first (the search never
reports a hybrid worse than its physical layer), and the rollout over the validation segments is the
expensive part of a validation. Rule ``physical_layer_rollout`` runs it once per search
(:func:`write_physical_layer_rollout`); each trial checks that the file is of its own untrained model (the
same physical layer, delays, coefficients, solver and validation data: :func:`rollout_key`) and scores the
saved states with its own loss (:func:`hybridfmu.training.validation.score_states`). A trial whose model is
not its physical layer, or whose key differs, simulates itself.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hybridfmu.io import atomic_path
from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.validation import ValidationBatch, simulate_segments

LOG = logging.getLogger(__name__)

#: Spec fields that do not change an untrained hybrid's derivative (its ANN contributes exactly zero).
ANN_ONLY_FIELDS = ("width", "depth", "gate_opening", "extra")


def untrained_is_physical_layer(model: NeuralFmu) -> bool:
    """True when ``model`` is a hybrid whose derivative is its physical layer's exactly: zero output layer
    (weights and bias), zero post-processing shift and FMU gates at 1."""
    if model.spec.physics_effects is None:
        return False
    output = model.ann.output
    return bool(torch.all(output.weight == 0) and torch.all(output.bias == 0) and torch.all(model.post.shift == 0)
                and torch.all(model.gates.g_F == 1))


def rollout_key(model: NeuralFmu, arrays: ManeuverArrays, sources: dict[str, str]) -> str:
    """What the untrained rollout depends on, as a hex digest: the spec without the ANN-only fields, the
    delays, the physical layer's trainable coefficients, the validation maneuver's inputs, starting states and
    segments (as the hybrid sees them), and ``sources`` ({name: digest} of the files the physical layer is
    made of: FMU, calibration, diagnosed model)."""
    spec = {key: value for key, value in model.spec.to_dict().items() if key not in ANN_ONLY_FIELDS}
    coefficients = model.fmu.coefficients()
    digest = hashlib.sha256()
    digest.update(json.dumps({"spec": spec, "sources": sources}, sort_keys=True, default=str).encode())
    digest.update(model.delay.delays_s().detach().numpy().tobytes())
    if coefficients is not None:
        digest.update(coefficients.detach().numpy().tobytes())
    for values in (arrays.time_s, arrays.u, arrays.x_init, arrays.spans):
        digest.update(np.ascontiguousarray(values).tobytes())
    return digest.hexdigest()


def write_physical_layer_rollout(path: str | Path, model: NeuralFmu, arrays: ManeuverArrays, sources: dict[str, str],
                                 batch: ValidationBatch | None = None) -> dict[str, Any]:
    """Simulate the untrained hybrid ``model`` over the validation segments of ``arrays`` and save the states
    (``sources`` as :func:`rollout_key`).

    Writes ``path`` (torch file: ``key``, ``states`` (S, n_max + 1, n_x), ``mask`` (S, n_max + 1)) atomically
    and returns its content.

    Raises:
        ValueError: ``model`` is not its physical layer (a neural FMU, or a hybrid already trained).
    """
    if not untrained_is_physical_layer(model):
        raise ValueError("physical-layer rollout: the model is not an untrained hybrid (its ANN does not contribute "
                         "exactly zero)")
    states, mask = simulate_segments(model, arrays, batch)
    content = {"key": rollout_key(model, arrays, sources), "states": states, "mask": mask}
    with atomic_path(path) as tmp:
        torch.save(content, tmp)
    LOG.info("physical layer over %d validation segments of %s: %s", int(mask.shape[0]), arrays.name,
             "finite" if bool(torch.isfinite(states[mask]).all()) else "diverged")
    return content


def read_physical_layer_rollout(path: str | Path, model: NeuralFmu, arrays: ManeuverArrays,
                                sources: dict[str, str]) -> tuple[torch.Tensor, torch.Tensor] | None:
    """The saved rollout of ``path`` when it is ``model``'s own untrained rollout over ``arrays`` (``sources``
    as :func:`rollout_key`): (states, mask); else None (the reason is logged).

    Raises:
        ValueError: the file is not a physical-layer rollout (names the file).
    """
    try:
        content = torch.load(path, weights_only=True)
        key, states, mask = content["key"], content["states"], content["mask"]
    except Exception as err:
        raise ValueError(f"{path}: not a physical-layer rollout written by rule physical_layer_rollout "
                         f"(fields key, states, mask): {type(err).__name__}: {err}") from err
    if not untrained_is_physical_layer(model):
        LOG.info("%s: not used, the model is not its physical layer", path)
        return None
    if key != rollout_key(model, arrays, sources):
        LOG.warning("%s: not used, it is the rollout of another physical layer, delays or validation data", path)
        return None
    return states, mask
