"""Input-delay layer: u(t + dt_g) from sampled inputs, one trainable, bounded time offset dt_g (s) per group."""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import torch
from torch import nn

#: Where a sample sits within its sampling interval for the interpolation.
#: ``hold_center``: sample j is the value held over [t_j, t_j + h) (as in the FMU's open-loop simulation
#: with inputs held between samples) and is placed at the interval's centre t_j + h/2, so dt = 0 adds no lag;
#: ``sample_instant``: sample j is placed at t_j.
SAMPLE_POSITIONS = {"hold_center": 0.5, "sample_instant": 0.0}


class InputDelay(nn.Module):
    """Differentiable time shift of sampled inputs: returns u_j(t + dt_g(j)) by linear interpolation, where
    input j belongs to group g(j) and every group has its own offset dt_g.

    Each dt_g is bounded to its group's ``[low_g, high_g]`` (``[min_s, max_s]`` unless ``bounds_s`` narrows
    it) by a smooth map of its trainable raw value: dt = centre_g + half_g * tanh(raw * scale_s / half_g),
    so near the centre dt ≈ centre_g + raw * scale_s (``scale_s`` sets how far one unit of ``raw`` moves
    dt, in s). With ``min_s == max_s`` the delays are fixed and have no trainable parameter.

    Args:
        sample_period_s: sampling period h of the input sequences (s).
        min_s, max_s: bounds of every dt_g (s); ``min_s <= init <= max_s`` (strictly inside if trainable).
        bounds_s: ``{group: (low, high)}`` narrower bounds (s) of some groups, within ``[min_s, max_s]``
            with ``low < high``; the others keep ``[min_s, max_s]``.
        init_s: initial dt (s): one value for every group, or ``{group: value}`` naming every group.
        scale_s: dt per unit of a raw parameter near the centre (s).
        sample_position: a key of ``SAMPLE_POSITIONS``.
        groups: ``[(group name, [input indices])]`` covering every input exactly once; None: one group
            ``"inputs"`` of all inputs.
        n_inputs: number of inputs n_u (checks ``groups``; without groups it may be None: any number).

    Attributes:
        raw: (G,) trainable raw offsets (a buffer when the delay is fixed).
        group_names: the G group names, in order.
    """

    def __init__(self, sample_period_s: float, min_s: float = 0.0, max_s: float = 0.0,
                 init_s: float | Mapping[str, float] = 0.0, scale_s: float = 1e-4,
                 sample_position: str = "hold_center", groups: Sequence[tuple[str, Sequence[int]]] | None = None,
                 n_inputs: int | None = None, bounds_s: Mapping[str, Sequence[float]] | None = None) -> None:
        super().__init__()
        if not sample_period_s > 0:
            raise ValueError(f"InputDelay: sample_period_s must be > 0, got {sample_period_s}")
        if sample_position not in SAMPLE_POSITIONS:
            raise ValueError(f"InputDelay: sample_position must be one of {sorted(SAMPLE_POSITIONS)}, "
                             f"got {sample_position!r}")
        if not scale_s > 0:
            raise ValueError(f"InputDelay: scale_s must be > 0, got {scale_s}")
        groups = _check_groups(groups, n_inputs)
        self.group_names = [name for name, _ in groups]
        self.n_inputs = sum(len(columns) for _, columns in groups)
        group_of_input = [0] * self.n_inputs
        for g, (_, columns) in enumerate(groups):
            for column in columns:
                group_of_input[column] = g
        self.register_buffer("group_of_input", torch.tensor(group_of_input, dtype=torch.long))
        masks = torch.zeros(len(groups), self.n_inputs, dtype=torch.float64)
        masks[torch.tensor(group_of_input, dtype=torch.long), torch.arange(self.n_inputs)] = 1.0
        self.register_buffer("group_masks", masks)
        inits = _initial_values(init_s, self.group_names)
        self.sample_period_s = float(sample_period_s)
        self.sample_offset = SAMPLE_POSITIONS[sample_position]
        self.min_s, self.max_s = float(min_s), float(max_s)
        self.bounds_s = _group_bounds(bounds_s, self.group_names, self.min_s, self.max_s)
        self.register_buffer("centre_s", torch.tensor([0.5 * (lo + hi) for lo, hi in self.bounds_s],
                                                      dtype=torch.float64), persistent=False)
        self.register_buffer("half_range_s", torch.tensor([0.5 * (hi - lo) for lo, hi in self.bounds_s],
                                                          dtype=torch.float64), persistent=False)
        self.scale_s = float(scale_s)
        for name, value, (low, high) in zip(self.group_names, inits, self.bounds_s):
            if not low <= value <= high:
                raise ValueError(f"InputDelay: expected the bounds of group {name!r} to hold its init_s, got "
                                 f"{low} <= {value} <= {high}")
        if self.max_s > self.min_s:
            raw = []
            for name, value, (low, high) in zip(self.group_names, inits, self.bounds_s):
                ratio = (value - 0.5 * (low + high)) / (0.5 * (high - low))
                if abs(ratio) >= 1.0:
                    raise ValueError(f"InputDelay: init_s={value} of group {name!r} must lie strictly inside "
                                     f"({low}, {high})")
                raw.append(math.atanh(ratio) * 0.5 * (high - low) / self.scale_s)
            self.raw = nn.Parameter(torch.tensor(raw, dtype=torch.float64))
        else:
            self.register_buffer("raw", torch.zeros(len(groups), dtype=torch.float64))

    @property
    def trainable(self) -> bool:
        return self.max_s > self.min_s

    def delays_s(self) -> torch.Tensor:
        """The current offsets dt_g (s), (G,), differentiable w.r.t. ``raw``."""
        if not self.trainable:
            return self.centre_s.clone()
        return self.centre_s + self.half_range_s * torch.tanh(self.raw * (self.scale_s / self.half_range_s))

    def input_delays_s(self) -> torch.Tensor:
        """The offset of every input (s), (n_u,), in input order (needs ``n_inputs`` or ``groups``)."""
        if self.n_inputs == 0:
            raise ValueError("InputDelay: built without n_inputs or groups, it does not know the inputs")
        return self.delays_s().index_select(0, self.group_of_input)

    def forward(self, u_seq: torch.Tensor, start_index: int, n_samples: int,
                offset_samples: float = 0.0) -> torch.Tensor:
        """Inputs at the times t_{start+k} + offset_samples*h + dt_g, k = 0..n_samples-1.

        Args:
            u_seq: sampled inputs (B, T, n_u) on the grid t_j = t_0 + j*h; values beyond either end are
                held at the end values.
            start_index: index of the first time instant in ``u_seq``.
            n_samples: number of time instants.
            offset_samples: extra shift of all instants in sampling periods (0.5 = RK4 half steps).

        Returns:
            (B, n_samples, n_u), differentiable w.r.t. ``u_seq`` and every dt_g.
        """
        positions = (start_index + offset_samples - self.sample_offset) + self.delays_s() / self.sample_period_s
        if positions.shape[0] == 1:
            return _interpolate(u_seq, positions[0], n_samples)
        shifted = None
        for g in range(positions.shape[0]):
            part = _interpolate(u_seq, positions[g], n_samples) * self.group_masks[g].to(u_seq.dtype)
            shifted = part if shifted is None else shifted + part
        return shifted


def format_delay(value_s: float) -> str:
    """A delay for people: '28.14 µs' below 1 ms, '44.08 ms' below 1 s, else '2.5 s'."""
    value_s = float(value_s)
    if abs(value_s) < 1e-3:
        return f"{value_s * 1e6:.2f} µs"
    if abs(value_s) < 1.0:
        return f"{value_s * 1e3:.4g} ms"
    return f"{value_s:.4g} s"


def describe_delays(delays_s: Mapping[str, float]) -> str:
    """Learned delays for a log line: ``{group: s}`` -> 'g1 28.14 µs, g2 -2.00 µs'."""
    return ", ".join(f"{name} {format_delay(value)}" for name, value in delays_s.items())


def _interpolate(u_seq: torch.Tensor, position: torch.Tensor, n_samples: int) -> torch.Tensor:
    """Samples at the fractional indices position + k, k = 0..n_samples-1: (B, n_samples, n_u)."""
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


def _check_groups(groups, n_inputs):
    if groups is None:
        return [("inputs", list(range(int(n_inputs or 0))))]
    groups = [(str(name), [int(c) for c in columns]) for name, columns in groups]
    if not groups:
        raise ValueError("InputDelay: groups is empty; name at least one group of inputs")
    names = [name for name, _ in groups]
    if len(set(names)) != len(names):
        raise ValueError(f"InputDelay: group names repeat: {names}")
    columns = sorted(c for _, cs in groups for c in cs)
    expected = list(range(len(columns) if n_inputs is None else int(n_inputs)))
    if columns != expected:
        raise ValueError(f"InputDelay: the groups must cover every input index {expected} exactly once, got "
                         f"{dict(groups)}")
    return groups


def _group_bounds(bounds_s, names, min_s, max_s):
    """[(low, high)] per group, in group order: ``bounds_s[group]`` where given, else (min_s, max_s)."""
    bounds_s = dict(bounds_s or {})
    unknown = [name for name in bounds_s if name not in names]
    if unknown:
        raise ValueError(f"InputDelay: bounds_s names unknown group(s) {unknown}; the groups are {names}")
    result = []
    for name in names:
        if name not in bounds_s:
            result.append((min_s, max_s))
            continue
        low, high = (float(value) for value in bounds_s[name])
        if not (min_s <= low < high <= max_s):
            raise ValueError(f"InputDelay: bounds_s of group {name!r} must satisfy min_s <= low < high <= max_s, "
                             f"got {min_s} <= {low} < {high} <= {max_s}")
        result.append((low, high))
    return result


def _initial_values(init_s, names):
    if isinstance(init_s, Mapping):
        missing = [name for name in names if name not in init_s]
        unknown = [name for name in init_s if name not in names]
        if missing or unknown:
            raise ValueError(f"InputDelay: init_s must name every group {names}; missing {missing}, unknown {unknown}")
        return [float(init_s[name]) for name in names]
    return [float(init_s)] * len(names)
