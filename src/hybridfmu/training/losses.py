"""Weighted angle/speed loss and the validation error measures."""

from __future__ import annotations

import torch

LOSS_KINDS = ("MAE", "MSE")


def weighted_loss(angle_error: torch.Tensor, speed_error: torch.Tensor, kind: str, w_speed: float,
                  angle_scale: float, speed_scale: float, mask: torch.Tensor | None = None) -> torch.Tensor:
    """(1 - w_speed) * E(angle_error / angle_scale) + w_speed * E(speed_error / speed_scale).

    Args:
        angle_error, speed_error: simulated minus measured angle (rad) and speed (rad/s), any equal shape.
        kind: "MAE" (mean absolute) or "MSE" (mean squared) for E.
        w_speed: weight of the speed term in [0, 1].
        angle_scale, speed_scale: spreads (std) of angle (rad) and speed (rad/s) in the training data.
        mask: optional bool tensor of the same shape; E averages over the True entries only.
    """
    if kind not in LOSS_KINDS:
        raise ValueError(f"loss kind must be one of {LOSS_KINDS}, got {kind!r}")
    if not 0.0 <= w_speed <= 1.0:
        raise ValueError(f"w_speed must be in [0, 1], got {w_speed}")
    terms = []
    for error, scale in ((angle_error, angle_scale), (speed_error, speed_scale)):
        scaled = error / scale
        values = scaled.abs() if kind == "MAE" else scaled * scaled
        terms.append(values.mean() if mask is None else values[mask].mean())
    return (1.0 - w_speed) * terms[0] + w_speed * terms[1]


def error_measures(angle_error: torch.Tensor, speed_error: torch.Tensor,
                   mask: torch.Tensor | None = None) -> dict[str, float]:
    """Angle MAE (rad) and MSE (rad^2), speed MAE (rad/s) and MSE (rad^2/s^2)."""
    if mask is not None:
        angle_error, speed_error = angle_error[mask], speed_error[mask]
    return {"angle_mae": float(angle_error.abs().mean()), "angle_mse": float((angle_error ** 2).mean()),
            "speed_mae": float(speed_error.abs().mean()), "speed_mse": float((speed_error ** 2).mean())}
