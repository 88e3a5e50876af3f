"""The configuration reference: every field of a case config, rendered from the schemas it is validated against.

``python -m hybridfmu.config_reference docs/config.md`` writes the page (atomically); ``--check`` changes nothing
and exits 1 with a diff when the page differs from what the schemas give, so the reference cannot fall behind
them. One section per top-level key of ``config.schema.yaml``, in its order, with the section's description and
a table of its fields: dotted path (``<name>`` for a key the user chooses, ``[]`` for the items of a list), the
accepted type, the default and the description.
"""

from __future__ import annotations

import argparse
import difflib
import json
import sys
from pathlib import Path
from typing import Any

from hybridfmu.config import SCHEMA_PATH, bundled_schema
from hybridfmu.io import atomic_path

BENCH_SECTIONS = ("bench", "withheld")
"""Sections only the emulated bench (the demo's stand-in for hardware) and its withheld-effect check read."""


def _cell(text: Any) -> str:
    """One table cell: on one line, with the characters Markdown would read as a column or a tag escaped."""
    return " ".join(str(text).split()).replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;")


def type_text(schema: dict[str, Any]) -> str:
    """The accepted values of ``schema`` in a few words (``number > 0``, ``one of a, b``, ``string or list``)."""
    if "const" in schema:
        return f"`{json.dumps(schema['const'])}`"
    if "enum" in schema:
        return "one of " + ", ".join(f"`{json.dumps(v) if not isinstance(v, str) else v}`" for v in schema["enum"])
    for combiner in ("oneOf", "anyOf"):
        if combiner in schema:
            return " or ".join(type_text(option) for option in schema[combiner])
    kind = schema.get("type") or ("object" if schema.get("properties") else None)
    if isinstance(kind, list):
        text = " or ".join(kind)
    elif kind == "array":
        items = schema.get("items")
        text = f"list of {type_text(items)}" if isinstance(items, dict) and items else "list"
    elif kind == "object" and isinstance(schema.get("additionalProperties"), dict) and not schema.get("properties"):
        text = f"map to {type_text(schema['additionalProperties'])}"
    else:
        text = kind or "any"
    bounds = [f"≥ {schema['minimum']}" if "minimum" in schema else "",
              f"> {schema['exclusiveMinimum']}" if "exclusiveMinimum" in schema else "",
              f"≤ {schema['maximum']}" if "maximum" in schema else "",
              f"< {schema['exclusiveMaximum']}" if "exclusiveMaximum" in schema else ""]
    bounds = [b for b in bounds if b]
    return text + (" " + ", ".join(bounds) if bounds else "")


def _default_text(schema: dict[str, Any]) -> str:
    if "default" not in schema:
        return ""
    value = schema["default"]
    if value in ({}, []) and schema.get("type") in ("object", "array"):
        return ""
    return f"`{json.dumps(value, ensure_ascii=False)}`"


def _item_variants(items: Any) -> list[tuple[str, dict[str, Any]]]:
    """The object shapes a list's items may take: ``[("", items)]`` for one shape, ``[("kind=scale", shape),
    ...]`` for items told apart by a constant ``kind``; ``[]`` for items that are no objects."""
    if not isinstance(items, dict):
        return []
    if items.get("properties"):
        return [("", items)]
    variants = []
    for option in items.get("oneOf") or []:
        if isinstance(option, dict) and option.get("properties"):
            kind = (option["properties"].get("kind") or {}).get("const")
            variants.append((f"kind={kind}" if kind is not None else "", option))
    return variants


def field_rows(schema: dict[str, Any], path: str, required: bool = False) -> list[tuple[str, str, str, str]]:
    """(path, type, default, description) of ``schema`` at ``path`` and of every field below it, depth first.

    ``required`` marks the row of a field its parent requires."""
    rows = []
    description = _cell(schema.get("description", ""))
    if required:
        description = ("**required.** " + description).strip()
    properties = schema.get("properties") or {}
    nested = dict(properties)
    if not properties and isinstance(schema.get("additionalProperties"), dict):
        value_schema = schema["additionalProperties"]
        if value_schema.get("properties"):
            nested = {"<name>": value_schema}
    items = schema.get("items") if schema.get("type") == "array" else None
    if path:
        rows.append((f"`{path}`", _cell(type_text(schema)) if not nested else "section", _default_text(schema),
                     description))
    needed = set(schema.get("required") or [])
    for name, child in nested.items():
        rows += field_rows(child, f"{path}.{name}" if path else name, name in needed)
    for suffix, variant in _item_variants(items):
        for name, child in variant["properties"].items():
            if suffix and name == "kind":
                continue
            rows += field_rows(child, f"{path}[{suffix}].{name}", name in set(variant.get("required") or []))
    for option in schema.get("oneOf") or []:
        if isinstance(option, dict) and option.get("properties"):
            for name, child in option["properties"].items():
                if name not in properties:
                    rows += field_rows(child, f"{path}.{name}", False)
    return rows


def reference_markdown(schema_path: str | Path = SCHEMA_PATH) -> str:
    """The whole reference page as Markdown."""
    schema = bundled_schema(str(schema_path))
    lines = ["# Configuration reference", "",
             "Every field of a case config (`config/config.yaml`, `config/cases/*.yaml`), rendered from the schemas "
             "it is validated against (`src/hybridfmu/schemas/`) by `python -m hybridfmu.config_reference "
             "docs/config.md`; a test fails when this page differs from them. `python -m hybridfmu.config "
             "<case>.yaml` checks a config file against them; the workflow also checks it against the FMU, the logs "
             "and the search budget before any job runs. `<name>`: a key you choose; `[]`: each item of a list.", ""]
    required = set(schema.get("required") or [])
    table = ["| field | type | default | description |", "|---|---|---|---|"]
    sections = {name: sub for name, sub in schema["properties"].items() if len(field_rows(sub, name)) > 1}
    scalars = [row for name, sub in schema["properties"].items() if name not in sections
               for row in field_rows(sub, name, name in required)]
    lines += ["## Top-level fields", ""] + table + [f"| {' | '.join(row)} |" for row in scalars] + [""]
    for section, section_schema in sections.items():
        lines += [f"## `{section}`", ""]
        if section in BENCH_SECTIONS:
            lines += ["*Read only by the emulated bench (the demo's stand-in for hardware) and its "
                      "withheld-effect check; a case with its own logs leaves it out.*", ""]
        if section in required:
            lines += ["**Required.**", ""]
        if section_schema.get("description"):
            lines += [_cell(section_schema["description"]).replace("\\|", "|"), ""]
        lines += table + [f"| {' | '.join(row)} |" for row in field_rows(section_schema, section)[1:]] + [""]
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Write the configuration reference page from the config schemas.")
    parser.add_argument("page", help="the Markdown page to write, e.g. docs/config.md")
    parser.add_argument("--check", action="store_true", help="change nothing; exit 1 if the page differs")
    args = parser.parse_args(argv)
    text = reference_markdown()
    page = Path(args.page)
    if args.check:
        current = page.read_text() if page.is_file() else ""
        if current == text:
            print(f"{page}: up to date with the schemas")
            return 0
        sys.stdout.writelines(difflib.unified_diff(current.splitlines(True), text.splitlines(True), str(page),
                                                   "the schemas"))
        print(f"{page}: differs from the schemas; run python -m hybridfmu.config_reference {page}")
        return 1
    with atomic_path(page) as tmp:
        Path(tmp).write_text(text)
    print(f"wrote {page}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
