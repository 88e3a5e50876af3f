"""A small withheld-effect check through the Python entry points (two short cases), and the
Snakemake rules' DAG for a tiny config."""

from __future__ import annotations

import copy
import csv
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hybridfmu.config import load_case_config
from hybridfmu.diagnosis import withheld

ROOT = Path(__file__).resolve().parents[1]
DURATION_S = 3.0


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory, ipbmotor_fmu):
    """The demo config with a small withheld section (Coulomb friction alone, and no effect)."""
    config = load_case_config(ROOT / "config" / "config.yaml")
    config = copy.deepcopy(config)
    config["results_dir"] = str(tmp_path_factory.mktemp("withheld_results"))
    config["withheld"].update({"duration_s": DURATION_S, "effects": ["coulomb_friction"], "pairs": [],
                               "none_case": True})
    config["withheld"]["diagnosis"] = {"selection": {"bootstrap_samples": 20}}
    return config


def run_case(config, name, fmu_path) -> tuple[Path, Path]:
    base = Path(config["results_dir"]) / "withheld"
    case_path = base / "cases" / f"{name}.yaml"
    withheld.write_case_config(config, name, fmu_path, case_path, duration_s=DURATION_S)
    maneuvers = list(config["withheld"]["maneuvers"])
    data, segments = {}, {}
    for m in maneuvers:
        raw = base / name / "raw" / f"{m}.mf4"
        truth = base / name / "raw" / f"{m}.truth.json"
        withheld.emulate_case(case_path, m, raw, truth, duration_s=DURATION_S)
        data[m] = base / name / "data" / f"{m}.parquet"
        withheld.ingest_case(case_path, raw, data[m])
        segments[m] = base / name / "segments" / f"{m}.json"
        withheld.segment_case(case_path, data[m], segments[m], segments[m].with_suffix(".png"), m)
    out = base / name / "diagnosis"
    withheld.diagnose_case(case_path, fmu_path, data, segments, out)
    return out / "diagnosis.json", base / name / "raw" / f"{maneuvers[-1]}.truth.json"


@pytest.mark.slow
def test_small_withheld_check(tiny_config, ipbmotor_fmu, tmp_path):
    names = withheld.case_names(tiny_config)
    assert names == ["single_coulomb_friction", "none"]
    diagnoses, truths = [], []
    for name in names:
        diagnosis, truth = run_case(tiny_config, name, ipbmotor_fmu)
        diagnoses.append(diagnosis)
        truths.append(truth)
    rows = withheld.summarise(names, diagnoses, truths, tmp_path / "summary.csv", tmp_path / "confusion.png",
                              tmp_path / "summary.md", expected=tiny_config["withheld"]["expected"])
    by_case = {r["case"]: r for r in rows}
    friction = by_case["single_coulomb_friction"]
    assert friction["found_effects"].split(";")[0] == "coulomb_friction"
    assert friction["named_effects"].split(";")[0] == "coulomb(omega)"
    assert friction["correct"] is True
    assert friction["shrink_factor"] >= 3.0
    assert by_case["none"]["found_effects"] == "none" and by_case["none"]["correct"] is True
    with open(tmp_path / "summary.csv") as handle:
        table = list(csv.DictReader(handle))
    assert [r["case"] for r in table] == names
    assert set(withheld.SUMMARY_COLUMNS) <= set(table[0])
    assert (tmp_path / "confusion.png").stat().st_size > 1000
    assert withheld.targets(rows) == {"single_top1_correct": True, "pairs_both_found": True,
                                      "none_names_nothing": True, "gap_shrinks_3x_where_correct": True}
    check_report_and_tracking(diagnoses[0], tmp_path)


def check_report_and_tracking(diagnosis_json: Path, tmp_path: Path) -> None:
    """The diagnosis folder holds the record, the report and its figures; the run is logged to MLflow."""
    from mlflow.tracking import MlflowClient

    from hybridfmu.diagnosis.report import log_to_mlflow
    from hybridfmu.io import read_json

    out = diagnosis_json.parent
    record = read_json(diagnosis_json)
    report = (out / "report.md").read_text()
    for heading in ("## Where", "## Which", "## How far", "### 1. `coulomb(omega)`"):
        assert heading in report
    figures = sorted(out.glob("*.png"))
    assert {p.name for p in figures} >= {"equation_error.png", "regions.png", "waterfall.png", "effects.png"}
    assert record["where"]["equations"]["carrier"] == "omega"
    assert record["which"]["chosen"][0]["equation"] == "omega"
    assert record["which"]["chosen"][0]["stability"]["coulomb_level"]["relative_spread"] < 0.2
    after = record["how_far"]["after"]
    assert {"angle_rmse", "angle_mae", "speed_rmse", "speed_mae"} <= set(after)
    assert after["angle_rmse"] < record["how_far"]["before"]["angle_rmse"]
    config = {"case": "single_coulomb_friction", "results_dir": str(tmp_path), "mlflow": {}}
    run_id = log_to_mlflow(record, {"json": diagnosis_json, "report": out / "report.md", "figures": figures}, config)
    client = MlflowClient(f"sqlite:///{tmp_path.resolve()}/mlflow.db")
    run = client.get_run(run_id)
    assert run.data.tags["hybridfmu.role"] == "diagnosis"
    assert run.data.metrics["gap/gap_before"] == pytest.approx(record["how_far"]["gap_before"])
    assert run.data.params["found_effects"] == "coulomb(omega)"
    assert "diagnosis/report.md" in {a.path for a in client.list_artifacts(run_id, "diagnosis")}


def test_case_configs_withhold_exactly_the_effect(tiny_config, ipbmotor_fmu):
    config = copy.deepcopy(tiny_config)
    config["withheld"]["pairs"] = [["cogging", "channel_time_offset"]]
    names = withheld.case_names(config)
    assert "pair_cogging__channel_time_offset" in names
    case = withheld.case_config(config, "pair_cogging__channel_time_offset", ipbmotor_fmu)
    assert sorted(case["bench"]["effects"]) == ["channel_time_offset", "cogging"]
    assert case["bench"]["true_parameter_offsets"] == {}
    assert case["fmu"]["source"] == "path" and case["fmu"]["path"] == str(ipbmotor_fmu)
    assert case["maneuvers"]["test"]["role"] == "test"
    offset = case["bench"]["effects"]["channel_time_offset"]["offset_s"]
    assert 1e-4 <= abs(offset) <= 1.5e-4
    again = withheld.case_config(config, "pair_cogging__channel_time_offset", ipbmotor_fmu)
    assert again["bench"]["effects"] == case["bench"]["effects"]  # seeded draws
    assert withheld.case_config(config, "none", ipbmotor_fmu)["bench"]["effects"] == {}


def test_named_effects_are_translated_through_the_expected_table():
    expected = {"cogging": ["periodic(theta)"], "channel_time_offset": ["time_offset(*)"]}
    record = {"which": {"found_effects": ["time_offset(d_a,d_b)", "periodic(theta)", "viscous(omega)"], "chosen": []},
              "where": {"equations": {"states": {"omega": {"ratio_to_noise": 3.0}}}},
              "how_far": {"gap_before": 0.3, "gap_after": 0.05}}
    truth = {"effects": [{"name": "cogging", "parameters": {}}, {"name": "channel_time_offset", "parameters": {}}]}
    row = withheld.case_row("pair_cogging__channel_time_offset", record, truth, expected)
    assert row["found_effects"] == "channel_time_offset;cogging;viscous(omega)"
    assert row["correct"] is True and row["shrink_factor"] == pytest.approx(6.0)
    single = withheld.case_row("single_cogging", record, {"effects": truth["effects"][:1]}, expected)
    assert single["correct"] is False  # the top-ranked named effect is not the withheld one
    assert withheld.bench_effect_of("periodic(omega)", expected) is None


def test_confusion_matrix_counts_detections_misses_and_spurious_names():
    rows = [{"true_effects": "cogging;channel_time_offset", "found_effects": "channel_time_offset"},
            {"true_effects": "none", "found_effects": "none"},
            {"true_effects": "cogging", "found_effects": "cogging;viscous_friction"}]
    labels, matrix = withheld.confusion_matrix(rows)
    assert labels == ["channel_time_offset", "cogging", "viscous_friction", "none"]
    at = {(labels[i], labels[j]): int(matrix[i, j]) for i in range(len(labels)) for j in range(len(labels))
          if matrix[i, j]}
    assert at == {("channel_time_offset", "channel_time_offset"): 1, ("cogging", "none"): 1,
                  ("cogging", "cogging"): 1, ("none", "viscous_friction"): 1, ("none", "none"): 1}


def test_bad_withheld_sections_are_named(tiny_config, ipbmotor_fmu):
    config = copy.deepcopy(tiny_config)
    config["withheld"]["effects"] = ["no_such_effect"]
    with pytest.raises(ValueError, match="config.withheld.effects"):
        withheld.case_names(config)
    config = copy.deepcopy(tiny_config)
    config["withheld"]["parameter_ranges"] = {"coulomb_friction": {"coulomb_torque_nm": "large"}}
    with pytest.raises(ValueError, match="parameter_ranges.coulomb_friction.coulomb_torque_nm"):
        withheld.case_config(config, "single_coulomb_friction", ipbmotor_fmu)
    with pytest.raises(ValueError, match="unknown withheld case name"):
        withheld.case_effects("double_trouble")


def test_snakemake_plans_one_job_per_case_and_maneuver(tiny_config, ipbmotor_fmu, tmp_path):
    config = copy.deepcopy(tiny_config)
    config["fmu"] = {**config["fmu"], "source": "path", "path": str(ipbmotor_fmu)}
    config["results_dir"] = str(tmp_path / "results")
    config["maneuvers"] = {m: {"role": v["role"], "raw": f"{config['results_dir']}/{config['case']}/raw/{m}.mf4"}
                           for m, v in config["maneuvers"].items()}
    config_path = tmp_path / "tiny.yaml"
    config_path.write_text(yaml.safe_dump(config))
    result = subprocess.run([sys.executable, "-m", "snakemake", "-n", "withheld",
                             "--configfile", str(config_path), "--directory", str(ROOT)],
                            capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-2000:]
    text = result.stdout + result.stderr
    counts = {line.split()[0]: int(line.split()[1]) for line in text.splitlines()
              if len(line.split()) == 2 and line.split()[1].isdigit()}
    assert counts.get("withheld_emulate") == 6 and counts.get("withheld_diagnose") == 2
    assert counts.get("withheld_summary") == 1
