"""The robustness target: each seed's config, and the figures pooled over every (seed, maneuver)."""

import pytest
import yaml

from hybridfmu.evaluation.robustness import seed_config, seed_job_counts, summarize, summary_markdown, write_summary
from hybridfmu.io import write_json_atomic
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_a_seeds_config_writes_elsewhere_and_its_bench_logs_follow():
    demo = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    changed = seed_config(demo, 5)
    assert changed["seed"] == 5 and changed["results_dir"] == "results/robustness/seed5"
    assert changed["maneuvers"]["test_hard"]["raw"] == "results/robustness/seed5/ipb/raw/test_hard.mf4"
    assert "robustness" not in changed and demo["seed"] == 20261122  # the case's own config is left alone
    user = {"case": "mine", "results_dir": "out", "seed": 1, "maneuvers": {"a": {"role": "test", "raw": "logs/a.csv"}}}
    assert seed_config(user, 2)["maneuvers"]["a"]["raw"] == "logs/a.csv"  # a user's logs stay where they are


def entry(fmu, neural, effects, hybrid, share):
    """One maneuver of a metrics file: angle MAE/MSE of each model and the hybrid's in-tolerance share."""
    errors = {"fmu": fmu, "neural_fmu": neural, "fmu_effects": effects, "hybrid": hybrid}
    out = {name: {"angle_mae": value, "angle_mse": value ** 2} for name, value in errors.items()}
    out["improvement"] = {"angle_mae": fmu / neural, "angle_mse": fmu ** 2 / neural ** 2}
    for name in ("fmu_effects", "hybrid"):
        out[f"improvement_{name}"] = {"angle_mae": fmu / errors[name], "angle_mse": fmu ** 2 / errors[name] ** 2}
    out["in_tolerance"] = {"hybrid": {"in_tolerance_share": share}}
    return out


def test_figures_are_pooled_over_every_seed_and_maneuver(tmp_path):
    seeds = {1: {"signals": ["angle"], "per_maneuver": {"a": entry(10.0, 1.0, 0.1, 0.05, 1.0),
                                                         "b": entry(10.0, 5.0, 0.2, 0.4, 0.5)}},
             2: {"signals": ["angle"], "per_maneuver": {"a": entry(8.0, 2.0, 0.1, 0.1, 0.9),
                                                         "b": entry(8.0, 0.5, 0.2, 0.1, 1.0)}}}
    summary = summarize(seeds)
    assert summary["seeds"] == [1, 2] and summary["maneuvers"] == ["a", "b"]
    hybrid = summary["models"]["hybrid"]["angle_mae_factor"]  # 200, 25, 80, 80
    assert (hybrid["median"], hybrid["min"], hybrid["max"], hybrid["n"]) == pytest.approx((80.0, 25.0, 200.0, 4))
    assert summary["models"]["neural_fmu"]["angle_mse_factor"]["max"] == pytest.approx(256.0)
    assert summary["models"]["hybrid"]["in_tolerance_share"]["median"] == pytest.approx(0.95)
    assert summary["hybrid_worse_than_fmu_effects"] == [
        {"seed": 1, "maneuver": "b", "signal": "angle", "hybrid_mae": 0.4, "fmu_effects_mae": 0.2}]
    text = summary_markdown("demo", summary, {2: 1800.0})
    assert "| hybrid (FMU + effects + ANN) | ×80 [×25 – ×200] |" in text
    assert "seed 1 b (angle)" in text and "seed 2 30 min" in text
    # with the jobs each run ran: a resumed run shows how little it ran
    logs = [tmp_path / "run2.log", tmp_path / "run3.log", tmp_path / "missing.log"]
    logs[0].write_text("Finished job 4.\n8 of 9 steps (89%) done\nFinished job 0.\n9 of 9 steps (100%) done\n")
    logs[1].write_text("Finished job 1.\nFinished job 0.\n")  # cut short before the step lines
    assert seed_job_counts(logs, [2, 3, 4]) == {2: 9, 3: 2}
    text_jobs = summary_markdown("demo", summary, {2: 570.0, 3: 3000.0}, {2: 9, 3: 187})
    assert "seed 2 10 min for 9 jobs, seed 3 50 min for 187 jobs." in text_jobs
    assert "counts only the jobs it ran" in text_jobs
    paths = {}
    for seed, metrics in seeds.items():
        paths[seed] = tmp_path / f"{seed}.json"
        write_json_atomic(paths[seed], metrics)
    written = write_summary("demo", paths, tmp_path / "summary.json", tmp_path / "summary.md")
    assert written == summary and (tmp_path / "summary.md").read_text() == summary_markdown("demo", summary)
    assert "closed-loop" not in text  # no seed has closed-loop errors
    for metrics in seeds.values():  # closed loop: the FMU's error over the model's, each driven by the controller
        for maneuver in metrics["per_maneuver"].values():
            maneuver["closed_loop"] = {"fmu": {"angle_mae": 0.02}, "hybrid": {"angle_mae": 0.005}}
    closed = summarize(seeds)["models"]["hybrid"]["angle_mae_closed_loop_factor"]
    assert (closed["median"], closed["n"]) == pytest.approx((4.0, 4))
    assert "| angle closed-loop MAE vs FMU |" in summary_markdown("demo", summarize(seeds))
    # the neural FMU's medians beside a reference's test factors (validation ones are not pooled here)
    reference = {"name": "paper", "factors": [{"role": "test", "metric": "angle_mae", "factor": 5.4},
                                              {"role": "test", "metric": "angle_mse", "factor": 74},
                                              {"role": "validation", "metric": "angle_mae", "factor": 4.6}]}
    referenced = write_summary("demo", paths, tmp_path / "summary.json", tmp_path / "summary.md", reference=reference)
    rows = {row["metric"]: row for row in referenced["reference"]}
    neural = referenced["models"]["neural_fmu"]
    assert set(rows) == {"angle_mae", "angle_mse"}
    assert rows["angle_mae"]["neural_fmu_median"] == neural["angle_mae_factor"]["median"]
    assert rows["angle_mae"]["reached"] == (neural["angle_mae_factor"]["median"] >= 5.4)
    assert rows["angle_mse"]["reached"] == (neural["angle_mse_factor"]["median"] >= 74)
    assert "against the reference's test factors (paper," in (tmp_path / "summary.md").read_text()
    with pytest.raises(ValueError, match="no seed"):
        summarize({})
