"""Loading and validating case configurations against the workflow's JSON schema."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml

#: The schema every case config is validated against (sections are $ref'd files beside it).
SCHEMA_PATH = Path(__file__).resolve().parents[2] / "workflow" / "schemas" / "config.schema.yaml"


class ConfigError(ValueError):
    """A case configuration does not match the schema; the message names the field."""


def validate_case_config(config: dict[str, Any], schema_path: str | Path = SCHEMA_PATH) -> dict[str, Any]:
    """Validate ``config`` in place (defaults from the schema are filled in) and return it.

    Raises:
        ConfigError: naming the offending field (e.g. ``config.training.batch_windows``)
            and what the schema expects there.
    """
    import jsonschema
    from snakemake.exceptions import WorkflowError
    from snakemake.utils import validate

    schema_path = Path(schema_path).resolve()
    try:
        validate(config, str(schema_path))
    except WorkflowError as err:
        cause = err.args[0] if err.args else err
        detail = _describe_validation_error(err)
        raise ConfigError(f"invalid case config: {detail or cause}") from None
    except jsonschema.ValidationError as err:  # pragma: no cover - depends on snakemake version
        raise ConfigError(f"invalid case config: {_format_error(err)}") from None
    fill_defaults(config, bundled_schema(schema_path))
    return config


def bundled_schema(schema_path: str | Path) -> dict[str, Any]:
    """The schema at ``schema_path`` with every ``$ref`` to a local file replaced by that file's content.

    Section schemas are separate files referenced from the top-level schema; bundling them
    lets defaults inside the sections be filled in (see :func:`fill_defaults`).
    """
    schema_path = Path(schema_path).resolve()
    with schema_path.open() as handle:
        schema = yaml.safe_load(handle)
    return _inline_refs(schema, schema_path.parent)


def _inline_refs(node: Any, base_dir: Path) -> Any:
    if isinstance(node, dict):
        ref = node.get("$ref")
        if isinstance(ref, str) and not ref.startswith("#") and "://" not in ref:
            target = (base_dir / ref).resolve()
            with target.open() as handle:
                inlined = _inline_refs(yaml.safe_load(handle), target.parent)
            rest = {key: _inline_refs(value, base_dir) for key, value in node.items() if key != "$ref"}
            return {**inlined, **rest}
        return {key: _inline_refs(value, base_dir) for key, value in node.items()}
    if isinstance(node, list):
        return [_inline_refs(item, base_dir) for item in node]
    return node


def fill_defaults(instance: Any, schema: dict[str, Any]) -> Any:
    """Fill ``default`` values of ``properties`` (recursively, also in absent sections) in place.

    Only plain ``properties`` and ``additionalProperties`` schemas are followed, which is all the
    case schemas use for nesting.
    """
    if not isinstance(instance, dict) or not isinstance(schema, dict):
        return instance
    for name, subschema in schema.get("properties", {}).items():
        if not isinstance(subschema, dict):
            continue
        if name not in instance and "default" in subschema:
            instance[name] = copy.deepcopy(subschema["default"])
        if name in instance:
            fill_defaults(instance[name], subschema)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        for name, value in instance.items():
            if name not in schema.get("properties", {}):
                fill_defaults(value, extra)
    return instance


def _describe_validation_error(err: BaseException) -> str:
    """Find the jsonschema error inside a Snakemake WorkflowError and format it."""
    import jsonschema

    seen: list[BaseException] = [err]
    while seen:
        current = seen.pop()
        if isinstance(current, jsonschema.ValidationError):
            return _format_error(current)
        for attr in ("__cause__", "__context__"):
            nested = getattr(current, attr, None)
            if nested is not None:
                seen.append(nested)
        for arg in getattr(current, "args", ()):
            if isinstance(arg, BaseException):
                seen.append(arg)
    return ""


def _format_error(err: Any) -> str:
    path = ".".join(str(p) for p in err.absolute_path)
    where = f"config.{path}" if path else "config (top level)"
    return f"{where}: {err.message}"


def load_case_config(path: str | Path) -> dict[str, Any]:
    """Read a case config YAML file, validate it, and return it with defaults filled in."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"case config {path} does not exist")
    with path.open() as handle:
        config = yaml.safe_load(handle)
    if not isinstance(config, dict):
        raise ConfigError(f"case config {path}: expected a mapping at the top level, got {type(config).__name__}")
    try:
        return validate_case_config(copy.deepcopy(config))
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


def case_results_dir(config: dict[str, Any]) -> Path:
    """Directory that holds every output of the case: ``<results_dir>/<case>``."""
    return Path(config.get("results_dir", "results")) / config["case"]
