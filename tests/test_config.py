"""The case config is validated against the workflow's schema; errors name the field."""

import copy
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from hybridfmu.config import ConfigError, load_case_config, validate_case_config

REPO = Path(__file__).resolve().parents[1]
DEMO_CONFIG = REPO / "config" / "config.yaml"


@pytest.fixture()
def demo_config():
    return yaml.safe_load(DEMO_CONFIG.read_text())


def test_demo_config_is_valid_and_gets_defaults(demo_config):
    config = validate_case_config(copy.deepcopy(demo_config))
    assert config["case"] == "ipb"
    assert config["mlflow"]["tracking_uri"] == ""


def test_every_case_config_is_valid():
    for path in sorted((REPO / "config").rglob("*.yaml")):
        load_case_config(path)


def test_unknown_key_is_named(demo_config):
    demo_config["fmu"]["colour"] = "blue"
    with pytest.raises(ConfigError, match=r"config\.fmu.*'colour' was unexpected"):
        validate_case_config(demo_config)


def test_bad_value_is_named(demo_config):
    demo_config["maneuvers"]["train"]["role"] = "training"
    with pytest.raises(ConfigError, match=r"config\.maneuvers\.train\.role"):
        validate_case_config(demo_config)


@pytest.mark.parametrize("engine", ["adjoint", "adjoint_numpy", "torchdiffeq"])
def test_the_three_gradient_engines_are_options(demo_config, engine):
    demo_config["training"]["gradients"] = engine
    assert validate_case_config(demo_config)["training"]["gradients"] == engine


@pytest.mark.parametrize("engine", ["adjoint_torch", "autograd", "torchdiffeq_adjoint", "adjoint_c"])
def test_test_reference_engines_are_no_options(demo_config, engine):
    """Slower than one of the three options in every row of benchmarks/train_step.py: test references only."""
    demo_config["training"]["gradients"] = engine
    with pytest.raises(ConfigError, match=rf"config\.training\.gradients: '{engine}' is not one of"):
        validate_case_config(demo_config)


def test_missing_file_and_non_mapping(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_case_config(tmp_path / "nope.yaml")
    bad = tmp_path / "list.yaml"
    bad.write_text("- a\n- b\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_case_config(bad)


def test_snakemake_stops_on_a_bad_config(tmp_path, demo_config):
    demo_config["seed"] = -3
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(demo_config))
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "-j1", "--configfile", str(bad)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode != 0
    assert "config.seed" in proc.stdout + proc.stderr


def test_a_case_configfile_replaces_the_demo_config(tmp_path, demo_config):
    """--configfile <case> must not inherit demo sections (e.g. the demo's extra maneuvers)."""
    case = copy.deepcopy(demo_config)
    case["case"] = "other"
    case["maneuvers"] = {"run1": {"role": "train", "raw": "logs/run1.mf4"}}
    path = tmp_path / "other.yaml"
    path.write_text(yaml.safe_dump(case))
    probe = tmp_path / "probe.smk"
    probe.write_text(
        f'include: "{REPO / "Snakefile"}"\n'
        'print("MANEUVERS=" + ",".join(sorted(config["maneuvers"])))\n'
    )
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "-j1", "-s", str(probe), "--configfile", str(path),
         "--directory", str(REPO)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    assert "MANEUVERS=run1\n" in proc.stdout + proc.stderr, proc.stdout + proc.stderr


# ---- the case's roles and units, checked before any job runs (hybridfmu.case_checks.check_case) -----------------

def _case(demo_config):
    config = copy.deepcopy(demo_config)
    return config


def test_check_case_names_a_nonexistent_fmu_variable(demo_config):
    from hybridfmu.case_checks import check_case

    config = validate_case_config(_case(demo_config))
    config["roles"]["states"]["psi_r"] = "speed"
    with pytest.raises(ConfigError, match=r"^case\.yaml: config\.roles\.states\.psi_r: the FMU .* has no state "
                                          r"'psi_r'"):
        check_case(config, "case.yaml")


def test_a_signal_without_unit_is_a_schema_error(demo_config):
    config = _case(demo_config)
    del config["signals"]["speed"]["unit"]
    with pytest.raises(ConfigError, match=r"config\.signals\.speed: 'unit' is a required property"):
        validate_case_config(config)


def test_check_case_names_a_unit_of_the_wrong_dimension(demo_config):
    from hybridfmu.case_checks import check_case

    config = validate_case_config(_case(demo_config))
    config["signals"]["speed"]["unit"] = "N"
    with pytest.raises(ConfigError, match=r"case\.yaml: config\.roles\.states\.omega: signal 'speed' is in 'N' .* "
                                          r"declared in 'rad/s'"):
        check_case(config, "case.yaml")
    config["signals"]["speed"]["unit"] = "blub"
    with pytest.raises(ConfigError, match=r"config\.signals\.speed\.unit: unknown unit 'blub'"):
        check_case(config, "case.yaml")


def test_demo_and_tiny_cases_pass_check_case():
    from hybridfmu.case_checks import check_case

    for path in (DEMO_CONFIG, REPO / "config" / "cases" / "tiny.yaml"):
        roles = check_case(load_case_config(path), str(path))
        assert roles.input_signals == ["duty_a", "duty_b", "duty_c", "u_dc", "load_torque"]
        assert roles.signals["speed"].unit == "rad/s" and roles.signals["load_torque"].unit == "N*m"


def test_snakemake_stops_before_any_job_on_a_wrong_fmu_variable(tmp_path, demo_config):
    demo_config["roles"]["inputs"]["tau_brake"] = "load_torque"
    bad = tmp_path / "bad_roles.yaml"
    bad.write_text(yaml.safe_dump(demo_config))
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "-j1", "--configfile", str(bad)],
        cwd=REPO, capture_output=True, text=True, timeout=120,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode != 0
    assert f"{bad}: config.roles.inputs.tau_brake: the FMU" in output, output[-2000:]
    assert "Job stats" not in output


# ---- the config file is read strictly (hybridfmu.config.read_config_file) ----------------------------------------

def test_a_key_listed_twice_is_named_with_file_line_and_field(tmp_path):
    path = tmp_path / "case.yaml"
    path.write_text("case: x\ntransforms:\n  - {kind: scale, input: a, output: b}\n"
                    "  - kind: scale\n    input: a\n    input: c\n")
    with pytest.raises(ConfigError, match=rf"^{path}:6: config\.transforms\[1\]\.input: key 'input' is listed twice "
                                          r"in config\.transforms\[1\] \(first at line 5, again at line 6"):
        load_case_config(path)


def test_anchors_merge_keys_and_equal_values_of_other_types_are_no_duplicates(tmp_path):
    from hybridfmu.config import read_config_file

    path = tmp_path / "case.yaml"
    path.write_text("base: &base {role: train, raw: a.csv}\nmaneuvers:\n  one: {<<: *base, raw: b.csv}\n"
                    "  two: *base\nnumbers: {1: one, '1': text}\n")
    assert read_config_file(path) == {"base": {"role": "train", "raw": "a.csv"},
                                      "maneuvers": {"one": {"role": "train", "raw": "b.csv"},
                                                    "two": {"role": "train", "raw": "a.csv"}},
                                      "numbers": {1: "one", "1": "text"}}


def test_malformed_yaml_is_named_with_file_line_column_and_field(tmp_path):
    path = tmp_path / "case.yaml"
    path.write_text("case: x\nhpo:\n  R: 9\n  search_space:\n    lr: {distribution: fixed, value: 1\n  eta: 3\n")
    with pytest.raises(ConfigError, match=rf"^{path}:6:\d+: not valid YAML near config\.hpo\.search_space\.lr\.value: "
                                          r"expected ',' or '\}'.* \(while parsing a flow mapping at line 5\); "
                                          r"expected well-formed YAML"):
        load_case_config(path)


def test_check_config_file_names_the_file_for_schema_errors_and_leaves_the_config_alone(tmp_path, demo_config):
    from hybridfmu.config import check_config_file

    path = tmp_path / "case.yaml"
    path.write_text(yaml.safe_dump(demo_config))
    config = copy.deepcopy(demo_config)
    assert check_config_file(path, config) == demo_config
    assert config == demo_config  # no defaults filled in here
    config["seed"] = -1
    with pytest.raises(ConfigError, match=rf"^{path}: invalid case config: config\.seed: -1"):
        check_config_file(path, config)


# ---- maneuvers: one raw log in two roles (hybridfmu.case_checks.check_maneuvers) ---------------------------------------

TANKS = REPO / "config" / "cases" / "tanks.yaml"


def _tanks():
    return load_case_config(TANKS)


def test_one_log_in_slices_and_side_by_side_records_is_legitimate(monkeypatch):
    from hybridfmu.case_checks import check_case

    monkeypatch.chdir(REPO)
    config = _tanks()
    roles = check_case(config, str(TANKS))
    assert roles.input_signals == ["u"]
    # the test record reads the same file and its whole time span, through other channels
    config["maneuvers"]["test"]["t_start_s"] = 100.0
    check_case(config, str(TANKS))
    # overlapping slices of the same role are not a leak between roles
    config["maneuvers"]["validation"]["role"] = "train"
    config["maneuvers"]["validation"]["t_start_s"] = 2000.0
    check_case(config, str(TANKS))


def test_a_copy_of_a_log_under_another_name_in_another_role_is_an_error(monkeypatch, tmp_path):
    """The test maneuver's log is the validation log's bytes under another file name: the same data in two roles.
    A log that differs in one byte is another log."""
    from hybridfmu.case_checks import check_case

    monkeypatch.chdir(REPO)
    config = _tanks()
    original = REPO / config["maneuvers"]["validation"]["raw"]
    copy_path = tmp_path / "test_log.csv"
    copy_path.write_bytes(original.read_bytes())
    config["maneuvers"]["test"] = {**config["maneuvers"]["validation"], "role": "test", "raw": str(copy_path)}
    with pytest.raises(ConfigError, match=rf"^tanks\.yaml: config\.maneuvers\.test: role test reads '{copy_path}', "
                                          r"a byte-identical copy of 'config/cases/tanks/dataBenchmark\.csv', with "
                                          r"the same channels as config\.maneuvers\.validation"):
        check_case(config, "tanks.yaml")
    changed = bytearray(original.read_bytes())
    changed[-2:-1] = b"7" if changed[-2:-1] != b"7" else b"8"
    copy_path.write_bytes(bytes(changed))
    check_case(config, "tanks.yaml")


def test_overlap_of_a_slice_and_same_channels_in_two_roles_is_an_error(monkeypatch):
    from hybridfmu.case_checks import check_case

    monkeypatch.chdir(REPO)
    config = _tanks()
    config["maneuvers"]["test"]["channels"] = {"u": "uEst", "level": "yEst"}   # the estimation record again
    config["maneuvers"]["test"]["t_start_s"] = 3999.0
    with pytest.raises(ConfigError, match=r"^tanks\.yaml: config\.maneuvers\.test: role test reads the same raw log "
                                          r".* as config\.maneuvers\.validation \(role validation\) over an "
                                          r"overlapping time span \(3000 s to end and 3999 s to end\)"):
        check_case(config, "tanks.yaml")
    # the same file under another name (a relative and an absolute path) is the same log
    config["maneuvers"]["test"]["t_start_s"] = None
    config["maneuvers"]["test"]["t_end_s"] = 10.0
    config["maneuvers"]["test"]["raw"] = str(REPO / "config" / "cases" / "tanks" / "dataBenchmark.csv")
    with pytest.raises(ConfigError, match=r"config\.maneuvers\.test: .* config\.maneuvers\.train \(role train\)"):
        check_case(config, "tanks.yaml")
    config["maneuvers"]["test"]["t_start_s"], config["maneuvers"]["test"]["t_end_s"] = 4000.0, 4100.0
    with pytest.raises(ConfigError, match=r"config\.maneuvers\.test: .* config\.maneuvers\.validation"):
        check_case(config, "tanks.yaml")


# ---- fmu.model_name of a user FMU (fmu.source: path) ---------------------------------------------------------

def _user_fmu(tmp_path, model_name=None):
    import zipfile

    fmu = tmp_path / "MassSpring.fmu"
    with zipfile.ZipFile(fmu, "w") as archive:
        archive.write(REPO / "tests" / "fixtures" / "mass_spring" / "modelDescription.xml", "modelDescription.xml")
    section = {"source": "path", "path": str(fmu)}
    if model_name is not None:
        section["model_name"] = model_name
    return fmu, section


def test_model_name_of_a_user_fmu_is_checked_when_set(tmp_path):
    from hybridfmu.data.roles import model_interface

    fmu, section = _user_fmu(tmp_path, "MassSpring")
    assert model_interface({"fmu": section}).state_names == ["x", "v"]
    _, section = _user_fmu(tmp_path)   # not set: any FMU
    assert model_interface({"fmu": section}).input_names == ["force"]
    _, section = _user_fmu(tmp_path, "Oscillator")
    with pytest.raises(ConfigError, match=rf"^config\.fmu\.model_name: 'Oscillator' does not match the FMU {fmu} "
                                          r"\(modelName 'MassSpring', modelIdentifier 'MassSpring'\)"):
        model_interface({"fmu": section})


def test_model_name_is_optional_for_a_user_fmu_and_required_for_a_build(demo_config):
    config = copy.deepcopy(demo_config)
    config["fmu"] = {"source": "path", "path": "models/Plant.fmu"}
    validate_case_config(config)
    config["fmu"] = {"source": "build"}
    with pytest.raises(ConfigError, match=r"config\.fmu: 'model_name' is a required property"):
        validate_case_config(config)


# ---- files written atomically get the mode a plain open() gives ------------------------------------------------

@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_atomic_files_get_the_mode_of_a_plain_open(tmp_path, umask):
    import os
    import stat

    import pandas as pd

    from hybridfmu.io import write_json_atomic, write_parquet_atomic, write_text_atomic

    previous = os.umask(umask)
    try:
        plain = tmp_path / "plain.txt"
        with open(plain, "w") as handle:
            handle.write("x")
        written = [write_json_atomic(tmp_path / "a.json", {"a": 1}), write_text_atomic(tmp_path / "b.md", "b"),
                   write_parquet_atomic(tmp_path / "c.parquet", pd.DataFrame({"x": [1.0]})),
                   write_text_atomic(tmp_path / "b.md", "again")]   # replacing an existing file
    finally:
        os.umask(previous)
    expected = 0o666 & ~umask
    assert stat.S_IMODE(plain.stat().st_mode) == expected
    for path in written:
        assert stat.S_IMODE(path.stat().st_mode) == expected, (path, oct(path.stat().st_mode))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.md", "c.parquet", "plain.txt"]


def test_a_failed_atomic_write_leaves_the_earlier_file(tmp_path):
    from hybridfmu.io import atomic_path, write_text_atomic

    target = write_text_atomic(tmp_path / "report.md", "earlier")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("writer failed")
    assert target.read_text() == "earlier" and [p.name for p in tmp_path.iterdir()] == ["report.md"]


# ---- no test maneuver: said plainly in the diagnosis and as the workflow starts --------------------------------

def test_without_a_test_maneuver_the_diagnosis_says_the_held_out_check_was_not_run(tmp_path):
    import json

    from diagnosis_models import msd_maneuvers, msd_problem
    from hybridfmu.diagnosis.report import write_outputs
    from hybridfmu.diagnosis.run import run_diagnosis

    problem, model = msd_problem()
    measured = msd_maneuvers(None, duration_s=20.0)
    del measured["test"]
    result = run_diagnosis(problem, model, measured)
    assert result.how_far is None
    config = {"case": "msd", "maneuvers": {"train": {"role": "train"}, "validation": {"role": "validation"}}}
    paths = write_outputs(result, config, tmp_path)
    record = json.loads(paths["json"].read_text())
    assert record["how_far"] is None and record["test_maneuvers"] == []
    assert record["how_far_not_run"].startswith("There is no test maneuver")
    assert "add a maneuver with role: test" in record["how_far_not_run"]
    assert "Held-out check not run: There is no test maneuver" in record["verdict"]
    report = paths["report"].read_text()
    assert "## How far\n\n**Not run.** There is no test maneuver" in report
    assert "held-out check" in report and "role: test" in report


def test_with_a_test_maneuver_nothing_is_said_to_be_missing(demo_config):
    from hybridfmu.case_checks import case_warnings

    assert case_warnings(validate_case_config(demo_config), "demo.yaml") == []
    for name in [name for name, item in demo_config["maneuvers"].items() if item["role"] == "test"]:
        del demo_config["maneuvers"][name]
    (warning,) = case_warnings(demo_config, "demo.yaml")
    assert warning.startswith("demo.yaml: config.maneuvers: no maneuver has role: test")
    assert "add a maneuver with role: test" in warning


def test_snakemake_warns_at_start_when_there_is_no_test_maneuver(tmp_path):
    config = yaml.safe_load((REPO / "config" / "cases" / "tiny.yaml").read_text())
    del config["maneuvers"]["test"]
    config["bench"]["maneuvers"].pop("test")
    path = tmp_path / "no_test.yaml"
    path.write_text(yaml.safe_dump(config))
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "-j1", "--snakefile", str(REPO / "Snakefile"), "--directory",
         str(tmp_path), "--configfile", str(path), "--nocolor"],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-3000:]
    assert f"Warning: {path}: config.maneuvers: no maneuver has role: test, so the held-out check" in output
    assert output.index("Warning:") < output.index("Building DAG")
