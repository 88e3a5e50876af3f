"""What the case's ``model`` section asks for, read without loading the model (the workflow asks as it starts)."""

from __future__ import annotations

from typing import Any


def uses_physics(model_config: dict[str, Any] | None) -> bool:
    """Whether the case's ``model`` section asks for a hybrid (``physics_terms`` other than ``none``)."""
    return (model_config or {}).get("physics_terms", "none") != "none"
