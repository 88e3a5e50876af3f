"""Gates: how much of the FMU's and of the ANN's dynamics make up the corrected state derivatives."""

from __future__ import annotations

import torch
from torch import nn


class Gates(nn.Module):
    """xdot[k] = g_F[k] * xdot_F[k] + g_A[k] * xdot_A[k] for the corrected states k; other states forwarded.

    Args:
        n_states: number of states n_x.
        corrected: indices of the corrected states (into the state vector), length n_c.
        opening: initial ANN gate g_A (the FMU gate g_F starts at 1).

    forward(xdot_F (N, n_x), xdot_A (N, n_c)) -> xdot (N, n_x).
    """

    def __init__(self, n_states: int, corrected: list[int], opening: float) -> None:
        super().__init__()
        if not corrected:
            raise ValueError("Gates: at least one corrected state is needed")
        if len(set(corrected)) != len(corrected) or min(corrected) < 0 or max(corrected) >= n_states:
            raise ValueError(f"Gates: corrected indices {corrected} must be distinct and in [0, {n_states})")
        self.n_states = n_states
        self.register_buffer("corrected", torch.tensor(corrected, dtype=torch.long))
        self.g_F = nn.Parameter(torch.ones(len(corrected), dtype=torch.float64))
        self.g_A = nn.Parameter(torch.full((len(corrected),), float(opening), dtype=torch.float64))

    def fmu_gate_vector(self) -> torch.Tensor:
        """(n_x,) factors on xdot_F: g_F at the corrected states, 1 elsewhere."""
        ones = torch.ones(self.n_states, dtype=self.g_F.dtype)
        return ones.index_copy(0, self.corrected, self.g_F)

    def forward(self, xdot_F: torch.Tensor, xdot_A: torch.Tensor) -> torch.Tensor:
        ann = torch.zeros_like(xdot_F).index_copy(1, self.corrected, xdot_A * self.g_A)
        return xdot_F * self.fmu_gate_vector() + ann
