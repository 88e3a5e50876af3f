"""Everything needed to rebuild a neural FMU (architecture, signal names, delay bounds), JSON-serialisable."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from hybridfmu.runge_kutta import TABLEAUS


@dataclass(frozen=True)
class EndStop:
    """A hard stop of a position state: the position is clamped to [min, max] after every solver step and
    the rate state is set to 0 while the position sits on (or is pushed beyond) the stop."""

    state: str
    rate_state: str
    min: float
    max: float


@dataclass(frozen=True)
class NeuralFmuSpec:
    """Architecture of a neural FMU (paper Fig. 7).

    Attributes:
        state_names, input_names: FMU states x (n_x) and inputs u (n_u), in FMU order.
        corrected_states: states whose derivative the ANN corrects (via the gates); the others are forwarded.
        ann_states, ann_inputs, ann_derivatives: which states, delayed inputs and FMU state derivatives
            feed the ANN (time never does).
        sample_period_s: solver step = sampling period of the data (s).
        width, depth: tanh MLP layout.
        gate_opening: initial ANN gate g_A.
        ann_output_init: "zero" starts the MLP's output layer at zero (the untrained neural FMU is the FMU
            plus g_A times the post-processing shift; the ANN's share grows with training), "random" keeps
            torch's default initialisation.
        delay_min_s, delay_max_s, delay_scale_s: input-delay bounds and raw scale (s), shared by the groups.
        delay_groups: group name -> inputs sharing one learned delay; every input in exactly one group.
            Empty: one group ``"inputs"`` of all inputs.
        delay_init_s: initial delay (s): one value for every group, or ``{group: value}``.
        delay_bounds_s: ``{group: [low, high]}`` (s) narrower bounds of some groups' delays, within
            ``[delay_min_s, delay_max_s]`` (e.g. the time-offset stage's estimate ± a few standard errors).
        delay_step_s: Adam step size of the delays (s per step: how far a delay moves per step at most,
            about); None: the delays train with the network's learning rate (dt moves about lr * scale_s).
        sample_position: how sampled inputs are placed within their interval (see ``InputDelay``).
        solver: fixed-step method on the sample grid ("rk4" or "euler").
        end_stop: optional hard stop of a position state.
        physics_effects: None for the paper's neural FMU (the FMU under the ANN); for a hybrid, the diagnosed
            effects its physical layer adds to the FMU (:mod:`hybridfmu.model.physics`; [] for the diagnosed
            model's parameters alone).
        physics_coefficient_step: a hybrid's additive terms' coefficients train with this Adam step (relative:
            about this fraction of a coefficient per step at most; ``FmuLayer``); None keeps the diagnosed values.
    """

    state_names: list[str]
    input_names: list[str]
    corrected_states: list[str]
    ann_states: list[str]
    ann_inputs: list[str]
    ann_derivatives: list[str]
    sample_period_s: float
    width: int = 8
    depth: int = 2
    gate_opening: float = 0.0
    ann_output_init: str = "zero"
    delay_min_s: float = 0.0
    delay_max_s: float = 0.0
    delay_init_s: float | dict[str, float] = 0.0
    delay_bounds_s: dict[str, list[float]] = field(default_factory=dict)
    delay_scale_s: float = 1e-4
    delay_groups: dict[str, list[str]] = field(default_factory=dict)
    delay_step_s: float | None = None
    sample_position: str = "hold_center"
    solver: str = "rk4"
    end_stop: EndStop | None = None
    physics_effects: list[str] | None = None
    physics_coefficient_step: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for group in ("corrected_states", "ann_states", "ann_derivatives"):
            unknown = [name for name in getattr(self, group) if name not in self.state_names]
            if unknown:
                raise ValueError(f"model.{group}: unknown state(s) {unknown}; the FMU's states are {self.state_names}")
        unknown = [name for name in self.ann_inputs if name not in self.input_names]
        if unknown:
            raise ValueError(f"model.ann_inputs: unknown input(s) {unknown}; the FMU's inputs are {self.input_names}")
        if not self.corrected_states:
            raise ValueError("model.corrected_states: name at least one state")
        if not (self.ann_states or self.ann_inputs or self.ann_derivatives):
            raise ValueError("model: the ANN needs at least one input signal (ann_states/ann_inputs/ann_derivatives)")
        if self.ann_output_init not in ("zero", "random"):
            raise ValueError(f"model.ann_output_init: expected 'zero' or 'random', got {self.ann_output_init!r}")
        if self.solver not in TABLEAUS:
            raise ValueError(f"model.solver: expected one of {', '.join(map(repr, TABLEAUS))}, got {self.solver!r}")
        if self.delay_groups:
            listed = [name for inputs in self.delay_groups.values() for name in inputs]
            unknown = [name for name in listed if name not in self.input_names]
            repeated = sorted({name for name in listed if listed.count(name) > 1})
            missing = [name for name in self.input_names if name not in listed]
            if unknown or repeated or missing:
                raise ValueError(f"model.input_delay.groups: every FMU input must be in exactly one group; unknown "
                                 f"{unknown}, in several groups {repeated}, in none {missing} (the FMU's inputs are "
                                 f"{self.input_names})")
        if isinstance(self.delay_init_s, dict):
            names = list(self.delay_group_columns())
            if sorted(self.delay_init_s) != sorted(names):
                raise ValueError(f"model.input_delay.init_s: expected a value for each group {names}, got "
                                 f"{sorted(self.delay_init_s)}")
        unknown = [name for name in self.delay_bounds_s if name not in self.delay_group_columns()]
        if unknown:
            raise ValueError(f"model.input_delay: bounds for unknown group(s) {unknown}; the groups are "
                             f"{list(self.delay_group_columns())}")
        if self.delay_step_s is not None and not self.delay_step_s > 0:
            raise ValueError(f"model.input_delay.step_s: expected > 0, got {self.delay_step_s}")
        if self.physics_coefficient_step is not None:
            if self.physics_effects is None:
                raise ValueError("model.physics_coefficient_step: only a hybrid (physics_terms) has coefficients "
                                 "to train")
            if not self.physics_coefficient_step > 0:
                raise ValueError(f"model.physics_coefficient_step: expected > 0, got {self.physics_coefficient_step}")
        if self.end_stop is not None:
            for name in (self.end_stop.state, self.end_stop.rate_state):
                if name not in self.state_names:
                    raise ValueError(f"model.end_stop: unknown state {name!r}; the FMU's states are {self.state_names}")

    def state_index(self, names: list[str]) -> list[int]:
        return [self.state_names.index(name) for name in names]

    def input_index(self, names: list[str]) -> list[int]:
        return [self.input_names.index(name) for name in names]

    def delay_group_columns(self) -> dict[str, list[int]]:
        """Group name -> indices of its inputs (FMU order); one group ``"inputs"`` when none are configured."""
        if not self.delay_groups:
            return {"inputs": list(range(len(self.input_names)))}
        return {name: self.input_index(list(inputs)) for name, inputs in self.delay_groups.items()}

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "NeuralFmuSpec":
        data = dict(data)
        if data.get("end_stop") is not None:
            data["end_stop"] = EndStop(**data["end_stop"])
        return cls(**data)
