"""The rules ingest and select_segments run through Snakemake on a case with its own raw log."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from test_data_ingest import raw_signals, write_mdf

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_ingest_and_select_segments_rules(tmp_path):
    raw = write_mdf(tmp_path / "logs" / "run1.mf4", raw_signals(duration_s=3.6))
    case = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    case["case"] = "datacase"
    case["results_dir"] = str(tmp_path / "results")
    case["maneuvers"] = {name: {"role": role, "raw": str(raw)}  # a case needs all three roles
                         for name, role in [("run1", "train"), ("run2", "validation"), ("run3", "test")]}
    # one log, split into slices that do not overlap (data of one role must not be data of another)
    case["maneuvers"]["run1"].update(t_end_s=2.0)
    case["maneuvers"]["run2"].update(t_start_s=2.0, t_end_s=2.5)
    case["maneuvers"]["run3"].update(t_start_s=2.5, t_end_s=3.5)
    case.pop("bench", None)  # a user's case: its own logs, no emulated bench
    case.pop("closed_loop")  # ... and no ECU references in them
    case["signals"] = {name: entry for name, entry in case["signals"].items()
                       if not entry["channel"].startswith(("BrkCtl_", "MotCtl_AngleRef", "MotCtl_SpeedFf",
                                                           "MotCtl_AccelFf", "MotCtl_SpeedLim", "MotCtl_CurrentLim"))}
    case["diagnosis"]["open_loop"].pop("test_maneuvers")  # the demo's held-out check names the demo's maneuver
    config_path = tmp_path / "case.yaml"
    config_path.write_text(yaml.safe_dump(case))
    target = tmp_path / "results" / "datacase" / "segments" / "run1.json"
    sliced = tmp_path / "results" / "datacase" / "data" / "run3.parquet"
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-j1", str(target), str(sliced), "--configfile", str(config_path)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    results = tmp_path / "results" / "datacase"
    frame = pd.read_parquet(results / "data" / "run1.parquet")
    assert frame["time_s"].iloc[0] == 0.0 and len(frame) > 19000
    assert {"load_torque", "current_d", "current_q", "speed"} <= set(frame.columns)
    assert pd.read_parquet(sliced)["time_s"].iloc[-1] == pytest.approx(1.0)
    record = json.loads(target.read_text())
    assert record["maneuver"] == "run1" and 0.0 < record["fraction_kept"] <= 1.0
    assert (results / "segments" / "run1.png").stat().st_size > 10_000
    for rule in ("ingest", "select_segments"):
        assert (results / "logs" / rule / "run1.log").read_text().strip()
        assert (results / "benchmarks" / rule / "run1.tsv").is_file()
