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
from typing import Any, Sequence

import numpy as np

from hybridfmu.export.input_stages import InputStage, column_lookahead, input_stages


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
        state_start_settable: (n_x,) whether a state takes a start value before the initialisation (its variable's
            initial is exact or approx, or it has a start value and no initial), as the workflow's open loop sets it.
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
    state_start_settable: tuple[bool, ...] = ()


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
        input_stages: the diagnosed changes of the logged inputs (:mod:`hybridfmu.export.input_stages`), before
            the delays read them; empty for none.
        events: step as the workflow's open loop of the FMU (+ effects) does, with the FMU's events handled
            (``hybridfmu.fmu.simulate``), instead of the neural rollout (then the ANN fields are unused);
        rate_hz: the grid's rate (its times are start + k / rate, as ingest writes them); event_tolerance_s,
            max_events: the open loop's event settings.
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
    input_stages: tuple[InputStage, ...] = ()
    events: bool = False
    rate_hz: float | None = None
    event_tolerance_s: float = 1e-10
    max_events: int = 100

    @property
    def input_lookahead(self) -> int:
        """Samples the input stages read ahead (the input with the most): the inputs as the model sees them are
        known that many samples after the logged ones."""
        return max((column_lookahead(self.input_stages, c) for c in range(len(self.inner.input_names))), default=0)

    @property
    def model_lookahead(self) -> int:
        """Samples after step k's start (of the inputs as the model sees them) that step k reads: the delays' and
        RK4's interpolation for a neural rollout, none for the open loop with the inputs held."""
        return 0 if self.events else self.delays.lookahead

    @property
    def lookahead(self) -> int:
        """The lag of the exported FMU's outputs behind the model, in samples: the input stages' and the model's."""
        return self.input_lookahead + self.model_lookahead

    @property
    def output_delay_s(self) -> float:
        """The lag of the exported FMU's outputs behind the model (s)."""
        return self.lookahead * self.sample_period_s


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
        parameters=chosen, platforms=tuple(platforms),
        state_start_settable=tuple(state.initial in ("exact", "approx") or (state.initial is None and state.start
                                                                           is not None) for state in states))


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


def _no_delays(n_u: int) -> DelayedInputs:
    """Every input read at its own sample (a model without learned delays)."""
    return DelayedInputs((0,) * n_u, (0.0,) * n_u, (0,) * n_u, (0.0,) * n_u, {})


def _fused_weights(model: Any) -> tuple[Any, np.ndarray, np.ndarray]:
    """A neural FMU's fused ANN: (``NeuralWeights``, w_u (n_u, H_0), b_first (H_0,))."""
    from hybridfmu.fmu.neural import NeuralWeights

    fused = model.fused()
    as_np = lambda tensor: tensor.detach().numpy().astype(np.float64)  # noqa: E731
    weights = NeuralWeights.from_arrays(as_np(fused.w_xd_t), [(as_np(w), as_np(b)) for w, b in fused.hidden],
                                        as_np(fused.w_out), as_np(fused.b_out), as_np(fused.g_fmu))
    return weights, np.ascontiguousarray(as_np(fused.w_u_t)), np.ascontiguousarray(as_np(fused.b_first))


def _end_stop(spec: Any) -> tuple[int, int, float, float] | None:
    if spec.end_stop is None:
        return None
    return (spec.state_names.index(spec.end_stop.state), spec.state_names.index(spec.end_stop.rate_state),
            float(spec.end_stop.min), float(spec.end_stop.max))


def _checked_inner(model: Any, fmu_path: str, parameters: dict[str, float] | None) -> InnerFmu:
    spec = model.spec
    inner = inner_fmu(fmu_path, parameters)
    if list(inner.state_names) != list(spec.state_names) or list(inner.input_names) != list(spec.input_names):
        raise ValueError(f"{fmu_path}: FMU states {list(inner.state_names)} / inputs {list(inner.input_names)} differ "
                         f"from the trained model's {spec.state_names} / {spec.input_names}")
    return inner


def _start_states(fmu_path: str, parameters: dict[str, float] | None) -> np.ndarray:
    from hybridfmu.fmu import load_fmu

    with load_fmu(fmu_path, parameters=parameters or None) as fmu:
        return np.array(fmu.initial_states, dtype=np.float64)


def neural_content(model: Any, fmu_path: str, parameters: dict[str, float] | None, model_kind: str = "neural_fmu",
                   description: str = "", conventions: Sequence[str] | None = None) -> ExportContent:
    """The export of a trained neural FMU ``model`` around the FMU at ``fmu_path`` with the calibrated
    ``parameters``; ``conventions``: each input's convention between samples (``hybridfmu.data.between_samples``;
    None: all held).

    Raises:
        ValueError: the model's states or inputs differ from the FMU's, or it is a hybrid (:func:`hybrid_content`).
    """
    spec = model.spec
    if spec.physics_effects is not None:
        raise ValueError("export: the model is a hybrid (its spec names physics_effects); export it with "
                         "hybrid_content, which carries its physical layer")
    inner = _checked_inner(model, fmu_path, parameters)
    weights, w_u, b_first = _fused_weights(model)
    return ExportContent(
        model=model_kind, description=description or "neural FMU: the FMU under an ANN that corrects "
        f"{', '.join(spec.corrected_states)}", inner=inner, sample_period_s=float(spec.sample_period_s),
        solver=spec.solver, widths=weights.widths, params=weights.params, w_u=w_u, b_first=b_first,
        delays=delayed_inputs(model), end_stop=_end_stop(spec), x_start=_start_states(fmu_path, parameters),
        input_stages=tuple(input_stages({}, list(spec.input_names), float(spec.sample_period_s), 3, conventions)))


def _coefficient_places(corrected: Any, reals: np.ndarray) -> list[int]:
    """Per additive coefficient, its place in the effect program's reals: the one real that takes a new value of
    it unchanged (found by setting each coefficient to a marker in turn); -1 where no single real does."""
    arrays = [array for _, array in corrected.row_coefficients]
    places = []
    flat = [(array, i) for array in arrays for i in range(array.size)]
    for array, i in flat:
        original = float(array[i])
        marker = original * 1.375 + 0.0625 if original != 0 else 0.0625
        array[i] = marker
        try:
            changed = np.asarray(corrected.effect_program().reals, dtype=float)
        finally:
            array[i] = original
        moved = np.flatnonzero(changed != reals)
        places.append(int(moved[0]) if moved.size == 1 and changed[moved[0]] == marker else -1)
    return places


def hybrid_content(model: Any, fmu_path: str, parameters: dict[str, float] | None,
                   description: str = "", conventions: Sequence[str] | None = None) -> ExportContent:
    """The export of a trained hybrid ``model`` (FMU + diagnosed effects + ANN) around the FMU at ``fmu_path``
    with the calibrated ``parameters``: its physical layer's parameters on top of them, its additive effect terms
    as an effect program (their trained coefficients tunable), its input changes as input stages (after each
    input's ``conventions`` between samples, as in :func:`neural_content`).

    Raises:
        ValueError: not a hybrid; an effect term or input change without a C form (naming it); a hybrid that is
            its physical layer (its evaluation simulates the FMU + effects with the FMU's events, which the export
            does not reproduce yet).
    """
    from hybridfmu.training.inference import is_its_physical_layer, physical_layer

    spec = model.spec
    physics = physical_layer(model)
    if spec.physics_effects is None or physics is None:
        raise ValueError("export: hybrid_content needs a hybrid (a neural FMU around the FMU + diagnosed effects)")
    if is_its_physical_layer(model):
        raise ValueError("export: this hybrid is its physical layer (ANN at zero), which the evaluation simulates as "
                         "the FMU + diagnosed effects with the FMU's events: export it with effects_content")
    model.fmu.apply_coefficients()  # the trained coefficients onto the physical layer
    corrected = physics.corrected
    program = corrected.effect_program() if corrected.has_correction else None
    if corrected.has_correction and program is None:
        raise ValueError(f"export: a term of the hybrid's physical layer ({', '.join(physics.effects)}) has no C form "
                         "(hybridfmu.fmu.effect_program); it cannot be exported")
    all_parameters = {**dict(parameters or {}), **physics.parameters}
    inner = _checked_inner(model, fmu_path, all_parameters)
    weights, w_u, b_first = _fused_weights(model)
    h = float(spec.sample_period_s)
    stages = input_stages(corrected.input_changes, list(spec.input_names), h, _lag_window(corrected, h), conventions)
    code, reals, names, places = _program_parts(corrected, program, physics.coefficient_names)
    return ExportContent(
        model="hybrid", description=description or "hybrid: the FMU plus the diagnosed effects "
        f"({', '.join(physics.effects)}) under an ANN that corrects {', '.join(spec.corrected_states)}",
        inner=inner, sample_period_s=h, solver=spec.solver, widths=weights.widths, params=weights.params, w_u=w_u,
        b_first=b_first, delays=delayed_inputs(model), end_stop=_end_stop(spec),
        x_start=_start_states(fmu_path, all_parameters), effect_code=code, effect_reals=reals,
        effect_sets_inputs=bool(program is not None and program.evaluates_model), coefficient_names=names,
        coefficient_index=places, input_stages=tuple(stages))


def _lag_window(corrected: Any, dt_s: float) -> int:
    """The smoothing window (samples) of the corrected model's input lags (``input_derivative``'s choice)."""
    from hybridfmu.diagnosis.derivatives import odd_window
    from hybridfmu.diagnosis.effects import DEFAULT_LAG_DERIVATIVE_SAMPLES

    if corrected.lag_window_s is None:
        return DEFAULT_LAG_DERIVATIVE_SAMPLES
    return odd_window(float(corrected.lag_window_s), dt_s, minimum=3)


def _program_parts(corrected: Any, program: Any, coefficient_names: Sequence[str]):
    """(code, reals, tunable coefficient names, their places in reals) of an effect program (all empty for None)."""
    if program is None:
        return (), (), (), ()
    code, reals = tuple(int(c) for c in program.code), tuple(float(r) for r in program.reals)
    found = _coefficient_places(corrected, np.asarray(reals))
    pairs = [(name, place) for name, place in zip(coefficient_names, found) if place >= 0]
    return code, reals, tuple(name for name, _ in pairs), tuple(place for _, place in pairs)


def effects_content(diagnosed_path: str, fmu_path: str, parameters: dict[str, float] | None, rate_hz: float,
                    conventions: Sequence[str] | None = None, description: str = "", effects: list[str] | None = None,
                    model_kind: str = "fmu_effects", changes_dt_s: float | None = None) -> ExportContent:
    """The export of the FMU plus the diagnosed effects (``diagnosis/diagnosed_model.pkl``) around the FMU at
    ``fmu_path`` with the calibrated ``parameters``, stepped as the evaluation simulates it
    (``DiagnosedModel.simulate``): the diagnosed parameters on top of the calibrated ones, the input changes as
    input stages, the additive terms as an effect program (their coefficients tunable), RK4 on the grid of
    ``rate_hz`` with the inputs held and the FMU's events handled. ``effects``: only these of the diagnosed model's
    effects (None: all; a hybrid that is its physical layer carries its own selection), ``model_kind`` the name in
    the record. ``changes_dt_s``: the sampling interval the input changes are computed with (the workflow takes the
    median step of a record's time stamps, :func:`hybridfmu.diagnosis.refit.simulate_corrected`, which can differ
    from 1 / rate in its last digits; this open loop is sensitive to it); None: 1 / ``rate_hz``.

    Raises:
        ValueError: an effect term or input change without a C form (naming it).
    """
    from hybridfmu.diagnosis.export import load_diagnosed
    from hybridfmu.fmu import load_fmu

    diagnosed = load_diagnosed(diagnosed_path).selected(effects)
    with load_fmu(fmu_path, parameters=parameters or None) as helper:
        corrected = diagnosed.corrected(helper)
        program = corrected.effect_program() if corrected.has_correction else None
        if corrected.has_correction and program is None:
            raise ValueError(f"export: a term of the FMU + diagnosed effects ({', '.join(diagnosed.effects)}) has no "
                             "C form (hybridfmu.fmu.effect_program); it cannot be exported")
        coefficient_names = [f"{name}[{i}]" for name, array in corrected.row_coefficients for i in range(array.size)]
        all_parameters = {**dict(parameters or {}), **diagnosed.parameters, **corrected.parameters}
        h = 1.0 / float(rate_hz)
        dt = float(changes_dt_s) if changes_dt_s is not None else h
        inner = inner_fmu(fmu_path, all_parameters)
        stages = input_stages(corrected.input_changes, list(inner.input_names), dt, _lag_window(corrected, dt),
                              conventions)
        code, reals, names, places = _program_parts(corrected, program, coefficient_names)
    n_x, n_u = len(inner.state_names), len(inner.input_names)
    terms = ", ".join(diagnosed.effects) or "parameters only"
    return ExportContent(
        model=model_kind, description=description or f"the FMU plus the diagnosed effects ({terms})", inner=inner,
        sample_period_s=h, solver="rk4", widths=(1,), params=np.zeros(5 * n_x), w_u=np.zeros((n_u, 1)),
        b_first=np.zeros(1), delays=_no_delays(n_u), end_stop=None, x_start=_start_states(fmu_path, all_parameters),
        effect_code=code, effect_reals=reals,
        effect_sets_inputs=bool(program is not None and program.evaluates_model), coefficient_names=names,
        coefficient_index=places, input_stages=tuple(stages), events=True, rate_hz=float(rate_hz))


def plain_content(reference: ExportContent) -> ExportContent:
    """The case's FMU alone, stepped the way ``reference`` steps it (its grid, solver, input stages none, delays
    zero, calibrated parameters, end stop): an ANN of one neuron with zero weights and the FMU's gate at 1, so that
    the exported model's derivative is the FMU's. The baseline of ``benchmarks/export_realtime.py``."""
    n_x, n_u = len(reference.inner.state_names), len(reference.inner.input_names)
    params = np.zeros(2 * n_x + n_x + 2 * n_x)  # W_xd (2 n_x, 1), W_out (1, n_x), b_out (n_x,), g (n_x,)
    params[-n_x:] = 1.0
    return ExportContent(model="fmu", description=f"the FMU {reference.inner.identifier} alone on the model's grid",
                         inner=reference.inner, sample_period_s=reference.sample_period_s, solver=reference.solver,
                         widths=(1,), params=params, w_u=np.zeros((n_u, 1)), b_first=np.zeros(1),
                         delays=_no_delays(n_u),
                         end_stop=reference.end_stop, x_start=reference.x_start)
