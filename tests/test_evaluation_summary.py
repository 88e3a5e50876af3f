"""The documentation's measured figures: rendered from a run's metrics and diagnosis, copied between markers."""

import numpy as np
import pytest

from hybridfmu.evaluation.measured_blocks import check_documents, main, replace_block, update_documents
from hybridfmu.evaluation.summary import case_summary

TEST_METRICS = {"maneuvers": ["test"], "duration_s": 4092.0, "signals": ["level"],
                "fmu": {"level_rmse": 0.76, "level_mae": 0.58}, "neural_fmu": {"level_rmse": 0.38, "level_mae": 0.3}}
DIAGNOSIS = {"which": {"found_effects": ["saturation_above(x2)"]},
             "how_far": {"before": {"level_rmse": 0.76}, "after": {"level_rmse": 0.19, "level_mae": 0.1}}}


def test_summary_quotes_each_model_with_its_factor_against_the_fmu():
    text = case_summary("tanks", TEST_METRICS, DIAGNOSIS, {"level": "V"})
    assert "| level | FMU | 0.76 V | 0.58 V | ×1 | ×1 |" in text
    assert "| level | neural FMU | 0.38 V | 0.3 V | ×1.93 | ×4 |" in text
    assert "| level | FMU + diagnosed effects (saturation_above(x2)) | 0.19 V | 0.1 V | ×5.8 | ×16 |" in text
    assert "listed by their rank in the diagnosis (drop-one score" in text


def test_summary_says_when_the_effects_were_recalibrated_with_the_fmu():
    refitted = {**DIAGNOSIS, "how_far": {**DIAGNOSIS["how_far"], "steps": [{"model": "FMU", "refit": {}}]}}
    text = case_summary("tanks", TEST_METRICS, refitted, {"level": "V"})
    assert "| level | FMU + diagnosed effects, recalibrated (saturation_above(x2)) | 0.19 V |" in text


def test_summary_names_the_terms_the_model_carries_without_naming_them():
    """The FMU + diagnosed effects row lists every term of that model: the named effects, then the adjustments and
    the unconfirmed terms, each with its role (the model carries them, the diagnosis does not name them)."""
    chosen = [{"effect": "overflow(x1->x2)", "role": "finding"}, {"effect": "time_offset(u)", "role": "adjustment"},
              {"effect": "parameter(k2)", "role": "unconfirmed"}, {"effect": "parameter(k3)", "role": "unconfirmed"}]
    diagnosis = {**DIAGNOSIS, "which": {"found_effects": ["overflow(x1->x2)"], "chosen": chosen}}
    text = case_summary("tanks", TEST_METRICS, diagnosis, {"level": "V"})
    assert ("| level | FMU + diagnosed effects (overflow(x1->x2); also in the model, not named: time_offset(u) "
            "(adjustment), parameter(k2) (unconfirmed), parameter(k3) (unconfirmed)) | 0.19 V |") in text
    only_unconfirmed = {**DIAGNOSIS, "which": {"found_effects": [], "chosen": chosen[2:3]}}
    assert "FMU + diagnosed effects (also in the model, not named: parameter(k2) (unconfirmed)) |" in \
        case_summary("tanks", TEST_METRICS, only_unconfirmed, {"level": "V"})


def test_summary_without_diagnosis_has_no_corrected_row():
    text = case_summary("tanks", TEST_METRICS, None, {"level": "V"})
    assert "diagnosed" not in text and text.count("| level |") == 2 and "rank" not in text


def test_readme_block_is_replaced_between_its_markers_only(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- measured:tanks -->\nold 1.0\n<!-- /measured:tanks -->\nrest\n")
    case_dir = tmp_path / "results" / "tanks"
    case_dir.mkdir(parents=True)
    (case_dir / "summary.md").write_text("new 2.0\n")
    assert update_documents([readme], [case_dir]) == [readme]
    assert readme.read_text() == "intro\n<!-- measured:tanks -->\nnew 2.0\n<!-- /measured:tanks -->\nrest\n"


def test_missing_markers_and_missing_summary_are_named(tmp_path):
    with pytest.raises(ValueError, match="measured:ipb"):
        replace_block("no markers here", "ipb", "x")
    readme = tmp_path / "README.md"
    readme.write_text("<!-- measured:ipb -->\n<!-- /measured:ipb -->\n")
    with pytest.raises(FileNotFoundError, match="summary.md"):
        update_documents([readme], [tmp_path / "ipb"])


def test_a_benchmark_block_is_copied_from_its_file(tmp_path):
    """``--block NAME=FILE``: a benchmark script's Markdown goes into the README's block NAME; a missing file is
    named and leaves the README as it was."""
    readme = tmp_path / "README.md"
    original = "a\n<!-- measured:workflow_wall -->\nold\n<!-- /measured:workflow_wall -->\nb\n"
    readme.write_text(original)
    with pytest.raises(FileNotFoundError, match="wall.md"):
        main(["--docs", str(readme), "--block", f"workflow_wall={tmp_path / 'wall.md'}"])
    assert readme.read_text() == original
    (tmp_path / "wall.md").write_text("| commit | wall time |\n| abc | 9.5 min |\n")
    assert main(["--docs", str(readme), "--block", f"workflow_wall={tmp_path / 'wall.md'}"]) == 0
    assert readme.read_text() == ("a\n<!-- measured:workflow_wall -->\n| commit | wall time |\n| abc | 9.5 min |\n"
                                  "<!-- /measured:workflow_wall -->\nb\n")
    with pytest.raises(SystemExit):
        main(["--docs", str(readme), "--block", "no-equals-sign"])


def test_summary_quotes_the_learned_delays_beside_the_truth(tmp_path):
    import json

    from hybridfmu.evaluation.summary import write_case_summary
    from test_evaluation_baseline import motor_roles

    metrics = {**TEST_METRICS, "dt_s": {"duties": 2.4e-5, "rest": 1e-6}}
    paths = {name: tmp_path / f"{name}.json" for name in ("metrics", "best", "offset", "truth")}
    paths["metrics"].write_text(json.dumps(metrics))
    paths["best"].write_text(json.dumps({"model_spec": {"delay_groups": {
        "duties": ["d_a", "d_b", "d_c"], "rest": ["u_dc", "tau_load"]}}}))
    paths["offset"].write_text(json.dumps({"groups": {"duties": {"delay_s": 2.7e-5}, "rest": {"delay_s": 0.0}}}))
    paths["truth"].write_text(json.dumps({"time_offset": {"input_delay_s": 3e-5,
                                                          "channels": ["DUTY_A", "DUTY_B", "DUTY_C"]}}))
    out = write_case_summary(tmp_path / "summary.md", "ipb", paths["metrics"], None, {"level": "V"},
                             best_path=paths["best"], time_offset_path=paths["offset"],
                             truth_paths=[str(paths["truth"])], roles=motor_roles())
    text = out.read_text()
    assert "| duties | 24.00 µs | 27.00 µs | 30.00 µs | -6.00 µs |" in text
    assert "| rest | 1.00 µs | 0.00 µs | 0.00 µs | +1.00 µs |" in text
    # without the run's files the summary has no delay table
    plain = write_case_summary(tmp_path / "plain.md", "ipb", paths["metrics"], None, {"level": "V"})
    assert "learned" not in plain.read_text().lower()


def test_check_names_a_block_edited_by_hand_and_changes_nothing(tmp_path, capsys):
    """``--check``: a README that quotes its run as written passes; one number typed over fails, naming the
    block, its file and the changed line; the README itself is never written."""
    readme = tmp_path / "README.md"
    case_dir = tmp_path / "results" / "tanks"
    case_dir.mkdir(parents=True)
    (case_dir / "summary.md").write_text("| level | FMU | 0.76 V |\n| level | hybrid | 0.38 V |\n")
    (tmp_path / "wall.md").write_text("| abc | 9.5 min |\n")
    readme.write_text("a\n<!-- measured:tanks -->\nold\n<!-- /measured:tanks -->\n"
                      "<!-- measured:wall -->\nold\n<!-- /measured:wall -->\nb\n")
    args = ["--docs", str(readme), str(case_dir), "--block", f"wall={tmp_path / 'wall.md'}"]
    assert main(args + ["--check"]) == 1
    assert "'tanks' differs" in capsys.readouterr().out
    assert main(args) == 0
    written = readme.read_text()
    assert check_documents([readme], [case_dir], {"wall": tmp_path / "wall.md"}) == (2, [])
    assert main(args + ["--check"]) == 0
    assert "2 of 2 block(s)" in capsys.readouterr().out
    readme.write_text(written.replace("0.38 V", "0.30 V"))
    count, differences = check_documents([readme], [case_dir], {"wall": tmp_path / "wall.md"})
    assert len(differences) == 1 and "block 'tanks'" in differences[0] and str(case_dir / "summary.md") in differences[0]
    assert "-| level | hybrid | 0.30 V |" in differences[0] and "+| level | hybrid | 0.38 V |" in differences[0]
    before = readme.read_text()
    assert main(args + ["--check"]) == 1
    assert readme.read_text() == before
    other_case = tmp_path / "results" / "ipb"
    other_case.mkdir()
    (other_case / "summary.md").write_text("x\n")
    with pytest.raises(ValueError, match="measured:ipb"):
        check_documents([readme], [other_case])


def test_summary_tables_the_closed_loop_errors_when_the_metrics_have_them():
    from hybridfmu.evaluation.comparison import ManeuverRun, role_metrics

    t = np.linspace(0.0, 1.0, 11)
    data = np.column_stack([np.linspace(0, 2, 11), np.full(11, 2.0)])
    runs = [ManeuverRun(name, t, ["angle", "speed"], data, data + 1.0, data + 0.5,
                        closed_loop={"fmu": data + 0.01, "neural_fmu": data + offset})
            for name, offset in (("a", 0.002), ("b", 0.004))]
    metrics = role_metrics("test", runs, {"length_s": 0.5}, {})
    text = case_summary("demo", metrics, None, {"angle": "rad", "speed": "rad/s"})
    assert "and in closed loop (driven by the case's control software" in text
    assert "| model | angle closed-loop MAE (rad) | speed closed-loop MAE (rad/s) |" in text
    assert "| neural FMU | 0.003 [0.002 – 0.004] | 0.003 [0.002 – 0.004] |" in text
    open_only = role_metrics("test", [ManeuverRun("a", t, ["angle", "speed"], data, data + 1.0, data + 0.5)],
                             {"length_s": 0.5}, {})
    assert "closed" not in case_summary("demo", open_only, None, {"angle": "rad", "speed": "rad/s"})


def test_blocks_are_found_in_whichever_document_holds_them_and_only_in_one(tmp_path):
    """A case's block goes into the page that has its markers (README or docs/), its pooled seed study into
    ``<case>_robustness``; a block opened in two documents, or in none, is an error naming them, and nothing
    is written."""
    readme, docs = tmp_path / "README.md", tmp_path / "docs"
    docs.mkdir()
    readme.write_text("top\n<!-- measured:wall -->\n<!-- /measured:wall -->\n")
    page = docs / "results.md"
    page.write_text("<!-- measured:ipb -->\nold\n<!-- /measured:ipb -->\n"
                    "<!-- measured:ipb_robustness -->\n<!-- /measured:ipb_robustness -->\n")
    case_dir = tmp_path / "results" / "ipb"
    (case_dir / "robustness").mkdir(parents=True)
    (case_dir / "summary.md").write_text("one seed\n")
    (case_dir / "robustness" / "summary.md").write_text("three seeds\n")
    (tmp_path / "wall.md").write_text("28 min\n")
    written = update_documents([readme, docs], [case_dir], {"wall": tmp_path / "wall.md"})
    assert sorted(written) == sorted([readme, page])
    assert "one seed" in page.read_text() and "three seeds" in page.read_text() and "28 min" in readme.read_text()
    assert update_documents([readme, docs], [case_dir], {"wall": tmp_path / "wall.md"}) == []  # nothing changed
    (docs / "other.md").write_text("<!-- measured:wall -->\n<!-- /measured:wall -->\n")
    before = page.read_text()
    with pytest.raises(ValueError, match="in .*README.md and again in .*other.md"):
        update_documents([readme, docs], [case_dir], {"wall": tmp_path / "wall.md"})
    (docs / "other.md").unlink()
    (tmp_path / "bench.md").write_text("x\n")
    with pytest.raises(ValueError, match="block\\(s\\) bench"):
        update_documents([readme, docs], [case_dir], {"bench": tmp_path / "bench.md"})
    assert page.read_text() == before


def _distribution(median, low, high, n=6):
    return {"median": median, "min": low, "max": high, "n": n}


def test_the_headline_tables_every_case_from_its_pooled_or_single_run(tmp_path):
    """The README's results table: a case with a seed study is quoted over every (seed, maneuver), one without
    from its run's test metrics; each case's caveats (models worse than their physics, the reference) follow;
    a case folder without either file is named."""
    import json

    from hybridfmu.evaluation.headline import headline_markdown

    pooled_dir, single_dir = tmp_path / "ipb", tmp_path / "tanks"
    (pooled_dir / "robustness").mkdir(parents=True)
    (single_dir / "metrics").mkdir(parents=True)
    models = {m: {"angle_mae_factor": _distribution(f, f / 2, f * 3, 12), "in_tolerance_share": _distribution(0.8, 0.5, 1.0)}
              for m, f in (("neural_fmu", 6.7), ("fmu_effects", 4.96), ("hybrid", 5.42), ("ceiling", 2e4))}
    (pooled_dir / "robustness" / "summary.json").write_text(json.dumps({
        "seeds": [1, 2], "maneuvers": ["a", "b", "c"], "signals": ["angle"], "models": models,
        "hybrid_worse_than_fmu_effects": [{"seed": 1, "maneuver": "a", "signal": "angle"}],
        "reference_name": "paper", "reference": [{"metric": "angle_mae", "factor": 5.4, "neural_fmu_median": 6.7,
                                                  "reached": True}]}))
    (single_dir / "metrics" / "test.json").write_text(json.dumps({
        "signals": ["level"], "maneuvers": ["test"], "warnings": ["test: hybrid is worse than fmu_effects"],
        "distribution": {"fmu": {"level_mae": _distribution(0.5, 0.5, 0.5, 1)},
                         "neural_fmu": {"level_mae_factor": _distribution(1.37, 1.37, 1.37, 1)},
                         "hybrid": {"level_mae_factor": _distribution(1.98, 1.98, 1.98, 1)}}}))
    text = headline_markdown([pooled_dir, single_dir])
    assert "| `ipb` | 3 test maneuvers × 2 seeds | angle MAE vs FMU | ×6.7 [×3.35 – ×20.1] | ×4.96 [×2.48 – ×14.9] |" in text
    assert "|  |  | within tolerance | 80 % [50 % – 100 %] |" in text
    assert "| `tanks` | 1 test maneuver | level MAE vs FMU | ×1.37 | – | ×1.98 | – |" in text
    assert "in 1 of 6 (seed, maneuver, signal)" in text and "×6.7 against the reference's ×5.4 (paper): reached" in text
    assert "1 warning(s) of a model worse than its own physics on a test maneuver: test: hybrid" in text
    with pytest.raises(FileNotFoundError, match="robustness/summary.json.*metrics/test.json"):
        headline_markdown([tmp_path / "empty"])
    readme = tmp_path / "README.md"
    readme.write_text("<!-- measured:headline -->\n<!-- /measured:headline -->\n")
    (pooled_dir / "summary.md").write_text("x\n")
    (single_dir / "summary.md").write_text("y\n")
    with pytest.raises(ValueError, match="block\\(s\\) ipb"):  # the cases' own blocks have no place here
        main(["--docs", str(readme), "--headline", str(pooled_dir), str(single_dir)])
