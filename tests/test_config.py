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
