"""Whether the data identify a fitted parameter: the combined uncertainty and its 90 % interval."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybridfmu.diagnosis.identification import (Z_90, combined_se, identification, is_location, rival_se,
                                               spread_widening)
from hybridfmu.diagnosis.report import not_identified, rival_text


def test_the_combined_se_is_the_largest_of_regression_bootstrap_and_maneuver_spread():
    row = {"name": "coulomb_level", "value": 1.0, "se": 0.01, "se_bootstrap": 0.02}
    assert combined_se(row, None) == 0.02
    # two maneuvers' spread: its standard deviation (1 degree of freedom) widened to Student's t, 6.31 / 1.645
    assert spread_widening(2) == pytest.approx(6.3137515 / Z_90)
    assert combined_se(row, {"train": 1.0, "validation": 1.2}) == pytest.approx(0.2 / math.sqrt(2) * 6.3137515 / Z_90)
    assert spread_widening(5) == pytest.approx(2.1318468 / Z_90) and spread_widening(10 ** 6) == pytest.approx(1.0, abs=1e-5)
    assert combined_se({"name": "x", "value": 1.0, "se": None}, {"train": 3.0}) is None


@pytest.mark.parametrize("value, se, identified, because", [
    (1.0, 0.1, True, None),
    (1.0, 0.7, False, "covers zero"),                       # 1 +- 1.15
    (-2.0, 1.1, False, "spans more than a factor 10"),      # -2 +- 1.81: -3.81 .. -0.19
    (116.7, 398.0, False, "covers zero"),                   # a Stribeck breakaway the data do not fix
    (0.383, 0.0024, True, None),
])
def test_a_size_is_identified_only_when_its_interval_neither_covers_zero_nor_spans_a_decade(value, se, identified,
                                                                                           because):
    out = identification({"name": "level_or_size", "value": value, "se": se}, None)
    assert out["identified"] is identified
    assert out["interval_90"] == pytest.approx([value - Z_90 * se, value + Z_90 * se])
    assert (because is None and out["not_identified_because"] is None) or because in out["not_identified_because"]


def test_a_maneuver_spread_makes_a_tight_regression_interval_honest():
    """The pendulum's case: a Coulomb level with a regression SE 50x too small, but two maneuvers that disagree."""
    row = {"name": "coulomb_level", "value": 0.383, "se": 0.0024, "se_bootstrap": 0.003}
    out = identification(row, {"train": 0.30, "validation": 0.46})
    assert out["se_combined"] == pytest.approx(0.16 / math.sqrt(2) * spread_widening(2))
    assert out["interval_90"][0] < 0.25 < out["interval_90"][1]


def test_locations_and_unsearched_settings_are_not_judged():
    assert is_location("threshold") and is_location("level") and is_location("phase_24")
    assert not is_location("coulomb_level") and not is_location("amplitude_24")
    assert identification({"name": "threshold", "value": 0.001, "se": 0.5}, None)["identified"] is None
    assert identification({"name": "order", "value": 24, "se": None}, None) == {
        "se_combined": None, "interval_90": None, "identified": None, "not_identified_because": None}


def test_the_verdict_lists_what_is_not_identified():
    chosen = [{"effect": "coulomb(v)", "parameters": [{"name": "coulomb_level", "identified": True},
                                                      {"name": "breakaway_level", "identified": False}]},
              {"effect": "periodic(x)", "parameters": [{"name": "order", "identified": None}]}]
    assert not_identified(chosen) == ["coulomb(v): breakaway_level"]


def test_effects_whose_estimates_correlate_are_grouped():
    from hybridfmu.diagnosis.identification import indistinguishable_groups
    from hybridfmu.diagnosis.report import group_text

    sd = np.array([1.0, 2.0, 0.5, 3.0])  # A: 1 coefficient, B: 2, C: 1
    corr = np.eye(4)
    corr[0, 2] = corr[2, 0] = -0.95     # A with B's first coefficient
    corr[1, 3] = corr[3, 1] = 0.3       # B's second with C: told apart
    cov = corr * np.outer(sd, sd)
    groups = indistinguishable_groups(["A", "B", "C"], [1, 2, 1], cov)
    assert groups == [{"effects": ["A", "B"], "pairs": [{"effects": ["A", "B"], "correlation": pytest.approx(-0.95)}]}]
    assert group_text(groups[0]) == "A and B"
    corr[2, 3] = corr[3, 2] = 0.92      # and C with B: one group of three
    groups = indistinguishable_groups(["A", "B", "C"], [1, 2, 1], corr * np.outer(sd, sd))
    assert groups[0]["effects"] == ["A", "B", "C"] and group_text(groups[0]) == "A, B and C"
    assert indistinguishable_groups(["A"], [1], np.eye(1)) == []


def test_a_positive_scale_is_judged_on_its_log_scale():
    tight = identification({"name": "smoothing", "value": 1.0, "se": 0.1}, None, log_scale=True)
    assert tight["identified"] is True
    assert tight["interval_90"] == pytest.approx([math.exp(-Z_90 * 0.1), math.exp(Z_90 * 0.1)])
    # the demo's load-dependent friction: the two maneuvers refine the smoothing to 0.136 and 0.018 rad/s
    vague = identification({"name": "smoothing", "value": 0.018, "se": 0.0055}, {"train": 0.136, "validation": 0.018},
                           log_scale=True)
    assert vague["identified"] is False and "spans more than a factor 10" in vague["not_identified_because"]
    assert vague["interval_90"][0] > 0
    assert identification({"name": "stribeck_velocity", "value": 0.0, "se": 0.1}, None, log_scale=True)[
        "identified"] is None  # switched off


def test_a_rival_widens_the_interval_to_reach_the_value_it_would_give():
    """The viscous case of the withheld suite: b alone +405 %, +151 % with the load's time offset beside it (a term
    the data support but that is too small to be named): the interval must reach both."""
    row = {"name": "relative_error", "value": 4.05, "se": 0.09, "se_bootstrap": 0.25}
    assert rival_se(4.05, [1.51]) == pytest.approx(2.54 / Z_90)
    assert combined_se(row, None, [1.51]) == pytest.approx(2.54 / Z_90)
    assert combined_se(row, None, [4.0]) == 0.25            # a rival within the noise changes nothing
    out = identification(row, None, alternatives=[1.51, 3.9])
    assert out["interval_90"] == pytest.approx([1.51, 6.59])
    assert out["identified"] is True
    assert identification(row, None, alternatives=[-0.2])["identified"] is False   # covers zero now
    # a log-scaled setting: the interval on the log scale reaches the rival's value
    log_out = identification({"name": "smoothing", "value": 0.01, "se": 1e-4}, None, log_scale=True,
                             alternatives=[0.04])
    assert log_out["interval_90"] == pytest.approx([0.0025, 0.04])
    assert rival_se(0.01, [-1.0], log_scale=True) is None and rival_se(1.0, [math.nan]) is None


def test_the_report_names_the_rival_an_estimate_rests_on():
    item = {"effect": "parameter(b)", "parameters": [{"name": "relative_error", "value": 4.05}],
            "rivals": [{"effect": "time_offset(tau_load)", "bic_drop": 795.0, "rejected_because": "small",
                        "values": {"relative_error": 1.51}}]}
    assert rival_text(item) == ("parameter(b): relative_error 4.05; with time_offset(tau_load) beside it "
                                "relative_error 1.51")
    assert rival_text({**item, "rivals": []}) is None


def test_an_effect_is_confirmed_by_one_identified_size():
    from hybridfmu.diagnosis.identification import confirmed

    rows = [{"name": "coulomb_level", "identified": False}, {"name": "breakaway_level", "identified": True},
            {"name": "smoothing", "identified": True}]
    assert confirmed(rows, ["coulomb_level", "breakaway_level"]) is True
    assert confirmed(rows[:1] + rows[2:], ["coulomb_level", "breakaway_level"]) is False  # a shape confirms nothing
    periodic = [{"name": "order", "identified": None}, {"name": "amplitude_24", "identified": False},
                {"name": "amplitude_48", "identified": False}, {"name": "phase_24", "identified": None}]
    assert confirmed(periodic, ["amplitude_"]) is False
    periodic[2]["identified"] = True
    assert confirmed(periodic, ["amplitude_"]) is True
    assert confirmed([{"name": "level", "identified": None}], ["level"]) is None  # nothing judged: not refused


def test_the_verdict_keeps_an_unconfirmed_term_apart_from_the_findings():
    from hybridfmu.diagnosis.result import EffectSelection

    def item(effect, kind, role):
        return {"effect": effect, "kind": kind, "role": role, "equation": "i_d", "equations": ["i_d"],
                "parameters": [], "rivals": []}

    which = EffectSelection(chosen=[item("parameter(R)", "parameter", "finding"),
                                    item("polynomial(i_d)", "polynomial", "unconfirmed"),
                                    item("time_offset(u)", "time_offset", "adjustment")],
                            equations={}, steps=[], calibration=[], skipped={}, terms=[], cache=None, n_candidates=3,
                            groups=[])
    assert which.found_effects == ["parameter(R)"]
    assert which.unconfirmed == ["polynomial(i_d)"] and which.adjustments == ["time_offset(u)"]


def test_a_chosen_term_without_an_identified_size_is_unconfirmed():
    from types import SimpleNamespace

    from hybridfmu.diagnosis.run import _role

    effect = SimpleNamespace(name="polynomial(i_d)", size_parameters=lambda setting: ["c_2", "c_3"])
    term = SimpleNamespace(effect=effect, setting={"degree": 3.0})
    rows = [{"name": "c_2", "identified": False}, {"name": "c_3", "identified": False},
            {"name": "degree", "identified": True}]
    assert _role(term, SimpleNamespace(adjustments=[]), rows) == "unconfirmed"
    rows[1]["identified"] = True
    assert _role(term, SimpleNamespace(adjustments=[]), rows) == "finding"
    assert _role(term, SimpleNamespace(adjustments=["polynomial(i_d)"]), rows) == "adjustment"
