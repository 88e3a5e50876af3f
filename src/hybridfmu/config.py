"""Loading and validating case configurations against the workflow's JSON schema."""

from __future__ import annotations

import copy
import functools
from pathlib import Path
from typing import Any

import yaml

#: The schema every case config is validated against (package data; sections are $ref'd files beside it).
SCHEMA_PATH = Path(__file__).resolve().parent / "schemas" / "config.schema.yaml"
#: libyaml's loader where PyYAML was built with it (several times faster), else the pure-Python one
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class ConfigError(ValueError):
    """A case configuration does not match the schema; the message names the field."""


def validate_case_config(config: dict[str, Any], schema_path: str | Path = SCHEMA_PATH) -> dict[str, Any]:
    """Validate ``config`` in place (defaults from the schema are filled in) and return it.

    The schema is JSON Schema 2020-12 in YAML; ``$ref`` to a file resolves relative to the referring file.
    Schema files are read once per process (the workflow validates the config and several sections each
    time Snakemake starts, in every job).

    Raises:
        ConfigError: naming the offending field (e.g. ``config.training.batch_windows``)
            and what the schema expects there.
    """
    import jsonschema

    path = str(Path(schema_path).resolve())
    try:
        _default_filling_validator(path).validate(config)
    except jsonschema.ValidationError as err:
        raise ConfigError(f"invalid case config: {_format_error(err)}") from None
    fill_defaults(config, bundled_schema(path))  # fill_defaults copies the defaults it sets
    return config


@functools.lru_cache(maxsize=None)
def _schema_file(path: str) -> dict[str, Any]:
    """The parsed schema file at the absolute ``path`` (read once; callers must not change it)."""
    with open(path, encoding="utf-8") as handle:
        return yaml.load(handle, Loader=_YAML_LOADER)


@functools.lru_cache(maxsize=None)
def _default_filling_validator(path: str) -> Any:
    """A Draft 2020-12 validator of the schema at the absolute ``path`` that, like Snakemake's config
    validation, sets each absent property that has a ``default`` before validating it (a copy of the default,
    so no two configs share one)."""
    from urllib.parse import urlparse
    from urllib.request import url2pathname

    from jsonschema import Draft202012Validator, validators
    from referencing import Registry, Resource
    from referencing.jsonschema import DRAFT202012

    def retrieve(uri: str) -> Resource:
        return Resource.from_contents(_schema_file(url2pathname(urlparse(uri).path)),
                                      default_specification=DRAFT202012)

    # $id: relative $refs resolve against the schema file itself
    schema = {**_schema_file(path), "$id": Path(path).as_uri()}
    validate_properties = Draft202012Validator.VALIDATORS["properties"]

    def set_defaults(validator: Any, properties: dict[str, Any], instance: Any, subschema: dict[str, Any]):
        if isinstance(instance, dict):
            for name, property_schema in properties.items():
                if isinstance(property_schema, dict) and "default" in property_schema and name not in instance:
                    instance[name] = copy.deepcopy(property_schema["default"])
        yield from validate_properties(validator, properties, instance, subschema)

    filling = validators.extend(Draft202012Validator, {"properties": set_defaults})
    return filling(schema, registry=Registry(retrieve=retrieve))


@functools.lru_cache(maxsize=None)
def bundled_schema(path: str) -> dict[str, Any]:
    """The schema at the absolute ``path`` with every ``$ref`` to a local file replaced by that file's content
    (built once; callers must not change it).

    Section schemas are separate files referenced from the top-level schema; bundling them
    lets defaults inside the sections be filled in (see :func:`fill_defaults`).
    """
    return _inline_refs(_schema_file(path), Path(path).parent)


def _inline_refs(node: Any, base_dir: Path) -> Any:
    if isinstance(node, dict):
        ref = node.get("$ref")
        if isinstance(ref, str) and not ref.startswith("#") and "://" not in ref:
            target = (base_dir / ref).resolve()
            inlined = _inline_refs(_schema_file(str(target)), target.parent)
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


def _format_error(err: Any) -> str:
    path = ".".join(str(p) for p in err.absolute_path)
    where = f"config.{path}" if path else "config (top level)"
    return f"{where}: {err.message}"


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Read a case config file strictly: the mapping it holds, exactly as written.

    Unlike ``yaml.safe_load`` (which keeps the last of two equal keys without a word), a key listed twice in
    one mapping is an error, and malformed YAML is answered with the file, line and column, and the field
    it occurs in.

    Raises:
        ConfigError: ``<file>:<line>: config.<field>: ...`` for a duplicate key or malformed YAML; a missing
            file; a file that does not hold a mapping.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"case config {path} does not exist; expected a YAML file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not a text file ({err}); expected a UTF-8 YAML case config") from None
    loader = yaml.SafeLoader(text)  # the pure-Python parser: its messages name the problem precisely
    try:
        node = loader.get_single_node()
        if node is not None:
            _check_duplicate_keys(node, "config", path)
        config = loader.construct_document(node) if node is not None else None
    except yaml.MarkedYAMLError as err:
        raise ConfigError(_malformed_yaml_message(path, text, err)) from None
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: not valid YAML ({err}); expected a YAML mapping of config sections") from None
    finally:
        loader.dispose()
    if not isinstance(config, dict):
        raise ConfigError(f"case config {path}: expected a mapping at the top level, got {type(config).__name__}")
    return config


def check_config_file(path: str | Path, config: dict[str, Any] | None = None) -> dict[str, Any]:
    """Check a case config file as the workflow starts; return the mapping the file holds.

    Snakemake reads ``--configfile`` with a plain YAML loader, so a key listed twice (e.g. a maneuver) would
    silently keep only its last value; this reads the file again strictly (:func:`read_config_file`). With
    ``config`` (the workflow's config, read from that file), also validates a copy of it against the schema
    with errors naming the file (``config`` itself is not changed).

    Raises:
        ConfigError: ``<file>:<line>: config.<field>: ...`` (duplicate key, malformed YAML) or
            ``<file>: invalid case config: config.<field>: ...`` (schema).
    """
    content = read_config_file(path)
    if config is not None:
        try:
            validate_case_config(copy.deepcopy(dict(config)))
        except ConfigError as err:
            raise ConfigError(f"{path}: {err}") from None
    return content


def _key_path(parent: str, key: Any) -> str:
    return f"{parent}.{key}"


def _check_duplicate_keys(node: yaml.Node, where: str, path: Path) -> None:
    """Raise ConfigError for the first key that occurs twice in one mapping of the composed ``node``."""
    if isinstance(node, yaml.MappingNode):
        seen: dict[tuple[str, Any], int] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                _check_duplicate_keys(value_node, where, path)
                continue
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
            line = key_node.start_mark.line + 1
            if key is not None:
                identity = (key_node.tag, key)
                if identity in seen:
                    raise ConfigError(
                        f"{path}:{line}: {_key_path(where, key)}: key {key!r} is listed twice in {where} (first at "
                        f"line {seen[identity]}, again at line {line}; YAML would keep only the last); expected each "
                        "key once")
                seen[identity] = line
            _check_duplicate_keys(value_node, _key_path(where, key if key is not None else "?"), path)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            _check_duplicate_keys(item, f"{where}[{index}]", path)


def _malformed_yaml_message(path: Path, text: str, err: yaml.MarkedYAMLError) -> str:
    """One line: file, line and column of a YAML syntax error, the field it occurs in, the parser's complaint."""
    mark = err.problem_mark or err.context_mark
    line = mark.line + 1 if mark is not None else 0
    column = mark.column + 1 if mark is not None else 0
    field = _field_before_error(text)
    problem = " ".join(str(err.problem or "syntax error").split())
    context = ""
    if err.context and err.context_mark is not None:
        context = f" ({' '.join(str(err.context).split())} at line {err.context_mark.line + 1})"
    lines = text.splitlines()
    bad_line = lines[line - 1] if 0 < line <= len(lines) else ""
    indent = bad_line[:len(bad_line) - len(bad_line.lstrip())]
    tab_hint = " (a tab in the indentation: YAML indents with spaces only)" if "\t" in indent else ""
    return (f"{path}:{line}:{column}: not valid YAML near {field}: {problem}{context}{tab_hint}; expected well-formed "
            "YAML (indentation with spaces, closed brackets and quotes, 'key: value' pairs)")


def _field_before_error(text: str) -> str:
    """The config field (``config.a.b``) the YAML parser was inside when it stopped on an error."""
    stack: list[dict[str, Any]] = []

    def node_started() -> None:
        if stack and stack[-1]["kind"] == "map":
            frame = stack[-1]
            frame["expect_key"] = not frame["expect_key"]
        elif stack:
            stack[-1]["index"] += 1

    try:
        for event in yaml.parse(text, Loader=yaml.SafeLoader):
            if isinstance(event, yaml.ScalarEvent):
                if stack and stack[-1]["kind"] == "map" and stack[-1]["expect_key"]:
                    stack[-1]["key"] = event.value
                node_started()
            elif isinstance(event, yaml.AliasEvent):
                node_started()
            elif isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                node_started()
                kind = "map" if isinstance(event, yaml.MappingStartEvent) else "seq"
                stack.append({"kind": kind, "key": None, "expect_key": True, "index": -1})
            elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                if stack:
                    stack.pop()
    except yaml.YAMLError:
        pass
    parts = ["config"]
    for frame in stack:
        if frame["kind"] == "map" and frame["key"] is not None:
            parts.append(f".{frame['key']}")
        elif frame["kind"] == "seq" and frame["index"] >= 0:
            parts.append(f"[{frame['index']}]")
    return "".join(parts) if len(parts) > 1 else "config (top level)"


def load_case_config(path: str | Path) -> dict[str, Any]:
    """Read a case config YAML file strictly (:func:`read_config_file`), validate it, and return it with
    defaults filled in."""
    path = Path(path)
    config = read_config_file(path)
    try:
        return validate_case_config(copy.deepcopy(config))
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from None


def case_results_dir(config: dict[str, Any]) -> Path:
    """Directory that holds every output of the case: ``<results_dir>/<case>``."""
    return Path(config.get("results_dir", "results")) / config["case"]


def case_fmu_path(config: dict[str, Any]) -> Path:
    """The case's FMU: ``<results_dir>/<case>/fmu/<model_name>.fmu`` when the workflow builds it from its C
    sources (``fmu.source: build``, rule ``build_fmu``), else the config's ``fmu.path``."""
    fmu = config["fmu"]
    if fmu["source"] == "build":
        return case_results_dir(config) / "fmu" / f"{fmu['model_name']}.fmu"
    return Path(fmu["path"])


def main(argv: list[str] | None = None) -> int:
    """``python -m hybridfmu.config FILE...``: check case config files (strict YAML, schema); 0 when all pass.

    Snakemake parses ``--configfile`` itself before the workflow starts and reports malformed YAML without
    file or line; this check names both.
    """
    import sys

    files = sys.argv[1:] if argv is None else argv
    if not files:
        print("usage: python -m hybridfmu.config CONFIG.yaml [...]", file=sys.stderr)
        return 2
    status = 0
    for name in files:
        try:
            load_case_config(name)
        except ConfigError as err:
            print(f"error: {err}", file=sys.stderr)
            status = 1
        else:
            print(f"{name}: ok")
    return status


if __name__ == "__main__":
    raise SystemExit(main())
