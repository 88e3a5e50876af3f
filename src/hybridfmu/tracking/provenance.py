"""Which code produced a result: the package's version and the git commit of its source tree.

A record that a later step aggregates (a diagnosis that the withheld suite scores, say) carries
:func:`code_version`, so that a summary over many records can say which code made them, and warn when a resumed
run mixes the records of two versions.
"""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

#: the package's source tree (``src/hybridfmu``): its commit and local changes are what a record was made with
PACKAGE_DIR = Path(__file__).resolve().parents[1]


def _git(args: list[str], directory: str | Path | None) -> str | None:
    """The stripped output of ``git <args>`` in ``directory``, or None when git or the repository is missing."""
    try:
        out = subprocess.run(["git", *args], cwd=directory, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def git_commit(directory: str | Path | None = None) -> str | None:
    """The current git commit of ``directory`` (default: the working directory), or None."""
    return _git(["rev-parse", "HEAD"], directory) or None


def code_version(directory: str | Path | None = None) -> dict[str, Any]:
    """The code a result is made with: ``version`` (the package's), ``commit`` (of the git checkout that holds
    ``directory``, default the package's source tree; None for an installed copy without git) and ``modified``
    (True when that tree has uncommitted changes, so the commit alone does not describe the code; None without git).
    """
    from hybridfmu import __version__

    directory = PACKAGE_DIR if directory is None else Path(directory)
    commit = git_commit(directory)
    status = _git(["status", "--porcelain", "--untracked-files=no", "--", "."], directory) if commit else None
    return {"version": __version__, "commit": commit, "modified": None if status is None else bool(status)}


def describe(version: dict[str, Any] | None) -> str:
    """A short name of a :func:`code_version`: the commit's first 10 characters (``+modified`` with local changes),
    ``version <v>`` without a commit, ``not recorded`` for None or a record without either."""
    if not version or not (version.get("commit") or version.get("version")):
        return "not recorded"
    if not version.get("commit"):
        return f"version {version['version']}"
    return str(version["commit"])[:10] + ("+modified" if version.get("modified") else "")
