"""Neural FMU from the case config, the FMU and a configuration of the search."""

from __future__ import annotations

from typing import Any

import torch

from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.model.settings import input_delay_settings
from hybridfmu.model.spec import EndStop, NeuralFmuSpec


def _names(value: Any, available: list[str], field: str) -> list[str]:
    if value == "all":
        return list(available)
    unknown = [name for name in value if name not in available]
    if unknown:
        raise ValueError(f"config.model.{field}: unknown name(s) {unknown}; the FMU has {available}")
    return list(value)


def model_spec(model_config: dict[str, Any], fmu_model: Any, sample_period_s: float, width: int, depth: int,
               gate_opening: float, delay_init_s: float | dict[str, float] | None = None,
               physics_effects: list[str] | None = None,
               delay_bounds_s: dict[str, list[float]] | None = None) -> NeuralFmuSpec:
    """The architecture: ``model_config`` is the validated ``model`` section; the FMU gives the state and
    input names (and the end-stop values from its parameters).

    ``delay_init_s``: the delays' start (s, one value or ``{group: value}``) when ``input_delay.init_s`` is
    ``time_offset`` (the search's plan holds the time-offset stage's estimates, ``initial_delays_s``);
    a number in the config is used as it is. ``delay_bounds_s``: {group: [low, high]} (s) narrower bounds of
    some groups' delays (the plan's ``delay_bounds_s``, from ``input_delay.within_standard_errors``).
    ``physics_effects``: the effects of a hybrid's physical layer
    (``PhysicsModel.effects``), None for the paper's neural FMU; a hybrid's coefficients train with
    ``model.physics_coefficient_step`` (null: fixed)."""
    states, inputs = list(fmu_model.state_names), list(fmu_model.input_names)
    delay = input_delay_settings(model_config["input_delay"], sample_period_s)
    init_s = delay["init_s"]
    if init_s == "time_offset":
        if delay_init_s is None:
            raise ValueError("config.model.input_delay.init_s is 'time_offset', but no estimate was given (the "
                             "search's plan holds it: rerun rule hpo_plan)")
        init_s = delay_init_s
    elif isinstance(init_s, dict):
        init_s = {name: float(value) for name, value in init_s.items()}
    else:
        init_s = float(init_s)
    end_stop = None
    stop = model_config.get("end_stop")
    if stop:
        names = [stop["min_parameter"], stop["max_parameter"]]
        unknown = [name for name in names if name not in fmu_model.parameter_names]
        if unknown:
            raise ValueError(f"config.model.end_stop: FMU parameter(s) {unknown} do not exist; the FMU has "
                             f"{fmu_model.parameter_names}")
        values = fmu_model.get_parameters(names)
        end_stop = EndStop(stop["state"], stop["rate_state"], float(values[names[0]]), float(values[names[1]]))
    ann = model_config["ann_inputs"]
    if not model_config.get("corrected_states"):
        raise ValueError(f"config.model.corrected_states: name the state(s) whose derivative the ANN corrects; "
                         f"the FMU's states are {states}")
    return NeuralFmuSpec(
        state_names=states, input_names=inputs,
        corrected_states=_names(model_config["corrected_states"], states, "corrected_states"),
        ann_states=_names(ann["states"], states, "ann_inputs.states"),
        ann_inputs=_names(ann["inputs"], inputs, "ann_inputs.inputs"),
        ann_derivatives=_names(ann["derivatives"], states, "ann_inputs.derivatives"),
        sample_period_s=float(sample_period_s), width=int(width), depth=int(depth), gate_opening=float(gate_opening),
        delay_min_s=float(delay["min_s"]), delay_max_s=float(delay["max_s"]), delay_init_s=init_s,
        delay_bounds_s={name: [float(low), float(high)] for name, (low, high) in (delay_bounds_s or {}).items()},
        delay_groups={name: list(inputs) for name, inputs in (delay.get("groups") or {}).items()},
        delay_step_s=None if delay.get("step_s") is None else float(delay["step_s"]),
        ann_output_init=model_config["ann_output_init"],
        delay_scale_s=float(delay["scale_s"]), sample_position=delay["sample_position"],
        solver=model_config["solver"], end_stop=end_stop,
        physics_effects=None if physics_effects is None else list(physics_effects),
        physics_coefficient_step=(None if physics_effects is None or model_config.get("physics_coefficient_step") is None
                                  else float(model_config["physics_coefficient_step"])))


def build_neural_fmu(rhs: Any, spec: NeuralFmuSpec, statistics: dict[str, Any] | None, seed: int) -> NeuralFmu:
    """A neural FMU whose MLP weights are drawn from a torch generator seeded with ``seed`` (the global
    torch RNG is left as it was)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return NeuralFmu(rhs, spec, statistics)
