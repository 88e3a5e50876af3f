"""Random training windows from the selected segments, gathered side by side into one batch."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from hybridfmu.training.data import ManeuverArrays


@dataclass
class WindowBatch:
    """B windows of n steps. ``u_seq`` (B, n + 2 pad + 1, n_u) reaches ``pad`` samples beyond both ends
    of each window (for the input delay); the window's first instant is ``u_seq[:, start_index]``.
    ``x0`` (B, n_x) initial states; ``targets`` (B, n + 1, n_t) measured target states (their units)."""

    u_seq: torch.Tensor
    start_index: int
    x0: torch.Tensor
    targets: torch.Tensor

    @property
    def n_steps(self) -> int:
        return self.targets.shape[1] - 1


def delay_padding(sample_period_s: float, delay_min_s: float, delay_max_s: float) -> int:
    """Samples needed beyond a window's ends so every delayed stage input is real data."""
    return int(math.ceil(max(abs(delay_min_s), abs(delay_max_s)) / sample_period_s)) + 2


class WindowSampler:
    """Draws window starts uniformly over all positions where a window of ``n_steps`` steps
    (n_steps + 1 samples) lies inside one selected segment, and gathers the batch.

    Args:
        arrays: the training maneuver.
        n_steps: steps per window (window length / sample period).
        pad: extra input samples on both sides (``delay_padding``).
    """

    def __init__(self, arrays: ManeuverArrays, n_steps: int, pad: int) -> None:
        if n_steps < 1:
            raise ValueError(f"windows need at least one step, got n_steps={n_steps}")
        self.n_steps, self.pad = int(n_steps), int(pad)
        first, count = [], []
        for start, end in arrays.spans:
            available = int(end - start) - self.n_steps
            if available > 0:
                first.append(int(start))
                count.append(available)
        if not count:
            longest = int((arrays.spans[:, 1] - arrays.spans[:, 0]).max()) if arrays.spans.size else 0
            raise ValueError(f"maneuver {arrays.name}: no selected segment holds a window of {self.n_steps} steps "
                             f"(longest segment: {longest} samples)")
        self._first = np.array(first, dtype=np.int64)
        self._cumulative = np.cumsum(count)
        self.n_positions = int(self._cumulative[-1])
        self._u = torch.from_numpy(np.ascontiguousarray(arrays.u))
        self._x = torch.from_numpy(np.ascontiguousarray(arrays.x_init))
        self._targets = torch.from_numpy(np.ascontiguousarray(arrays.targets))
        self._offsets = torch.arange(-self.pad, self.n_steps + self.pad + 1)
        self._steps = torch.arange(self.n_steps + 1)

    def sample_starts(self, rng: np.random.Generator, batch: int) -> np.ndarray:
        """(batch,) window start indices into the maneuver."""
        draws = rng.integers(0, self.n_positions, size=batch)
        span = np.searchsorted(self._cumulative, draws, side="right")
        previous = np.where(span > 0, self._cumulative[np.maximum(span - 1, 0)], 0)
        return self._first[span] + (draws - previous)

    def gather(self, starts: np.ndarray) -> WindowBatch:
        starts_t = torch.as_tensor(starts, dtype=torch.long)
        index = (starts_t[:, None] + self._offsets[None, :]).clamp(0, self._u.shape[0] - 1)
        steps = starts_t[:, None] + self._steps[None, :]
        return WindowBatch(u_seq=self._u[index], start_index=self.pad, x0=self._x[starts_t],
                           targets=self._targets[steps])
