"""Shared checks of the bad-input suite: every kind of bad input (config, log, FMU, fault) is answered by an
error that names the file and the field or channel, and leaves what was already written intact."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest


def assert_names(message: str, *parts: str) -> None:
    """Fail unless ``message`` contains every one of ``parts`` (file names, fields, channels, expectations)."""
    missing = [part for part in parts if part not in message]
    assert not missing, f"message does not name {missing}:\n{message}"


def snapshot(folder: str | Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every file under ``folder`` (what was already written)."""
    folder = Path(folder)
    return {str(path.relative_to(folder)): hashlib.sha256(path.read_bytes()).hexdigest()
            for path in sorted(folder.rglob("*")) if path.is_file()}


def assert_intact(folder: str | Path, before: dict[str, str]) -> None:
    """Fail if a file of ``before`` was changed or removed, or a temporary (half-written) file is left over."""
    after = snapshot(folder)
    changed = [name for name, digest in before.items() if after.get(name) != digest]
    assert not changed, f"files changed or lost under {folder}: {changed}"
    leftovers = [name for name in after if name not in before and Path(name).name.startswith(".")]
    assert not leftovers, f"temporary files left under {folder}: {leftovers}"


@pytest.fixture
def outputs(tmp_path: Path) -> Path:
    """A results folder holding earlier outputs (a JSON, a Parquet-like binary, a log), to check they survive."""
    folder = tmp_path / "results"
    (folder / "data").mkdir(parents=True)
    (folder / "data" / "earlier.json").write_text('{"kept": true}\n')
    (folder / "data" / "earlier.bin").write_bytes(bytes(range(256)))
    (folder / "logs").mkdir()
    (folder / "logs" / "earlier.log").write_text("an earlier run\n")
    return folder
