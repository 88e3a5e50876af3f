"""A small withheld-effect check through the Python entry points (one seed: Coulomb friction and no effect, both
with motor parameter offsets), and the Snakemake rules' DAG for a tiny config. Drawing and scoring have their own
unit tests (tests/test_withheld_drawing.py, tests/test_withheld_scoring.py)."""

from __future__ import annotations

import copy
import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hybridfmu import __version__
from hybridfmu.config import read_config_file, validate_case_config
from hybridfmu_bench.withheld import suite as withheld
from hybridfmu_bench.withheld.report import SUMMARY_COLUMNS, summarise

ROOT = Path(__file__).resolve().parents[1]
DURATION_S = 3.0


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory):
    """The demo config with a small withheld section of its own: seed 0, Coulomb friction at 1-1.5 x the demo's
    (well detectable) and the none case; the maneuvers and the expected table are the demo's."""
    config = read_config_file(ROOT / "config" / "config.yaml")
    demo = config.get("withheld") or {}
    config["results_dir"] = str(tmp_path_factory.mktemp("withheld_results"))
    config["withheld"] = {"duration_s": DURATION_S, "seeds": [0], "effects": ["coulomb_friction"], "pairs": [],
                          "sizes_per_effect": 1, "size_range": [1.0, 1.5], "none_case": True,
                          "maneuvers": copy.deepcopy(demo["maneuvers"]),
                          "expected": {**demo.get("expected", {}), "coulomb_friction": ["coulomb(omega)"]},
                          "diagnosis": {"selection": {"bootstrap_samples": 20}}}
    return validate_case_config(config)


def run_case(config, name, fmu_path) -> tuple[Path, Path, Path]:
    base = Path(config["results_dir"]) / "withheld"
    case_path, draw_path = base / "cases" / f"{name}.yaml", base / "cases" / f"{name}.draw.json"
    withheld.write_case_config(config, name, fmu_path, case_path, draw_path, duration_s=DURATION_S)
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
    return out / "diagnosis.json", base / name / "raw" / f"{maneuvers[-1]}.truth.json", draw_path


@pytest.mark.slow
def test_small_withheld_check(tiny_config, ipbmotor_fmu, tmp_path):
    names = withheld.case_names(tiny_config)
    assert names == ["s0__single_coulomb_friction__size1", "s0__none"]
    files = [run_case(tiny_config, name, ipbmotor_fmu) for name in names]
    out = summarise(names, *map(list, zip(*files)), tmp_path / "summary.csv", tmp_path / "confusion.png",
                    tmp_path / "detection.png", tmp_path / "summary.md", expected=tiny_config["withheld"]["expected"])
    by_case = {r["case"]: r for r in out["rows"]}
    friction = by_case["s0__single_coulomb_friction__size1"]
    assert friction["detected"] == [True] and "coulomb_friction" in friction["found_effects"]
    assert friction["where_correct"] is True and friction["named_in"] == ["omega"]
    assert friction["parameter_error_pct"][0] < 25.0
    assert friction["effect_size"][0] > 0.1 and 1.0 <= friction["size_scale"][0] <= 1.5
    for row in out["rows"]:  # offsets like the demo bench's in every case, never counted as extras
        assert set(row["offsets_true"]) == {"R", "L_d", "L_q", "psi"}
        assert not any(e.startswith("parameter(") and e[10:-1] in row["offsets_true"] for e in row["extra_effects"])
    with open(tmp_path / "summary.csv") as handle:
        table = list(csv.DictReader(handle))
    assert [r["case"] for r in table] == names and set(SUMMARY_COLUMNS) <= set(table[0])
    assert (tmp_path / "confusion.png").stat().st_size > 1000 and (tmp_path / "detection.png").stat().st_size > 1000
    summary = (tmp_path / "summary.md").read_text()
    assert "| coulomb_friction | 1 | 1/1 |" in summary
    assert "Every case was diagnosed by the code at " in summary  # the diagnosis records its code
    check_report(files[0][0])
    check_sparse_benchmark(tiny_config, ipbmotor_fmu, "s0__single_coulomb_friction__size1")
    check_setting_benchmark(tiny_config, ipbmotor_fmu, "s0__single_coulomb_friction__size1", tmp_path)


def check_sparse_benchmark(config, fmu_path: Path, case: str) -> None:
    """benchmarks/sparse_selection.py scores a finished case: the forward selection's row is the suite's own, and
    STLSQ has a row of the same columns per threshold."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("sparse_selection", ROOT / "benchmarks" / "sparse_selection.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    row = bench.score_case_files(case, Path(config["results_dir"]) / "withheld", Path(fmu_path),
                                 config["withheld"]["expected"], config["withheld"].get("background") or {})
    assert row["case"] == case and row["n_columns"] > 0
    assert "coulomb_friction" in row["forward"]["found_effects"]
    assert sorted(row["sparse"]) == sorted(bench.THRESHOLDS)
    assert all(set(r) == set(row["forward"]) for r in row["sparse"].values())


def check_setting_benchmark(config, fmu_path: Path, case: str, tmp_path: Path) -> None:
    """benchmarks/diagnosis_setting.py diagnoses a finished case again with changed settings (here a fixed kernel
    where the suite's came from the model's time scale) and scores both diagnoses the suite's way."""
    bench = _setting_benchmark()
    withheld_dir = Path(config["results_dir"]) / "withheld"
    changes = [bench.parse_change(text) for text in ("diagnosis.kernel_s=0.002", "diagnosis.selection.noise_margin=0.2",
                                                     "diagnosis.smoothing_s=default")]
    assert changes == [(["kernel_s"], 0.002), (["selection", "noise_margin"], 0.2), (["smoothing_s"], "default")]
    bench._diagnose((case, withheld_dir, Path(fmu_path), tmp_path / "changed", changes))
    changed_case = yaml.safe_load((tmp_path / "changed" / case / "case.yaml").read_text())
    assert changed_case["diagnosis"]["kernel_s"] == 0.002
    assert changed_case["diagnosis"]["selection"]["noise_margin"] == 0.2
    changed = json.loads((tmp_path / "changed" / case / "diagnosis" / "diagnosis.json").read_text())
    suite = json.loads((withheld_dir / case / "diagnosis" / "diagnosis.json").read_text())
    assert changed["method"]["kernel_choice"] is None and suite["method"]["kernel_choice"]["samples"] >= 9
    section = config["withheld"]
    scored = {name: bench.score([case], {case: root / case / "diagnosis" / "diagnosis.json"}, withheld_dir,
                                section["expected"], section.get("background") or {}, None)
              for name, root in (("suite", withheld_dir), ("changed", tmp_path / "changed"))}
    assert scored["suite"]["kernel_samples"]["median"] == suite["method"]["kernel_choice"]["samples"]
    assert scored["changed"]["kernel_samples"]["median"] == 21  # 0.002 s on the 10 kHz grid
    assert scored["changed"]["measures"]["n_cases"] == 1
    text = bench.markdown({"n_cases": 1, "change": "the code at 0123456789, `diagnosis.kernel_s=0.002`",
                           "suite_code": "abcdefabcd", "arguments": "--set x", **scored})
    assert "the suite's diagnoses (the code at abcdefabcd) against the same cases diagnosed with the code at " \
           "0123456789, `diagnosis.kernel_s=0.002` (`python benchmarks/diagnosis_setting.py --set x`" in text
    assert "| exact set, cases above the limits |" in text and "| none cases naming nothing |" in text
    assert "| cases naming what the suite's diagnosis names | – | " in text
    assert "| median windowed shrink of the named effects on top of the parameter corrections, exact cases |" in text
    assert "| largest windowed shrink of the named effects, none cases |" in text


def check_report(diagnosis_json: Path) -> None:
    """The diagnosis folder holds the record, the report and its figures; the diagnosis never saw the bench."""
    from hybridfmu.io import read_json

    out = diagnosis_json.parent
    record = read_json(diagnosis_json)
    report = (out / "report.md").read_text()
    rank = next(c["rank"] for c in record["which"]["chosen"] if c["effect"] == "coulomb(omega)")
    for heading in ("## Where", "## Which", "## How far", f"### {rank}. `coulomb(omega)`"):
        assert heading in report
    assert {p.name for p in out.glob("*.png")} >= {"equation_error.png", "regions.png", "waterfall.png", "effects.png"}
    assert "Parameter errors are fitted from the start" in report and "| parameter error | equation(s) |" in report
    table: list[int] = []  # cells per row of each Markdown table: an unescaped | in a name would break a row
    for line in report.splitlines() + [""]:
        if line.startswith("|"):
            table.append(len(re.split(r"(?<!\\)\|", line)))
        elif table:
            assert len(set(table)) == 1, (line, table)
            table = []
    assert record["model_parameters"] == {}  # the FMU's nominal values, not the bench's
    assert record["code"]["version"] == __version__ and "commit" in record["code"]
    record.pop("case")  # the case id names the withheld effect; nothing else of the record may
    text = json.dumps(record)
    assert not [word for word in ("coulomb_friction", "bench", "truth") if word in text]


def test_snakemake_plans_one_job_per_case_seed_and_maneuver(tiny_config, ipbmotor_fmu, tmp_path):
    config = copy.deepcopy(tiny_config)
    config["withheld"].update({"seeds": [0, 1], "sizes_per_effect": 2})
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
    cases = 2 * (2 + 1)  # seeds x (two sizes of one effect + none)
    assert counts.get("withheld_case") == cases and counts.get("withheld_diagnose") == cases
    assert counts.get("withheld_emulate") == counts.get("withheld_segments") == 3 * cases
    assert counts.get("withheld_summary") == 1
    assert "s1__single_coulomb_friction__size2" in text


def _setting_benchmark():
    import importlib.util

    spec = importlib.util.spec_from_file_location("diagnosis_setting", ROOT / "benchmarks" / "diagnosis_setting.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


def _fake_suite(root: Path, case: str, diagnosis: dict, draw: dict, truth: dict) -> None:
    (root / "cases").mkdir(parents=True)
    (root / "cases" / f"{case}.yaml").write_text(yaml.safe_dump({"diagnosis": diagnosis}))
    (root / "cases" / f"{case}.draw.json").write_text(json.dumps(draw))
    for part, record in (("raw/test.truth.json", truth), ("diagnosis/diagnosis.json", {"maneuvers": ["test"]})):
        (root / case / part).parent.mkdir(parents=True, exist_ok=True)
        (root / case / part).write_text(json.dumps(record))


def test_setting_benchmark_against_another_suite_names_the_settings_that_differ(tmp_path):
    """``--against`` compares two finished suites of the same draws: it names the diagnosis settings in which their
    case configs differ and refuses suites of other draws or truths."""
    bench = _setting_benchmark()
    old = {"kernel_s": 0.01, "open_loop": {"window_s": 0.12, "horizons": 3}, "end_stop_margin": 0.07}
    new = {"kernel_s": 0.01, "open_loop": {"window_s": "auto", "horizons": 3}}
    assert bench._settings_differences(old, new) == ["diagnosis.end_stop_margin=default",
                                                     'diagnosis.open_loop.window_s="auto"']
    case, draw, truth = "s0__none", {"effects": []}, {"J": 1.0, "summary": {"wall_s": 0.9}}
    _fake_suite(tmp_path / "a", case, old, draw, truth)
    _fake_suite(tmp_path / "b", case, new, draw, {**truth, "summary": {"wall_s": 1.4}})
    assert bench.against_suite(tmp_path / "a", tmp_path / "b", [case]) == [
        "diagnosis.end_stop_margin=default", 'diagnosis.open_loop.window_s="auto"']
    _fake_suite(tmp_path / "c", case, new, draw, {"J": 2.0})
    with pytest.raises(SystemExit, match="test.truth.json: missing or not the same"):
        bench.against_suite(tmp_path / "a", tmp_path / "c", [case])
