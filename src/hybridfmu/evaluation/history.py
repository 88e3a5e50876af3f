"""The per-trial histories of the hyperparameter search, as the training writes them.

Each training job writes ``<hpo_dir>/b<bracket>/r<rung>/c<config>/result.json`` with the trial id,
the resource trained so far (``resource_s``, seconds of training data), the validation ``objective``
at the rung's end, ``status``, and ``curve``: the training loss against the resource over every
rung so far (rows ``[resource_s, loss]``, loss null where it was not finite). Results left from an
earlier search (another plan) are recognised by their configuration ``hash`` against
``<hpo_dir>/plan.json`` and skipped.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybridfmu.io import read_json

LOG = logging.getLogger(__name__)


@dataclass
class TrialHistory:
    """One configuration of the search.

    Attributes:
        trial_id, bracket, config: identity (``b<bracket>c<config>``).
        hyperparameters: its sampled hyperparameters.
        rungs: per rung reached, ``{"rung", "resource_s", "objective" (None if failed), "status"}``, by rung.
        curve: training loss (K, 2) rows [resource_s, loss] up to its last rung (NaN where not finite).
    """

    trial_id: str
    bracket: int
    config: int
    hyperparameters: dict
    rungs: list[dict] = field(default_factory=list)
    curve: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))

    @property
    def status(self) -> str:
        return self.rungs[-1]["status"] if self.rungs else "missing"


@dataclass
class SearchHistory:
    """Every trial of a search and the best one (``best_trial_id`` from ``best.json``)."""

    trials: list[TrialHistory]
    best_trial_id: str | None

    @property
    def brackets(self) -> list[int]:
        return sorted({trial.bracket for trial in self.trials})


def read_histories(hpo_dir: str | Path, best_path: str | Path | None = None) -> SearchHistory:
    """Collect the trials from the ``result.json`` files under ``hpo_dir``.

    Raises:
        FileNotFoundError: no result file under ``hpo_dir``.
        ValueError: a result file lacks a field (names the file and the field).
    """
    hpo_dir = Path(hpo_dir)
    paths = sorted(hpo_dir.glob("b*/r*/c*/result.json"))
    if not paths:
        raise FileNotFoundError(f"{hpo_dir}: no trial results (b<bracket>/r<rung>/c<config>/result.json)")
    plan_hashes = _plan_hashes(hpo_dir / "plan.json")
    trials: dict[str, TrialHistory] = {}
    last_rung: dict[str, int] = {}
    stale = 0
    for path in paths:
        record = read_json(path)
        for key in ("trial_id", "bracket", "config", "rung", "resource_s", "objective", "status", "curve"):
            if key not in record:
                raise ValueError(f"{path}: field {key!r} missing (expected a trial result of the search)")
        if plan_hashes is not None and plan_hashes.get((int(record["bracket"]), int(record["config"]))) != \
                record.get("hash"):
            stale += 1
            continue
        trial = trials.setdefault(record["trial_id"], TrialHistory(
            record["trial_id"], int(record["bracket"]), int(record["config"]), record.get("hyperparameters", {})))
        trial.rungs.append({"rung": int(record["rung"]), "resource_s": float(record["resource_s"]),
                            "objective": record["objective"], "status": record["status"]})
        if int(record["rung"]) >= last_rung.get(trial.trial_id, -1):
            last_rung[trial.trial_id] = int(record["rung"])
            trial.curve = np.array([[row[0], np.nan if row[1] is None else row[1]] for row in record["curve"]],
                                   dtype=float).reshape(-1, 2)
    if stale:
        LOG.warning("%s: skipped %d result file(s) of an earlier search (configuration not in plan.json)", hpo_dir,
                    stale)
    if not trials:
        raise FileNotFoundError(f"{hpo_dir}: no trial result of the current search (plan.json)")
    for trial in trials.values():
        trial.rungs.sort(key=lambda item: item["rung"])
    best_trial_id = read_json(best_path).get("trial_id") if best_path else None
    ordered = sorted(trials.values(), key=lambda t: (t.bracket, t.config))
    return SearchHistory(ordered, best_trial_id)


def _plan_hashes(plan_path: Path) -> dict[tuple[int, int], str] | None:
    """(bracket, config) -> configuration hash of the search plan, or None without a plan."""
    if not plan_path.is_file():
        return None
    plan = read_json(plan_path)
    try:
        return {(int(bracket["bracket"]), int(item["config"])): item["hash"]
                for bracket in plan["brackets"] for item in bracket["configs"]}
    except (KeyError, TypeError) as err:
        raise ValueError(f"{plan_path}: field {err} missing (expected the search plan)") from None
