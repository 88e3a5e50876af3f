"""Pre- and post-processing layers: trainable element-wise shift and scale."""

from __future__ import annotations

import torch
from torch import nn


def _as_parameter(values, size: int, name: str, owner: str) -> nn.Parameter:
    tensor = torch.as_tensor(values, dtype=torch.float64).clone().reshape(-1)
    if tensor.numel() != size:
        raise ValueError(f"{owner}: {name} has {tensor.numel()} values, expected {size}")
    if not torch.isfinite(tensor).all():
        raise ValueError(f"{owner}: {name} must be finite, got {tensor.tolist()}")
    return nn.Parameter(tensor)


class ShiftScale(nn.Module):
    """Pre-processing: y = (z + shift) * scale, per feature. z (N, m) -> y (N, m).

    ``from_statistics(mean, std)`` sets shift = -mean and scale = 1/std (scale 1 for features whose
    spread is not above ``min_std``), so normalised inputs have zero mean and unit spread over the data
    they were computed on.
    """

    def __init__(self, shift, scale) -> None:
        super().__init__()
        size = torch.as_tensor(shift).numel()
        self.shift = _as_parameter(shift, size, "shift", "ShiftScale")
        self.scale = _as_parameter(scale, size, "scale", "ShiftScale")

    @classmethod
    def from_statistics(cls, mean, std, min_std: float = 1e-12) -> "ShiftScale":
        mean = torch.as_tensor(mean, dtype=torch.float64)
        std = torch.as_tensor(std, dtype=torch.float64)
        scale = torch.where(std > min_std, 1.0 / std.clamp_min(min_std), torch.ones_like(std))
        return cls(-mean, scale)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return (z + self.shift) * self.scale

    def inverse(self) -> "ScaleShift":
        """The post-processing layer that undoes this one (a new, independent module)."""
        with torch.no_grad():
            return ScaleShift(1.0 / self.scale, -self.shift)


class ScaleShift(nn.Module):
    """Post-processing: y = a * scale + shift, per output. a (N, m) -> y (N, m).

    ``from_statistics(mean, std)`` sets scale = std and shift = mean, so an ANN output of unit spread
    becomes a signal with the spread of the quantity it models.
    """

    def __init__(self, scale, shift) -> None:
        super().__init__()
        size = torch.as_tensor(scale).numel()
        self.scale = _as_parameter(scale, size, "scale", "ScaleShift")
        self.shift = _as_parameter(shift, size, "shift", "ScaleShift")

    @classmethod
    def from_statistics(cls, mean, std) -> "ScaleShift":
        return cls(std, mean)

    def forward(self, a: torch.Tensor) -> torch.Tensor:
        return a * self.scale + self.shift
