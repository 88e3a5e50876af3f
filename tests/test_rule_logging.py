"""A rule's process logs to its log file, and an error that ends it lands there with its traceback (not only in
Snakemake's output), once."""

from __future__ import annotations

import subprocess
import sys


def test_an_uncaught_error_is_written_to_the_rule_log(tmp_path):
    log = tmp_path / "logs" / "rule.log"
    code = ("from hybridfmu.progress import setup_rule_logging\n"
            f"setup_rule_logging({str(log)!r})\n"
            "raise ValueError('case.yaml: config.model.corrected_states: expected a state')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 1
    text = log.read_text()
    assert "the job failed: ValueError: case.yaml: config.model.corrected_states: expected a state" in text
    assert "Traceback (most recent call last)" in text
    assert result.stderr.count("the job failed: ValueError") == 1  # stderr once, through the same handler
