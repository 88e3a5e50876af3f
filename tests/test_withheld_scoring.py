"""Scoring and aggregating withheld cases on synthetic diagnosis records: exact sets, offsets, parameter
conversion, effect size, where, detection limits, false alarms and the summary files."""

from __future__ import annotations

import csv
import math

import pytest

from hybridfmu_bench.withheld.report import (aggregate, above_limits, code_sentence, code_versions, confusion_matrix,
                                             settings_sentence, settings_versions,
                                                 detection_limit, detection_limits, split_seeds, summarise)
from hybridfmu_bench.withheld.scoring import effect_size, rejected_candidates, score_case
from hybridfmu.evaluation.measured_blocks import replace_block
from hybridfmu.io import write_json_atomic

J = 2.0e-4
EXPECTED = {"coulomb_friction": ["coulomb(omega)"], "viscous_friction": ["viscous(omega)", "parameter(b)"],
            "load_dependent_friction": ["coulomb(omega)*|tau_load|"], "cogging": ["periodic(theta)"],
            "inverter_deadtime": ["deadtime(*)"], "channel_time_offset": ["time_offset(*)"],
            "inertia_mismatch": ["parameter(J)"]}
OFFSETS = {"R": 0.04, "L_d": 0.03, "psi": -0.02}


def chosen(effect: str, equation: str, **params: float) -> dict:
    return {"effect": effect, "equation": equation, "parameters": [{"name": k, "value": v} for k, v in params.items()]}


def record(items: list[dict], first_step: dict[str, dict[str, float]] | None = None, gaps=(0.02, 0.01, 0.006, 0.001),
           model_parameters: dict | None = None) -> dict:
    """A diagnosis.json: ``items`` chosen in rank order, ``first_step``: equation -> {candidate: relative
    improvement} of the first selection step."""
    equations, every = {}, []
    for state, candidates in (first_step or {"omega": {}}).items():
        rows = [{"effect": e, "equations": [state], "relative_improvement": r, "rss": 100.0 * (1 - r), "bic": -r,
                 "bic_drop": r, "explained_share": r, "explained_to_noise": r, "rejected_because": "BIC drop below 10"}
                for e, r in sorted(candidates.items(), key=lambda kv: -kv[1])]
        every += rows
        equations[state] = {"steps": [{"candidates": rows, "chosen": None, "reason": "BIC drop 1 below 10"}],
                            "n_samples": 100, "rss_without_effects": 100.0, "noise_variance": 0.5}
    return {"case": "x", "model_parameters": model_parameters or {},
            "which": {"found_effects": list(dict.fromkeys(i["effect"] for i in items)), "chosen": items,
                      "equations": equations,
                      "steps": [{"candidates": sorted(every, key=lambda r: r["bic"]), "chosen": None,
                                 "reason": "BIC drop below 10"}]},
            "where": {"equations": {"states": {"omega": {"ratio_to_noise": 2.0}}}},
            "how_far": {"gap_before": gaps[0], "gap_after": gaps[1], "window_gap_before": gaps[2],
                        "window_gap_after": gaps[3]},
            "method": {"selection": {"min_bic_drop": 10.0}}}


def truth(effects: dict[str, dict], offsets: dict[str, float] | None = None) -> dict:
    return {"effects": [{"name": k, "parameters": v} for k, v in effects.items()],
            "parameter_offsets": OFFSETS if offsets is None else offsets,
            "nominal_parameters": {"J": J}, "pwm_frequency_hz": 1.0e4}


def draw(case: str, effects: dict[str, float], kind: str = "single") -> dict:
    return {"case": case, "seed": 0, "kind": kind, "stratum": 1 if kind == "single" else None,
            "effects": list(effects), "size_scales": effects, "size_range": [0.1, 3.0], "strata": 2,
            "offset_scale_range": [0.5, 1.5]}


COULOMB = {"coulomb_torque_nm": 0.04, "breakaway_torque_nm": 0.06, "stribeck_speed_rad_s": 3.0,
           "smoothing_speed_rad_s": 0.5}


def test_a_fitted_size_interval_is_checked_against_the_truth():
    """The 90 % interval of the fitted Coulomb level (x J) contains the bench's 0.04 N m in one case, not in the other."""
    def item(se):
        level = 0.042 / J
        return {"effect": "coulomb(omega)", "equation": "omega", "parameters": [
            {"name": "coulomb_level", "value": level, "interval_90": [level - 1.645 * se, level + 1.645 * se]}]}
    wide = score_case(record([item(10.0)]), truth({"coulomb_friction": COULOMB}), draw("c", {"coulomb_friction": 1.0}),
                      EXPECTED)
    assert wide["interval_covers_truth"] is True
    assert wide["effects_detail"][0]["interval_90"] == pytest.approx([0.042 - 1.645 * 10.0 * J, 0.042 + 1.645 * 10.0 * J])
    tight = score_case(record([item(1.0)]), truth({"coulomb_friction": COULOMB}), draw("c", {"coulomb_friction": 1.0}),
                       EXPECTED)
    assert tight["interval_covers_truth"] is False
    untold = score_case(record([chosen("coulomb(omega)", "omega", coulomb_level=0.042 / J)]),
                        truth({"coulomb_friction": COULOMB}), draw("c", {"coulomb_friction": 1.0}), EXPECTED)
    assert untold["interval_covers_truth"] is None
    coverage = aggregate([wide, tight, untold], {})["interval_coverage"]
    assert coverage == {"coulomb_friction": {"covered": 1, "n": 2}}


def test_a_true_offset_is_a_finding_and_an_extra_is_an_error():
    items = [chosen("coulomb(omega)", "omega", coulomb_level=0.042 / J),
             chosen("parameter(R)", "i_d", relative_error=0.036, corrected_value=0.0311),
             chosen("parameter(R)", "i_q", relative_error=0.05, corrected_value=0.0315)]
    row = score_case(record(items), truth({"coulomb_friction": COULOMB}), draw("c", {"coulomb_friction": 1.0}),
                     EXPECTED)
    assert row["exact"] is True and row["found_effects"] == ["coulomb_friction"] and row["extra_effects"] == []
    assert row["offsets_found"] == ["R"] and row["offsets_missed"] == ["L_d", "psi"]
    assert row["offset_errors_pct"]["R"] == pytest.approx(10.0)  # the top-ranked parameter(R): 0.036 vs 0.04
    assert row["parameter_error_pct"] == [pytest.approx(5.0)]
    assert row["shrink_factor"] == pytest.approx(6.0) and row["gap_shrink"] == pytest.approx(2.0)
    items.append(chosen("periodic(theta)", "omega", order=24, amplitude_24=10.0))
    items.append(chosen("parameter(L_q)", "i_q", relative_error=0.03, corrected_value=6.2e-5))  # not offset
    row = score_case(record(items), truth({"coulomb_friction": COULOMB}), draw("c", {"coulomb_friction": 1.0}),
                     EXPECTED)
    assert row["exact"] is False and row["extra_effects"] == ["cogging", "parameter(L_q)"]
    assert row["found_effects"] == ["coulomb_friction", "cogging", "parameter(L_q)"]
    none = score_case(record(items[1:3]), truth({}), draw("n", {}, kind="none"), EXPECTED)
    assert none["exact"] is True and none["true_effects"] == [] and none["where_correct"] is None
    missed = score_case(record(items[1:2]), truth({"coulomb_friction": COULOMB}), draw("c", {"coulomb_friction": 1}),
                        EXPECTED)
    assert missed["exact"] is False and missed["detected"] == [False] and missed["parameter_error_pct"] == ["missed"]


@pytest.mark.parametrize("effect, parameters, item, fitted", [
    ("viscous_friction", {"coefficient_nm_s": 3e-5}, chosen("viscous(omega)", "omega", coefficient=0.165), 3.3e-5),
    ("viscous_friction", {"coefficient_nm_s": 3e-5},
     chosen("parameter(b)", "omega", relative_error=1.5, corrected_value=5.0e-5), 3.0e-5),
    ("load_dependent_friction", {"coefficient_apply": 0.10, "coefficient_release": 0.06, "smoothing_speed_rad_s": 0.5},
     chosen("coulomb(omega)*|tau_load|", "omega", coefficient_positive=0.11 / J, coefficient_negative=0.07 / J), 0.09),
    ("cogging", {"harmonics": [{"order_per_rev": 24, "amplitude_nm": 0.012, "phase_rad": 0.0}]},
     chosen("periodic(theta)", "omega", order=12, amplitude_12=3.0, amplitude_24=0.0114 / J), 0.0114),
    ("inverter_deadtime", {"deadtime_s": 2e-7, "current_smoothing_a": 0.5},
     chosen("deadtime(d_a,d_b,d_c)", "i_q", duty_error=2.2e-3, current_scale_a=0.5), 2.2e-7),
    ("channel_time_offset", {"offset_s": -3e-5}, chosen("time_offset(d_a,d_b,d_c)", "i_d", offset_s=-2.7e-5), -2.7e-5),
    ("inertia_mismatch", {"scale": 0.95}, chosen("parameter(J)", "omega", relative_error=-0.045, corrected_value=0),
     -0.045),
])
def test_parameters_are_converted_to_the_bench_units(effect, parameters, item, fitted):
    row = score_case(record([item]), truth({effect: parameters}), draw("c", {effect: 1.0}), EXPECTED)
    true = row["true_size_parameters"][effect]["value"]
    assert row["fitted_size_parameters"][effect]["value"] == pytest.approx(fitted)
    assert row["parameter_error_pct"][0] == pytest.approx(abs(fitted - true) / abs(true) * 100)
    assert row["exact"] is True and row["where_correct"] is True


def test_an_estimate_with_its_rival_beside_is_scored_beside_the_named_one():
    """The viscous damping named as parameter(b) at +405 % (its extra damping 4x the true one) and at +151 % with the
    load's time offset beside it: both errors are scored, the aggregate and the per-effect table give both."""
    from hybridfmu_bench.withheld.report import per_effect_errors

    item = chosen("parameter(b)", "omega", relative_error=4.05, corrected_value=1.01e-4)
    item["rivals"] = [{"effect": "time_offset(tau_load)", "bic_drop": 795.0, "rejected_because": "small",
                       "values": {"relative_error": 1.51, "corrected_value": 5.02e-5}}]
    true = {"coefficient_nm_s": 2.2e-5}
    row = score_case(record([item]), truth({"viscous_friction": true}), draw("v", {"viscous_friction": 1.0}), EXPECTED)
    alone, beside = 1.01e-4 * 4.05 / 5.05, 5.02e-5 * 1.51 / 2.51
    assert row["fitted_size_parameters"]["viscous_friction"]["value"] == pytest.approx(alone)
    assert row["fitted_size_parameters"]["viscous_friction"]["with_rival"] == pytest.approx(beside)
    assert row["parameter_error_pct"] == [pytest.approx(abs(alone - 2.2e-5) / 2.2e-5 * 100)]
    assert row["parameter_error_with_rival_pct"] == [pytest.approx(abs(beside - 2.2e-5) / 2.2e-5 * 100)]
    plain = score_case(record([chosen("viscous(omega)", "omega", coefficient=0.11)]),
                       truth({"viscous_friction": true}), draw("w", {"viscous_friction": 1.0}), EXPECTED)
    assert plain["parameter_error_with_rival_pct"] == [None]
    row["effect_size"] = plain["effect_size"] = [0.5]
    measures = aggregate([row, plain], {"viscous_friction": {"reached": True, "limit": 0.1}})
    assert measures["n_with_rival"] == 1
    assert measures["median_parameter_error_with_rival_pct"] == pytest.approx(
        (row["parameter_error_with_rival_pct"][0] + plain["parameter_error_pct"][0]) / 2)
    table = per_effect_errors([row, plain])["viscous_friction"]
    assert table["n"] == 2 and table["n_with_rival"] == 1
    assert table["median"] == pytest.approx((row["parameter_error_pct"][0] + plain["parameter_error_pct"][0]) / 2)


def test_an_adjustment_is_no_finding():
    """A term fitted beside the named effects only to keep their estimates unbiased is neither a found effect nor an
    extra; named, the same term is an extra."""
    adjustment = {**chosen("coulomb(omega)", "omega", coulomb_level=0.01 / J), "role": "adjustment"}
    viscous = chosen("viscous(omega)", "omega", coefficient=0.15)
    case = (truth({"viscous_friction": {"coefficient_nm_s": 3e-5}}), draw("v", {"viscous_friction": 1.0}), EXPECTED)
    row = score_case(record([viscous, adjustment]), *case)
    assert row["exact"] is True and row["found_effects"] == ["viscous_friction"] and row["extra_effects"] == []
    named = score_case(record([viscous, {**adjustment, "role": "finding"}]), *case)
    assert named["exact"] is False and named["extra_effects"] == ["coulomb_friction"]
    unconfirmed = score_case(record([viscous, {**adjustment, "role": "unconfirmed"}]), *case)
    assert unconfirmed["exact"] is True and unconfirmed["extra_effects"] == []
    alone = score_case(record([{**viscous, "role": "unconfirmed"}]), *case)
    assert alone["detected"] == [False] and alone["parameter_error_pct"] == ["missed"]


def test_a_cogging_order_mismatch_and_a_sign_error_are_reported():
    cogging = {"harmonics": [{"order_per_rev": 36, "amplitude_nm": 0.012, "phase_rad": 0.0}]}
    row = score_case(record([chosen("periodic(theta)", "omega", order=12, amplitude_12=50.0, amplitude_24=3.0)]),
                     truth({"cogging": cogging}), draw("c", {"cogging": 1.0}), EXPECTED)
    assert row["parameter_error_pct"] == ["mismatch"] and row["detected"] == [True]
    assert "drawn 36, fitted [12, 24]" in row["fitted_size_parameters"]["cogging"]["note"]
    row = score_case(record([chosen("time_offset(d_a)", "i_q", offset_s=3e-5)]),
                     truth({"channel_time_offset": {"offset_s": -3e-5}}), draw("c", {"channel_time_offset": 1.0}),
                     EXPECTED)
    assert row["parameter_error_pct"] == [pytest.approx(200.0)]


def test_where_correct_needs_the_equation_the_effect_acts_on():
    offset = {"channel_time_offset": {"offset_s": 3e-5}}
    wrong = score_case(record([chosen("time_offset(tau_load)", "omega", offset_s=1e-3)]), truth(offset),
                       draw("c", {"channel_time_offset": 1.0}), EXPECTED)
    assert wrong["detected"] == [True] and wrong["where_correct"] is False and wrong["named_in"] == ["omega"]
    both = score_case(record([chosen("time_offset(tau_load)", "omega", offset_s=1e-3),
                              chosen("time_offset(d_a,d_b,d_c)", "i_q", offset_s=3.3e-5)]), truth(offset),
                      draw("c", {"channel_time_offset": 1.0}), EXPECTED)
    assert both["where_correct"] is True and both["named_in"] == ["i_q,omega"]
    assert both["parameter_error_pct"] == [pytest.approx(10.0)]  # from the one named where it acts


def test_effect_size_is_the_root_of_the_best_first_step_improvement_of_the_matching_candidates():
    rec = record([], first_step={"omega": {"coulomb(omega)": 0.16, "coulomb(omega)*|tau_load|": 0.5},
                                 "i_q": {"time_offset(d_a)": 0.09, "time_offset(d_a,d_b,d_c)": 0.25}})
    assert effect_size(rec, ["coulomb(omega)"]) == pytest.approx(0.4)
    assert effect_size(rec, ["time_offset(*)"]) == pytest.approx(0.5)
    assert effect_size(rec, ["periodic(theta)"]) is None
    pair = score_case(rec, truth({"channel_time_offset": {"offset_s": 1e-5}, "coulomb_friction": COULOMB}),
                      draw("p", {"channel_time_offset": 0.5, "coulomb_friction": 2.0}, kind="pair"), EXPECTED)
    assert pair["effect_size"] == [pytest.approx(0.5), pytest.approx(0.4)]  # in the order of true_effects
    assert pair["true_effects"] == ["channel_time_offset", "coulomb_friction"] and pair["size_scale"] == [0.5, 2.0]


def test_detection_limit():
    assert detection_limit([(0.01, False), (0.05, True), (0.03, False), (0.2, True), (0.1, True)])["limit"] == 0.05
    # a detection below a miss does not count: every case above the limit is detected
    out = detection_limit([(0.01, True), (0.03, False), (0.2, True), (0.1, True)])
    assert out["limit"] == 0.1 and out["largest_missed"] == 0.03 and out["n_detected"] == 3
    out = detection_limit([(0.3, True), (0.5, True), (None, False)])
    assert out["limit"] == 0.3 and out["all_detected"] and out["n"] == 2
    out = detection_limit([(0.1, True), (0.9, False)])
    assert out["reached"] is False and out["limit"] is None
    assert detection_limit([])["reached"] is False


def _row(case, kind, effects, sizes, detected, exact, errors=None, shrink=4.0):
    return {"case": case, "kind": kind, "true_effects": effects, "effect_size": sizes, "detected": detected,
            "size_scale": [1.0] * len(effects), "exact": exact, "where_correct": all(detected) if effects else None,
            "parameter_error_pct": errors or [5.0] * len(effects), "shrink_factor": shrink, "gap_shrink": 2.0,
            "found_effects": [e for e, d in zip(effects, detected) if d], "offsets_true": {}, "offsets_found": []}


def test_aggregate_judges_the_cases_above_the_limits():
    rows = [_row("a1", "single", ["cogging"], [0.05], [False], False, ["missed"]),
            _row("a2", "single", ["cogging"], [0.3], [True], True, [10.0], 5.0),
            _row("a3", "single", ["cogging"], [0.6], [True], False, [30.0], 2.0),
            _row("b1", "single", ["inertia_mismatch"], [0.5], [False], False, ["missed"]),
            _row("p1", "pair", ["cogging", "inertia_mismatch"], [0.4, 0.9], [True, False], False),
            _row("p2", "pair", ["cogging", "cogging"], [0.4, 0.4], [True, True], True, [4.0, "mismatch"], 3.5),
            _row("n1", "none", [], [], [], True, shrink=None), _row("n2", "none", [], [], [], False, shrink=None)]
    limits = detection_limits(rows)
    assert limits["cogging"]["limit"] == 0.3 and limits["cogging"]["size_scale_at_limit"] == 1.0
    assert limits["inertia_mismatch"]["reached"] is False
    assert [r["case"] for r in rows if above_limits(r, limits)] == ["a2", "a3", "p2"]
    measures = aggregate(rows, limits, {"exact_set_accuracy": 0.6})
    assert measures["exact_set_accuracy"] == pytest.approx(2 / 3) and measures["n_mismatches"] == 1
    assert measures["median_parameter_error_pct"] == pytest.approx(10.0)  # of 10, 30, 4
    assert measures["median_windowed_shrink"] == pytest.approx(3.5)
    assert measures["fraction_windowed_shrink_at_target"] == pytest.approx(2 / 3)
    assert measures["verdicts"] == {"exact_set_accuracy": True, "median_parameter_error_pct": True,
                                    "windowed_shrink": True, "none_names_nothing": False}
    labels, matrix = confusion_matrix(rows)
    assert labels == ["cogging", "inertia_mismatch", "none"]
    assert matrix[labels.index("cogging"), labels.index("none")] == 1
    assert matrix[labels.index("inertia_mismatch"), labels.index("none")] == 2


def test_rejected_candidates_report_the_margins_against_the_thresholds():
    rec = record([])
    rec["which"]["equations"] = {"i_d": {}, "omega": {}}
    rec["which"]["steps"] = [
        {"chosen": "parameter(R)", "reason": "accepted",
         "candidates": [{"effect": "parameter(R)", "equations": ["i_d", "i_q"], "rss": 120.0, "bic": 50.0,
                         "bic_drop": 30.0, "relative_improvement": 0.4, "rejected_because": None}]},
        {"chosen": None, "reason": "BIC drop 2.0 below 10.0",
         "candidates": [{"effect": "parameter(psi)", "equations": ["i_q", "omega"], "rss": 119.0, "bic": 40.0,
                         "relative_improvement": 0.01, "within_tolerance": True},
                        {"effect": "coulomb(omega)", "equations": ["omega"], "rss": 116.0, "bic": 44.0,
                         "bic_drop": 6.0, "relative_improvement": 0.02, "explained_share": 0.01,
                         "explained_to_noise": 0.2, "rejected_because": "BIC drop 6.0 below 10.0"},
                        {"effect": "viscous(i_d)", "equations": ["i_d"], "rss": 114.0, "bic": 46.0, "bic_drop": 4.0,
                         "relative_improvement": 0.05, "explained_share": 0.03, "explained_to_noise": 0.15,
                         "rejected_because": "BIC drop 4.0 below 10.0"}]}]
    by_equation = {row["equation"]: row for row in rejected_candidates(rec)}
    row = by_equation["i_d"]
    assert row["effect"] == "viscous(i_d)" and row["chosen_before"] == ["parameter(R)"]
    assert row["bic_drop"] == pytest.approx(4.0) and row["relative_improvement"] == pytest.approx(0.05)
    assert row["explained_share"] == pytest.approx(0.03) and row["explained_to_noise"] == pytest.approx(0.15)
    assert row["reason"] == "BIC drop 4.0 below 10.0"
    row = by_equation["omega"]  # the parameter error within tolerance is not weighed
    assert row["effect"] == "coulomb(omega)" and row["bic_drop"] == pytest.approx(6.0)
    accepted = record([])
    accepted["which"]["steps"] = rec["which"]["steps"][:1]
    (row,) = rejected_candidates(accepted)
    assert row["effect"] is None and "max_effects_per_equation" in row["reason"]


def test_summary_files_from_synthetic_cases(tmp_path):
    cases = {"s0__single_coulomb_friction__size1": (0.01, None), "s0__single_coulomb_friction__size2": (0.16, 0.04),
             "s1__single_coulomb_friction__size1": (0.25, 0.05), "s0__none": (None, None)}
    paths = {"d": [], "t": [], "w": []}
    for name, (improvement, torque) in cases.items():
        effects = {} if name.endswith("none") else \
            {"coulomb_friction": dict(COULOMB, coulomb_torque_nm=torque or 0.005)}
        items = [chosen("coulomb(omega)", "omega", coulomb_level=1.05 * torque / J)] if torque else []
        items.append(chosen("parameter(R)", "i_q", relative_error=0.04, corrected_value=0.0312))
        first = {"omega": {"coulomb(omega)": improvement or 0.001, "coulomb(omega)*|tau_load|": 0.3}}
        for key, data in (("d", record(items, first)), ("t", truth(effects)),
                          ("w", draw(name, {e: 1.0 for e in effects}, "none" if not effects else "single"))):
            paths[key].append(tmp_path / f"{name}.{key}.json")
            write_json_atomic(paths[key][-1], data)
    out = summarise(list(cases), paths["d"], paths["t"], paths["w"], tmp_path / "summary.csv",
                    tmp_path / "confusion.png", tmp_path / "detection.png", tmp_path / "summary.md", EXPECTED)
    assert out["limits"]["coulomb_friction"]["limit"] == pytest.approx(0.4)
    assert out["measures"]["exact_set_accuracy"] == 1.0 and out["measures"]["verdicts"]["none_names_nothing"]
    with open(tmp_path / "summary.csv") as handle:
        table = list(csv.DictReader(handle))
    assert [r["case"] for r in table] == list(cases)
    assert {"case", "seed", "true_effects", "found_effects", "exact", "effect_size", "parameter_error_pct",
            "shrink_factor", "gap_shrink", "offsets_found", "where_correct"} <= set(table[0])
    assert table[1]["effect_size"] == "0.4" and table[1]["parameter_error_pct"] == "5"
    assert table[0]["parameter_error_pct"] == "missed" and table[3]["true_effects"] == ""
    for figure in ("confusion.png", "detection.png"):
        assert (tmp_path / figure).stat().st_size > 5000
    text = (tmp_path / "summary.md").read_text()
    assert not text.startswith("#") and "| coulomb_friction | 3 | 2/3 | 0.4 |" in text
    assert "| exact set of named effects" in text and "met" in text and "False alarms" in text
    assert "coulomb(omega)*\\|tau_load\\|" in text  # the strongest rejected candidate, escaped for the table
    readme = "intro\n<!-- measured:withheld -->\nold\n<!-- /measured:withheld -->\n"
    assert text.strip() in replace_block(readme, "withheld", text)


def test_limits_come_from_the_calibration_seeds_and_the_evaluation_seeds_are_only_scored(tmp_path):
    """Seed 0 calibrates, seed 1 evaluates: the limit is seed 0's alone (seed 1's small detected case would lower it),
    seed 1's cases are judged against it, and the summary reports both splits and says which is out of sample."""
    cases = {"s0__single_coulomb_friction__size1": (0.04, None), "s0__single_coulomb_friction__size2": (0.25, 0.05),
             "s0__none": (None, None), "s1__single_coulomb_friction__size1": (0.01, 0.002),
             "s1__single_coulomb_friction__size2": (0.36, 0.06), "s1__none": (None, None)}
    paths = {"d": [], "t": [], "w": []}
    for name, (improvement, torque) in cases.items():
        effects = {} if name.endswith("none") else \
            {"coulomb_friction": dict(COULOMB, coulomb_torque_nm=torque or 0.005)}
        items = [chosen("coulomb(omega)", "omega", coulomb_level=torque / J)] if torque else []
        first = {"omega": {"coulomb(omega)": improvement or 0.001}}
        drawn = {**draw(name, {e: 1.0 for e in effects}, "none" if not effects else "single"),
                 "seed": int(name.split("__")[0][1:])}
        for key, data in (("d", record(items, first)), ("t", truth(effects)), ("w", drawn)):
            paths[key].append(tmp_path / f"{name}.{key}.json")
            write_json_atomic(paths[key][-1], data)
    out = summarise(list(cases), paths["d"], paths["t"], paths["w"], tmp_path / "summary.csv",
                    tmp_path / "confusion.png", tmp_path / "detection.png", tmp_path / "summary.md", EXPECTED,
                    calibration_seeds=[0], headline_path=tmp_path / "headline.md")
    assert out["limits"]["coulomb_friction"]["limit"] == pytest.approx(0.5)  # seed 0: missed 0.2, detected 0.5
    assert [r["split"] for r in out["rows"]] == ["calibration"] * 3 + ["evaluation"] * 3
    assert [r["above_limit"] for r in out["rows"]] == [False, True, False, False, True, False]
    evaluation = out["by_split"]["evaluation"]
    assert out["measures"] is evaluation and evaluation["above_cases"] == ["s1__single_coulomb_friction__size2"]
    assert evaluation["exact_set_accuracy"] == 1.0 and evaluation["exact_set_accuracy_all"] == 1.0
    assert out["by_split"]["calibration"]["exact_set_accuracy_all"] == pytest.approx(0.5)
    assert {a["case"] for a in out["alarms"]} <= {"s0__none"}  # the thresholds' evidence: calibration seeds only
    with open(tmp_path / "summary.csv") as handle:
        table = list(csv.DictReader(handle))
    assert [(r["split"], r["above_limit"]) for r in table][3:5] == [("evaluation", "False"), ("evaluation", "True")]
    text = (tmp_path / "summary.md").read_text()
    assert "Seeds 0 calibrate" in text and "Seeds 1 evaluate" in text and "out of sample" in text
    assert "| measure | calibration seeds | evaluation seeds | target | verdict |" in text
    # the per-effect parameter errors judge the evaluation seeds' cases above the limits: seed 1's 0.06 N m, exact
    per_effect = [line for line in text.splitlines() if line.startswith("| coulomb_friction | 1 | ")]
    assert len(per_effect) == 1 and per_effect[0].endswith(" | 0 |")   # one estimate, no rival
    # the README's short account: the same rows of the same measures, both splits, said which one is out of sample
    headline = (tmp_path / "headline.md").read_text()
    assert "6 emulated cases" in headline and "seeds 1 are scored with them (out of sample" in headline
    table_rows = [line for line in headline.splitlines() if line.startswith("| exact set")]
    assert len(table_rows) == 2 and all(line in text for line in table_rows)
    assert "| exact set of named effects, every case with effects (no limit applied) | 50 % (1/2) | 100 % (2/2) |" \
        in headline
    assert "every case with effects (no limit applied) | 50 % (1/2) | 100 % (2/2) |" in text
    with pytest.raises(ValueError, match="calibration_seeds: \\[5\\]"):
        summarise(list(cases), paths["d"], paths["t"], paths["w"], tmp_path / "s.csv", tmp_path / "c.png",
                  tmp_path / "d.png", tmp_path / "s.md", EXPECTED, calibration_seeds=[5])


def test_every_seed_calibrates_unless_other_seeds_are_named():
    assert split_seeds([0, 1, 2], None) == {0: "calibration", 1: "calibration", 2: "calibration"}
    assert split_seeds([0, 1, 2], [2]) == {0: "evaluation", 1: "evaluation", 2: "calibration"}


def test_a_background_condition_named_is_no_extra_but_a_withheld_effect_of_the_same_form_counts_first():
    """A sensor lag present in every case (withheld.background) is a finding, not an extra; without the table it
    is an extra; a name that matches a withheld effect's pattern counts for that effect first."""
    background = {"pressure_sensor_lag": ["time_offset(tau_load)", "input_lag(tau_load)"]}
    items = [chosen("input_lag(tau_load)", "omega", lag_s=0.0015)]
    none_truth, none_draw = truth({}), draw("n", {}, kind="none")
    row = score_case(record(items), none_truth, none_draw, EXPECTED, background)
    assert row["exact"] is True and row["background_found"] == ["pressure_sensor_lag"] and row["extra_effects"] == []
    row = score_case(record(items), none_truth, none_draw, EXPECTED)
    assert row["exact"] is False and row["extra_effects"] == ["input_lag(tau_load)"]
    offset = {"offset_s": 3.0e-5}
    items = [chosen("time_offset(tau_load)", "i_q", offset_s=2.9e-5)]
    row = score_case(record(items), truth({"channel_time_offset": offset}),
                     draw("t", {"channel_time_offset": 1.0}), EXPECTED, background)
    assert row["found_effects"] == ["channel_time_offset"] and row["background_found"] == []


def test_effect_size_of_a_calibrated_parameter_comes_from_its_calibration_record():
    rec = record([], first_step={"omega": {"viscous(omega)": 0.04}})
    assert effect_size(rec, ["parameter(J)"]) is None
    rec["which"]["calibration"] = [{"effect": "parameter(J)", "relative_improvement": 0.36, "outcome": "kept"},
                                   {"effect": "parameter(b)", "relative_improvement": None,
                                    "outcome": "exchanged for time_offset(tau_load)"}]
    assert effect_size(rec, ["parameter(J)"]) == pytest.approx(0.6)
    assert effect_size(rec, ["viscous(omega)", "parameter(b)"]) == pytest.approx(0.2)
    rec["which"]["calibration"][0]["relative_improvement"] = 1.03  # the other equations' gain counted too
    assert effect_size(rec, ["parameter(J)"]) == 1.0


def _three_case_summaries(tmp_path, extras: dict[str, dict]):
    """Write a three-case suite (two single Coulomb cases on seeds 0 and 1, a none case) whose diagnosis records
    carry ``extras[case]`` (e.g. their ``code``), and return a function that summarises a list of its cases and
    gives back (summary.md, headline.md)."""
    paths = {"d": [], "t": [], "w": []}
    for name, extra in extras.items():
        effects = {} if name.endswith("none") else {"coulomb_friction": dict(COULOMB)}
        items = [chosen("coulomb(omega)", "omega", coulomb_level=0.04 / J)] if effects else []
        drawn = {**draw(name, {e: 1.0 for e in effects}, "none" if not effects else "single"),
                 "seed": int(name.split("__")[0][1:])}
        for key, data in (("d", {**record(items, {"omega": {"coulomb(omega)": 0.3}}), **extra}),
                          ("t", truth(effects)), ("w", drawn)):
            paths[key].append(tmp_path / f"{name}.{key}.json")
            write_json_atomic(paths[key][-1], data)

    def summaries(names):
        index = [list(extras).index(n) for n in names]
        summarise(names, *([paths[k][i] for i in index] for k in "dtw"), tmp_path / "summary.csv",
                  tmp_path / "confusion.png", tmp_path / "detection.png", tmp_path / "summary.md", EXPECTED,
                  headline_path=tmp_path / "headline.md")
        return (tmp_path / "summary.md").read_text(), (tmp_path / "headline.md").read_text()

    return summaries


def test_the_summaries_name_the_code_of_the_diagnoses_and_warn_when_a_resumed_run_mixes_two(tmp_path):
    """Every case's diagnosis records its code; one version is named, two (a run resumed across a code change) are
    a warning in the summary and in the README's short account."""
    old, new = {"version": "0.1.0", "commit": "a" * 40, "modified": False}, {"version": "0.1.0", "commit": "b" * 40}
    assert code_versions({"x": {"code": new}, "y": {"code": old}, "z": {"code": new}}) == {"b" * 10: 2, "a" * 10: 1}
    assert code_sentence({"b" * 10: 3}) == f"Every case was diagnosed by the code at {'b' * 10}."
    assert "do not record" in code_sentence(code_versions({"x": {}}))
    cases = {"s0__single_coulomb_friction__size1": new, "s0__none": new, "s1__single_coulomb_friction__size1": old}
    summaries = _three_case_summaries(tmp_path, {name: {"code": code} for name, code in cases.items()})

    for text in summaries(list(cases)[:2]):
        assert f"Every case was diagnosed by the code at {'b' * 10}." in text and "WARNING" not in text
    for text in summaries(list(cases)):
        assert "WARNING: the cases were diagnosed by 2 versions of the code" in text
        assert f"{'b' * 10}: 2 cases, {'a' * 10}: 1 case)" in text


def test_the_summaries_warn_when_the_cases_were_diagnosed_with_different_settings(tmp_path):
    """Each diagnosis records the digest of the diagnosis section it was asked for; a suite whose cases carry two
    (a suite resumed after a change of the section, or cases copied from another suite) says so in its summary and
    in the README's short account, naming each group; records from before the digest are not counted."""
    from hybridfmu.diagnosis.report import settings_digest

    old, new = {"open_loop": {"window_s": 0.12}, "kernel_s": None}, {"kernel_s": None, "open_loop": {}}
    assert settings_digest(new) == settings_digest({"open_loop": {}, "kernel_s": None}) != settings_digest(old)
    assert len(settings_digest(new)) == 12
    digests = {"x": settings_digest(new), "y": settings_digest(old), "z": settings_digest(new)}
    groups = settings_versions({case: {"settings_digest": d} for case, d in digests.items()})
    assert groups == {settings_digest(new): ["x", "z"], settings_digest(old): ["y"]}
    assert settings_sentence({settings_digest(new): ["x", "z"]}) == ""
    assert settings_sentence(settings_versions({"x": {"settings_digest": "abc"}, "y": {}})) == ""
    text = settings_sentence(groups)
    assert text.startswith("**WARNING: the cases were diagnosed with 2 different diagnosis settings**")
    assert f"{settings_digest(new)}: 2 cases (e.g. x); {settings_digest(old)}: 1 case (e.g. y)" in text
    cases = {"s0__single_coulomb_friction__size1": new, "s0__none": new, "s1__single_coulomb_friction__size1": old}
    summaries = _three_case_summaries(tmp_path, {name: {"settings_digest": settings_digest(section)}
                                                 for name, section in cases.items()})

    for text in summaries(list(cases)[:2]):
        assert "different diagnosis settings" not in text
    for text in summaries(list(cases)):
        assert "WARNING: the cases were diagnosed with 2 different diagnosis settings" in text
