"""What the case's ``model`` section asks for, read without loading the model (the workflow asks as it starts)."""

from __future__ import annotations

from typing import Any


def uses_physics(model_config: dict[str, Any] | None) -> bool:
    """Whether the case's ``model`` section asks for a hybrid (``physics_terms`` other than ``none``)."""
    return (model_config or {}).get("physics_terms", "none") != "none"


#: Without ``model.input_delay.min_s`` / ``max_s``, every learned delay lies within this many grid samples of 0.
DELAY_BOUND_SAMPLES = 3


def input_delay_settings(delay_config: dict[str, Any] | None, sample_period_s: float) -> dict[str, Any]:
    """``model.input_delay`` with the fields the config leaves out (null) chosen from the grid: ``min_s`` and
    ``max_s`` ∓ :data:`DELAY_BOUND_SAMPLES` samples, ``scale_s`` one sample (s). A configured value wins."""
    delay = dict(delay_config or {})
    step_s = float(sample_period_s)
    if delay.get("min_s") is None:
        delay["min_s"] = -DELAY_BOUND_SAMPLES * step_s
    if delay.get("max_s") is None:
        delay["max_s"] = DELAY_BOUND_SAMPLES * step_s
    if delay.get("scale_s") is None:
        delay["scale_s"] = step_s
    return delay

