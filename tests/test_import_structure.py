"""The packages' modules import each other without circles, their subpackages too, and the core never imports
the emulated bench.

Every import is read from the source, those inside functions included; neither the module graph nor the graph of
the core's subpackages (``hybridfmu.data``, ``hybridfmu.training``, ...; a top-level module counts as one) may
have a strongly connected component of more than one node: the layers import in one direction, from data and FMU
access up to training, evaluation and reports. The bench (``hybridfmu_bench``: the "real hardware" with its ground
truth, and the withheld suite that drives it) may import the core; no module of ``hybridfmu`` may import it."""

from __future__ import annotations

import ast
from pathlib import Path

import networkx

SOURCE = Path(__file__).resolve().parent.parent / "src"
#: The core package and the bench package.
PACKAGES = [SOURCE / "hybridfmu", SOURCE / "hybridfmu_bench"]


def module_name(path: Path) -> str:
    parts = path.relative_to(SOURCE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> networkx.DiGraph:
    """Module -> the packages' modules it imports (at module level or inside a function)."""
    modules = {module_name(path): path for package in PACKAGES for path in package.rglob("*.py")}
    graph = networkx.DiGraph()
    graph.add_nodes_from(modules)
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the module's package, one level up per further dot
                    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
                    package = package[:len(package) - (node.level - 1)]
                    base = ".".join(package + ([node.module] if node.module else []))
                # "from a.b import c": module a.b.c when c is one, else a.b
                targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                           for alias in node.names]
            else:
                continue
            for target in targets:
                if target in modules and target != name:
                    graph.add_edge(name, target)
    return graph


def test_the_modules_import_each_other_without_circles():
    graph = import_graph()
    assert graph.number_of_nodes() > 50 and graph.number_of_edges() > 100  # the walk sees the package
    assert graph.has_edge("hybridfmu.model.neural_fmu", "hybridfmu.model.delay")  # relative imports too
    circles = [component for component in networkx.strongly_connected_components(graph) if len(component) > 1]
    assert not circles, sorted(map(sorted, circles))


def test_the_core_never_imports_the_bench():
    graph = import_graph()
    assert graph.has_edge("hybridfmu_bench.emulate", "hybridfmu.io")  # the walk sees the bench's imports of the core
    offenders = sorted((module, target) for module, target in graph.edges
                       if module.split(".")[0] == "hybridfmu" and target.split(".")[0] == "hybridfmu_bench")
    assert not offenders, offenders


def subpackage(module: str) -> str:
    """``hybridfmu.training.trial`` -> ``hybridfmu.training``; a top-level module is its own node."""
    return ".".join(module.split(".")[:2])


def test_the_core_subpackages_import_in_one_direction():
    graph = import_graph()
    layers = networkx.DiGraph()
    for module, target in graph.edges:
        a, b = subpackage(module), subpackage(target)
        if a != b and a.startswith("hybridfmu.") and b.startswith("hybridfmu."):
            layers.add_edge(a, b, via=f"{module} -> {target}")
    assert layers.has_edge("hybridfmu.training", "hybridfmu.model")  # the graph sees the layers
    circles = [component for component in networkx.strongly_connected_components(layers) if len(component) > 1]
    arrows = sorted(data["via"] for a, b, data in layers.edges(data=True)
                    if any(a in circle and b in circle for circle in circles))
    assert not circles, arrows
