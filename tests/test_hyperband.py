"""Hyperband: bracket arithmetic (the paper's R = 81, eta = 3), selection, search plan and sampling."""

import math

import pytest

from hybridfmu.data.settings import section_settings
from hybridfmu.training.hyperband import (check_budget, hyperband_brackets, max_bracket, rank_results,
                                          select_survivors, total_configurations)
from hybridfmu.training.plan import plan_entry, search_plan
from hybridfmu.training.search_space import PAPER_SEARCH_SPACE, config_hash, sample_configuration


def test_paper_brackets_r81_eta3():
    brackets = hyperband_brackets(81, 3)
    assert max_bracket(81, 3) == 4
    assert [b.s for b in brackets] == [4, 3, 2, 1, 0]
    rungs = {b.s: [(r.n_configs, r.resource_units) for r in b.rungs] for b in brackets}
    assert rungs[4] == [(81, 1), (27, 3), (9, 9), (3, 27), (1, 81)]
    assert rungs[3] == [(34, 3), (11, 9), (3, 27), (1, 81)]
    assert rungs[2] == [(15, 9), (5, 27), (1, 81)]
    assert rungs[1] == [(8, 27), (2, 81)]
    assert rungs[0] == [(5, 81)]
    assert total_configurations(81, 3) == 143
    # every bracket spends about the same budget (successive halving with resumption)
    for bracket in brackets:
        assert bracket.rungs[-1].resource_units == 81


def test_small_search_and_non_integer_ratio():
    assert [(b.n_configs, [r.n_configs for r in b.rungs]) for b in hyperband_brackets(9, 3)] == [
        (9, [9, 3, 1]), (5, [5, 1]), (3, [3])]
    brackets = hyperband_brackets(10, 3)
    assert max_bracket(10, 3) == 2 and brackets[0].rungs[0].resource_units == pytest.approx(10 / 9)
    assert [b.n_configs for b in hyperband_brackets(3, 3)] == [3, 2]  # R = eta: the smallest real search
    with pytest.raises(ValueError, match="eta"):
        hyperband_brackets(9, 1)


@pytest.mark.parametrize("R, eta, expected", [
    (1, 3, r"^R = 1 is smaller than eta = 3: .* single configuration .* expected R >= eta"),
    (2.5, 3, r"^R = 2.5 is smaller than eta = 3"),
    (0.5, 3, r"^R = 0.5: expected at least 1"),
    (9, 1, r"^eta = 1: expected a reduction factor above 1"),
    (9, 0.5, r"^eta = 0.5: expected a reduction factor above 1"),
    (math.inf, 3, r"^R = inf: expected a finite number"),
    (math.nan, 3, r"^R = nan: expected a finite number"),
    (81, math.nan, r"^eta = nan: expected a finite number"),
    (81, 1.001, r"^R = 81, eta = 1.001: 4397 brackets .* expected at most 20"),
])
def test_degenerate_budgets_are_rejected(R, eta, expected):
    """R < eta would silently run one configuration (no search); eta near 1 an unbounded number of them."""
    for function in (hyperband_brackets, max_bracket, total_configurations):
        with pytest.raises(ValueError, match=expected):
            function(R, eta)


def test_budget_errors_name_the_config_fields():
    with pytest.raises(ValueError, match=r"^config\.hpo\.R = 2 is smaller than config\.hpo\.eta = 3: .* expected "
                                         r"config\.hpo\.R >= config\.hpo\.eta"):
        check_budget(2, 3, names=("config.hpo.R", "config.hpo.eta"))
    check_budget(3, 3)
    check_budget(2 ** 19, 2)  # 20 brackets: the most allowed


def test_selection_ranks_by_objective_and_never_promotes_failures():
    results = [{"config": 0, "status": "ok", "objective": 0.5},
               {"config": 1, "status": "failed", "objective": None},
               {"config": 2, "status": "ok", "objective": 0.1},
               {"config": 3, "status": "diverged", "objective": None},
               {"config": 4, "status": "ok", "objective": 0.5},
               {"config": 5, "status": "ok", "objective": math.inf}]
    assert [r["config"] for r in rank_results(results)] == [2, 0, 4, 1, 3, 5]
    assert select_survivors(results, 2) == [2, 0]
    assert select_survivors(results, 10) == [2, 0, 4]
    assert select_survivors(results, 0) == []


def test_sampling_is_seeded_and_within_the_space():
    a = sample_configuration(PAPER_SEARCH_SPACE, seed=7, bracket=4, index=3)
    assert a == sample_configuration(PAPER_SEARCH_SPACE, seed=7, bracket=4, index=3)
    assert a != sample_configuration(PAPER_SEARCH_SPACE, seed=7, bracket=4, index=4)
    assert a != sample_configuration(PAPER_SEARCH_SPACE, seed=8, bracket=4, index=3)
    draws = [sample_configuration(PAPER_SEARCH_SPACE, 1, 0, i) for i in range(300)]
    lrs = [d["lr"] for d in draws]
    assert 1e-6 <= min(lrs) and max(lrs) <= 1e-4
    assert sum(lr < 1e-5 for lr in lrs) == pytest.approx(150, abs=40)  # log-uniform: half below the geometric mean
    assert {d["beta2"] for d in draws} == {0.9999, 0.999, 0.99} and {d["loss"] for d in draws} == {"MAE", "MSE"}
    assert {d["width"] for d in draws} == {8, 16, 32} and {d["depth"] for d in draws} == {2, 3, 4}
    assert all(0.01 <= d["window_s"] <= 0.1 and 0 <= d["gate_opening"] <= 0.5 for d in draws)
    assert config_hash(a) == config_hash(dict(reversed(list(a.items()))))
    with pytest.raises(ValueError, match="search_space.lr"):
        sample_configuration({"lr": {"distribution": "normal"}}, 0, 0, 0)


def test_the_default_search_is_sized_by_the_data():
    """The schema's defaults leave the budget and the windows to the data: 10 passes over the selected training
    data per configuration, windows of 100-400 grid samples; a configured value wins; a missing figure is named."""
    from hybridfmu.training.search_defaults import chosen_search_settings

    hpo, training = section_settings({}, "hpo"), section_settings({}, "training")
    assert hpo["R"] == 9 and hpo["eta"] == 3 and hpo["max_resource_s"] is None
    chosen, notes = chosen_search_settings(hpo, sample_period_s=1e-3, training_data_s=8.0)
    assert chosen["max_resource_s"] == pytest.approx(80.0) and "window_samples" not in chosen["search_space"]
    assert chosen["search_space"]["window_s"] == {"distribution": "uniform", "low": pytest.approx(0.1),
                                                  "high": pytest.approx(0.4)}
    assert len(notes) == 2 and "8 s of selected training data" in notes[0] and "window_samples" in notes[1]
    plan = search_plan(chosen, training, seed=3, search_id="x")
    assert plan["n_configurations"] == 17 and plan["unit_s"] == pytest.approx(80 / 9)
    windows = [c["hyperparameters"]["window_s"] for b in plan["brackets"] for c in b["configs"]]
    assert all(0.1 <= w <= 0.4 for w in windows) and max(c["hyperparameters"]["lr"] for b in plan["brackets"]
                                                          for c in b["configs"]) <= 1e-2
    configured = dict(hpo, max_resource_s=5.0, search_space=PAPER_SEARCH_SPACE)
    assert chosen_search_settings(configured, 1e-3, 8.0) == (configured, [])
    with pytest.raises(ValueError, match="config.hpo.max_resource_s"):
        chosen_search_settings(hpo, 1e-3, None)


def test_paper_plan_from_the_papers_sections():
    hpo = section_settings({"R": 81, "max_resource_s": 100.0, "search_space": PAPER_SEARCH_SPACE}, "hpo")
    training = section_settings({}, "training")
    plan = search_plan(hpo, training, seed=3, search_id="x")
    assert plan["n_configurations"] == 143 == sum(len(b["configs"]) for b in plan["brackets"])
    assert plan["unit_s"] == pytest.approx(100 / 81)
    entry = plan_entry(plan, bracket=4, rung=2, config=10)
    assert entry["resource_s"] == pytest.approx(9 * 100 / 81) and entry["last_rung"] == 4
    assert entry["hyperparameters"]["batch_windows"] == training["batch_windows"]
    assert search_plan(hpo, training, seed=3, search_id="x") == plan
    with pytest.raises(ValueError, match="bracket 0 has rungs 0..0"):
        plan_entry(plan, bracket=0, rung=1, config=0)


def test_target_weights_in_the_search_space_and_objective():
    """w_<state> entries sample like any [0, 1] parameter and must name a target state of the case."""
    from types import SimpleNamespace

    from hybridfmu.training.hpo import check_target_weights
    from hybridfmu.training.losses import objective_from_config

    space = dict(PAPER_SEARCH_SPACE, w_v={"distribution": "uniform", "low": 0.0, "high": 1.0})
    hpo = section_settings({"search_space": space, "objective": {"loss": "MSE", "w_v": 0.25}}, "hpo")
    draws = [sample_configuration(hpo["search_space"], 1, 0, i)["w_v"] for i in range(50)]
    assert all(0.0 <= w <= 1.0 for w in draws) and len(set(draws)) == 50

    class Roles(SimpleNamespace):
        def weights_with(self, overrides):
            from hybridfmu.data.roles import CaseRoles
            return CaseRoles.weights_with(self, overrides)

    roles = Roles(target_weights={"p": 0.5, "v": 0.5}, target_states=["p", "v"])
    check_target_weights(hpo, roles)
    objective = objective_from_config(hpo["objective"], roles)
    assert objective.loss == "MSE" and objective.weights == pytest.approx({"p": 0.75, "v": 0.25})
    assert objective_from_config({"loss": "MAE"}, roles).weights == {"p": 0.5, "v": 0.5}
    with pytest.raises(ValueError, match=r"config\.hpo\.search_space\.w_q: 'q' is not a target state"):
        check_target_weights({"search_space": {"w_q": {}}, "objective": {}}, roles)
    with pytest.raises(ValueError, match=r"config\.hpo\.objective"):
        objective_from_config({"loss": "MAE", "w_q": 0.2}, roles)
    with pytest.raises(Exception, match="w_"):
        section_settings({"objective": {"loss": "MAE", "weight": 0.2}}, "hpo")
