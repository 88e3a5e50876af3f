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


# ---- the case's roles and units, checked before any job runs (hybridfmu.case.check_case) -----------------

def _case(demo_config):
    config = copy.deepcopy(demo_config)
    return config


def test_check_case_names_a_nonexistent_fmu_variable(demo_config):
    from hybridfmu.case import check_case

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
    from hybridfmu.case import check_case

    config = validate_case_config(_case(demo_config))
    config["signals"]["speed"]["unit"] = "N"
    with pytest.raises(ConfigError, match=r"case\.yaml: config\.roles\.states\.omega: signal 'speed' is in 'N' .* "
                                          r"declared in 'rad/s'"):
        check_case(config, "case.yaml")
    config["signals"]["speed"]["unit"] = "blub"
    with pytest.raises(ConfigError, match=r"config\.signals\.speed\.unit: unknown unit 'blub'"):
        check_case(config, "case.yaml")


def test_demo_and_tiny_cases_pass_check_case():
    from hybridfmu.case import check_case

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
