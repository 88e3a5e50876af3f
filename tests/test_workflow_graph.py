"""The demo's workflow graph: its held-out test maneuvers are read by no rule before the evaluation.

A dry run of the whole demo (nothing is executed) lists every job with its input files. A test maneuver that the
diagnosis' held-out check does not name (config.diagnosis.open_loop.test_maneuvers) may be read only by the bench
that records it, by the data preparation every maneuver goes through, and by the evaluation: no training,
selection, calibration or diagnosis job sees it.
"""

import re
import subprocess
import sys
from pathlib import Path

import yaml

from hybridfmu.diagnosis.settings import diagnosis_maneuvers

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "config" / "config.yaml"

#: Rules that may read a held-out maneuver's files: the bench (the emulated world and its own spread check), the
#: data preparation of every maneuver, and the evaluation after the models are chosen.
EVALUATION_SIDE = {"emulate_bench", "check_bench_spread", "ingest", "select_segments", "simulate_baseline",
                   "simulate_ceiling", "simulate_best", "simulate_closed_loop", "evaluate", "plot", "report", "summary", "export",
                   "all"}


def dry_run_inputs(workdir: Path) -> list[tuple[str, list[str]]]:
    """(rule, input files) of every job of a dry run of the demo in ``workdir``."""
    done = subprocess.run([sys.executable, "-m", "snakemake", "-n", "-j1", "--snakefile", str(REPO / "Snakefile"),
                           "--directory", str(workdir), "--configfile", str(DEMO), "--nocolor"],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]
    jobs, rule = [], None
    for line in (done.stdout + done.stderr).splitlines():
        found = re.match(r"^(?:local)?(?:rule|checkpoint) (\w+):", line)
        if found:
            rule = found.group(1)
            continue
        found = re.match(r"^\s+input: (.*)$", line)
        if found and rule:
            jobs.append((rule, [item.strip() for item in found.group(1).split(",")]))
    return jobs


def test_held_out_maneuvers_are_read_by_no_rule_before_the_evaluation(tmp_path):
    config = yaml.safe_load(DEMO.read_text())
    tests = [name for name, item in config["maneuvers"].items() if item["role"] == "test"]
    unseen = [name for name in tests if name not in diagnosis_maneuvers(config)]
    assert len(tests) >= 6 and len(unseen) >= 5, (tests, unseen)
    jobs = dry_run_inputs(tmp_path)
    assert {rule for rule, _ in jobs} >= {"train_rung", "diagnose", "score_finalist", "score_finalists", "simulate_best",
                                         "evaluate"}
    pattern = re.compile(r"/(?:raw|data|segments|baseline|evaluation/ceiling|evaluation/trajectories)/(" +
                         "|".join(map(re.escape, unseen)) + r")\.")
    readers = {rule for rule, inputs in jobs for path in inputs if pattern.search(path)}
    assert readers and readers <= EVALUATION_SIDE, sorted(readers - EVALUATION_SIDE)
    assert {"simulate_best", "simulate_closed_loop", "evaluate"} <= readers  # the check sees the evaluation read them


def test_the_held_out_check_names_test_maneuvers_only():
    import pytest

    from hybridfmu.config import ConfigError

    config = yaml.safe_load(DEMO.read_text())
    config["diagnosis"]["open_loop"]["test_maneuvers"] = []
    assert diagnosis_maneuvers(config) == list(config["maneuvers"])  # empty: every test maneuver
    config["diagnosis"]["open_loop"]["test_maneuvers"] = ["validation", "test_hard"]
    with pytest.raises(ConfigError, match=r"demo.yaml: config.diagnosis.open_loop.test_maneuvers: \['validation'\]"):
        diagnosis_maneuvers(config, "demo.yaml")
