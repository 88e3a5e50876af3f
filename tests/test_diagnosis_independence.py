"""The diagnosis knows nothing of the emulated bench: no default of the diagnosis package and no value of a
case config's ``diagnosis`` section equals a constant of the bench (its config section, its settings'
defaults, its effect catalog's defaults, its module constants). That no module of the package imports the bench
is checked with the package's whole import graph (tests/test_import_structure.py).

The bench plays the real world; a diagnosis that carried one of its numbers (a sensor lag, a smoothing
current, a PWM frequency) would be told the answer. Values that are dimensionless statistics or grids
(quantiles, relative grids, counts, selection thresholds) are no physical constants and are not compared,
nor are 0 and 1. The FMU's own nominal parameters are the model's, which the diagnosis may read.
"""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import math
import pkgutil
from pathlib import Path
from typing import Any, Iterator

import pytest
import yaml

import hybridfmu_bench as bench_package
import hybridfmu.diagnosis as diagnosis_package

ROOT = Path(__file__).resolve().parents[1]
#: Case configs whose logs come from the emulated bench (cases on real measurements have no bench section).
BENCH_CONFIGS = [path for path in sorted([ROOT / "config" / "config.yaml", ROOT / "config" / "paper.yaml",
                                          *(ROOT / "config" / "cases").glob("*.yaml")])
                 if "bench" in (yaml.safe_load(path.read_text()) or {})]
#: Unit suffixes of setting names; values of different units never collide (a 0.004 s kernel is no 0.004 N m).
UNIT_SUFFIXES = ("s", "a", "v", "hz", "nm", "rad", "bar", "m", "cm3", "ohm", "nm_s", "rad_s", "rad_s2", "pa", "w",
                 "kg", "kgm2", "h", "wb")

#: Key names (or parts of them) of dimensionless settings: statistics, grids relative to the data, counts.
DIMENSIONLESS_KEYS = ("quantile", "relative", "order", "harmonic", "degree", "samples", "iterations", "dpi", "seed",
                      "top_statements", "tolerance", "margin_relative", "threshold_relative", "kinds", "correlation",
                      "range_ratio", "fraction", "time_constants")
#: Sections of the diagnosis settings that hold only dimensionless selection thresholds.
DIMENSIONLESS_SECTIONS = ("selection",)
#: Bench constants that are the FMU's own (nominal) parameters, not the bench's truth.
MODEL_OWN = ("NOMINAL_PARAMETERS",)
#: Bench modules outside the real world's physics (the log writer; the withheld suite, which drives the bench).
SKIPPED_BENCH_MODULES = ("hybridfmu_bench.mdf_writer", "hybridfmu_bench.withheld")


def numbers(value: Any, path: str = "") -> Iterator[tuple[str, float]]:
    """(path, number) for every int/float (not bool) nested in dicts, lists and tuples."""
    if isinstance(value, bool) or value is None:
        return
    if isinstance(value, (int, float)):
        yield path, float(value)
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from numbers(item, f"{path}.{key}" if path else str(key))
    elif isinstance(value, (list, tuple)):
        for j, item in enumerate(value):
            yield from numbers(item, f"{path}[{j}]")


def is_dimensionless(path: str) -> bool:
    parts = path.lower().replace("[", ".").split(".")
    if any(part in DIMENSIONLESS_SECTIONS for part in parts):
        return True
    return any(key in part for part in parts for key in DIMENSIONLESS_KEYS)


def _modules(package: Any) -> Iterator[Any]:
    for info in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
        yield importlib.import_module(info.name)


def _module_constants(module: Any, skip: tuple[str, ...] = ()) -> Iterator[tuple[str, float]]:
    """Numbers of a module's UPPER_CASE constants, dataclass field defaults and classes' PARAMETERS."""
    for name, value in vars(module).items():
        if name.isupper() and name not in skip and not inspect.ismodule(value):
            yield from numbers(value, f"{module.__name__}.{name}")
        if inspect.isclass(value) and value.__module__ == module.__name__:
            if dataclasses.is_dataclass(value):
                for f in dataclasses.fields(value):
                    if f.default is not dataclasses.MISSING:
                        yield from numbers(f.default, f"{module.__name__}.{name}.{f.name}")
            params = vars(value).get("PARAMETERS")
            if isinstance(params, dict):
                yield from numbers(params, f"{module.__name__}.{name}.PARAMETERS")


def _schema_defaults(path: Path) -> Iterator[tuple[str, float]]:
    def walk(node: Any, where: str) -> Iterator[tuple[str, float]]:
        if isinstance(node, dict):
            if "default" in node:
                yield from numbers(node["default"], where)
            for key, item in (node.get("properties") or {}).items():
                yield from walk(item, f"{where}.{key}" if where else key)
            for key in ("items", "additionalProperties"):
                if isinstance(node.get(key), dict):
                    yield from walk(node[key], where)
    yield from walk(yaml.safe_load(path.read_text()), "")


def bench_values() -> dict[float, list[str]]:
    """Every number the bench holds -> where it comes from."""
    values: dict[float, list[str]] = {}
    for module in _modules(bench_package):
        if module.__name__ not in SKIPPED_BENCH_MODULES:
            for path, value in _module_constants(module, skip=MODEL_OWN):
                values.setdefault(value, []).append(path)
    for path, value in _schema_defaults(ROOT / "src" / "hybridfmu" / "schemas" / "bench.schema.yaml"):
        values.setdefault(value, []).append(f"bench.schema.yaml:{path}")
    for config in BENCH_CONFIGS:
        section = (yaml.safe_load(config.read_text()) or {}).get("bench") or {}
        for path, value in numbers(section):
            values.setdefault(value, []).append(f"{config.name}:bench.{path}")
    return {v: p for v, p in values.items() if v not in (0.0, 1.0)}


def _inline_defaults(path: Path) -> Iterator[tuple[str, float]]:
    """Numbers given as defaults in ``<mapping>.get("key", default)`` calls of a source file."""
    for node in ast.walk(ast.parse(path.read_text())):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "get"
                and len(node.args) == 2 and isinstance(node.args[0], ast.Constant)
                and isinstance(node.args[0].value, str)):
            try:
                default = ast.literal_eval(node.args[1])
            except ValueError:
                continue
            yield from numbers(default, f"{path.name}:{node.args[0].value}")


def diagnosis_values() -> list[tuple[str, float]]:
    """Every physical number of the diagnosis' defaults and of the case configs' diagnosis sections."""
    out: list[tuple[str, float]] = []
    for module in _modules(diagnosis_package):
        out += [(p, v) for p, v in _module_constants(module) if not is_dimensionless(p)]
        out += [(p, v) for p, v in _inline_defaults(Path(module.__file__)) if not is_dimensionless(p)]
    schema = ROOT / "src" / "hybridfmu" / "schemas" / "diagnosis.schema.yaml"
    out += [(f"diagnosis.schema.yaml:{p}", v) for p, v in _schema_defaults(schema) if not is_dimensionless(p)]
    for config in BENCH_CONFIGS:
        data = yaml.safe_load(config.read_text()) or {}
        sections = {"diagnosis": data.get("diagnosis") or {},
                    "withheld.diagnosis": (data.get("withheld") or {}).get("diagnosis") or {}}
        for name, section in sections.items():
            out += [(f"{config.name}:{name}.{p}", v) for p, v in numbers(section) if not is_dimensionless(p)]
    return [(p, v) for p, v in out if v not in (0.0, 1.0)]


def unit_of(path: str) -> str | None:
    """The unit suffix of a setting's name (``kernel_s`` -> ``s``, ``current_scales_a[0]`` -> ``a``), or None."""
    name = path.split(":")[-1].split(".")[-1].split("[")[0].lower()
    for suffix in sorted(UNIT_SUFFIXES, key=len, reverse=True):
        if name.endswith("_" + suffix):
            return suffix
    return None


def collisions(diagnosis: list[tuple[str, float]], bench: dict[float, list[str]]) -> list[str]:
    """Diagnosis values equal (to 1e-9 relative) to a bench value of the same unit (or where either name
    carries no unit), as readable lines."""
    out = []
    for path, value in diagnosis:
        unit = unit_of(path)
        for bench_value, places in bench.items():
            if not math.isclose(value, bench_value, rel_tol=1e-9, abs_tol=0.0):
                continue
            for where in places:
                other = unit_of(where)
                if unit is None or other is None or unit == other:
                    out.append(f"{path} = {value:g} equals the bench's {where}")
                    break
    return out


def test_no_diagnosis_default_or_config_value_equals_a_bench_constant():
    bench = bench_values()
    assert len(bench) > 50, "the bench's constants were not found"
    diagnosis = diagnosis_values()
    assert len(diagnosis) > 10, "the diagnosis' settings were not found"
    found = collisions(diagnosis, bench)
    assert not found, "the diagnosis carries bench constants:\n" + "\n".join(found)


def test_the_check_catches_a_copied_bench_constant():
    """A sensor lag copied from the bench's sensor settings into a diagnosis section is caught."""
    from hybridfmu_bench.settings import SensorSettings

    lag = SensorSettings().pressure_lag_s
    planted = [("config.yaml:diagnosis.input_lag_compensation_s.tau_load", lag)]
    found = collisions(planted, bench_values())
    assert found and "pressure_lag_s" in found[0]


@pytest.mark.parametrize("path", ["input_lag_compensation_s.tau_load", "plugin_options.x.current_scales_a[0]",
                                  "end_stop_margin", "kernel_s"])
def test_physical_settings_are_compared(path):
    assert not is_dimensionless(path)
