"""Validation: open-loop simulation over the selected segments of a maneuver, each from its measured state."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.model.spec import NeuralFmuSpec
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.losses import MEASURES, Objective, error_measures, weighted_loss
from hybridfmu.training.solver import rollout
from hybridfmu.training.windows import delay_padding


@dataclass(frozen=True)
class ValidationBatch:
    """What every validation of one maneuver shares, whatever the model's parameters: the segments side by
    side (their input sequences with the delay's padding, first states, measured targets) and the mask of
    the samples inside each segment. Built once per job by :func:`validation_batch`."""

    u_seq: torch.Tensor    # (S, n_max + 2 pad + 1, n_u)
    pad: int
    x0: torch.Tensor       # (S, n_x)
    n_steps: int           # n_max
    mask: torch.Tensor     # (S, n_max + 1) True where a sample lies inside its segment
    targets: torch.Tensor  # (S, n_max + 1, n_t)
    target_index: torch.Tensor


def validation_batch(spec: NeuralFmuSpec, arrays: ManeuverArrays) -> ValidationBatch:
    """The validation batch of ``arrays`` for models of ``spec`` (its sample period and delay range)."""
    pad = delay_padding(spec.sample_period_s, spec.delay_min_s, spec.delay_max_s)
    starts = torch.as_tensor(arrays.spans[:, 0], dtype=torch.long)
    lengths = torch.as_tensor(arrays.spans[:, 1] - arrays.spans[:, 0], dtype=torch.long)
    n_steps = int(lengths.max()) - 1
    u = torch.from_numpy(np.ascontiguousarray(arrays.u))
    index = (starts[:, None] + torch.arange(-pad, n_steps + pad + 1)[None, :]).clamp(0, u.shape[0] - 1)
    x0 = torch.from_numpy(np.ascontiguousarray(arrays.x_init))[starts]
    mask = torch.arange(n_steps + 1)[None, :] < lengths[:, None]
    steps = torch.arange(n_steps + 1)
    target_rows = (starts[:, None] + steps[None, :]).clamp(0, arrays.time_s.size - 1)
    targets = torch.from_numpy(np.ascontiguousarray(arrays.targets))[target_rows]
    return ValidationBatch(u_seq=u[index], pad=pad, x0=x0, n_steps=n_steps, mask=mask, targets=targets,
                           target_index=torch.as_tensor(arrays.target_index, dtype=torch.long))


def simulate_segments(model: NeuralFmu, arrays: ManeuverArrays,
                      batch: ValidationBatch | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """All selected segments side by side, open loop from their first samples.

    ``batch``: :func:`validation_batch` of ``arrays`` for ``model.spec`` (built here when None).

    Returns (states (S, n_max + 1, n_x), mask (S, n_max + 1) True where a sample lies inside its segment; the
    states outside a segment are not meaningful).
    """
    batch = batch or validation_batch(model.spec, arrays)
    with torch.no_grad():  # each segment integrated over its own length only
        states = rollout(model, batch.u_seq, batch.pad, batch.x0, batch.n_steps, row_steps=batch.mask.sum(1) - 1)
    return states, batch.mask


def validate(model: NeuralFmu, arrays: ManeuverArrays, loss_kind: str, weights: dict[str, float],
             objective: Objective, statistics: dict[str, Any],
             batch: ValidationBatch | None = None) -> dict[str, float]:
    """Open-loop error over the selected segments of ``arrays``.

    Args:
        model: the neural FMU; arrays: the validation maneuver.
        loss_kind, weights: the trial's own loss (kind, target state -> weight).
        objective: the search's common selection measure (:class:`Objective`).
        statistics: training data statistics (``target_std``: the loss scales).
        batch: :func:`validation_batch` of ``arrays`` for ``model.spec``, shared by a job's validations
            (built here when None).

    Returns:
        ``loss`` (the trial's own weighted loss), ``objective``, ``<signal>_mae``, ``<signal>_mse``,
        ``<signal>_rmse`` per target signal (units of the signal), and ``finite`` (1.0, or 0.0 when the
        simulation diverged; then every value is inf).
    """
    batch = batch or validation_batch(model.spec, arrays)
    states, mask = simulate_segments(model, arrays, batch)
    return score_states(states, mask, batch, arrays, loss_kind, weights, objective, statistics)


def score_states(states: torch.Tensor, mask: torch.Tensor, batch: ValidationBatch, arrays: ManeuverArrays,
                 loss_kind: str, weights: dict[str, float], objective: Objective,
                 statistics: dict[str, Any]) -> dict[str, float]:
    """The metrics of :func:`validate` from simulated segments (``simulate_segments``: states (S, n_max + 1,
    n_x), mask (S, n_max + 1)) of ``batch``, the validation batch of ``arrays``."""
    mask = mask.clone()
    mask[:, 0] = False  # the initial state is given, not predicted
    errors = states.index_select(2, batch.target_index) - batch.targets  # (S, n + 1, n_t)
    scales = [float(value) for value in statistics["target_std"]]
    if not bool(torch.isfinite(errors[mask]).all()):
        names = [f"{signal}_{measure}" for signal in arrays.target_signals for measure in MEASURES]
        return {"loss": math.inf, "objective": math.inf, **{name: math.inf for name in names}, "finite": 0.0}
    metrics = error_measures(errors, arrays.target_signals, mask)
    metrics["loss"] = float(weighted_loss(errors, loss_kind, [weights[n] for n in arrays.target_states], scales,
                                          mask))
    metrics["objective"] = float(weighted_loss(errors, objective.loss,
                                               [objective.weights[n] for n in arrays.target_states], scales, mask))
    metrics["finite"] = 1.0
    return metrics
