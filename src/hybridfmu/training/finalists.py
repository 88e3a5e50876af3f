"""The search's final choice over whole maneuvers (config ``hpo.selection``, rule ``score_finalists``).

Hyperband ranks configurations by the validation objective: the open loop over the selected segments of the
validation maneuver, each segment started from its measured state. What a user wants from the chosen model is
the evaluation's open loop: every whole maneuver from its first sample, through the rest phases between the
segments, where a model must stay in step on its own. With ``hpo.selection.maneuvers`` the search's finalists
(the ``top`` configurations of the brackets' last rungs with the best objectives) are each run that way over
the named maneuvers (train and validation only; the test maneuver stays unseen), and the one whose error is
the smallest fraction of the FMU's is chosen:

- per maneuver, the **error ratio** is the objective's weighted mean over the target states of model error /
  FMU error (the objective's loss kind, MAE or MSE, on the whole trajectory);
- the **score** is the geometric mean of the maneuvers' ratios (below 1: better than the FMU on average);
- a finalist that diverges or leaves the finite range scores infinity.

A hybrid's search scores one more candidate the same way: its **physical layer** (the FMU plus the diagnosed
effects under the untrained ANN, whose output is exactly zero, with its delays fixed at zero: the model "FMU +
diagnosed effects" itself, simulated as that model, :func:`without_delays`). A trained
configuration may replace it only if it is no worse than the physical layer on **every** maneuver of the choice in
**every** target state (its error ratio against the FMU at most the layer's), and then only with a smaller score.
When none qualifies, the physical layer is chosen: the hybrid is then its own physics, and the report says so. The
chosen hybrid is therefore never worse than its physical layer on any whole maneuver the choice sees, in any target
(:func:`worse_than`).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from hybridfmu.io import read_json, write_json_atomic
from hybridfmu.training.candidates import PHYSICAL_LAYER_ID, candidate_names
from hybridfmu.training.hyperband import rank_results
from hybridfmu.training.losses import Objective

LOG = logging.getLogger(__name__)


def last_rung_results(selection_paths: Sequence[str | Path]) -> list[dict[str, Any]]:
    """The results of every bracket's last rung (the candidates of the final choice), each with its
    ``result_path``, ranked best objective first (:func:`hybridfmu.training.hyperband.rank_results`)."""
    finals = []
    for path in selection_paths:
        selection = read_json(path)
        if not selection.get("last_rung"):
            continue
        for item in selection["ranking"]:
            finals.append({**read_json(item["result"]), "result_path": item["result"]})
    return rank_results(finals)


def finalist_results(selection_paths: Sequence[str | Path], top: int) -> list[dict[str, Any]]:
    """The ``top`` successful last-rung results with the best finite objectives, best first."""
    ranked = [r for r in last_rung_results(selection_paths)
              if r.get("status") == "ok" and isinstance(r.get("objective"), (int, float))
              and math.isfinite(float(r["objective"]))]
    return ranked[:top]


def target_errors(simulated: np.ndarray, measured: np.ndarray, loss: str) -> np.ndarray:
    """(n_t,) MAE or MSE per target column of two (T, n_t) trajectories (model units)."""
    difference = np.asarray(simulated, dtype=float) - np.asarray(measured, dtype=float)
    if loss == "MSE":
        return np.mean(difference ** 2, axis=0)
    return np.mean(np.abs(difference), axis=0)


def error_ratio(model_targets: np.ndarray, fmu_targets: np.ndarray, measured_targets: np.ndarray,
                target_states: Sequence[str], objective: Objective) -> tuple[float, dict[str, float]]:
    """The model's error as a fraction of the FMU's on one whole maneuver.

    Args:
        model_targets, fmu_targets, measured_targets: (T, n_t) target states (model units).
        target_states: (n_t,) their names; objective: loss kind and one weight per target state.

    Returns:
        (the objective's weighted mean of the per-target ratios, {state: model error / FMU error}); a target
        the FMU reproduces exactly has ratio 1 when the model does too, else infinity. Infinity when the
        model's trajectory is not finite.
    """
    if not np.all(np.isfinite(model_targets)):
        return math.inf, {name: math.inf for name in target_states}
    model_errors = target_errors(model_targets, measured_targets, objective.loss)
    fmu_errors = target_errors(fmu_targets, measured_targets, objective.loss)
    ratios = {}
    for name, model_error, fmu_error in zip(target_states, model_errors, fmu_errors):
        if fmu_error > 0.0:
            ratios[name] = float(model_error / fmu_error)
        else:
            ratios[name] = 1.0 if model_error == 0.0 else math.inf
    total_weight = sum(objective.weights[name] for name in target_states)
    weighted = sum(objective.weights[name] * ratios[name] for name in target_states) / total_weight
    return float(weighted), ratios


def geometric_mean(values: Sequence[float]) -> float:
    """Geometric mean of positive values; infinity when any is infinite, 0 when any is 0."""
    values = [float(v) for v in values]
    if not values:
        raise ValueError("geometric_mean: no values")
    if any(math.isinf(v) or math.isnan(v) for v in values):
        return math.inf
    if any(v <= 0.0 for v in values):
        return 0.0
    return float(math.exp(sum(math.log(v) for v in values) / len(values)))


def finite_or_null(value: Any) -> Any:
    """``value`` with every non-finite float (a diverged finalist's ratio or score) as None, for JSON."""
    if isinstance(value, dict):
        return {key: finite_or_null(item) for key, item in value.items()}
    if isinstance(value, list):
        return [finite_or_null(item) for item in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def choose_finalist(scored: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The finalist with the smallest finite ``score``; None when every finalist diverged. A score of None (read back
    from JSON) counts as diverged. Ties: a hybrid's physical layer first (a trained configuration replaces it only
    with a smaller score: one that scores the same on every maneuver has not learned anything these maneuvers show,
    typically its best checkpoint is its untrained state, and the hybrid is then reported as its physical layer), then
    the better objective."""
    finite = [entry for entry in scored if entry["score"] is not None and math.isfinite(float(entry["score"]))]
    if not finite:
        return None
    return min(finite, key=lambda entry: (float(entry["score"]), entry.get("trial_id") != PHYSICAL_LAYER_ID,
                                          math.inf if entry.get("objective") is None else float(entry["objective"])))


def worse_than(entry: dict[str, Any], reference: dict[str, Any]) -> list[str]:
    """Where a scored candidate is worse than ``reference`` (a hybrid's physical layer): ``"<maneuver>: <state>"`` for
    every maneuver and target state whose error ratio against the FMU exceeds the reference's. A ratio that is None or
    not finite (diverged) is worse than any finite one; where the reference diverged nothing is worse. Entries as
    :func:`score_model` writes them (``maneuvers.<name>.ratios.<state>``)."""
    def ratio(value: Any) -> float:
        return math.inf if value is None or not math.isfinite(float(value)) else float(value)

    worse = []
    for name, item in reference.get("maneuvers", {}).items():
        mine = ((entry.get("maneuvers") or {}).get(name) or {}).get("ratios") or {}
        for state, value in (item.get("ratios") or {}).items():
            if ratio(mine.get(state)) > ratio(value):
                worse.append(f"{name}: {state}")
    return worse


def score_model(model: Any, maneuvers: dict[str, tuple[Any, np.ndarray]], roles: Any, calibration: Any,
                maneuvers_config: dict[str, Any] | None, objective: Objective, label: str,
                progress: Any = None) -> dict[str, Any]:
    """One candidate open loop over every whole maneuver against the FMU.

    Args:
        model: a trained (or untrained) neural FMU or hybrid.
        maneuvers: name -> (:class:`hybridfmu.training.measured.MeasuredManeuver`, the FMU's (T, n_x) baseline).
        roles, calibration, maneuvers_config: the case roles, its calibration and config ``maneuvers``.
        objective: loss kind and target weights; label: the candidate's name in the log.

    Returns:
        ``{"maneuvers": {name: {"ratio", "ratios"}}, "score"}`` (:func:`error_ratio`, :func:`geometric_mean`).
    """
    from hybridfmu.training.inference import physical_layer, simulate_neural_fmu
    from hybridfmu.training.measured import initial_state

    state_names = list(roles.state_names)
    out: dict[str, Any] = {"maneuvers": {}}
    for name, (measured, fmu_states) in maneuvers.items():
        index = [state_names.index(state) for state in measured.target_states]
        x0 = initial_state(model.fmu.rhs.model, measured.x[0], roles, calibration, name, maneuvers_config)
        layer = physical_layer(model)
        if layer is not None:
            x0 = layer.diagnosed.initial_state(x0, name)  # the physical layer's start, as the evaluation
        try:
            states = np.asarray(simulate_neural_fmu(model, measured.time_s, measured.u, x0), dtype=float)
        except (FloatingPointError, RuntimeError) as err:
            LOG.warning("candidate %s diverged on %s: %s", label, name, err)
            states = np.full((measured.time_s.size, len(state_names)), np.nan)
        ratio, ratios = error_ratio(states[:, index], fmu_states[:, index], measured.targets,
                                    measured.target_states, objective)
        out["maneuvers"][name] = {"ratio": ratio, "ratios": ratios}
        if progress is not None:
            progress.update(float(measured.time_s[-1] - measured.time_s[0]))
    out["score"] = geometric_mean([m["ratio"] for m in out["maneuvers"].values()])
    return out


def without_delays(section: dict[str, Any]) -> dict[str, Any]:
    """A copy of a search plan or a ``model`` section whose input delays are fixed at zero: the plan without its
    delays' start and bounds (``initial_delays_s``, ``delay_bounds_s``), the section's ``input_delay`` with
    ``min_s = max_s = init_s = 0`` and no ``within_standard_errors``."""
    copy = {key: value for key, value in section.items() if key not in ("initial_delays_s", "delay_bounds_s")}
    if "input_delay" in copy:
        delay = {key: value for key, value in (copy["input_delay"] or {}).items() if key != "within_standard_errors"}
        copy["input_delay"] = {**delay, "min_s": 0.0, "max_s": 0.0, "init_s": 0.0}
    return copy


def write_physical_layer_checkpoint(*, plan_path: str | Path, train_arrays_path: str | Path,
                                    validation_arrays_path: str | Path, statistics_path: str | Path,
                                    fmu_path: str | Path, calibration_path: str | Path | None,
                                    model_config: dict[str, Any], diagnosed_path: str | Path,
                                    checkpoint_path: str | Path) -> Path:
    """Rule ``physical_layer_checkpoint``: a hybrid search's physical layer as a candidate of the final choice.

    The untrained hybrid of the search's first configuration (its ANN's output exactly zero, FMU gates at 1,
    effect coefficients at their start) with its input delays fixed at zero: the FMU plus the diagnosed effects
    (their time offsets included) and nothing else, the model "FMU + diagnosed effects" itself. Saved as a trial
    checkpoint (``bracket``, ``rung`` and ``config`` None) that :func:`score_finalists` scores like the trained
    finalists, so a trained hybrid is chosen only where it beats that model on the whole maneuvers.

    Raises:
        ValueError: the untrained model is not its physical layer (``model.ann_output_init`` is not zero).
    """
    import torch

    from hybridfmu.io import atomic_path
    from hybridfmu.training.physical_layer_rollout import untrained_is_physical_layer
    from hybridfmu.io import file_sha256
    from hybridfmu.training.checkpoint import CHECKPOINT_FORMAT
    from hybridfmu.training.trial import first_configuration, trial_model

    plan = read_json(plan_path)
    entry = first_configuration(plan)
    _, _, statistics, model = trial_model(without_delays(plan), entry, without_delays(model_config),
                                          train_arrays_path, validation_arrays_path, statistics_path, fmu_path,
                                          calibration_path, diagnosed_path)
    if not untrained_is_physical_layer(model):
        raise ValueError("config.model.ann_output_init: the untrained hybrid is not its physical layer (its ANN's "
                         "output is not zero), so the physical layer cannot be a candidate of the final choice; set "
                         "ann_output_init: zero")
    fmu = {"path": str(fmu_path), "sha256": file_sha256(fmu_path),
           "calibration": str(calibration_path) if calibration_path else None}
    with atomic_path(checkpoint_path) as tmp:
        torch.save({"format": CHECKPOINT_FORMAT, "status": "ok", "reason": "the physical layer (ANN at zero)",
                    "bracket": None, "rung": None, "config": None, "hash": entry["hash"],
                    "spec": model.spec.to_dict(), "statistics": statistics,
                    "hyperparameters": entry["hyperparameters"], "trainer": None, "model": model.state_dict(),
                    "best": None, "validations": [], "fmu": fmu, "mlflow_run_id": None}, tmp)
    LOG.info("physical layer of search %s (delays %s) saved to %s", plan["search_id"], model.delay_s(),
             checkpoint_path)
    return Path(checkpoint_path)


def physical_layer_entry(checkpoint_path: str | Path, model: Any) -> dict[str, Any]:
    """The finalist entry of a physical layer (:func:`write_physical_layer_checkpoint`) loaded as ``model``: the
    fields a best.json needs (``trial_id`` :data:`PHYSICAL_LAYER_ID`, ``checkpoint``, ``hyperparameters``,
    ``delay_s``, ``gates``, ``fmu`` ...), without scores."""
    from hybridfmu.training.checkpoint import load_checkpoint

    checkpoint = load_checkpoint(checkpoint_path)
    return {"trial_id": PHYSICAL_LAYER_ID, "bracket": None, "config": None, "rung": None, "objective": None,
            "checkpoint": str(checkpoint_path), "hyperparameters": checkpoint["hyperparameters"],
            "delay_s": model.delay_s(), "gates": model.gate_values(), "fmu": checkpoint["fmu"], "validation": None,
            "resource_s": 0.0, "status": "ok", "mlflow_run_id": None}


def _scoring_inputs(plan_path: str | Path, maneuver_paths: dict[str, dict[str, str]],
                    calibration_path: str | Path | None, roles: Any) -> tuple[dict[str, Any], Objective, Any,
                                                                              dict[str, tuple[Any, np.ndarray]]]:
    """The plan, its objective, the calibration and name -> (measured maneuver, the FMU's baseline states)."""
    from hybridfmu.training.measured import read_baseline
    from hybridfmu.training.losses import objective_from_config
    from hybridfmu.training.measured import load_calibration, read_measured

    if not maneuver_paths:
        raise ValueError("config.hpo.selection.maneuvers: no maneuver to score the finalists on")
    plan = read_json(plan_path)
    objective = objective_from_config(plan["objective"], roles)
    calibration = load_calibration(calibration_path)
    state_names = list(roles.state_names)
    maneuvers: dict[str, tuple[Any, np.ndarray]] = {}
    for name, paths in maneuver_paths.items():
        measured = read_measured(paths["data"], roles)
        maneuvers[name] = (measured, read_baseline(paths["baseline"], state_names, measured.time_s))
    return plan, objective, calibration, maneuvers


def score_candidate(*, candidate: str, plan_path: str | Path, selection_paths: Sequence[str | Path], top: int,
                    maneuver_paths: dict[str, dict[str, str]], fmu_path: str | Path,
                    calibration_path: str | Path | None, roles: Any, maneuvers_config: dict[str, Any] | None,
                    score_path: str | Path, diagnosed_path: str | Path | None = None,
                    physical_layer_path: str | Path | None = None) -> dict[str, Any]:
    """Rule ``score_finalist``: one candidate of a search's final choice open loop over every whole maneuver.

    Args:
        candidate: ``rank<k>`` (the finalist with the k-th best objective,
            :func:`hybridfmu.training.candidates.finalist_candidate`) or :data:`PHYSICAL_LAYER_ID` (a hybrid's
            physical layer, ``physical_layer_path``).
        plan_path, selection_paths, top, maneuver_paths, fmu_path, calibration_path, roles, maneuvers_config,
        diagnosed_path, physical_layer_path: as for :func:`score_finalists`.
        score_path: output JSON.

    Writes ``score_path``: the candidate's entry of ``finalists.json`` (:func:`score_finalists`), or
    ``{"candidate", "absent": true}`` when fewer than ``k`` configurations finished with a finite objective.
    Returns it.
    """
    from hybridfmu.progress import Progress
    from hybridfmu.training.inference import load_checkpoint_model

    if top < 1:
        raise ValueError(f"config.hpo.selection.top: expected at least 1 finalist, got {top}")
    if candidate not in candidate_names(top, physical_layer_path is not None):
        raise ValueError(f"score_finalist: unknown candidate {candidate!r}; expected one of "
                         f"{candidate_names(top, physical_layer_path is not None)}")
    plan, objective, calibration, maneuvers = _scoring_inputs(plan_path, maneuver_paths, calibration_path, roles)
    parameters = dict(calibration.parameters) or None
    if candidate == PHYSICAL_LAYER_ID:
        if diagnosed_path is None:
            raise ValueError("score_finalists: the physical layer of a hybrid needs its diagnosed model")
        model = load_checkpoint_model(physical_layer_path, fmu_path, parameters, diagnosed_path)
        entry = {**physical_layer_entry(physical_layer_path, model), "objective_rank": None}
    else:
        rank = int(candidate[len("rank"):])
        finalists = finalist_results(selection_paths, top)
        if rank > len(finalists):
            LOG.info("no finalist of rank %d: %d configuration(s) finished with a finite objective", rank,
                     len(finalists))
            write_json_atomic(score_path, {"candidate": candidate, "absent": True})
            return {"candidate": candidate, "absent": True}
        result = finalists[rank - 1]
        model = load_checkpoint_model(result["checkpoint"], fmu_path, parameters, diagnosed_path)
        entry = {key: result.get(key) for key in ("trial_id", "bracket", "config", "rung", "objective", "checkpoint")}
        entry["objective_rank"] = rank
    simulated_s = sum(float(m.time_s[-1] - m.time_s[0]) for m, _ in maneuvers.values())
    progress = Progress(simulated_s, f"candidate {candidate} of search {plan['search_id']}", "simulated s", LOG)
    entry.update(score_model(model, maneuvers, roles, calibration, maneuvers_config, objective,
                             entry["trial_id"], progress))
    progress.finish()
    what = "physical layer (the FMU + effects, ANN at zero)" if candidate == PHYSICAL_LAYER_ID else \
        f"finalist {entry['trial_id']} (objective {entry['objective']:.4g}, rank {entry['objective_rank']})"
    LOG.info("%s: score %.4g (%s)", what, entry["score"],
             ", ".join(f"{name} {m['ratio']:.4g}" for name, m in entry["maneuvers"].items()))
    entry = {"candidate": candidate, **entry}
    write_json_atomic(score_path, finite_or_null(entry))
    return finite_or_null(entry)


def choose_among_candidates(*, candidate_paths: Sequence[str | Path], maneuvers: Sequence[str], top: int,
                            plan_path: str | Path, roles: Any, scores_path: str | Path) -> dict[str, Any]:
    """Rule ``score_finalists``: the final choice among the scored candidates (:func:`score_candidate`).

    Writes ``scores_path`` (``finalists.json``, layout in :func:`score_finalists`) and returns it.
    """
    from hybridfmu.training.losses import objective_from_config

    objective = objective_from_config(read_json(plan_path)["objective"], roles)
    scored, layer_entry = [], None
    for path in candidate_paths:
        entry = read_json(path)
        if entry.get("absent"):
            continue
        entry = {key: value for key, value in entry.items() if key != "candidate"}
        scored.append(entry)
        if entry["trial_id"] == PHYSICAL_LAYER_ID:
            layer_entry = entry
    worse_on = {} if layer_entry is None else \
        {entry["trial_id"]: worse_than(entry, layer_entry) for entry in scored if entry is not layer_entry}
    admissible = [entry for entry in scored if not worse_on.get(entry["trial_id"])]
    chosen = choose_finalist(admissible)
    record = {"maneuvers": list(maneuvers), "top": top, "objective": objective.to_dict(),
              "finalists": scored, "chosen": None if chosen is None else chosen["trial_id"]}
    if layer_entry is not None:
        record["physical_layer"] = {"score": layer_entry["score"],
                                    "beaten_by": [entry["trial_id"] for entry in admissible if entry is not layer_entry
                                                  and entry["score"] is not None and layer_entry["score"] is not None
                                                  and float(entry["score"]) < float(layer_entry["score"])],
                                    "worse_on": {trial: where for trial, where in worse_on.items() if where}}
        for trial, where in worse_on.items():
            if where:
                LOG.info("finalist %s is worse than the physical layer on %s: it cannot be chosen", trial,
                         ", ".join(where))
        if chosen is layer_entry:
            LOG.warning("no trained configuration is better than the physical layer over the whole maneuvers %s "
                        "without being worse on one of them: the hybrid is its physical layer (the FMU + effects, "
                        "ANN at zero)", list(maneuvers))
    write_json_atomic(scores_path, finite_or_null(record))
    if chosen is None:
        LOG.warning("every finalist diverged over the whole maneuvers; the search falls back to the objective")
    else:
        LOG.info("chosen over whole maneuvers %s: %s (score %.4g, objective rank %s)", list(maneuvers),
                 chosen["trial_id"], chosen["score"], chosen["objective_rank"])
    return record


def score_finalists(*, plan_path: str | Path, selection_paths: Sequence[str | Path], top: int,
                    maneuver_paths: dict[str, dict[str, str]], fmu_path: str | Path,
                    calibration_path: str | Path | None, roles: Any, maneuvers_config: dict[str, Any] | None,
                    scores_path: str | Path, diagnosed_path: str | Path | None = None,
                    physical_layer_path: str | Path | None = None) -> dict[str, Any]:
    """Run each finalist open loop over every whole maneuver and score it against the FMU, in one process (the
    workflow runs :func:`score_candidate` once per candidate in parallel, then :func:`choose_among_candidates`).

    Args:
        plan_path: the search plan (its ``objective``); selection_paths: the rungs' selections (the last
            rungs' name the candidates); top: how many finalists.
        maneuver_paths: maneuver name -> ``{"data": ingested Parquet, "baseline": the FMU's baseline Parquet}``.
        fmu_path, calibration_path: the FMU and its calibration (None: as configured).
        roles: :class:`hybridfmu.data.roles.CaseRoles`; maneuvers_config: config ``maneuvers`` (initial states).
        scores_path: output JSON; the candidates' own files go to ``finalists/<candidate>.json`` beside it.
        diagnosed_path: the diagnosed model under a hybrid's ANN (search "hybrid"), else None.
        physical_layer_path: for a hybrid's search, its physical layer's checkpoint
            (:func:`write_physical_layer_checkpoint`): scored too, and chosen unless a finalist beats it without
            being worse on any maneuver; None: the finalists alone.

    Writes ``scores_path``: ``{"maneuvers", "top", "objective", "finalists": [{"trial_id", "bracket",
    "config", "rung", "objective", "objective_rank", "checkpoint", "maneuvers": {name: {"ratio",
    "ratios"}}, "score"}], "chosen"}`` (a diverged finalist's ratios and score are null; ``chosen``: a trial
    id, or None when every finalist diverged); with ``physical_layer_path`` the physical layer is the last finalist
    (trial id :data:`PHYSICAL_LAYER_ID`, with what a best.json needs of it) and ``physical_layer`` holds its
    ``score``, the finalists that beat it (``beaten_by``: a smaller score and worse on no maneuver) and where the
    others are worse than it (``worse_on``: trial id -> ``"<maneuver>: <state>"``; :func:`worse_than`).
    Returns it.
    """
    folder = Path(scores_path).parent / "finalists"
    paths = []
    for candidate in candidate_names(top, physical_layer_path is not None):
        path = folder / f"{candidate}.json"
        score_candidate(candidate=candidate, plan_path=plan_path, selection_paths=selection_paths, top=top,
                        maneuver_paths=maneuver_paths, fmu_path=fmu_path, calibration_path=calibration_path,
                        roles=roles, maneuvers_config=maneuvers_config, score_path=path,
                        diagnosed_path=diagnosed_path, physical_layer_path=physical_layer_path)
        paths.append(path)
    return choose_among_candidates(candidate_paths=paths, maneuvers=list(maneuver_paths), top=top,
                                   plan_path=plan_path, roles=roles, scores_path=scores_path)
