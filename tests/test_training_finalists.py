"""The final choice over whole maneuvers (hpo.selection) and the per-search settings (hpo.searches)."""

import math

import numpy as np
import pytest

from hybridfmu.config import ConfigError
from hybridfmu.data.settings import section_settings
from hybridfmu.io import write_json_atomic
from hybridfmu.training.finalists import (choose_finalist, error_ratio, finalist_results, finite_or_null,
                                          geometric_mean)
from hybridfmu.training.hpo import finalist_choice
from hybridfmu.training.plan import search_settings
from hybridfmu.training.losses import Objective


def test_error_ratio_weights_each_target_by_the_objective():
    measured = np.zeros((4, 2))
    fmu = np.array([[2.0, 1.0]] * 4)      # FMU errors: angle 2, speed 1
    model = np.array([[1.0, 0.25]] * 4)   # model errors: angle 1 (ratio 0.5), speed 0.25 (ratio 0.25)
    ratio, ratios = error_ratio(model, fmu, measured, ["theta", "omega"], Objective("MAE", {"theta": 0.8, "omega": 0.2}))
    assert ratios == pytest.approx({"theta": 0.5, "omega": 0.25})
    assert ratio == pytest.approx(0.8 * 0.5 + 0.2 * 0.25)
    squared, _ = error_ratio(model, fmu, measured, ["theta", "omega"], Objective("MSE", {"theta": 0.5, "omega": 0.5}))
    assert squared == pytest.approx(0.5 * 0.25 + 0.5 * 0.0625)


def test_error_ratio_of_a_diverged_model_or_an_exact_fmu():
    measured = np.zeros((3, 1))
    objective = Objective("MAE", {"theta": 1.0})
    assert error_ratio(np.array([[np.nan]] * 3), np.ones((3, 1)), measured, ["theta"], objective)[0] == math.inf
    assert error_ratio(np.zeros((3, 1)), np.zeros((3, 1)), measured, ["theta"], objective)[0] == 1.0
    assert error_ratio(np.ones((3, 1)), np.zeros((3, 1)), measured, ["theta"], objective)[0] == math.inf


def test_geometric_mean_and_choice():
    assert geometric_mean([0.5, 2.0]) == pytest.approx(1.0)
    assert geometric_mean([0.1, math.inf]) == math.inf
    with pytest.raises(ValueError):
        geometric_mean([])
    scored = [{"trial_id": "a", "score": 0.3, "objective": 0.1}, {"trial_id": "b", "score": 0.2, "objective": 0.5},
              {"trial_id": "c", "score": None, "objective": 0.01}, {"trial_id": "d", "score": 0.2, "objective": 0.4}]
    assert choose_finalist(scored)["trial_id"] == "d"  # smallest score; the tie goes to the better objective
    assert choose_finalist([{"trial_id": "x", "score": math.inf, "objective": 0.1}]) is None
    assert finite_or_null({"a": [math.inf, 1.0], "b": float("nan")}) == {"a": [None, 1.0], "b": None}


def write_search(folder, results):
    """Last-rung results and their selection as rule select_rung writes them; returns the selection's path."""
    ranking = []
    for result in results:
        path = folder / f"c{result['config']}.json"
        write_json_atomic(path, result)
        ranking.append({"config": result["config"], "trial_id": result["trial_id"], "status": result["status"],
                        "reason": None, "objective": result["objective"], "result": str(path)})
    selection = folder / "selection.json"
    write_json_atomic(selection, {"bracket": 0, "rung": 0, "last_rung": True, "survivors": [], "ranking": ranking})
    return selection


def test_finalists_are_the_best_successful_last_rung_results(tmp_path):
    results = [{"trial_id": f"b0c{i}", "bracket": 0, "rung": 0, "config": i, "status": status,
                "objective": objective, "checkpoint": f"c{i}.pt"}
               for i, (status, objective) in enumerate([("ok", 0.3), ("failed", None), ("ok", 0.1), ("ok", 0.2)])]
    selection = write_search(tmp_path, results)
    assert [r["trial_id"] for r in finalist_results([selection], 2)] == ["b0c2", "b0c3"]
    assert [r["trial_id"] for r in finalist_results([selection], 10)] == ["b0c2", "b0c3", "b0c0"]

    ranked = finalist_results([selection], 10)
    scores = tmp_path / "finalists.json"
    write_json_atomic(scores, {"maneuvers": ["train", "val"], "chosen": "b0c3", "finalists": [
        {"trial_id": "b0c2", "score": 0.4, "objective_rank": 1}, {"trial_id": "b0c3", "score": 0.2, "objective_rank": 2}]})
    best, choice = finalist_choice(scores, ranked)
    assert best["trial_id"] == "b0c3" and choice["by"] == "maneuvers" and choice["objective_rank"] == 2
    write_json_atomic(scores, {"maneuvers": ["train"], "chosen": None, "finalists": [
        {"trial_id": "b0c2", "score": None, "objective_rank": 1}]})
    best, choice = finalist_choice(scores, ranked)
    assert best["trial_id"] == "b0c2" and choice["by"] == "objective"
    write_json_atomic(scores, {"maneuvers": ["train"], "chosen": "b9c9", "finalists": [
        {"trial_id": "b9c9", "score": 0.1, "objective_rank": 1}]})
    with pytest.raises(ValueError, match=r"finalists.json: chosen trial 'b9c9' is not among"):
        finalist_choice(scores, ranked)


def test_search_settings_override_the_section_for_one_search():
    hpo = section_settings({"R": 9, "max_resource_s": 18.0, "selection": {"maneuvers": ["validation"], "top": 3},
                            "searches": {"hpo": {"R": 27, "max_resource_s": 54.0,
                                                 "selection": {"maneuvers": ["train", "validation"]}},
                                         "hybrid": {"selection": {"maneuvers": []}}}}, "hpo")
    neural = search_settings(hpo, "hpo")
    assert (neural["R"], neural["max_resource_s"], neural["eta"]) == (27, 54.0, 3)
    assert neural["selection"] == {"maneuvers": ["train", "validation"], "top": 5}
    hybrid = search_settings(hpo, "hybrid")
    assert (hybrid["R"], hybrid["max_resource_s"]) == (9, 18.0) and "selection" not in hybrid
    assert "searches" not in neural and "searches" not in hybrid
    plain = section_settings({"R": 9}, "hpo")
    # a config that never mentions the new settings keeps the settings (and the search id) it had
    assert search_settings(plain, "hpo") == {k: v for k, v in plain.items() if k != "searches"}
    assert search_settings(hpo, "other")["selection"] == {"maneuvers": ["validation"], "top": 3}
    # a search's own search space replaces the section's, all of it; the other search keeps the section's
    space = dict(plain["search_space"], lr={"distribution": "loguniform", "low": 1e-4, "high": 1e-3})
    own = section_settings({"R": 9, "searches": {"hybrid": {"search_space": space}}}, "hpo")
    assert search_settings(own, "hybrid")["search_space"] == space
    assert search_settings(own, "hpo")["search_space"] == plain["search_space"]
    with pytest.raises(ConfigError, match=r"searches\.hybrid\.search_space: 'beta1' is a required property"):
        section_settings({"searches": {"hybrid": {"search_space": {"lr": space["lr"]}}}}, "hpo")


def test_the_test_maneuver_never_chooses_and_each_budget_is_checked():
    with pytest.raises(ConfigError, match=r"config\.hpo\.selection\.maneuvers"):
        section_settings({"selection": {"maneuvers": ["test"]}}, "hpo")
    with pytest.raises(ConfigError, match=r"config\.hpo\.searches"):
        section_settings({"searches": {"neural": {"R": 3}}}, "hpo")
    from hybridfmu.case_checks import check_hpo

    check_hpo({"hpo": {"R": 9, "eta": 3, "searches": {"hpo": {"R": 27}}}})
    with pytest.raises(ConfigError, match=r"config\.hpo\.searches\.hybrid\.R"):
        check_hpo({"hpo": {"R": 9, "eta": 3, "searches": {"hybrid": {"R": 1}}}})


def test_a_hybrids_physical_layer_is_chosen_when_no_finalist_beats_it(tmp_path):
    """The physical layer has no objective: it wins a tied score (a trained configuration replaces it only with a
    smaller one) and a lower one, and finalist_choice hands select_best its entry (checkpoint, delays, gates) like a
    trial's result."""
    layer = {"trial_id": "physical_layer", "score": 0.5, "objective": None, "objective_rank": None,
             "checkpoint": "physical_layer.pt", "hyperparameters": {"width": 8}, "delay_s": {"duties": 3e-5},
             "gates": {"omega": {"g_F": 1.0, "g_A": 0.2}}, "fmu": {"path": "m.fmu"}, "validation": None,
             "resource_s": 0.0, "status": "ok", "bracket": None, "config": None, "rung": None}
    trained = {"trial_id": "b0c1", "score": 0.5, "objective": 0.2, "objective_rank": 1}
    assert choose_finalist([trained, layer])["trial_id"] == "physical_layer"  # a tie: nothing learned
    assert choose_finalist([{**trained, "score": 0.6}, layer])["trial_id"] == "physical_layer"
    assert choose_finalist([{**trained, "score": 0.4}, layer])["trial_id"] == "b0c1"
    other = {"trial_id": "b1c0", "score": 0.4, "objective": 0.1, "objective_rank": 2}
    assert choose_finalist([{**trained, "score": 0.4}, other, layer])["trial_id"] == "b1c0"  # then the objective

    results = [{"trial_id": "b0c1", "bracket": 0, "rung": 0, "config": 1, "status": "ok", "objective": 0.2,
                "checkpoint": "c1.pt"}]
    ranked = finalist_results([write_search(tmp_path, results)], 5)
    scores = tmp_path / "finalists.json"
    write_json_atomic(scores, {"maneuvers": ["train", "validation"], "chosen": "physical_layer",
                               "finalists": [{**trained, "score": 0.6}, layer],
                               "physical_layer": {"score": 0.5, "beaten_by": []}})
    best, choice = finalist_choice(scores, ranked)
    assert best["checkpoint"] == "physical_layer.pt" and best["delay_s"] == {"duties": 3e-5}
    assert choice["objective_rank"] is None and choice["physical_layer"] == {"score": 0.5, "beaten_by": []}
    from hybridfmu.evaluation.report import chosen_by_text

    assert chosen_by_text(choice) == ("open loop over the whole train and validation maneuvers (error 0.5 of the "
                                      "FMU's; the physical layer (ANN at zero), among 2 candidates: the finalists and "
                                      "the physical layer)")


def _scored(trial_id, score, ratios, objective=0.1):
    """A candidate entry as score_model writes it: ratios {maneuver: {state: ratio}}."""
    return {"trial_id": trial_id, "score": score, "objective": objective, "objective_rank": 1,
            "maneuvers": {name: {"ratio": None if None in r.values() else sum(r.values()) / len(r), "ratios": r}
                          for name, r in ratios.items()}}


def test_a_finalist_worse_than_the_physical_layer_on_one_maneuver_cannot_replace_it(tmp_path):
    """b0c1 has the smaller score but is worse than the physical layer in the angle of the validation maneuver: the
    choice takes b0c2, which is worse nowhere; without b0c2 it takes the physical layer. finalists.json says where."""
    from hybridfmu.training.finalists import choose_among_candidates, worse_than

    layer = {**_scored("physical_layer", 0.5, {"train": {"theta": 0.5, "omega": 0.6},
                                                 "validation": {"theta": 0.4, "omega": 0.5}}), "objective": None}
    better_overall = _scored("b0c1", 0.3, {"train": {"theta": 0.1, "omega": 0.2},
                                           "validation": {"theta": 0.41, "omega": 0.3}})
    worse_nowhere = _scored("b0c2", 0.45, {"train": {"theta": 0.5, "omega": 0.55},
                                           "validation": {"theta": 0.4, "omega": 0.45}})
    diverged = _scored("b1c0", None, {"train": {"theta": None, "omega": None},
                                      "validation": {"theta": None, "omega": None}})
    assert worse_than(better_overall, layer) == ["validation: theta"]
    assert worse_than(worse_nowhere, layer) == [] and worse_than(layer, layer) == []
    assert worse_than(diverged, layer) == ["train: theta", "train: omega", "validation: theta", "validation: omega"]

    class Roles:
        def weights_with(self, overrides):
            return {"theta": 0.5, "omega": 0.5}

    plan = tmp_path / "plan.json"
    write_json_atomic(plan, {"objective": {"loss": "MAE"}})

    def choose(entries):
        paths = []
        for entry in entries:
            paths.append(tmp_path / f"{entry['trial_id']}.json")
            write_json_atomic(paths[-1], {"candidate": entry["trial_id"], **entry})
        return choose_among_candidates(candidate_paths=paths, maneuvers=["train", "validation"], top=3,
                                       plan_path=plan, roles=Roles(), scores_path=tmp_path / "finalists.json")

    record = choose([better_overall, worse_nowhere, diverged, layer])
    assert record["chosen"] == "b0c2"
    assert record["physical_layer"]["beaten_by"] == ["b0c2"]
    assert record["physical_layer"]["worse_on"] == {"b0c1": ["validation: theta"],
                                                    "b1c0": worse_than(diverged, layer)}
    assert choose([better_overall, layer])["chosen"] == "physical_layer"
    assert choose([better_overall])["chosen"] == "b0c1"  # a search without a physical layer: the smallest score
