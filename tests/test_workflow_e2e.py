"""The whole workflow, FMU build to report, on the tiny case through Snakemake; then single stages again.

The tiny case (config/cases/tiny.yaml) has short maneuvers and a tiny Hyperband budget. The run
happens in a temporary directory (outputs, Snakemake metadata, MLflow store), with the repository's
Snakefile.
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "config" / "cases" / "tiny.yaml"

# Minutes, not seconds (the whole workflow); still part of the default `pytest` run.
pytestmark = pytest.mark.slow


def snakemake(workdir: Path, configfile: Path, *args: str, timeout_s: float = 600) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "snakemake", "-j2", "--snakefile", str(REPO / "Snakefile"),
               "--directory", str(workdir), "--configfile", str(configfile), "--nocolor", *args]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=timeout_s, env=env)
    if result.returncode != 0:
        log = result.stdout[-6000:] + "\n" + result.stderr[-12000:]
        raise AssertionError(f"snakemake {' '.join(args)} failed ({result.returncode}):\n{log}")
    return result


def planned_rules(output: str) -> set[str]:
    """Rule names of the jobs a (dry) run lists in its job table."""
    rules, in_table = set(), False
    for line in output.splitlines():
        parts = line.split()
        if line.startswith("job") and "count" in line:
            in_table = True
            continue
        if in_table:
            if not parts or parts[0] == "total":
                break
            if parts[0].startswith("-"):
                continue
            if parts[0] != "all":
                rules.add(parts[0])
    return rules


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("tiny_case")
    start = time.perf_counter()
    snakemake(workdir, TINY)
    elapsed_s = time.perf_counter() - start
    config = yaml.safe_load(TINY.read_text())
    return workdir, workdir / config.get("results_dir", "results") / config["case"], config, elapsed_s


def test_every_stage_writes_its_outputs(tiny_run):
    workdir, results, config, elapsed_s = tiny_run
    print(f"tiny workflow: {elapsed_s:.1f} s")
    for maneuver in config["maneuvers"]:
        assert (results / "baseline" / f"{maneuver}.parquet").is_file()
        baseline = json.loads((results / "baseline" / f"{maneuver}.metrics.json").read_text())
        assert baseline["fmu"]["angle_mae"] >= 0
    for role in ("validation", "test"):
        metrics = json.loads((results / "metrics" / f"{role}.json").read_text())
        for model in ("fmu", "neural_fmu", "improvement"):
            assert set(metrics[model]) == {f"{signal}_{measure}" for signal in ("angle", "speed")
                                           for measure in ("mae", "mse", "rmse")}
        assert metrics["fmu"]["angle_mae"] > 0 and metrics["neural_fmu"]["angle_mae"] > 0
        assert metrics["improvement"]["angle_mae"] == pytest.approx(
            metrics["fmu"]["angle_mae"] / metrics["neural_fmu"]["angle_mae"])
        assert isinstance(metrics["dt_s"], float) and metrics["gates"]
        assert metrics["zooms"] and all({"t_start_s", "t_end_s", "fmu", "neural_fmu", "improvement"} <= set(z)
                                        for z in metrics["zooms"])
    figures = sorted(p.name for p in (results / "figures").glob("*.png"))
    for name in ("time_offset.png", "training_curves.png", "hyperband.png", "validation_angle.png",
                 "validation_angle_zoom.png", "test_speed.png", "test_speed_zoom.png"):
        assert name in figures
    report = (results / "report.md").read_text()
    assert "| validation | angle | MAE |" in report and "×4.6" in report and "![" in report
    run = json.loads((results / "evaluation" / "mlflow_run.json").read_text())
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=run["tracking_uri"])
    logged = client.get_run(run["run_id"])
    assert "test/improvement/angle_mae" in logged.data.metrics
    assert {a.path for a in client.list_artifacts(run["run_id"])} >= {"figures", "metrics", "report.md"}


def test_nothing_left_to_do(tiny_run):
    workdir, _, _, _ = tiny_run
    output = snakemake(workdir, TINY, "-n")
    assert planned_rules(output.stdout) == set(), output.stdout[-4000:]


def evaluation_targets(workdir: Path, results: Path) -> list[str]:
    """The report and the figures, relative to the working directory as the rules name them: the
    evaluation's end of the DAG (training, evaluation and plots upstream)."""
    paths = [results / "report.md", *sorted((results / "figures").glob("*.png"))]
    return [str(path.relative_to(workdir)) for path in paths]


def test_forcerun_plot_only_redraws(tiny_run):
    workdir, results, _, _ = tiny_run
    best = results / "hpo" / "best.json"
    metrics = results / "metrics" / "test.json"
    figure = results / "figures" / "test_angle.png"
    before = {path: path.stat().st_mtime_ns for path in (best, metrics, figure)}
    # targets before --forcerun, which takes several values
    output = snakemake(workdir, TINY, *evaluation_targets(workdir, results), "--forcerun", "plot")
    ran = planned_rules(output.stdout + output.stderr)
    assert ran == {"plot", "report"}, ran
    assert best.stat().st_mtime_ns == before[best] and metrics.stat().st_mtime_ns == before[metrics]
    assert figure.stat().st_mtime_ns > before[figure]


def test_changing_a_plot_option_reruns_only_plotting(tiny_run, tmp_path):
    workdir, results, config, _ = tiny_run
    changed = dict(config)
    changed["evaluation"] = {**config.get("evaluation", {}),
                             "plot": {**config.get("evaluation", {}).get("plot", {}), "dpi": 61}}
    configfile = tmp_path / "tiny_dpi.yaml"
    configfile.write_text(yaml.safe_dump(changed, sort_keys=False))  # key order is part of Snakemake params
    output = snakemake(workdir, configfile, "-n", *evaluation_targets(workdir, results))
    assert planned_rules(output.stdout + output.stderr) == {"plot", "report"}
    changed["evaluation"]["zoom"] = {**config["evaluation"].get("zoom", {}), "length_s": {"angle": 0.7, "speed": 1.0}}
    configfile.write_text(yaml.safe_dump(changed, sort_keys=False))
    output = snakemake(workdir, configfile, "-n", *evaluation_targets(workdir, results))
    assert planned_rules(output.stdout + output.stderr) == {"evaluate", "plot", "report"}


def test_snakemake_report(tiny_run):
    workdir, _, _, _ = tiny_run
    snakemake(workdir, TINY, "--report", str(workdir / "report.html"))
    html = (workdir / "report.html").read_text(errors="replace")
    assert len(html) > 10000 and "training_curves.png" in html
