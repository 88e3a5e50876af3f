"""The search plan: Hyperband brackets and rungs, and every bracket's sampled configurations."""

from __future__ import annotations

from typing import Any

from hybridfmu.training.hyperband import hyperband_brackets, total_configurations
from hybridfmu.training.search_space import config_hash, sample_configuration, trial_seed


def search_plan(hpo: dict[str, Any], training: dict[str, Any], seed: int, search_id: str) -> dict[str, Any]:
    """JSON-able plan from the validated ``hpo`` and ``training`` sections and the master seed.

    Layout: ``{"search_id", "R", "eta", "max_resource_s", "unit_s", "n_configurations", "objective",
    "brackets": [{"bracket": s, "rungs": [{"rung", "n_configs", "resource_units", "resource_s"}],
    "configs": [{"config", "seed", "hash", "hyperparameters"}]}]}``.
    """
    R, eta, max_resource_s = float(hpo["R"]), float(hpo["eta"]), float(hpo["max_resource_s"])
    unit_s = max_resource_s / R
    space = dict(hpo["search_space"])
    space.setdefault("batch_windows", {"distribution": "fixed", "value": int(training["batch_windows"])})
    brackets = []
    for bracket in hyperband_brackets(R, eta):
        configs = []
        for index in range(bracket.n_configs):
            values = sample_configuration(space, seed, bracket.s, index)
            configs.append({"config": index, "seed": trial_seed(seed, bracket.s, index), "hash": config_hash(values),
                            "hyperparameters": values})
        brackets.append({
            "bracket": bracket.s,
            "rungs": [{"rung": rung.index, "n_configs": rung.n_configs, "resource_units": rung.resource_units,
                       "resource_s": rung.resource_units * unit_s} for rung in bracket.rungs],
            "configs": configs})
    return {"search_id": search_id, "R": R, "eta": eta, "max_resource_s": max_resource_s, "unit_s": unit_s,
            "n_configurations": total_configurations(R, eta), "objective": dict(hpo["objective"]),
            "brackets": brackets}


def plan_entry(plan: dict[str, Any], bracket: int, rung: int, config: int) -> dict[str, Any]:
    """{"bracket", "rung", "config", "seed", "hash", "hyperparameters", "resource_s", "last_rung"} of a job."""
    for entry in plan["brackets"]:
        if entry["bracket"] == bracket:
            if not 0 <= rung < len(entry["rungs"]):
                raise ValueError(f"search plan: bracket {bracket} has rungs 0..{len(entry['rungs']) - 1}, not {rung}")
            if not 0 <= config < len(entry["configs"]):
                raise ValueError(f"search plan: bracket {bracket} has configs 0..{len(entry['configs']) - 1}, "
                                 f"not {config}")
            item = entry["configs"][config]
            return {"bracket": bracket, "rung": rung, "config": config, "seed": item["seed"], "hash": item["hash"],
                    "hyperparameters": item["hyperparameters"], "resource_s": entry["rungs"][rung]["resource_s"],
                    "last_rung": len(entry["rungs"]) - 1}
    raise ValueError(f"search plan: no bracket {bracket}")


def search_settings(hpo_config: dict[str, Any], search: str) -> dict[str, Any]:
    """The validated ``config.hpo`` section as one search sees it: its ``searches.<search>`` entries replace
    the section's, and ``searches`` itself is dropped. A ``selection`` without maneuvers (the objective
    decides, the default) is dropped too, so a search's settings, and with them its id, stay those of a
    config that never mentioned it."""
    settings = {key: value for key, value in hpo_config.items() if key != "searches"}
    settings.update((hpo_config.get("searches") or {}).get(search) or {})
    selection = settings.get("selection") or {}
    if selection.get("maneuvers"):
        settings["selection"] = {"maneuvers": list(selection["maneuvers"]), "top": int(selection.get("top", 5))}
    else:
        settings.pop("selection", None)
    return settings
