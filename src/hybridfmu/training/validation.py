"""Validation: open-loop simulation over the selected segments of a maneuver, each from its measured state."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.losses import MEASURES, Objective, error_measures, weighted_loss
from hybridfmu.training.solver import rollout
from hybridfmu.training.windows import delay_padding


def simulate_segments(model: NeuralFmu, arrays: ManeuverArrays) -> tuple[torch.Tensor, torch.Tensor]:
    """All selected segments side by side, open loop from their first samples.

    Returns (states (S, n_max + 1, n_x), mask (S, n_max + 1) True where a sample lies inside its segment).
    """
    spec = model.spec
    pad = delay_padding(spec.sample_period_s, spec.delay_min_s, spec.delay_max_s)
    starts = torch.as_tensor(arrays.spans[:, 0], dtype=torch.long)
    lengths = torch.as_tensor(arrays.spans[:, 1] - arrays.spans[:, 0], dtype=torch.long)
    n_steps = int(lengths.max()) - 1
    u = torch.from_numpy(np.ascontiguousarray(arrays.u))
    index = (starts[:, None] + torch.arange(-pad, n_steps + pad + 1)[None, :]).clamp(0, u.shape[0] - 1)
    x0 = torch.from_numpy(np.ascontiguousarray(arrays.x_init))[starts]
    with torch.no_grad():
        states = rollout(model, u[index], pad, x0, n_steps)
    mask = torch.arange(n_steps + 1)[None, :] < lengths[:, None]
    return states, mask


def validate(model: NeuralFmu, arrays: ManeuverArrays, loss_kind: str, weights: dict[str, float],
             objective: Objective, statistics: dict[str, Any]) -> dict[str, float]:
    """Open-loop error over the selected segments of ``arrays``.

    Args:
        model: the neural FMU; arrays: the validation maneuver.
        loss_kind, weights: the trial's own loss (kind, target state -> weight).
        objective: the search's common selection measure (:class:`Objective`).
        statistics: training data statistics (``target_std``: the loss scales).

    Returns:
        ``loss`` (the trial's own weighted loss), ``objective``, ``<signal>_mae``, ``<signal>_mse``,
        ``<signal>_rmse`` per target signal (units of the signal), and ``finite`` (1.0, or 0.0 when the
        simulation diverged; then every value is inf).
    """
    states, mask = simulate_segments(model, arrays)
    mask = mask.clone()
    mask[:, 0] = False  # the initial state is given, not predicted
    steps = torch.arange(states.shape[1])
    index = (torch.as_tensor(arrays.spans[:, 0])[:, None] + steps[None, :]).clamp(0, arrays.time_s.size - 1)
    targets = torch.from_numpy(np.ascontiguousarray(arrays.targets))[index]  # (S, n + 1, n_t)
    errors = states.index_select(2, torch.as_tensor(arrays.target_index, dtype=torch.long)) - targets
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
