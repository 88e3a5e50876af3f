"""What Snakemake loads as the workflow starts (each run, and each Slurm job, parses the Snakefile): the
modules the Snakefile and the rule files import must not pull in PyTorch, SciPy's signal processing, MLflow,
pandas or matplotlib (seconds per start; `python benchmarks/workflow_start.py` measures the start)."""

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "scipy.signal", "mlflow", "pandas", "matplotlib")


def start_modules() -> list[str]:
    """The project modules the Snakefile and workflow/rules/*.smk import (at any indentation)."""
    files = [REPO / "Snakefile", *sorted((REPO / "workflow" / "rules").glob("*.smk"))]
    return sorted({name for path in files
                   for name in re.findall(r"^\s*from (hybridfmu[\w.]*) import", path.read_text(), re.MULTILINE)})


def loaded_heavy_modules(modules: list[str]) -> list[str]:
    code = ("import importlib, sys\n"
            f"for name in {modules!r}: importlib.import_module(name)\n"
            f"print(','.join(name for name in {HEAVY!r} if name in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert done.returncode == 0, done.stderr
    return [name for name in done.stdout.strip().split(",") if name]


def test_the_workflow_start_loads_no_heavy_library():
    modules = start_modules()
    assert {"hybridfmu.config", "hybridfmu.data.roles", "hybridfmu.model.settings"} <= set(modules), modules
    assert loaded_heavy_modules(modules) == []


def test_the_check_sees_a_heavy_import():
    assert loaded_heavy_modules(["hybridfmu.model.neural_fmu", "hybridfmu.data.ingest"]) == ["torch", "pandas"]


def test_a_training_job_of_the_neural_fmu_loads_no_signal_processing():
    """scipy.signal (~1.5 s to import) is imported where the diagnosis' derivatives use it: the modules of a
    training job, the diagnosis' derivatives themselves included, do not load it."""
    modules = ["hybridfmu.training.trial", "hybridfmu.api.stages", "hybridfmu.diagnosis.derivatives"]
    assert "scipy.signal" not in loaded_heavy_modules(modules)
    assert "mlflow" not in loaded_heavy_modules(modules)
