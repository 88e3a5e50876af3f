"""The documentation site builds without a warning (``mkdocs build --strict``): every page in the nav, every
link resolved, the API reference generated from the docstrings of ``hybridfmu.api``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_the_site_builds_strictly(tmp_path):
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                            cwd=REPO, capture_output=True, text=True, timeout=300,
                            env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-6000:]
    reference = (tmp_path / "site" / "reference" / "index.html").read_text()
    for name in ("load_case", "read_log", "simulate_fmu", "diagnose", "load_run", "simulate_trained"):
        assert f'id="hybridfmu.api.{name}"' in reference, name
