"""Input-delay layer: u(t + dt) from sampled inputs, with a trainable, bounded time offset dt (s)."""

from __future__ import annotations

import math

import torch
from torch import nn

#: Where a sample sits within its sampling interval for the interpolation.
#: ``hold_center``: sample j is the value held over [t_j, t_j + h) (as in the FMU's open-loop simulation
#: with inputs held between samples) and is placed at the interval's centre t_j + h/2, so dt = 0 adds no lag;
#: ``sample_instant``: sample j is placed at t_j.
SAMPLE_POSITIONS = {"hold_center": 0.5, "sample_instant": 0.0}


class InputDelay(nn.Module):
    """Differentiable time shift of sampled inputs: returns u(t + dt) by linear interpolation.

    dt is bounded to ``[min_s, max_s]`` by a smooth map of the trainable parameter ``raw``:
    dt = centre + half_range * tanh(raw * scale_s / half_range), so near the centre
    dt ≈ centre + raw * scale_s (``scale_s`` sets how far one unit of ``raw`` moves dt, in s).
    With ``min_s == max_s`` the delay is fixed and has no trainable parameter.

    Args:
        sample_period_s: sampling period h of the input sequences (s).
        min_s, max_s: bounds of dt (s); ``min_s <= init_s <= max_s`` (strictly inside if trainable).
        init_s: initial dt (s).
        scale_s: dt per unit of the raw parameter near the centre (s).
        sample_position: a key of ``SAMPLE_POSITIONS``.
    """

    def __init__(self, sample_period_s: float, min_s: float = 0.0, max_s: float = 0.0, init_s: float = 0.0,
                 scale_s: float = 1e-4, sample_position: str = "hold_center") -> None:
        super().__init__()
        if not sample_period_s > 0:
            raise ValueError(f"InputDelay: sample_period_s must be > 0, got {sample_period_s}")
        if not min_s <= init_s <= max_s:
            raise ValueError(f"InputDelay: expected min_s <= init_s <= max_s, got {min_s}, {init_s}, {max_s}")
        if sample_position not in SAMPLE_POSITIONS:
            raise ValueError(f"InputDelay: sample_position must be one of {sorted(SAMPLE_POSITIONS)}, "
                             f"got {sample_position!r}")
        if not scale_s > 0:
            raise ValueError(f"InputDelay: scale_s must be > 0, got {scale_s}")
        self.sample_period_s = float(sample_period_s)
        self.sample_offset = SAMPLE_POSITIONS[sample_position]
        self.centre_s = 0.5 * (min_s + max_s)
        self.half_range_s = 0.5 * (max_s - min_s)
        self.scale_s = float(scale_s)
        if self.half_range_s > 0:
            ratio = (init_s - self.centre_s) / self.half_range_s
            if abs(ratio) >= 1.0:
                raise ValueError(f"InputDelay: init_s={init_s} must lie strictly inside ({min_s}, {max_s})")
            raw = math.atanh(ratio) * self.half_range_s / self.scale_s
            self.raw = nn.Parameter(torch.tensor(raw, dtype=torch.float64))
        else:
            self.register_buffer("raw", torch.tensor(0.0, dtype=torch.float64))

    @property
    def trainable(self) -> bool:
        return self.half_range_s > 0

    def delay_s(self) -> torch.Tensor:
        """The current time offset dt (s), a 0-d tensor (differentiable w.r.t. ``raw``)."""
        if not self.trainable:
            return torch.full((), self.centre_s, dtype=torch.float64)
        return self.centre_s + self.half_range_s * torch.tanh(self.raw * (self.scale_s / self.half_range_s))

    def forward(self, u_seq: torch.Tensor, start_index: int, n_samples: int,
                offset_samples: float = 0.0) -> torch.Tensor:
        """Inputs at the times t_{start+k} + offset_samples*h + dt, k = 0..n_samples-1.

        Args:
            u_seq: sampled inputs (B, T, n_u) on the grid t_j = t_0 + j*h; values beyond either end are
                held at the end values.
            start_index: index of the first time instant in ``u_seq``.
            n_samples: number of time instants.
            offset_samples: extra shift of all instants in sampling periods (0.5 = RK4 half steps).

        Returns:
            (B, n_samples, n_u), differentiable w.r.t. ``u_seq`` and dt.
        """
        position = (start_index + offset_samples - self.sample_offset) + self.delay_s() / self.sample_period_s
        first = int(math.floor(float(position.detach())))
        fraction = position - first
        length = u_seq.shape[1]
        if first >= 0 and first + n_samples + 1 <= length:
            lower = u_seq.narrow(1, first, n_samples)
            upper = u_seq.narrow(1, first + 1, n_samples)
        else:
            index = torch.arange(first, first + n_samples, device=u_seq.device)
            lower = u_seq.index_select(1, index.clamp(0, length - 1))
            upper = u_seq.index_select(1, (index + 1).clamp(0, length - 1))
        return torch.lerp(lower, upper, fraction.to(u_seq.dtype))
