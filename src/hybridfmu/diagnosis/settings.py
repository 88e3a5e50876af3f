"""What the case's ``diagnosis`` section asks of the workflow, read without loading the diagnosis (the workflow asks
as it starts)."""

from __future__ import annotations

from typing import Any

from hybridfmu.config import ConfigError


def diagnosis_maneuvers(config: dict[str, Any], config_file: str = "config") -> list[str]:
    """The maneuvers the diagnosis reads, in config order: every train and validation maneuver, and the test
    maneuvers of its held-out check (``diagnosis.open_loop.test_maneuvers``; every test maneuver when empty).

    Raises:
        ConfigError: a named test maneuver is not a maneuver of the case with role test (names the file and field).
    """
    maneuvers = config["maneuvers"]
    named = list(((config.get("diagnosis") or {}).get("open_loop") or {}).get("test_maneuvers") or [])
    tests = [name for name, item in maneuvers.items() if item["role"] == "test"]
    wrong = [name for name in named if name not in tests]
    if wrong:
        raise ConfigError(f"{config_file}: config.diagnosis.open_loop.test_maneuvers: {wrong} are not maneuvers with "
                          f"role test; expected some of {tests}")
    held_out = named or tests
    return [name for name, item in maneuvers.items() if item["role"] != "test" or name in held_out]
