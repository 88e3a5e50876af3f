"""Atomic file output: nothing already written is lost or left half-written.

Every writer creates a temporary file in the destination folder and renames it over the
destination only when the content is complete (``os.replace`` is atomic on POSIX).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import secrets
from pathlib import Path
from typing import Any, Iterator


@contextlib.contextmanager
def atomic_path(destination: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``destination``; rename it over ``destination`` on success.

    On an exception the temporary file is removed and ``destination`` is untouched.
    ``suffix`` defaults to the destination's suffix (some writers choose the format by it).
    """
    destination = Path(destination)
    destination.parent.mkdir(parents=True, exist_ok=True)
    tmp_path = _create_temporary(destination, suffix if suffix is not None else destination.suffix)
    try:
        yield tmp_path
        os.replace(tmp_path, destination)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def _create_temporary(destination: Path, suffix: str) -> Path:
    """Create an empty, new file beside ``destination`` with the mode a plain ``open(path, "w")`` gives.

    ``tempfile.mkstemp`` creates its files with mode 0600 (owner only), which the rename would carry over to
    the result; here the file is created with 0666 and the process's umask applies (0644 under umask 022),
    as for any file the user writes.
    """
    for _ in range(100):
        candidate = destination.parent / f".{destination.name}.{secrets.token_hex(4)}{suffix}"
        try:
            handle = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
        except FileExistsError:
            continue
        os.close(handle)
        return candidate
    raise FileExistsError(f"{destination.parent}: no unused temporary file name for {destination.name}")


def write_json_atomic(destination: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON (NaN/inf are rejected) atomically; return the path."""
    text = json.dumps(data, indent=2, sort_keys=False, allow_nan=False, default=_json_default)
    with atomic_path(destination) as tmp:
        tmp.write_text(text + "\n")
    return Path(destination)


def write_text_atomic(destination: str | Path, text: str) -> Path:
    """Write ``text`` atomically; return the path."""
    with atomic_path(destination) as tmp:
        tmp.write_text(text)
    return Path(destination)


def write_parquet_atomic(destination: str | Path, frame: Any) -> Path:
    """Write a pandas DataFrame to Parquet atomically; return the path."""
    with atomic_path(destination) as tmp:
        frame.to_parquet(tmp, index=False)
    return Path(destination)


def file_sha256(path: str | Path) -> str:
    """SHA-256 hex digest of the file at ``path`` (read in 1 MiB blocks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_json(path: str | Path) -> Any:
    """Read a JSON file, naming the file in the error when it is missing or malformed."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file does not exist")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from None


def _json_default(value: Any) -> Any:
    """Make NumPy scalars and arrays JSON-serialisable."""
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot write {type(value).__name__} as JSON")
