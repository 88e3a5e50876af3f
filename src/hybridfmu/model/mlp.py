"""The artificial neural network of the neural FMU: a tanh multilayer perceptron."""

from __future__ import annotations

import torch
from torch import nn


class TanhMLP(nn.Module):
    """``depth`` hidden layers of ``width`` tanh units and a linear output layer.

    z (N, n_in) -> (N, n_out). Weights are float64, initialised by ``torch.nn.Linear``'s default
    (seed the torch generator before construction for reproducibility).
    """

    def __init__(self, n_in: int, n_out: int, width: int, depth: int) -> None:
        super().__init__()
        if n_in < 1 or n_out < 1 or width < 1 or depth < 1:
            raise ValueError(f"TanhMLP: n_in, n_out, width, depth must be >= 1, got {n_in}, {n_out}, {width}, {depth}")
        sizes = [n_in] + [width] * depth
        self.hidden = nn.ModuleList(nn.Linear(a, b, dtype=torch.float64) for a, b in zip(sizes[:-1], sizes[1:]))
        self.output = nn.Linear(width, n_out, dtype=torch.float64)
        self.width = width
        self.depth = depth

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        for layer in self.hidden:
            z = torch.tanh(layer(z))
        return self.output(z)
