"""Does the search's objective pick the model that is best open loop over whole maneuvers?

The search ranks each configuration by its open-loop validation objective over the selected segments of
the validation maneuver, each segment started from its measured state. The evaluation runs the chosen model
over every whole validation and test maneuver from the first sample, through the rest phases between the
segments. This script runs every trained configuration of a finished search the evaluation's way (its last
rung's reported state, the calibrated FMU's initial state, the logged inputs) and prints, per configuration,
the objective, its rank, and the improvement of its whole-trajectory MAE and MSE over the FMU's baseline on
each validation and test maneuver, per target signal. The selected configuration is marked.

Needs a finished search (``results/<case>/<search>/best.json``) and the baselines of the evaluated maneuvers
(rule ``simulate_baseline``); the hybrid's search also needs ``diagnosis/diagnosed_model.pkl``.

    python benchmarks/search_selection.py [--config config/config.yaml] [--search hpo] [--top N] [--markdown FILE]

Prints one line per configuration with rate and time left, the table, and as its last line a JSON object.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from hybridfmu.case import case_roles
from hybridfmu.config import check_config_file
from hybridfmu.evaluation.evaluate import read_baseline
from hybridfmu.evaluation.metrics import improvement_factors, trajectory_errors
from hybridfmu.io import atomic_path, read_json
from hybridfmu.training.inference import load_trained_neural_fmu, physical_layer, simulate_neural_fmu
from hybridfmu.training.measured import initial_state, load_calibration, read_measured


def last_rungs(search_dir: Path) -> list[Path]:
    """Per configuration of the search, the folder of the highest rung it trained (``b<k>/r<j>/c<i>``)."""
    latest: dict[tuple[str, str], Path] = {}
    for result in sorted(search_dir.glob("b*/r*/c*/result.json")):
        folder = result.parent
        bracket, rung, config = folder.parent.parent.name, folder.parent.name, folder.name
        key = (bracket, config)
        if key not in latest or int(rung[1:]) > int(latest[key].parent.name[1:]):
            latest[key] = folder
    return sorted(latest.values())


def whole_trajectory_factors(model, roles, calibration, config, results: Path, maneuver: str,
                             hybrid: bool) -> dict[str, float | None]:
    """Improvement factors (FMU error / model error) of ``<signal>_mae`` and ``<signal>_mse`` over the whole
    ``maneuver``, open loop from its first sample as rule ``simulate_best`` runs it; empty when the model
    diverges."""
    measured = read_measured(results / "data" / f"{maneuver}.parquet", roles)
    fmu_states = read_baseline(results / "baseline" / f"{maneuver}.parquet", list(roles.state_names),
                               measured.time_s)
    x0 = initial_state(model.fmu.rhs.model, measured.x[0], roles, calibration, maneuver, config["maneuvers"])
    if hybrid:
        x0 = physical_layer(model).diagnosed.initial_state(x0, maneuver)
    try:
        states = np.asarray(simulate_neural_fmu(model, measured.time_s, measured.u, x0), dtype=float)
    except (FloatingPointError, RuntimeError):
        return {}
    if not np.all(np.isfinite(states)):
        return {}
    index = [list(roles.state_names).index(name) for name in measured.target_states]
    signals = list(measured.target_signals)
    reference = trajectory_errors(fmu_states[:, index], measured.targets, signals)
    candidate = trajectory_errors(states[:, index], measured.targets, signals)
    keys = [key for key in reference if not key.endswith("_rmse")]
    return improvement_factors({k: reference[k] for k in keys}, {k: candidate[k] for k in keys})


def markdown(rows: list[dict], maneuvers: dict[str, str], search: str, config_path: str,
             top: int | None = None) -> str:
    """The table: one row per configuration (the ``top`` best only, when given), best objective first."""
    keys = sorted({key for row in rows for values in row["factors"].values() for key in values})
    columns = [(name, key) for name in maneuvers for key in keys]
    which = "Every configuration" if top is None else f"The {top} configurations with the best objectives"
    option = "" if top is None else f" --top {top}"
    lines = [f"{which} of search `{search}` open loop over whole maneuvers, against the FMU "
             f"(`benchmarks/search_selection.py --config {config_path} --search {search}{option}`; factor = FMU "
             "error / model error, above 1 is better; ✓: the configuration the search selected):", "",
             "| configuration | objective (rank) | " + " | ".join(f"{name} {key}" for name, key in columns) + " |",
             "|---|---|" + "---|" * len(columns)]
    for row in rows:
        cells = []
        for name, key in columns:
            value = row["factors"].get(name, {}).get(key)
            cells.append("diverged" if not row["factors"].get(name) else
                         ("–" if value is None else f"×{value:.3g}"))
        mark = " ✓" if row["selected"] else ""
        lines.append(f"| {row['trial']}{mark} | {row['objective']:.4g} ({row['rank']}) | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _objective(result: dict) -> float:
    """A rung result's validation objective (inf for a failed or diverged configuration)."""
    objective = result.get("objective")
    return float("inf") if objective is None else float(objective)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="config/config.yaml")
    parser.add_argument("--search", default="hpo", help="hpo (the neural FMU) or hybrid")
    parser.add_argument("--markdown", default=None, help="also write the table to this file")
    parser.add_argument("--top", type=int, default=None,
                        help="only the N configurations with the best objectives (a large search)")
    args = parser.parse_args()
    if args.top is not None and args.top < 1:
        parser.error(f"--top: expected a positive number of configurations, got {args.top}")

    config = check_config_file(args.config)
    roles = case_roles(config)
    results = Path(config.get("results_dir", "results")) / config["case"]
    search_dir = results / args.search
    best = read_json(search_dir / "best.json")
    fmu_path = config["fmu"].get("path") or results / "fmu" / f"{config['fmu']['model_name']}.fmu"
    calibration = load_calibration(results / "calibration" / "calibration.json")
    diagnosed = results / "diagnosis" / "diagnosed_model.pkl" if args.search == "hybrid" else None
    maneuvers = {name: item["role"] for name, item in config["maneuvers"].items()
                 if item["role"] in ("validation", "test")}
    folders = last_rungs(search_dir)
    if not folders:
        raise SystemExit(f"{search_dir}: no trained configuration (b*/r*/c*/result.json); run the search first")
    if args.top is not None:
        folders = sorted(folders, key=lambda folder: _objective(read_json(folder / "result.json")))[:args.top]
    rows = []
    started = time.perf_counter()
    for done, folder in enumerate(folders, start=1):
        result = read_json(folder / "result.json")
        with tempfile.TemporaryDirectory() as scratch:  # the loader reads a best.json naming the checkpoint
            pointer = Path(scratch) / "best.json"
            pointer.write_text(json.dumps({"checkpoint": str((folder / "checkpoint.pt").resolve())}))
            model = load_trained_neural_fmu(pointer, fmu_path, dict(calibration.parameters) or None, diagnosed)
        factors = {name: whole_trajectory_factors(model, roles, calibration, config, results, name,
                                                  diagnosed is not None) for name in maneuvers}
        rows.append({"trial": result.get("trial_id", folder.as_posix()), "folder": folder.as_posix(),
                     "objective": _objective(result), "factors": factors,
                     "selected": result.get("trial_id") == best.get("trial_id")})
        elapsed = time.perf_counter() - started
        print(f"{done}/{len(folders)} {rows[-1]['trial']}: objective {rows[-1]['objective']:.4g}, "
              + ", ".join(f"{name} {key} ×{value:.3g}" for name, values in factors.items()
                          for key, value in values.items() if value is not None)
              + f" ({done / elapsed:.2f} configurations/s, {(len(folders) - done) * elapsed / done:.0f} s left)",
              flush=True)
    rows.sort(key=lambda row: row["objective"])
    for rank, row in enumerate(rows, start=1):
        row["rank"] = rank
    table = markdown(rows, maneuvers, args.search, args.config, args.top)
    print(table)
    if args.markdown:
        with atomic_path(args.markdown) as tmp:
            Path(tmp).write_text(table)
    print(json.dumps({"config": args.config, "search": args.search, "maneuvers": maneuvers,
                      "configurations": [{key: row[key] for key in ("trial", "objective", "rank", "selected",
                                                                      "factors")} for row in rows]}))


if __name__ == "__main__":
    main()
