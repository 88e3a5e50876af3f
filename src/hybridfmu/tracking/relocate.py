"""Make the MLflow store of a results folder point at its own artifacts again after the folder was moved or
copied: ``python -m hybridfmu.tracking.relocate <results_dir>``.

MLflow records absolute artifact locations (experiments' ``artifact_location``, runs' ``artifact_uri``,
``file:///<old results_dir>/mlartifacts/...``). This rewrites every location under an ``mlartifacts`` folder
to the same place under ``<results_dir>/mlartifacts`` of ``<results_dir>/mlflow.db``; other locations
(remote stores) are left alone. Running it again changes nothing.
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
from pathlib import Path
from urllib.parse import unquote, urlparse

ARTIFACT_FOLDER = "mlartifacts"


def _local_path(location: str) -> Path | None:
    if location.startswith("file:"):
        return Path(unquote(urlparse(location).path))
    if "://" in location:
        return None
    return Path(location)


def relocated(location: str, artifact_root: Path) -> str | None:
    """``location`` under ``artifact_root`` (same part below its ``mlartifacts`` folder), or None if it is not a
    local location under an ``mlartifacts`` folder."""
    path = _local_path(location)
    if path is None or ARTIFACT_FOLDER not in path.parts:
        return None
    index = len(path.parts) - 1 - path.parts[::-1].index(ARTIFACT_FOLDER)
    new = artifact_root.joinpath(*path.parts[index + 1:])
    return new.as_uri() if location.startswith("file:") else str(new)


def relocate_store(results_dir: str | Path) -> dict[str, int]:
    """Rewrite the artifact locations of ``<results_dir>/mlflow.db``; returns the number of changed
    experiments and runs. Raises FileNotFoundError (naming it) when there is no store."""
    results_dir = Path(results_dir).resolve()
    database = results_dir / "mlflow.db"
    if not database.is_file():
        raise FileNotFoundError(f"{database}: no MLflow store (expected the mlflow.db of a results folder)")
    root = results_dir / ARTIFACT_FOLDER
    counts = {"experiments": 0, "runs": 0}
    with sqlite3.connect(database, timeout=60) as connection:
        for table, key, column, count in (("experiments", "experiment_id", "artifact_location", "experiments"),
                                          ("runs", "run_uuid", "artifact_uri", "runs")):
            rows = connection.execute(f"SELECT {key}, {column} FROM {table}").fetchall()
            for identifier, location in rows:
                new = relocated(location or "", root)
                if new is not None and new != location:
                    connection.execute(f"UPDATE {table} SET {column} = ? WHERE {key} = ?", (new, identifier))
                    counts[count] += 1
    return counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hybridfmu.tracking.relocate", description=__doc__.splitlines()[0])
    parser.add_argument("results_dir", help="the results folder holding mlflow.db and mlartifacts/")
    args = parser.parse_args(argv)
    try:
        counts = relocate_store(args.results_dir)
    except (FileNotFoundError, sqlite3.Error) as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(f"{args.results_dir}: artifact locations of {counts['experiments']} experiment(s) and {counts['runs']} "
          f"run(s) now under {Path(args.results_dir).resolve() / ARTIFACT_FOLDER}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
