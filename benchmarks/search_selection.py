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
        [--finalists-on train validation [--finalists-top 5]]

With ``--finalists-on`` it also scores the search's finalists as rule ``score_finalists`` would with
``hpo.selection: {maneuvers: [...], top: ...}`` (open loop over those whole maneuvers against the FMU), shows
each finalist's score in the table and marks (◆) the finalist that selection would choose: the comparison of
the two ways to choose on one finished search, without rerunning it.

Prints one line per configuration with rate and time left, the table, and as its last line a JSON object.
"""

from __future__ import annotations

import argparse
import json
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

from hybridfmu.data.roles import case_roles
from hybridfmu.config import check_config_file
from hybridfmu.training.measured import read_baseline
from hybridfmu.evaluation.metrics import improvement_factors, trajectory_errors
from hybridfmu.io import atomic_path, read_json
from hybridfmu.training.finalists import finite_or_null, score_finalists
from hybridfmu.training.inference import load_trained_neural_fmu, physical_layer, simulate_neural_fmu
from hybridfmu.training.maneuver_roles import role_maneuver
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
             top: int | None = None, finalists: dict | None = None) -> str:
    """The table: one row per configuration (the ``top`` best only, when given), best objective first."""
    keys = sorted({key for row in rows for values in row["factors"].values() for key in values})
    columns = [(name, key) for name in maneuvers for key in keys]
    which = "Every configuration" if top is None else f"The {top} configurations with the best objectives"
    option = "" if top is None else f" --top {top}"
    if finalists is not None:
        option += f" --finalists-on {' '.join(finalists['roles'])} --finalists-top {finalists['top']}"
    scores = {} if finalists is None else {f["trial_id"]: f["score"] for f in finalists["finalists"]}
    score_header = "" if finalists is None else f"score over whole {' + '.join(finalists['roles'])} | "
    lines = [f"{which} of search `{search}` open loop over whole maneuvers, against the FMU "
             f"(`benchmarks/search_selection.py --config {config_path} --search {search}{option}`; factor = FMU "
             "error / model error, above 1 is better; ✓: the configuration the search selected"
             + ("" if finalists is None else
                f"; score: the finalist's error as a fraction of the FMU's over the whole {' and '.join(finalists['roles'])} "
                f"maneuvers, ◆: the finalist with the smallest, which hpo.selection would choose")
             + "):", "",
             "| configuration | objective (rank) | " + score_header
             + " | ".join(f"{name} {key}" for name, key in columns) + " |",
             "|---|---|" + ("---|" if finalists is not None else "") + "---|" * len(columns)]
    for row in rows:
        cells = []
        for name, key in columns:
            value = row["factors"].get(name, {}).get(key)
            cells.append("diverged" if not row["factors"].get(name) else
                         ("–" if value is None else f"×{value:.3g}"))
        mark = (" ✓" if row["selected"] else "") + (
            " ◆" if finalists is not None and row["trial"] == finalists["chosen"] else "")
        score = ""
        if finalists is not None:
            value = scores.get(row["trial"], "–")
            score = ("diverged" if value is None else value if isinstance(value, str) else f"{value:.3g}") + " | "
        lines.append(f"| {row['trial']}{mark} | {row['objective']:.4g} ({row['rank']}) | " + score
                     + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def score_search_finalists(config: dict, roles, results: Path, search_dir: Path, fmu_path, diagnosed,
                           on_roles: list[str], top: int) -> dict:
    """The search's finalists scored over the whole maneuvers of ``on_roles`` as rule score_finalists does:
    ``{"roles", "top", "finalists": [{"trial_id", "score", ...}], "chosen"}``."""
    training = config.get("training") or {}
    names = {role: role_maneuver(config, role, training.get(f"{role}_maneuver")) for role in on_roles}
    paths = {name: {"data": str(results / "data" / f"{name}.parquet"),
                    "baseline": str(results / "baseline" / f"{name}.parquet")} for name in names.values()}
    with tempfile.TemporaryDirectory() as scratch:
        record = score_finalists(plan_path=search_dir / "plan.json",
                                 selection_paths=sorted(str(p) for p in search_dir.glob("b*/r*/selection.json")),
                                 top=top, maneuver_paths=paths, fmu_path=fmu_path,
                                 calibration_path=results / "calibration" / "calibration.json", roles=roles,
                                 maneuvers_config=config["maneuvers"], scores_path=Path(scratch) / "finalists.json",
                                 diagnosed_path=diagnosed)
    return {**finite_or_null(record), "roles": on_roles}


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
    parser.add_argument("--finalists-on", nargs="+", choices=["train", "validation"], default=None,
                        help="also score the finalists over these whole maneuvers (roles), as hpo.selection would")
    parser.add_argument("--finalists-top", type=int, default=5, help="number of finalists (hpo.selection.top)")
    args = parser.parse_args()
    if args.top is not None and args.top < 1:
        parser.error(f"--top: expected a positive number of configurations, got {args.top}")
    if args.finalists_top < 1:
        parser.error(f"--finalists-top: expected a positive number of finalists, got {args.finalists_top}")

    logging.basicConfig(level=logging.INFO, format="%(message)s")  # the finalists' progress lines
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
    finalists = None
    if args.finalists_on:
        finalists = score_search_finalists(config, roles, results, search_dir, fmu_path, diagnosed,
                                           args.finalists_on, args.finalists_top)
    table = markdown(rows, maneuvers, args.search, args.config, args.top, finalists)
    print(table)
    if args.markdown:
        with atomic_path(args.markdown) as tmp:
            Path(tmp).write_text(table)
    print(json.dumps({"config": args.config, "search": args.search, "maneuvers": maneuvers, "finalists": finalists,
                      "configurations": [{key: row[key] for key in ("trial", "objective", "rank", "selected",
                                                                      "factors")} for row in rows]}))


if __name__ == "__main__":
    main()
