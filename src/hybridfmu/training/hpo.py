"""The search's workflow steps (one function per Snakemake rule; the per-trial job is ``trial.run_trial_rung``):
prepare the training data, plan the search, select the survivors of a rung, pick the best configuration."""

from __future__ import annotations

import hashlib
import json
import logging
import shutil
from pathlib import Path
from typing import Any

from hybridfmu.model.delay import describe_delays
from hybridfmu.model.settings import DELAY_BOUND_SAMPLES, input_delay_settings
from hybridfmu.io import atomic_path, read_json, write_json_atomic
from hybridfmu.training.data import build_maneuver_arrays
from hybridfmu.training.candidates import PHYSICAL_LAYER_ID
from hybridfmu.training.hyperband import rank_results, select_survivors
from hybridfmu.training.plan import search_plan
from hybridfmu.training.search_defaults import chosen_search_settings
from hybridfmu.training.statistics import data_statistics

LOG = logging.getLogger(__name__)

#: Fields of each trial (one per configuration and rung) in the search summary.
TRIAL_SUMMARY_KEYS = ("trial_id", "bracket", "rung", "config", "hash", "status", "reason", "objective", "validation",
                      "resource_s", "steps", "skipped_steps", "delay_s", "gates", "hyperparameters", "curve",
                      "mlflow_run_id", "wall_time_s")


def prepare_training_data(*, fmu_path: str | Path, calibration_path: str | Path | None, roles: Any,
                          maneuvers: dict[str, str], maneuvers_config: dict[str, Any] | None,
                          data_paths: dict[str, str], segments_paths: dict[str, str],
                          baseline_paths: dict[str, str | None], array_paths: dict[str, str],
                          statistics_path: str | Path) -> dict[str, Any]:
    """Arrays of the train and validation maneuvers, and the training data statistics.

    Args:
        fmu_path, calibration_path: the FMU and its calibration (parameters, unmeasured initial states);
            None = the FMU as configured.
        roles: :class:`hybridfmu.data.roles.CaseRoles` of the case.
        maneuvers: role ("train", "validation") -> maneuver name; the other dicts are keyed by role.
        maneuvers_config: config ``maneuvers`` (``initial_states_from`` of the calibration).
        baseline_paths: the FMU baseline per role, used only for states that are not measured (may be None
            or missing, then the FMU is simulated here).
    """
    from hybridfmu.training.measured import load_calibrated_fmu, load_calibration

    calibration = load_calibration(calibration_path)
    fmu_model = load_calibrated_fmu(fmu_path, calibration)
    arrays = {}
    for role, name in maneuvers.items():
        arrays[role] = build_maneuver_arrays(name, data_paths[role], segments_paths[role], fmu_model, roles,
                                             calibration, maneuvers_config, baseline_paths.get(role))
        kept = int((arrays[role].spans[:, 1] - arrays[role].spans[:, 0]).sum())
        LOG.info("%s (%s): %d samples, %d segments with %d samples (%.3g s)", name, role, arrays[role].time_s.size,
                 len(arrays[role].spans), kept, kept * arrays[role].sample_period_s)
    statistics = data_statistics(arrays["train"], fmu_model)
    for role, array in arrays.items():
        array.save(array_paths[role])
    write_json_atomic(statistics_path, statistics)
    return statistics


def check_target_weights(hpo_config: dict[str, Any], roles: Any) -> None:
    """Every ``w_<state>`` of the search space and the objective names a target state of the case.

    Raises:
        ValueError: naming the config field and the case's target states.
    """
    targets = list(roles.target_states)
    for where, names in (("config.hpo.search_space", hpo_config.get("search_space", {})),
                         ("config.hpo.objective", hpo_config.get("objective", {}))):
        for name in names:
            if name.startswith("w_") and name[2:] not in targets:
                raise ValueError(f"{where}.{name}: {name[2:]!r} is not a target state; expected w_<state> for one "
                                 f"of config.roles.targets {targets}")


def search_id(case: str, seed: int, sections: dict[str, Any]) -> str:
    """Stable id of a search: hash of the case, the master seed and the sections that define it."""
    text = json.dumps({"case": case, "seed": seed, **sections}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def plan_search(*, case: str, seed: int, hpo_config: dict[str, Any], training_config: dict[str, Any],
                model_config: dict[str, Any], plan_path: str | Path, tracking_uri: str | None,
                experiment: str | None, roles: Any = None, time_offset_path: str | Path | None = None,
                sample_period_s: float | None = None, training_data_s: float | None = None) -> dict[str, Any]:
    """Write the search plan (brackets, rungs, sampled configurations) and create the MLflow parent run
    (skipped when ``tracking_uri`` is None). With ``roles`` the target weights ``w_<state>`` of the search
    space and the objective are checked against the case's target states.

    When ``model.input_delay.init_s`` is ``time_offset``, the plan's ``initial_delays_s`` ({group: s}) are
    the time-offset stage's estimates (``time_offset_path``, rule ``time_offset``), the start of every
    configuration's delays; with ``input_delay.within_standard_errors`` its ``delay_bounds_s`` ({group:
    [low, high]}) hold each identified group's delay within that many standard errors of its estimate;
    ``sample_period_s`` (the grid's step) sizes the delays' range and the windows, ``training_data_s`` (the selected
    training data, s) the budget, where the config leaves them out (:mod:`hybridfmu.training.search_defaults`; the
    plan's ``chosen_from_data`` says how)."""
    hpo_config, chosen = chosen_search_settings(hpo_config, sample_period_s, training_data_s)
    delay_config = model_config.get("input_delay") or {}
    if sample_period_s is not None and any(delay_config.get(key) is None for key in ("min_s", "max_s", "scale_s")):
        resolved = input_delay_settings(delay_config, sample_period_s)
        chosen.append(f"model.input_delay: within {resolved['min_s'] * 1e3:.4g} … {resolved['max_s'] * 1e3:.4g} ms "
                      f"(±{DELAY_BOUND_SAMPLES} samples of the grid), scale_s {resolved['scale_s'] * 1e3:.4g} ms "
                      "(one sample), where the config leaves them out")
    sections = {"hpo": hpo_config, "training": training_config, "model": model_config}
    initial_delays = initial_delays_from_time_offset(model_config, time_offset_path)
    if initial_delays is not None:
        sections["initial_delays_s"] = initial_delays
    delay_bounds = delay_bounds_from_time_offset(model_config, time_offset_path, sample_period_s)
    if delay_bounds is not None:
        sections["delay_bounds_s"] = delay_bounds
    if roles is not None:
        check_target_weights(hpo_config, roles)
        sections["targets"] = dict(roles.target_weights)
    identifier = search_id(case, seed, sections)
    plan = search_plan(hpo_config, training_config, seed, identifier)
    if initial_delays is not None:
        plan["initial_delays_s"] = initial_delays
    if delay_bounds is not None:
        plan["delay_bounds_s"] = delay_bounds
    if chosen:
        plan["chosen_from_data"] = chosen
        for note in chosen:
            LOG.info("chosen from the data: %s", note)
    if tracking_uri:
        from hybridfmu.training.search_tracking import start_search

        params = {"R": plan["R"], "eta": plan["eta"], "max_resource_s": plan["max_resource_s"],
                  "unit_s": plan["unit_s"], "n_configurations": plan["n_configurations"],
                  "objective": json.dumps(plan["objective"]), "seed": seed,
                  "search_space": json.dumps(hpo_config["search_space"], sort_keys=True)}
        if initial_delays is not None:
            params["initial_delays_s"] = json.dumps(initial_delays, sort_keys=True)
        if delay_bounds is not None:
            params["delay_bounds_s"] = json.dumps(delay_bounds, sort_keys=True)
        params["physics_terms"] = json.dumps(model_config.get("physics_terms", "none"))
        if model_config.get("physics_terms", "none") != "none":
            params["physics_coefficient_step"] = json.dumps(model_config.get("physics_coefficient_step"))
        plan["tracking"] = start_search(tracking_uri, experiment or case, identifier, case, params)
    write_json_atomic(plan_path, plan)
    LOG.info("search %s: %d brackets, %d configurations, one unit = %.4g s of data", identifier,
             len(plan["brackets"]), plan["n_configurations"], plan["unit_s"])
    return plan


def initial_delays_from_time_offset(model_config: dict[str, Any],
                                    time_offset_path: str | Path | None) -> dict[str, float] | None:
    """{group: s} from the time-offset summary when ``model.input_delay.init_s`` is ``time_offset``, else None.

    Raises:
        ValueError: the summary is missing, or does not estimate exactly the configured groups.
    """
    delay = model_config.get("input_delay", {})
    if delay.get("init_s") != "time_offset":
        return None
    if not time_offset_path:
        raise ValueError("config.model.input_delay.init_s is 'time_offset', but the time-offset summary "
                         "(rule time_offset) was not given")
    groups = read_json(time_offset_path).get("groups")
    expected = sorted((delay.get("groups") or {"inputs": None}).keys())
    if not isinstance(groups, dict) or sorted(groups) != expected:
        raise ValueError(f"{time_offset_path}: field 'groups' estimates {sorted(groups or {})}, expected the groups "
                         f"of config.model.input_delay {expected}; rerun rule time_offset")
    return {name: float(groups[name]["delay_s"]) for name in expected}


def delay_bounds_from_time_offset(model_config: dict[str, Any], time_offset_path: str | Path | None,
                                  sample_period_s: float | None = None) -> dict[str, list[float]] | None:
    """{group: [low, high]} (s) for every group the time-offset stage identified, when
    ``model.input_delay.within_standard_errors`` (k) is set: its estimate ± k bootstrap standard errors,
    within ``[min_s, max_s]``. The training loss compares only the target states, where a delay can trade
    off against the model's other errors; the band keeps the learned delay where the time-offset stage's
    windows (every measured state, right after the inputs change) put it. Groups not identified keep
    ``[min_s, max_s]`` (where the config leaves them out, chosen from ``sample_period_s``,
    :func:`hybridfmu.model.settings.input_delay_settings`). None when k is not set.

    Raises:
        ValueError: k is set but ``init_s`` is not ``time_offset``, or the summary lacks an identified group's
            standard error (names the file and the group).
    """
    delay = model_config.get("input_delay", {})
    k = delay.get("within_standard_errors")
    if k is None:
        return None
    if delay.get("init_s") != "time_offset":
        raise ValueError(f"config.model.input_delay.within_standard_errors is {k}, which needs init_s: time_offset "
                         f"(the bounds are around the time-offset stage's estimates), got init_s "
                         f"{delay.get('init_s')!r}")
    initial = initial_delays_from_time_offset(model_config, time_offset_path)
    groups = read_json(time_offset_path)["groups"]
    if delay.get("min_s") is None or delay.get("max_s") is None:
        if sample_period_s is None:
            raise ValueError("config.model.input_delay.min_s/max_s are chosen from the data's sample period, "
                             "which the search's plan was not given")
        delay = input_delay_settings(delay, sample_period_s)
    low_s, high_s = float(delay["min_s"]), float(delay["max_s"])
    bounds = {}
    for name, estimate_s in initial.items():
        entry = groups[name]
        if not entry.get("identified"):
            continue
        error_s = entry.get("standard_error_s")
        if error_s is None or not float(error_s) > 0:
            raise ValueError(f"{time_offset_path}: group {name!r} is identified but has no positive "
                             f"'standard_error_s' (got {error_s!r}); config.model.input_delay.within_standard_errors "
                             f"needs it: set evaluation.time_offset.groups.bootstrap_samples > 0 and rerun rule "
                             f"time_offset")
        half_width_s = float(k) * float(error_s)
        bounds[name] = [max(low_s, estimate_s - half_width_s), min(high_s, estimate_s + half_width_s)]
    return bounds


def select_rung(*, plan_path: str | Path, bracket: int, rung: int, result_paths: list[str],
                selection_path: str | Path) -> dict[str, Any]:
    """Rank the rung's results by validation objective and keep the next rung's number of survivors."""
    plan = read_json(plan_path)
    entry = next((b for b in plan["brackets"] if b["bracket"] == bracket), None)
    if entry is None:
        raise ValueError(f"{plan_path}: no bracket {bracket}")
    results = []
    for path in result_paths:
        result = read_json(path)
        if result.get("bracket") != bracket or result.get("rung") != rung:
            raise ValueError(f"{path}: result of b{result.get('bracket')} r{result.get('rung')}, "
                             f"expected b{bracket} r{rung}")
        results.append({**result, "result_path": str(path)})
    last = rung == len(entry["rungs"]) - 1
    n_keep = 0 if last else entry["rungs"][rung + 1]["n_configs"]
    survivors = select_survivors(results, n_keep)
    ranking = [{"config": r["config"], "trial_id": r["trial_id"], "status": r["status"], "reason": r["reason"],
                "objective": r["objective"], "result": r["result_path"]} for r in rank_results(results)]
    selection = {"bracket": bracket, "rung": rung, "last_rung": last, "survivors": survivors,
                 "n_failed": sum(r["status"] != "ok" for r in results), "ranking": ranking}
    write_json_atomic(selection_path, selection)
    LOG.info("bracket %d rung %d: %d results (%d failed), survivors %s", bracket, rung, len(results),
             selection["n_failed"], survivors)
    return selection


def select_best(*, plan_path: str | Path, selection_paths: list[str], best_path: str | Path,
                best_model_path: str | Path, summary_path: str | Path, case: str,
                finalists_path: str | Path | None = None) -> dict[str, Any]:
    """The best configuration over all brackets: by the validation objective of the brackets' last rungs, or,
    with ``finalists_path`` (rule ``score_finalists``, config ``hpo.selection``), the finalist chosen there
    over whole maneuvers (the objective decides when every finalist diverged).

    ``selection_paths``: the selections of every rung of every bracket (the last rungs' decide).

    Writes ``summary_path`` (every trial of every rung: hyperparameters, status, validation, training
    curve), copies the best checkpoint to ``best_model_path`` and writes ``best_path``:
    ``{"trial_id", "bracket", "config", "rung", "checkpoint", "source_checkpoint", "hyperparameters",
    "validation", "objective", "delay_s", "gates", "model_spec", "fmu", "mlflow_run_id", "tracking",
    "summary", ...}``.
    """
    from hybridfmu.training.checkpoint import load_checkpoint

    plan = read_json(plan_path)
    finals, trials = [], []
    for path in selection_paths:
        selection = read_json(path)
        for item in selection["ranking"]:
            record = read_json(item["result"])
            if selection.get("last_rung"):
                finals.append(record)
            trials.append({key: record.get(key) for key in TRIAL_SUMMARY_KEYS})
    trials.sort(key=lambda t: (-t["bracket"], t["config"], t["rung"]))
    ranked = [r for r in rank_results(finals) if r["status"] == "ok" and r["objective"] is not None]
    best, choice = (ranked[0] if ranked else None), {"by": "objective"}
    if ranked and finalists_path is not None:
        best, choice = finalist_choice(finalists_path, ranked)
    summary = {"search_id": plan["search_id"], "R": plan["R"], "eta": plan["eta"], "unit_s": plan["unit_s"],
               "max_resource_s": plan["max_resource_s"], "objective": plan["objective"],
               "n_configurations": plan["n_configurations"], "trials": trials,
               "best_trial": best["trial_id"] if best else None, "selection": choice}
    write_json_atomic(summary_path, summary)
    if not ranked:
        if plan.get("tracking"):
            from hybridfmu.training.search_tracking import finish_search
            finish_search(plan["tracking"], None, summary_path)
        raise RuntimeError(f"hyperparameter search of case {case}: every configuration of the last rungs failed "
                           f"or diverged; see {summary_path}")
    checkpoint = load_checkpoint(best["checkpoint"])
    with atomic_path(best_model_path) as tmp:
        shutil.copyfile(best["checkpoint"], tmp)
    record = {
        "case": case, "trial_id": best["trial_id"], "bracket": best["bracket"], "config": best["config"],
        "rung": best["rung"], "checkpoint": str(best_model_path), "source_checkpoint": best["checkpoint"],
        "hyperparameters": best["hyperparameters"], "objective": best["objective"], "validation": best["validation"],
        "resource_s": best["resource_s"], "delay_s": best["delay_s"], "gates": best["gates"],
        "model_spec": checkpoint["spec"], "fmu": best["fmu"], "mlflow_run_id": best.get("mlflow_run_id"),
        "tracking": plan.get("tracking"), "search_id": plan["search_id"], "summary": str(summary_path),
        "ranking": [{"trial_id": r["trial_id"], "objective": r["objective"]} for r in ranked],
        "selection": choice,
    }
    write_json_atomic(best_path, record)
    if plan.get("tracking"):
        from hybridfmu.training.search_tracking import finish_search
        finish_search(plan["tracking"], record, summary_path)
    LOG.info("best: %s (objective %s, chosen by %s, delays %s, gates %s)", best["trial_id"],
             "none" if best["objective"] is None else f"{best['objective']:.4g}", choice["by"],
             describe_delays(best["delay_s"]), best["gates"])
    return record


def finalist_choice(finalists_path: str | Path, ranked: list[dict[str, Any]]) -> tuple[dict[str, Any], dict[str, Any]]:
    """The result chosen by rule ``score_finalists`` among ``ranked`` (the last rungs' successful results, best
    objective first), and how: ``{"by": "maneuvers", "maneuvers", "score", "objective_rank", "finalists":
    [{"trial_id", "score"}]}``, or ``{"by": "objective", ...}`` when every finalist diverged.

    Raises:
        ValueError: the chosen trial is none of the ranked results (the scores belong to another search run).
    """
    scores = read_json(finalists_path)
    finalists = [{"trial_id": f["trial_id"], "score": f["score"], "objective_rank": f["objective_rank"]}
                 for f in scores["finalists"]]
    if scores.get("chosen") is None:
        LOG.warning("%s: every finalist diverged over %s; choosing by the objective", finalists_path,
                    scores.get("maneuvers"))
        return ranked[0], {"by": "objective", "maneuvers": scores.get("maneuvers"), "finalists": finalists}
    by_trial = {r["trial_id"]: r for r in ranked}
    layer = next((f for f in scores["finalists"] if f["trial_id"] == PHYSICAL_LAYER_ID), None)
    if layer is not None:  # a hybrid's physical layer, chosen unless a finalist beats it on every maneuver (finalists.worse_than)
        by_trial[PHYSICAL_LAYER_ID] = layer
    if scores["chosen"] not in by_trial:
        raise ValueError(f"{finalists_path}: chosen trial {scores['chosen']!r} is not among the search's last-rung "
                         f"results {sorted(by_trial)}; rerun rule score_finalists")
    chosen = next(f for f in finalists if f["trial_id"] == scores["chosen"])
    choice = {"by": "maneuvers", "maneuvers": scores["maneuvers"], "score": chosen["score"],
              "objective_rank": chosen["objective_rank"], "finalists": finalists}
    if layer is not None:
        choice["physical_layer"] = scores.get("physical_layer")
    return by_trial[scores["chosen"]], choice
