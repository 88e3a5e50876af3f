"""Random sampling of hyperparameter configurations from the configured search space.

Each parameter is ``{distribution: loguniform|uniform, low, high}``, ``{distribution: choice, values: [...]}``
or ``{distribution: fixed, value: ...}``. A configuration depends only on (seed, bracket, index).
"""

from __future__ import annotations

import hashlib
import json
import math
from typing import Any

import numpy as np

#: The paper's search space (Sec. 3.2) without its target weight; the windows per step come from
#: ``training.batch_windows``, a target weight ``w_<state>`` from the case (config/paper.yaml).
PAPER_SEARCH_SPACE: dict[str, dict[str, Any]] = {
    "lr": {"distribution": "loguniform", "low": 1e-6, "high": 1e-4},
    "beta1": {"distribution": "choice", "values": [0.99, 0.9]},
    "beta2": {"distribution": "choice", "values": [0.9999, 0.999, 0.99]},
    "window_s": {"distribution": "uniform", "low": 0.01, "high": 0.1},
    "loss": {"distribution": "choice", "values": ["MAE", "MSE"]},
    "width": {"distribution": "choice", "values": [8, 16, 32]},
    "depth": {"distribution": "choice", "values": [2, 3, 4]},
    "gate_opening": {"distribution": "uniform", "low": 0.0, "high": 0.5},
}


def _draw(name: str, spec: dict[str, Any], rng: np.random.Generator) -> Any:
    kind = spec.get("distribution")
    if kind == "loguniform":
        low, high = float(spec["low"]), float(spec["high"])
        if not 0 < low <= high:
            raise ValueError(f"config.hpo.search_space.{name}: loguniform needs 0 < low <= high, got {low}, {high}")
        return float(math.exp(rng.uniform(math.log(low), math.log(high))))
    if kind == "uniform":
        low, high = float(spec["low"]), float(spec["high"])
        if not low <= high:
            raise ValueError(f"config.hpo.search_space.{name}: uniform needs low <= high, got {low}, {high}")
        return float(rng.uniform(low, high))
    if kind == "choice":
        values = list(spec["values"])
        if not values:
            raise ValueError(f"config.hpo.search_space.{name}: choice needs at least one value")
        return values[int(rng.integers(0, len(values)))]
    if kind == "fixed":
        return spec["value"]
    raise ValueError(f"config.hpo.search_space.{name}: distribution must be loguniform, uniform, choice or fixed, "
                     f"got {kind!r}")


def sample_configuration(space: dict[str, dict[str, Any]], seed: int, bracket: int, index: int) -> dict[str, Any]:
    """Draw one configuration (parameters in sorted name order from a generator seeded by
    (seed, bracket, index))."""
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), 1, int(bracket), int(index)])))
    return {name: _draw(name, space[name], rng) for name in sorted(space)}


def trial_seed(seed: int, bracket: int, index: int) -> int:
    """Seed of a trial's model initialisation and window sampler (63-bit)."""
    state = np.random.SeedSequence([int(seed), 2, int(bracket), int(index)]).generate_state(2, dtype=np.uint32)
    return int(state[0]) << 31 | int(state[1]) >> 1


def config_hash(values: dict[str, Any]) -> str:
    """Short stable hash of a configuration (12 hex digits)."""
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:12]
