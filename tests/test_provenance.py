"""Which code made a result: the commit of a git tree, whether it has local changes, and its short name."""

from __future__ import annotations

import subprocess

from hybridfmu import __version__
from hybridfmu.tracking.provenance import code_version, describe


def git(tree, *args):
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=tree, check=True,
                   capture_output=True)


def test_a_tree_names_its_commit_and_its_local_changes(tmp_path):
    (tmp_path / "module.py").write_text("x = 1\n")
    git(tmp_path, "init", "-q")
    git(tmp_path, "add", "module.py")
    git(tmp_path, "commit", "-qm", "first")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=tmp_path, capture_output=True, text=True).stdout.strip()
    clean = code_version(tmp_path)
    assert clean == {"version": __version__, "commit": head, "modified": False}
    assert describe(clean) == head[:10]
    (tmp_path / "module.py").write_text("x = 2\n")
    changed = code_version(tmp_path)
    assert changed["commit"] == head and changed["modified"] is True
    assert describe(changed) == head[:10] + "+modified"


def test_outside_git_only_the_version_is_known(tmp_path):
    outside = code_version(tmp_path)
    assert outside == {"version": __version__, "commit": None, "modified": None}
    assert describe(outside) == f"version {__version__}"
    assert describe(None) == describe({}) == "not recorded"
