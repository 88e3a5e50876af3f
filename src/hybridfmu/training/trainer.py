"""Mini-batch training of a neural FMU with Adam, skipping bad steps, resumable bit for bit.

The resource is the amount of training data processed: B windows of n steps cost B * n samples
(B * n * h seconds). ``train_until`` stops at the first step boundary at or beyond the target, so a run
to r1 followed by a resumed run to r2 takes exactly the steps of one run to r2.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from hybridfmu.model.neural_fmu import NeuralFmu
from hybridfmu.progress import Progress
from hybridfmu.training.data import ManeuverArrays
from hybridfmu.training.losses import weight_overrides, weighted_loss
from hybridfmu.training.optim import Adam
from hybridfmu.training.solver import rollout
from hybridfmu.training.windows import WindowSampler, delay_padding

LOG = logging.getLogger(__name__)

#: Hyperparameters every configuration has; target weights ``w_<state>`` are optional extras.
HYPERPARAMETER_NAMES = ("lr", "beta1", "beta2", "window_s", "loss", "width", "depth", "gate_opening", "batch_windows")


@dataclass(frozen=True)
class Hyperparameters:
    """One configuration of the search: Adam (lr, beta1, beta2), window length (s), loss kind (MAE/MSE),
    MLP width and depth, initial ANN gate, windows per step, and target weights set by the search
    (``target_weights``: state -> weight, from entries ``w_<state>``; the case's roles share the rest)."""

    lr: float
    beta1: float
    beta2: float
    window_s: float
    loss: str
    width: int
    depth: int
    gate_opening: float
    batch_windows: int
    target_weights: dict[str, float] = field(default_factory=dict)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "Hyperparameters":
        missing = [name for name in HYPERPARAMETER_NAMES if name not in values]
        if missing:
            raise ValueError(f"hyperparameters: missing {missing}")
        unknown = [name for name in values if name not in HYPERPARAMETER_NAMES and not name.startswith("w_")]
        if unknown:
            raise ValueError(f"hyperparameters: unknown {unknown}; expected {list(HYPERPARAMETER_NAMES)} and "
                             "target weights w_<state>")
        return cls(lr=float(values["lr"]), beta1=float(values["beta1"]), beta2=float(values["beta2"]),
                   window_s=float(values["window_s"]), loss=str(values["loss"]), width=int(values["width"]),
                   depth=int(values["depth"]), gate_opening=float(values["gate_opening"]),
                   batch_windows=int(values["batch_windows"]), target_weights=weight_overrides(values))

    def to_dict(self) -> dict[str, Any]:
        values = asdict(self)
        values.update({f"w_{state}": weight for state, weight in values.pop("target_weights").items()})
        return values


@dataclass(frozen=True)
class TrainerSettings:
    """max_skipped_steps: a trial with more skipped steps ends as diverged; max_grad_norm: a step whose
    gradient norm exceeds it (or is not finite) is skipped; gradients: how a step's gradient is computed
    (``rollout``'s option of that name)."""

    max_skipped_steps: int = 20
    max_grad_norm: float = 1e8
    gradients: str = "adjoint"


def parameter_groups(model: NeuralFmu) -> list[dict[str, Any]]:
    """Adam's parameter groups: the network at the configuration's learning rate; when
    ``model.spec.delay_step_s`` is set, the input delays at their own rate step_s / scale_s (so a delay moves
    about step_s per step at most, whatever lr); when a hybrid's coefficients train, their relative changes
    at ``model.spec.physics_coefficient_step``."""
    spec = model.spec
    own: list[dict[str, Any]] = []
    if spec.delay_step_s is not None and model.delay.trainable:
        own.append({"params": [model.delay.raw], "lr": spec.delay_step_s / spec.delay_scale_s})
    if model.fmu.coefficient_change is not None:
        own.append({"params": [model.fmu.coefficient_change], "lr": float(spec.physics_coefficient_step)})
    if not own:
        return [{"params": list(model.parameters())}]
    separate = {id(p) for group in own for p in group["params"]}
    network = [p for p in model.parameters() if id(p) not in separate]
    return [{"params": network}, *own]


class TrialDiverged(RuntimeError):
    """Too many steps had to be skipped; the trial ends."""


class Trainer:
    """Trains ``model`` on random windows of ``arrays``.

    Args:
        model: the neural FMU.
        arrays: the training maneuver.
        hyper: the configuration.
        statistics: the training data statistics; ``target_std`` (n_t,) are the loss scales.
        settings: skip rules.
        seed: seed of the window sampler.
        weights: target state -> loss weight (e.g. ``roles.weights_with(hyper.target_weights)``), for every
            target of ``arrays``.
    """

    def __init__(self, model: NeuralFmu, arrays: ManeuverArrays, hyper: Hyperparameters, statistics: dict[str, Any],
                 settings: TrainerSettings, seed: int, weights: dict[str, float]) -> None:
        spec = model.spec
        self.model, self.hyper, self.settings = model, hyper, settings
        missing = [name for name in arrays.target_states if name not in weights]
        if missing:
            raise ValueError(f"Trainer: no loss weight for target state(s) {missing}")
        self.weights = [float(weights[name]) for name in arrays.target_states]
        self.scales = [float(value) for value in statistics["target_std"]]
        if len(self.scales) != len(arrays.target_states):
            raise ValueError(f"Trainer: {len(self.scales)} target scales in the statistics for targets "
                             f"{arrays.target_states}; rerun rule hpo_prepare")
        self.h = spec.sample_period_s
        self.n_steps = max(1, int(round(hyper.window_s / self.h)))
        self.sampler = WindowSampler(arrays, self.n_steps, delay_padding(self.h, spec.delay_min_s, spec.delay_max_s))
        self.target_index = torch.as_tensor([spec.state_names.index(name) for name in arrays.target_states],
                                            dtype=torch.long)
        # torch.optim.Adam's numbers without torch.optim.Optimizer (whose first use imports torch._dynamo)
        self.optimizer = Adam(parameter_groups(model), lr=hyper.lr, betas=(hyper.beta1, hyper.beta2))
        self.rng = np.random.Generator(np.random.PCG64(seed))
        self.used_samples = 0
        self.steps = 0
        self.skipped_steps = 0
        self.history: list[list[float]] = []  # [resource_s, loss, skipped (0/1), gradient norm]

    @property
    def samples_per_step(self) -> int:
        return self.hyper.batch_windows * self.n_steps

    @property
    def resource_used_s(self) -> float:
        return self.used_samples * self.h

    def step(self) -> dict[str, float]:
        """One optimizer step on a fresh batch; returns {"loss", "grad_norm", "skipped"}."""
        batch = self.sampler.gather(self.sampler.sample_starts(self.rng, self.hyper.batch_windows))
        self.optimizer.zero_grad(set_to_none=True)
        try:
            states = rollout(self.model, batch.u_seq, batch.start_index, batch.x0, batch.n_steps,
                             gradients=self.settings.gradients)
        except FloatingPointError as err:  # the simulation diverged within a window
            LOG.warning("step %d: %s", self.steps + 1, err)
            states = None
        if states is None:
            loss = torch.tensor(math.nan, dtype=torch.float64)
        else:
            errors = states[:, 1:].index_select(2, self.target_index) - batch.targets[:, 1:]
            loss = weighted_loss(errors, self.hyper.loss, self.weights, self.scales)
        loss_value = float(loss.detach())
        grad_norm = math.nan
        if math.isfinite(loss_value):
            loss.backward()
            norms = [p.grad.detach().norm() for p in self.model.parameters() if p.grad is not None]
            grad_norm = float(torch.linalg.vector_norm(torch.stack(norms))) if norms else 0.0
        skipped = not (math.isfinite(grad_norm) and grad_norm <= self.settings.max_grad_norm)
        if skipped:
            self.skipped_steps += 1
            self.optimizer.zero_grad(set_to_none=True)
        else:
            self.optimizer.step()
        self.used_samples += self.samples_per_step
        self.steps += 1
        self.history.append([self.resource_used_s, loss_value, float(skipped), grad_norm])
        return {"loss": loss_value, "grad_norm": grad_norm, "skipped": float(skipped)}

    def train_until(self, resource_s: float, progress: Progress | None = None) -> None:
        """Step until ``resource_s`` seconds of training data are processed.

        Raises:
            TrialDiverged: more than ``settings.max_skipped_steps`` steps were skipped.
        """
        target_samples = int(round(resource_s / self.h))
        while self.used_samples < target_samples:
            result = self.step()
            if progress is not None:
                progress.update(self.samples_per_step * self.h)
            if result["skipped"]:
                LOG.warning("step %d skipped (loss %.4g, gradient norm %.4g); %d skipped so far", self.steps,
                            result["loss"], result["grad_norm"], self.skipped_steps)
            if self.skipped_steps > self.settings.max_skipped_steps:
                raise TrialDiverged(f"{self.skipped_steps} steps skipped (non-finite or huge gradients; limit "
                                    f"{self.settings.max_skipped_steps})")

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to continue exactly: model, optimizer, RNG states, resource used, history."""
        return {"model": self.model.state_dict(), "optimizer": self.optimizer.state_dict(),
                "rng": self.rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                "used_samples": self.used_samples, "steps": self.steps, "skipped_steps": self.skipped_steps,
                "history": [list(row) for row in self.history]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        self.used_samples = int(state["used_samples"])
        self.steps = int(state["steps"])
        self.skipped_steps = int(state["skipped_steps"])
        self.history = [list(row) for row in state["history"]]
