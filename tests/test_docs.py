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


def test_the_readme_is_short_and_every_measured_table_lives_in_one_place():
    """README.md at most 15 KB; every measured block of the README and the pages is opened once (a second copy
    would be an error of ``measured_blocks``); the README carries the results table and the demo's wall time."""
    from hybridfmu.evaluation.measured_blocks import block_locations, document_paths

    readme = REPO / "README.md"
    assert readme.stat().st_size <= 15 * 1024, readme.stat().st_size
    locations = block_locations(document_paths([readme, REPO / "docs"]))
    assert locations["headline"] == readme and locations["workflow_wall"] == readme
    assert {"ipb", "ipb_robustness", "tanks", "withheld", "train_step"} <= set(locations)
    for name, path in locations.items():
        assert path.read_text().count(f"<!-- /measured:{name} -->") == 1, (name, path)


def test_the_configuration_reference_is_rendered_from_the_schemas(tmp_path):
    """docs/config.md is what ``python -m hybridfmu.config_reference`` writes from the schemas: a field added to a
    schema without the page rewritten fails here; the page names every section and the fields of a list's items."""
    from hybridfmu.config_reference import main, reference_markdown

    page = (REPO / "docs" / "config.md").read_text()
    assert page == reference_markdown(), "docs/config.md is behind the schemas: python -m hybridfmu.config_reference docs/config.md"
    for field in ("`fmu.source`", "`signals.<name>.channel`", "`transforms[kind=park].pole_pairs`",
                  "`maneuvers.<name>.role`", "`training.gradients`", "`hpo.searches"):
        assert field in page, field
    stale = tmp_path / "config.md"
    stale.write_text(page.replace("Master seed", "Seed"))
    assert main([str(stale), "--check"]) == 1 and "Seed" in stale.read_text()
    assert main([str(stale)]) == 0 and main([str(stale), "--check"]) == 0
