"""Config sections of the data stage (``ingest``, ``segments``, ``signals``) with schema defaults."""

from __future__ import annotations

import copy
from typing import Any

from hybridfmu.config import SCHEMA_PATH, ConfigError, validate_case_config

SCHEMA_DIR = SCHEMA_PATH.parent


def section_settings(section: dict[str, Any] | None, name: str) -> dict[str, Any]:
    """Return a validated copy of config section ``name`` with the schema's defaults filled in.

    Args:
        section: the section as found in the case config (``config[name]``); None means empty.
        name: ``"ingest"``, ``"segments"`` or ``"signals"`` (schema ``src/hybridfmu/schemas/<name>.schema.yaml``).

    Raises:
        ConfigError: naming the field as ``config.<name>.<field>``.
    """
    data = copy.deepcopy(section) if section is not None else {}
    if not isinstance(data, dict):
        raise ConfigError(f"invalid case config: config.{name}: expected a mapping, got {type(data).__name__}")
    try:
        return validate_case_config(data, SCHEMA_DIR / f"{name}.schema.yaml")
    except ConfigError as err:
        message = str(err)
        if "config (top level)" in message:
            message = message.replace("config (top level)", f"config.{name}", 1)
        else:
            message = message.replace(": config.", f": config.{name}.", 1)
        raise ConfigError(message) from None
