"""What an exported FMU carries: the embedded FMU's interface and everything learned on top of it.

:func:`neural_content` reads a trained neural FMU (``hybridfmu.model.NeuralFmu``, as the evaluation loads it) into
an :class:`ExportContent`: the fused ANN's weights in the layout of the C engine (``hybridfmu.fmu.neural``), the
learned input delays as the interpolation positions the workflow's ``InputDelay`` uses on a whole record, the end
stop, the calibrated parameters and the state start values. :mod:`hybridfmu.export.header` writes it as the C
header the wrapper (``c/cs_wrapper.c``) is compiled with.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class InnerFmu:
    """The embedded Model-Exchange FMU.

    Attributes:
        identifier: its modelIdentifier (the binary's name); guid: its GUID.
        state_names, input_names: (n_x,), (n_u,) in FMU order; vr_states, vr_derivatives, vr_inputs: their value
            references; n_event_indicators: its numberOfEventIndicators.
        input_start: (n_u,) the inputs' start values (0 where none is declared).
        parameters: parameter name -> (value reference, value) set before its initialisation (the calibrated ones).
        platforms: the binary platforms it ships (only ``linux64`` can be loaded by the exported binary built here).
    """

    identifier: str
    guid: str
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    vr_states: tuple[int, ...]
    vr_derivatives: tuple[int, ...]
    vr_inputs: tuple[int, ...]
    n_event_indicators: int
    input_start: tuple[float, ...]
    parameters: dict[str, tuple[int, float]] = field(default_factory=dict)
    platforms: tuple[str, ...] = ()


@dataclass(frozen=True)
class DelayedInputs:
    """The learned input delays as interpolation positions: input i at step k's node (grid or half step) is
    ``lerp(u[k + first[i]], u[k + first[i] + 1], fraction[i])`` (indices before the record's first sample read
    the first sample). ``delays_s``: {group: learned delay (s)}, for the record."""

    grid_first: tuple[int, ...]
    grid_fraction: tuple[float, ...]
    half_first: tuple[int, ...]
    half_fraction: tuple[float, ...]
    delays_s: dict[str, float]

    @property
    def lookahead(self) -> int:
        """Samples after step k's start that step k reads (its end's upper interpolation sample): the lag of the
        exported FMU's outputs, in samples."""
        return max(0, 2 + max(self.grid_first, default=-2), 1 + max(self.half_first, default=-1))

    @property
    def lookback(self) -> int:
        """Samples before step k's start that step k reads."""
        return max(0, -min((*self.grid_first, *self.half_first), default=0))


@dataclass(frozen=True)
class ExportContent:
    """One exported model.

    Attributes:
        model: ``neural_fmu``, ``fmu_effects`` or ``hybrid``; description: one line for people.
        inner: the embedded FMU; sample_period_s: the solver step (s); solver: ``rk4`` or ``euler``.
        widths: the ANN's layer widths H_0..H_L; params: the fused weights (``hybridfmu.fmu.neural.NeuralWeights``
            layout); w_u: (n_u, H_0) the first layer's input weights; b_first: (H_0,) its bias (pre-processing
            folded in).
        delays: the learned input delays. end_stop: (position index, rate index, lower, upper) or None.
        x_start: (n_x,) default start values of the states.
        effect_code, effect_reals: an effect program added to the FMU's derivatives (``effects.c``), empty for none;
        coefficient_names, coefficient_index: the program's tunable coefficients and their places in
            ``effect_reals``.
    """

    model: str
    description: str
    inner: InnerFmu
    sample_period_s: float
    solver: str
    widths: tuple[int, ...]
    params: np.ndarray
    w_u: np.ndarray
    b_first: np.ndarray
    delays: DelayedInputs
    end_stop: tuple[int, int, float, float] | None
    x_start: np.ndarray
    effect_code: tuple[int, ...] = ()
    effect_reals: tuple[float, ...] = ()
    effect_sets_inputs: bool = False
    coefficient_names: tuple[str, ...] = ()
    coefficient_index: tuple[int, ...] = ()

    @property
    def output_delay_s(self) -> float:
        """The lag of the exported FMU's outputs behind the model (s)."""
        return self.delays.lookahead * self.sample_period_s


def inner_fmu(fmu_path: str, parameters: dict[str, float] | None) -> InnerFmu:
    """The interface of the Model-Exchange FMU at ``fmu_path`` with ``parameters`` (the calibrated ones) to set.

    Raises:
        ValueError: the FMU has no Model-Exchange interface, or a parameter is not one of its variables.
    """
    from fmpy import read_model_description

    description = read_model_description(str(fmu_path))
    if description.modelExchange is None:
        raise ValueError(f"{fmu_path}: no Model-Exchange interface (the export embeds a Model-Exchange FMU)")
    variables = {variable.name: variable for variable in description.modelVariables}
    states = [derivative.variable.derivative for derivative in description.derivatives]
    derivatives = [derivative.variable for derivative in description.derivatives]
    inputs = [variable for variable in description.modelVariables if variable.causality == "input"]
    chosen = {}
    for name, value in (parameters or {}).items():
        if name not in variables:
            raise ValueError(f"{fmu_path}: calibrated parameter {name!r} is not a variable of the FMU")
        chosen[name] = (int(variables[name].valueReference), float(value))
    import zipfile

    with zipfile.ZipFile(fmu_path) as archive:
        platforms = sorted({name.split("/")[1] for name in archive.namelist()
                            if name.startswith("binaries/") and name.count("/") >= 2 and name.split("/")[1]})
    return InnerFmu(
        identifier=description.modelExchange.modelIdentifier, guid=description.guid,
        state_names=tuple(state.name for state in states), input_names=tuple(v.name for v in inputs),
        vr_states=tuple(int(state.valueReference) for state in states),
        vr_derivatives=tuple(int(d.valueReference) for d in derivatives),
        vr_inputs=tuple(int(v.valueReference) for v in inputs),
        n_event_indicators=int(description.numberOfEventIndicators or 0),
        input_start=tuple(float(v.start) if v.start not in (None, "") else 0.0 for v in inputs),
        parameters=chosen, platforms=tuple(platforms))


def delayed_inputs(model: Any) -> DelayedInputs:
    """The interpolation positions of a neural FMU's learned delays on a whole record, computed exactly as the
    evaluation's open loop computes them (``hybridfmu.training.inference.simulate_neural_fmu``: the record padded
    by ``delay_padding`` samples, ``InputDelay.forward`` at offsets 0 and 0.5)."""
    import torch

    from hybridfmu.training.windows import delay_padding

    spec, delay = model.spec, model.delay
    pad = delay_padding(spec.sample_period_s, spec.delay_min_s, spec.delay_max_s)
    with torch.no_grad():
        delays = delay.delays_s()
        positions = {offset: (pad + offset - delay.sample_offset) + delays / delay.sample_period_s
                     for offset in (0.0, 0.5)}
    group_of_input = delay.group_of_input.tolist()
    firsts, fractions = {}, {}
    for offset, position in positions.items():
        first = [int(math.floor(float(value))) for value in position]
        fraction = [float(value - base) for value, base in zip(position, first)]
        firsts[offset] = tuple(first[g] - pad for g in group_of_input)
        fractions[offset] = tuple(fraction[g] for g in group_of_input)
    return DelayedInputs(firsts[0.0], fractions[0.0], firsts[0.5], fractions[0.5], model.delay_s())


def neural_content(model: Any, fmu_path: str, parameters: dict[str, float] | None, model_kind: str = "neural_fmu",
                   description: str = "") -> ExportContent:
    """The export of a trained neural FMU ``model`` around the FMU at ``fmu_path`` with the calibrated
    ``parameters``.

    Raises:
        ValueError: the model's states or inputs differ from the FMU's, or it is a hybrid (its physical layer is
            exported by the hybrid's own path).
    """
    from hybridfmu.fmu import load_fmu
    from hybridfmu.fmu.neural import NeuralWeights

    spec = model.spec
    if spec.physics_effects is not None:
        raise ValueError("export: a hybrid's physical layer (diagnosed effects and input changes) has no export yet; "
                         "neural_content exports the paper's neural FMU")
    inner = inner_fmu(fmu_path, parameters)
    if list(inner.state_names) != list(spec.state_names) or list(inner.input_names) != list(spec.input_names):
        raise ValueError(f"{fmu_path}: FMU states {list(inner.state_names)} / inputs {list(inner.input_names)} differ "
                         f"from the trained model's {spec.state_names} / {spec.input_names}")
    fused = model.fused()
    as_np = lambda tensor: tensor.detach().numpy().astype(np.float64)  # noqa: E731
    weights = NeuralWeights.from_arrays(as_np(fused.w_xd_t), [(as_np(w), as_np(b)) for w, b in fused.hidden],
                                        as_np(fused.w_out), as_np(fused.b_out), as_np(fused.g_fmu))
    end_stop = None
    if spec.end_stop is not None:
        end_stop = (spec.state_names.index(spec.end_stop.state), spec.state_names.index(spec.end_stop.rate_state),
                    float(spec.end_stop.min), float(spec.end_stop.max))
    with load_fmu(fmu_path, parameters=parameters or None) as fmu:
        x_start = np.array(fmu.initial_states, dtype=np.float64)
    return ExportContent(
        model=model_kind, description=description or "neural FMU: the FMU under an ANN that corrects "
        f"{', '.join(spec.corrected_states)}", inner=inner, sample_period_s=float(spec.sample_period_s),
        solver=spec.solver, widths=weights.widths, params=weights.params, w_u=np.ascontiguousarray(as_np(fused.w_u_t)),
        b_first=np.ascontiguousarray(as_np(fused.b_first)), delays=delayed_inputs(model), end_stop=end_stop,
        x_start=x_start)
