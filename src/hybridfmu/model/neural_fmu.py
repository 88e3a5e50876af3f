"""The neural FMU (paper Fig. 7): input delay -> FMU -> pre-processing -> tanh MLP -> post-processing -> gates."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from .delay import InputDelay
from .fmu_layer import FmuLayer, Rhs
from .gates import Gates
from .mlp import TanhMLP
from .shift_scale import ScaleShift, ShiftScale
from .spec import NeuralFmuSpec

#: Keys of the data statistics the pre/post-processing is initialised from (all in FMU order).
STATISTICS_KEYS = ("x_mean", "x_std", "u_mean", "u_std", "xdot_mean", "xdot_std")


class NeuralFmu(nn.Module):
    """Hybrid model: state derivative xdot = gates(xdot_F, post(ANN(pre([x, u, xdot_F])))).

    Args:
        rhs: differentiable FMU right-hand side ``(x (N, n_x), u (N, n_u)) -> (N, n_x)``.
        spec: architecture (``NeuralFmuSpec``).
        statistics: dict with ``STATISTICS_KEYS`` (lists in FMU order: means and spreads of the states,
            inputs and FMU derivatives over the training data); None gives identity pre/post-processing
            (e.g. before loading a state dict).

    Layers: ``delay`` (InputDelay), ``fmu`` (FmuLayer), ``pre`` (ShiftScale), ``ann`` (TanhMLP),
    ``post`` (ScaleShift), ``gates`` (Gates).
    """

    def __init__(self, rhs: Rhs, spec: NeuralFmuSpec, statistics: dict[str, Any] | None = None) -> None:
        super().__init__()
        self.spec = spec
        n_x, n_u = len(spec.state_names), len(spec.input_names)
        self.n_states, self.n_inputs = n_x, n_u
        self.delay = InputDelay(spec.sample_period_s, spec.delay_min_s, spec.delay_max_s, spec.delay_init_s,
                                spec.delay_scale_s, spec.sample_position,
                                groups=list(spec.delay_group_columns().items()), n_inputs=n_u,
                                bounds_s=spec.delay_bounds_s)
        self.fmu = FmuLayer(rhs, n_x, n_u, train_coefficients=_trains_coefficients(rhs, spec))
        self.register_buffer("idx_states", torch.tensor(spec.state_index(spec.ann_states), dtype=torch.long))
        self.register_buffer("idx_inputs", torch.tensor(spec.input_index(spec.ann_inputs), dtype=torch.long))
        self.register_buffer("idx_derivs", torch.tensor(spec.state_index(spec.ann_derivatives), dtype=torch.long))
        corrected = spec.state_index(spec.corrected_states)
        self.register_buffer("idx_corrected", torch.tensor(corrected, dtype=torch.long))
        n_ann_in = len(spec.ann_states) + len(spec.ann_inputs) + len(spec.ann_derivatives)
        mean, std = self._ann_input_statistics(statistics, n_ann_in)
        self.pre = ShiftScale.from_statistics(mean, std)
        out_mean, out_std = self._ann_output_statistics(statistics, len(corrected))
        self.post = ScaleShift.from_statistics(out_mean, out_std)
        self.ann = TanhMLP(n_ann_in, len(corrected), spec.width, spec.depth)
        if spec.ann_output_init == "zero":
            with torch.no_grad():
                self.ann.output.weight.zero_()
                self.ann.output.bias.zero_()
        self.gates = Gates(n_x, corrected, spec.gate_opening)

    def _ann_input_statistics(self, statistics, n_ann_in):
        if statistics is None:
            return torch.zeros(n_ann_in, dtype=torch.float64), torch.ones(n_ann_in, dtype=torch.float64)
        _check_statistics(statistics, self.n_states, self.n_inputs)
        parts_mean, parts_std = [], []
        for key, index in (("x", self.idx_states), ("u", self.idx_inputs), ("xdot", self.idx_derivs)):
            parts_mean.append(torch.as_tensor(statistics[f"{key}_mean"], dtype=torch.float64)[index])
            parts_std.append(torch.as_tensor(statistics[f"{key}_std"], dtype=torch.float64)[index])
        return torch.cat(parts_mean), torch.cat(parts_std)

    def _ann_output_statistics(self, statistics, n_corrected):
        if statistics is None:
            return torch.zeros(n_corrected, dtype=torch.float64), torch.ones(n_corrected, dtype=torch.float64)
        mean = torch.as_tensor(statistics["xdot_mean"], dtype=torch.float64)[self.idx_corrected]
        if self.spec.physics_effects is not None:
            # a hybrid's ANN corrects what the physical layer leaves, a residual around zero: no shift, so that
            # with a zero output layer the untrained hybrid is its physical layer exactly
            mean = torch.zeros_like(mean)
        std = torch.as_tensor(statistics["xdot_std"], dtype=torch.float64)[self.idx_corrected]
        return mean, torch.where(std > 0, std, torch.ones_like(std))

    # ------------------------------------------------------------------ reference composition
    def ann_features(self, x: torch.Tensor, u: torch.Tensor, xdot_F: torch.Tensor) -> torch.Tensor:
        """The ANN's raw input signals [x_sel, u_sel, xdot_F_sel] (N, n_ann_in)."""
        return torch.cat([x.index_select(1, self.idx_states), u.index_select(1, self.idx_inputs),
                          xdot_F.index_select(1, self.idx_derivs)], dim=1)

    def derivative(self, x: torch.Tensor, u_delayed: torch.Tensor) -> torch.Tensor:
        """Hybrid state derivative, layer by layer. x (N, n_x), delayed inputs (N, n_u) -> (N, n_x)."""
        xdot_F = self.fmu(x, u_delayed)
        xdot_A = self.post(self.ann(self.pre(self.ann_features(x, u_delayed, xdot_F))))
        return self.gates(xdot_F, xdot_A)

    # ------------------------------------------------------------------ fused evaluation
    def fused(self) -> "FusedDerivative":
        """The same derivative with pre-processing folded into the first layer and post-processing and the
        gates folded into the output layer (few tensor ops per call; gradients flow to every parameter)."""
        n_x, n_u = self.n_states, self.n_inputs
        first = self.ann.hidden[0]
        weight = first.weight * self.pre.scale  # (H, m)
        bias = first.bias + first.weight @ (self.pre.shift * self.pre.scale)
        n_s, n_in = len(self.idx_states), len(self.idx_inputs)
        w_states, w_inputs, w_derivs = weight[:, :n_s], weight[:, n_s:n_s + n_in], weight[:, n_s + n_in:]
        hidden_size = weight.shape[0]
        zeros_x = weight.new_zeros(hidden_size, n_x)
        w_x = zeros_x.index_copy(1, self.idx_states, w_states)
        w_d = zeros_x.index_copy(1, self.idx_derivs, w_derivs)
        w_u = weight.new_zeros(hidden_size, n_u).index_copy(1, self.idx_inputs, w_inputs)
        hidden = [(layer.weight.t(), layer.bias) for layer in self.ann.hidden[1:]]
        out = self.ann.output
        gain = self.gates.g_A * self.post.scale  # (n_c,)
        w_out = out.weight.new_zeros(hidden_size, n_x).index_copy(
            1, self.idx_corrected, (out.weight * gain[:, None]).t())
        b_out = out.bias.new_zeros(n_x).index_copy(
            0, self.idx_corrected, self.gates.g_A * (self.post.scale * out.bias + self.post.shift))
        return FusedDerivative(
            rhs=self.fmu, w_xd_t=torch.cat([w_x, w_d], dim=1).t().contiguous(), w_u_t=w_u.t().contiguous(),
            b_first=bias, hidden=hidden, w_out=w_out, b_out=b_out, g_fmu=self.gates.fmu_gate_vector())

    # ------------------------------------------------------------------ learned quantities
    def delay_s(self) -> dict[str, float]:
        """Learned input time offsets {group: dt (s)}."""
        values = self.delay.delays_s().detach().tolist()
        return dict(zip(self.delay.group_names, values))

    def input_delays_s(self) -> dict[str, float]:
        """Learned time offset of every input {input: dt (s)}, FMU order."""
        return dict(zip(self.spec.input_names, self.delay.input_delays_s().detach().tolist()))

    def physics_coefficients(self) -> dict[str, dict[str, float]]:
        """A hybrid's trained coefficients of its physical layer's additive terms
        {"<effect>[i]": {"diagnosed": ..., "trained": ...}}; {} when they are fixed."""
        values = self.fmu.coefficients()
        if values is None:
            return {}
        names = self.fmu.physics.coefficient_names
        return {name: {"diagnosed": float(start), "trained": float(value)}
                for name, start, value in zip(names, self.fmu.coefficient_start.tolist(), values.detach().tolist())}

    def gate_values(self) -> dict[str, dict[str, float]]:
        """{corrected state: {"g_F": ..., "g_A": ...}}."""
        g_fmu, g_ann = self.gates.g_F.detach(), self.gates.g_A.detach()
        return {name: {"g_F": float(g_fmu[i]), "g_A": float(g_ann[i])}
                for i, name in enumerate(self.spec.corrected_states)}


@dataclass
class FusedDerivative:
    """Folded form of ``NeuralFmu.derivative``; call ``input_term`` once for all input samples, then
    ``__call__`` per solver stage. Shapes: x (N, n_x), u (N, n_u), input term (N, H)."""

    rhs: FmuLayer
    w_xd_t: torch.Tensor   # (2 n_x, H)
    w_u_t: torch.Tensor    # (n_u, H)
    b_first: torch.Tensor  # (H,)
    hidden: list[tuple[torch.Tensor, torch.Tensor]]
    w_out: torch.Tensor    # (H, n_x)
    b_out: torch.Tensor    # (n_x,)
    g_fmu: torch.Tensor    # (n_x,)

    def input_term(self, u: torch.Tensor) -> torch.Tensor:
        """First-layer contribution of the inputs plus its bias: u (..., n_u) -> (..., H)."""
        return torch.matmul(u, self.w_u_t) + self.b_first

    def __call__(self, x: torch.Tensor, u: torch.Tensor, input_term: torch.Tensor) -> torch.Tensor:
        xdot_F = self.rhs(x, u)
        h = torch.tanh(torch.addmm(input_term, torch.cat([x, xdot_F], dim=1), self.w_xd_t))
        for weight_t, bias in self.hidden:
            h = torch.tanh(torch.addmm(bias, h, weight_t))
        return torch.addmm(torch.addcmul(self.b_out, xdot_F, self.g_fmu), h, self.w_out)


def _trains_coefficients(rhs: Rhs, spec: NeuralFmuSpec) -> bool:
    """Whether the FMU layer trains its physical layer's coefficients: a hybrid with a coefficient step whose
    physical layer has additive terms (one with input changes or parameters only has none to train)."""
    if spec.physics_coefficient_step is None:
        return False
    coefficients = getattr(getattr(rhs, "model", None), "coefficients", None)
    return coefficients is not None and len(coefficients) > 0


def _check_statistics(statistics: dict[str, Any], n_x: int, n_u: int) -> None:
    for key in STATISTICS_KEYS:
        if key not in statistics:
            raise ValueError(f"NeuralFmu statistics: missing {key!r} (expected keys {list(STATISTICS_KEYS)})")
        expected = n_u if key.startswith("u_") else n_x
        if len(statistics[key]) != expected:
            raise ValueError(f"NeuralFmu statistics: {key!r} has {len(statistics[key])} values, expected {expected}")
