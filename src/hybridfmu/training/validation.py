"""Validation: open-loop simulation over the selected segments of a maneuver, each from its measured state."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.losses import error_measures, weighted_loss
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


def validate(model: NeuralFmu, arrays: ManeuverArrays, loss_kind: str, w_speed: float,
             objective: dict[str, Any], scales: dict[str, float]) -> dict[str, float]:
    """Open-loop error over the selected segments of ``arrays``.

    Returns ``loss`` (the trial's own weighted loss), ``objective`` (the search's common selection
    measure: ``objective["loss"]``, ``objective["w_speed"]``), angle/speed MAE and MSE (rad, rad/s),
    and ``finite`` (1.0, or 0.0 when the simulation diverged; then loss and objective are inf).
    """
    states, mask = simulate_segments(model, arrays)
    mask = mask.clone()
    mask[:, 0] = False  # the initial state is given, not predicted
    steps = torch.arange(states.shape[1])
    index = (torch.as_tensor(arrays.spans[:, 0])[:, None] + steps[None, :]).clamp(0, arrays.time_s.size - 1)
    angle = torch.from_numpy(arrays.angle)[index]
    speed = torch.from_numpy(arrays.speed)[index]
    i_angle, i_speed = arrays.state_names.index(arrays.angle_state), arrays.state_names.index(arrays.speed_state)
    angle_error = states[:, :, i_angle] - angle
    speed_error = states[:, :, i_speed] - speed
    finite = bool(torch.isfinite(angle_error[mask]).all() and torch.isfinite(speed_error[mask]).all())
    if not finite:
        return {"loss": math.inf, "objective": math.inf, "angle_mae": math.inf, "angle_mse": math.inf,
                "speed_mae": math.inf, "speed_mse": math.inf, "finite": 0.0}
    metrics = error_measures(angle_error, speed_error, mask)
    metrics["loss"] = float(weighted_loss(angle_error, speed_error, loss_kind, w_speed, scales["angle_std"],
                                          scales["speed_std"], mask))
    metrics["objective"] = float(weighted_loss(angle_error, speed_error, objective["loss"], objective["w_speed"],
                                               scales["angle_std"], scales["speed_std"], mask))
    metrics["finite"] = 1.0
    return metrics
