"""The weighted loss over the target states and the validation error measures per target signal.

Errors are simulated minus measured target states, last axis = targets (order of the case's
``target_states``), each in the model unit of its signal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import torch

LOSS_KINDS = ("MAE", "MSE")
#: Error measures per target signal, in the order they are written (``<signal>_<measure>``).
MEASURES = ("mae", "mse", "rmse")


def weighted_loss(errors: torch.Tensor, kind: str, weights: Sequence[float], scales: Sequence[float],
                  mask: torch.Tensor | None = None) -> torch.Tensor:
    """sum_k w_k * E(errors[..., k] / scale_k) with E the mean absolute ("MAE") or mean squared ("MSE") value.

    Args:
        errors: (..., n_t) simulated minus measured targets.
        kind: "MAE" or "MSE".
        weights: (n_t,) target weights (each in [0, 1]).
        scales: (n_t,) spreads (std) of the targets in the training data, in their units.
        mask: optional bool tensor of shape ``errors.shape[:-1]``; E averages over the True entries only.

    Returns:
        0-d tensor (dimensionless).
    """
    if kind not in LOSS_KINDS:
        raise ValueError(f"loss kind must be one of {LOSS_KINDS}, got {kind!r}")
    n_targets = errors.shape[-1]
    if len(weights) != n_targets or len(scales) != n_targets:
        raise ValueError(f"weighted_loss: {n_targets} targets but {len(weights)} weights and {len(scales)} scales")
    if any(not 0.0 <= float(w) <= 1.0 for w in weights):
        raise ValueError(f"target weights must lie in [0, 1], got {list(weights)}")
    scale = torch.as_tensor([float(s) for s in scales], dtype=errors.dtype)
    scaled = errors / scale
    values = scaled.abs() if kind == "MAE" else scaled * scaled
    means = values.mean(dim=tuple(range(values.dim() - 1))) if mask is None else values[mask].mean(dim=0)
    return (means * torch.as_tensor([float(w) for w in weights], dtype=errors.dtype)).sum()


def error_measures(errors: torch.Tensor, signals: Sequence[str], mask: torch.Tensor | None = None) -> dict[str, float]:
    """``<signal>_mae``, ``<signal>_mse``, ``<signal>_rmse`` per target signal (units of the signal, squared
    for the MSE).

    Args:
        errors: (..., n_t) simulated minus measured targets; signals: (n_t,) their signal names.
        mask: optional bool tensor of shape ``errors.shape[:-1]`` selecting the samples.
    """
    flat = errors.reshape(-1, errors.shape[-1]) if mask is None else errors[mask]
    out: dict[str, float] = {}
    for k, signal in enumerate(signals):
        column = flat[:, k]
        mse = float((column ** 2).mean())
        out[f"{signal}_mae"] = float(column.abs().mean())
        out[f"{signal}_mse"] = mse
        out[f"{signal}_rmse"] = math.sqrt(mse) if math.isfinite(mse) else math.inf
    return out


@dataclass(frozen=True)
class Objective:
    """The search's common validation measure: loss kind and one weight per target state (sum 1)."""

    loss: str
    weights: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {"loss": self.loss, "weights": dict(self.weights)}


def weight_overrides(values: dict[str, Any]) -> dict[str, float]:
    """Target weights set explicitly by entries ``w_<state>`` (hyperparameters, objective): state -> weight."""
    return {key[2:]: float(value) for key, value in values.items() if key.startswith("w_")}


def objective_from_config(objective: dict[str, Any], roles: Any) -> Objective:
    """The validated ``hpo.objective`` section (``loss`` and optional ``w_<state>``) with the case's roles.

    Raises:
        ValueError: a ``w_<state>`` names no target state (the message lists the targets).
    """
    try:
        weights = roles.weights_with(weight_overrides(objective))
    except ValueError as err:
        raise ValueError(f"config.hpo.objective: {err}") from None
    return Objective(str(objective.get("loss", "MAE")), weights)
