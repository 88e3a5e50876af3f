"""The wall-time benchmark's Markdown: the machine it ran on and the verdict against a stated target."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _benchmark():
    spec = importlib.util.spec_from_file_location("workflow_wall", ROOT / "benchmarks" / "workflow_wall.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_table_names_the_processor_and_says_which_commit_is_within_the_target(tmp_path):
    wall = _benchmark()
    summary = {"a" * 40: {"wall_s": [1700.0, 1900.0], "jobs": 190, "median_s": 1800.0},
               "b" * 40: {"wall_s": [1801.0], "jobs": 190, "median_s": 1801.0}}
    text = wall.markdown(summary, None, 2, target_min=30, processor="Some CPU 9000")
    lines = text.splitlines()
    assert f"({os.cpu_count()} cores, Some CPU 9000; `benchmarks/workflow_wall.py`)" in lines[0]
    assert lines[2] == "| commit | jobs | wall time | runs | within 30 min |"
    assert lines[4] == "| aaaaaaaaaa | 190 | 30.0 min | 28.3 min, 31.7 min | yes |"
    assert lines[5] == "| bbbbbbbbbb | 190 | 30.0 min | 30.0 min | no |"
    assert "within" not in wall.markdown(summary, None, 2, processor="x")


def test_the_processor_is_read_from_cpuinfo(tmp_path):
    wall = _benchmark()
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nvendor_id\t: X\nmodel name\t: AMD EPYC 7B13\nflags\t: fpu\n")
    assert wall.processor_name(cpuinfo) == "AMD EPYC 7B13"
    assert wall.processor_name(tmp_path / "missing")  # falls back to platform.processor() or a name, never empty
