"""Which maneuver of the case config a training stage uses for a role (read as the workflow starts, light)."""

from __future__ import annotations

from typing import Any


def role_maneuver(config: dict[str, Any], role: str, chosen: str = "") -> str:
    """The maneuver used for ``role`` (train / validation): ``chosen`` if set, else the first of that role."""
    maneuvers = config["maneuvers"]
    if chosen:
        if chosen not in maneuvers:
            raise ValueError(f"config.training: maneuver {chosen!r} is not in config.maneuvers {list(maneuvers)}")
        return chosen
    for name, item in maneuvers.items():
        if item["role"] == role:
            return name
    raise ValueError(f"config.maneuvers: no maneuver with role {role!r} (training needs one)")
