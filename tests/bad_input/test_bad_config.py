"""Bad case configs are answered before anything runs: one clear error naming the config file and the field
(config.x.y), with what was expected, and nothing already written is touched.

Most kinds are checked through the functions the workflow calls as it starts (``load_case_config``, which
reads the file strictly and validates it against the schema, and ``check_case``: roles against the FMU,
units, maneuvers, Hyperband budget); a few through ``snakemake -n`` on a copy of the tiny case, which must stop
before any job and before the MLflow store is created.
"""

from __future__ import annotations

import copy
import importlib.util
import os
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any, Callable

import pytest
import yaml

from hybridfmu.case_checks import check_case
from hybridfmu.config import ConfigError, load_case_config


def _suite_helpers():
    """The bad-input suite's helpers (tests/bad_input/conftest.py), by path: ``conftest`` names several modules."""
    spec = importlib.util.spec_from_file_location("bad_input_conftest", Path(__file__).with_name("conftest.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_HELPERS = _suite_helpers()
assert_names, snapshot, assert_intact = _HELPERS.assert_names, _HELPERS.snapshot, _HELPERS.assert_intact

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "config" / "cases" / "tiny.yaml"
IPBMOTOR_DESCRIPTION = REPO / "src" / "hybridfmu" / "fmu" / "c" / "ipbmotor" / "modelDescription.xml"
MASS_SPRING_DESCRIPTION = REPO / "tests" / "fixtures" / "mass_spring" / "modelDescription.xml"


def tiny_config() -> dict[str, Any]:
    return yaml.safe_load(TINY.read_text())


def write_config(folder: Path, config: dict[str, Any], name: str = "case.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def edited_tiny(folder: Path, edit: Callable[[dict[str, Any]], None], name: str = "case.yaml") -> Path:
    """A copy of the tiny case with ``edit`` applied, its results under ``folder``."""
    config = copy.deepcopy(tiny_config())
    config["results_dir"] = str(folder / "results")
    edit(config)
    return write_config(folder, config, name)


def edited_tiny_text(folder: Path, old: str, new: str, name: str = "case.yaml") -> Path:
    """A copy of the tiny case file with one text replacement (for what a YAML dump cannot write)."""
    text = TINY.read_text()
    assert old in text, old
    path = folder / name
    path.write_text(text.replace(old, new, 1))
    return path


def fake_fmu(description: Path, destination: Path) -> Path:
    """An FMU archive holding only its modelDescription.xml (enough for every check before a job runs)."""
    with zipfile.ZipFile(destination, "w") as archive:
        archive.write(description, "modelDescription.xml")
    return destination


def config_error(path: Path, outputs: Path) -> str:
    """The message of the ConfigError the workflow's start-up checks raise for ``path``; nothing is written."""
    before = snapshot(outputs)
    with pytest.raises(ConfigError) as caught:
        check_case(load_case_config(path), str(path))
    assert_intact(outputs, before)
    message = str(caught.value)
    assert "\n" not in message.strip(), f"expected one line:\n{message}"
    return message


# ---- the kinds of bad config, each through the functions the workflow calls at its start ---------------------

def test_a_maneuver_key_listed_twice(tmp_path, outputs):
    path = edited_tiny_text(tmp_path, "  test: {role: test, raw: results/tiny/raw/test.mf4}\n",
                            "  test: {role: test, raw: results/tiny/raw/test.mf4}\n"
                            "  validation: {role: test, raw: results/tiny/raw/other.mf4}\n")
    message = config_error(path, outputs)
    line = TINY.read_text().splitlines().index("  test: {role: test, raw: results/tiny/raw/test.mf4}") + 2
    assert_names(message, f"{path}:{line}:", "config.maneuvers.validation", "listed twice", "expected each key once")


def test_a_key_listed_twice_deep_in_a_section(tmp_path, outputs):
    path = edited_tiny_text(tmp_path, "    beta1: {distribution: fixed, value: 0.9}\n",
                            "    beta1: {distribution: fixed, value: 0.9}\n"
                            "    lr: {distribution: fixed, value: 1.0e-3}\n")
    assert_names(config_error(path, outputs), str(path), "config.hpo.search_space.lr", "listed twice")


def test_malformed_yaml(tmp_path, outputs):
    path = edited_tiny_text(tmp_path, "  validation: {role: validation, raw: results/tiny/raw/validation.mf4}\n",
                            "  validation: {role: validation, raw: results/tiny/raw/validation.mf4\n")
    message = config_error(path, outputs)
    line = TINY.read_text().splitlines().index("  test: {role: test, raw: results/tiny/raw/test.mf4}") + 1
    assert_names(message, f"{path}:{line}:", "not valid YAML", "config.maneuvers.validation", "expected")


def test_a_tab_in_the_indentation(tmp_path, outputs):
    path = edited_tiny_text(tmp_path, "  R: 3\n", "\tR: 3\n")
    assert_names(config_error(path, outputs), str(path), "not valid YAML", "config.hpo", "tab", "spaces")


def test_the_test_maneuver_reads_the_validation_log(tmp_path, outputs):
    def edit(config):
        config["maneuvers"]["test"]["raw"] = config["maneuvers"]["validation"]["raw"]
    path = edited_tiny(tmp_path, edit)
    assert_names(config_error(path, outputs), str(path), "config.maneuvers.test", "config.maneuvers.validation",
                 "same raw log", "overlapping", "expected")


def test_overlapping_slices_of_one_log_in_train_and_validation(tmp_path, outputs):
    config = yaml.safe_load((REPO / "config" / "cases" / "tanks.yaml").read_text())
    config["results_dir"] = str(tmp_path / "results")
    config["maneuvers"]["train"]["raw"] = str(REPO / config["maneuvers"]["train"]["raw"])
    config["maneuvers"]["validation"]["raw"] = config["maneuvers"]["train"]["raw"]
    config["maneuvers"]["validation"]["t_start_s"] = 2500.0   # the train slice ends at 3000 s
    config["maneuvers"]["test"]["raw"] = config["maneuvers"]["train"]["raw"]
    path = write_config(tmp_path, config)
    assert_names(config_error(path, outputs), str(path), "config.maneuvers.validation", "config.maneuvers.train",
                 "2500 s to end", "start to 3000 s")


def test_r_smaller_than_eta(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["hpo"].update(R=2))
    assert_names(config_error(path, outputs), str(path), "config.hpo.R", "config.hpo.eta",
                 "expected config.hpo.R >= config.hpo.eta")


def test_eta_so_close_to_one_that_the_search_explodes(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["hpo"].update(R=81, eta=1.001))
    assert_names(config_error(path, outputs), str(path), "config.hpo.eta", "brackets", "expected at most")


def test_a_model_name_that_is_not_the_user_fmu(tmp_path, outputs):
    fmu = fake_fmu(MASS_SPRING_DESCRIPTION, tmp_path / "MassSpring.fmu")

    def edit(config):
        config["fmu"] = {"source": "path", "path": str(fmu), "model_name": "MassSpringDamper"}
    path = edited_tiny(tmp_path, edit)
    assert_names(config_error(path, outputs), str(path), "config.fmu.model_name", "'MassSpringDamper'", str(fmu),
                 "modelName 'MassSpring'", "expected")


def test_an_fmu_variable_that_does_not_exist_in_roles(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["roles"]["states"].update(psi_r="speed"))
    assert_names(config_error(path, outputs), str(path), "config.roles.states.psi_r", "has no state", "expected")


def test_a_signal_unit_of_the_wrong_dimension(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["signals"]["u_dc"].update(unit="A"))
    assert_names(config_error(path, outputs), str(path), "config.roles.inputs.u_dc", "'A'", "same dimension")


def test_a_missing_required_field(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["roles"].pop("states"))
    assert_names(config_error(path, outputs), str(path), "config.roles", "'states' is a required property")


def test_an_unknown_section(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c.update(trainig={"batch_windows": 2}))
    assert_names(config_error(path, outputs), str(path), "config (top level)", "'trainig' was unexpected")


def test_a_negative_rate(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["ingest"].update(rate_hz=-10000.0))
    assert_names(config_error(path, outputs), str(path), "config.ingest.rate_hz", "-10000")


def test_a_convention_between_samples_that_does_not_exist(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["roles"]["between_samples"].update(u_dc="cubic"))
    assert_names(config_error(path, outputs), str(path), "config.roles.between_samples.u_dc", "'cubic'", "'hold'",
                 "'linear'")


def test_a_maneuver_without_raw_file(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["maneuvers"]["test"].pop("raw"))
    assert_names(config_error(path, outputs), str(path), "config.maneuvers.test", "'raw' is a required property")


def test_a_target_that_is_not_a_measured_state(tmp_path, outputs):
    def edit(config):
        config["roles"]["states"].pop("theta")
        config["model"]["end_stop"] = None
    path = edited_tiny(tmp_path, edit)
    assert_names(config_error(path, outputs), str(path), "config.roles.targets.theta", "not a measured state")


def test_a_target_weight_that_is_not_positive(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["roles"]["targets"].update(theta=0))
    assert_names(config_error(path, outputs), str(path), "config.roles.targets.theta", "0")


def test_a_channel_override_for_a_signal_that_is_not_logged(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["maneuvers"]["test"].update(channels={"speeed": "MotPos_Speed2"}))
    assert_names(config_error(path, outputs), str(path), "config.maneuvers.test.channels.speeed",
                 "not a logged signal", "expected one of")


def test_a_slice_that_ends_before_it_starts(tmp_path, outputs):
    path = edited_tiny(tmp_path, lambda c: c["maneuvers"]["train"].update(t_start_s=2.0, t_end_s=1.0))
    assert_names(config_error(path, outputs), str(path), "config.maneuvers.train", "t_end_s = 1.0",
                 "expected a slice of positive length")


# ---- through Snakemake: it stops before any job, before the MLflow store exists --------------------------------

def snakemake_dry_run(workdir: Path, configfile: Path) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "snakemake", "-n", "-j1", "--snakefile", str(REPO / "Snakefile"),
               "--directory", str(workdir), "--configfile", str(configfile), "--nocolor"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    return subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300, env=env)


def assert_stopped_before_any_job(proc: subprocess.CompletedProcess, outputs: Path, before: dict[str, str],
                                  *parts: str) -> None:
    output = proc.stdout + proc.stderr
    assert proc.returncode != 0, output[-3000:]
    assert_names(output, *parts)
    assert "Job stats" not in output and "Building DAG" not in output, output[-3000:]
    assert_intact(outputs, before)
    assert not list(outputs.parent.rglob("mlflow.db")), "the MLflow store was created"
    assert not (outputs / "tiny").exists(), "a case folder was created"


def tiny_in(outputs: Path, edit: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """The tiny case with its results in the folder of earlier outputs (``outputs`` = <workdir>/results)."""
    config = tiny_config()
    config["results_dir"] = "results"
    if edit is not None:
        edit(config)
    return config


def test_snakemake_stops_on_a_maneuver_listed_twice(outputs):
    workdir = outputs.parent
    text = TINY.read_text().replace("  test: {role: test, raw: results/tiny/raw/test.mf4}\n",
                                    "  test: {role: test, raw: results/tiny/raw/test.mf4}\n"
                                    "  train: {role: test, raw: results/tiny/raw/other.mf4}\n", 1)
    path = workdir / "dup.yaml"
    path.write_text(text)
    before = snapshot(outputs)
    proc = snakemake_dry_run(workdir, path)
    assert_stopped_before_any_job(proc, outputs, before, f"{path}:", "config.maneuvers.train", "listed twice")


def test_snakemake_stops_on_one_raw_log_in_two_roles(outputs):
    workdir = outputs.parent

    def edit(config):
        config["maneuvers"]["test"]["raw"] = config["maneuvers"]["train"]["raw"]
    path = write_config(workdir, tiny_in(outputs, edit), "leak.yaml")
    before = snapshot(outputs)
    proc = snakemake_dry_run(workdir, path)
    assert_stopped_before_any_job(proc, outputs, before, str(path), "config.maneuvers.test",
                                  "config.maneuvers.train", "same raw log")


def test_snakemake_stops_on_a_wrong_model_name(outputs):
    workdir = outputs.parent
    fmu = fake_fmu(IPBMOTOR_DESCRIPTION, workdir / "motor.fmu")

    def edit(config):
        config["fmu"] = {"source": "path", "path": str(fmu), "model_name": "Motor"}
    path = write_config(workdir, tiny_in(outputs, edit), "wrong_name.yaml")
    before = snapshot(outputs)
    proc = snakemake_dry_run(workdir, path)
    assert_stopped_before_any_job(proc, outputs, before, str(path), "config.fmu.model_name", "'Motor'", str(fmu),
                                  "modelName 'IPBMotor'")


def test_snakemake_on_malformed_yaml_stops_and_the_check_names_file_and_line(outputs):
    """Snakemake parses --configfile itself before the workflow runs, and its message names neither the file nor
    the line; it stops before any job, and ``python -m hybridfmu.config`` names both."""
    workdir = outputs.parent
    path = edited_tiny_text(workdir, "  R: 3\n", "  R: [3\n", "broken.yaml")
    before = snapshot(outputs)
    proc = snakemake_dry_run(workdir, path)
    assert_stopped_before_any_job(proc, outputs, before, "not valid JSON or YAML")
    check = subprocess.run([sys.executable, "-m", "hybridfmu.config", str(path)], cwd=REPO, capture_output=True,
                           text=True, timeout=120)
    assert check.returncode == 1
    line = TINY.read_text().splitlines().index("  R: 3") + 1
    assert_names(check.stderr, f"{path}:", "not valid YAML", "config.hpo")
    assert any(f"{path}:{n}:" in check.stderr for n in (line, line + 1)), check.stderr


#: A name or value another section gives that the FMU does not have, refused before any job (not when the stage
#: that reads it starts, after the search): (key path, value, the field named, the words expected in the message).
FMU_NAME_MISTAKES = {
    "diagnosis equation": (("diagnosis", "equations"), ["omegaa"], "config.diagnosis.equations", "'omegaa'",
                           "measured state"),
    "corrected state": (("model", "corrected_states"), ["omegaa"], "config.model.corrected_states", "'omegaa'",
                        "not a state of the FMU"),
    "ANN input": (("model", "ann_inputs", "inputs"), ["d_x"], "config.model.ann_inputs.inputs", "'d_x'",
                  "not an input of the FMU"),
    "delay group input": (("model", "input_delay", "groups"), {"duties": ["d_a", "d_z"]},
                          "config.model.input_delay.groups.duties", "'d_z'", "not an input"),
    "end-stop parameter": (("model", "end_stop"), {"state": "theta", "rate_state": "omega",
                                                   "min_parameter": "theta_lo", "max_parameter": "theta_max"},
                           "config.model.end_stop.min_parameter", "'theta_lo'", "not a parameter"),
    "state from derivative": (("diagnosis", "state_from_derivative"), {"omega": "angle"},
                              "config.diagnosis.state_from_derivative", "'angle'", "measured state"),
    "FMU parameter": (("fmu", "parameters"), {"Rs": 0.1}, "config.fmu.parameters.Rs", "'Rs'",
                      "not a parameter of the FMU"),
    "FMU parameter value": (("fmu", "parameters"), {"R": float("nan")}, "config.fmu.parameters.R", "nan",
                            "expected a finite number"),
    "search space bounds": (("hpo", "search_space", "window_s"), {"distribution": "uniform", "low": 0.1, "high": 0.01},
                            "config.hpo.search_space.window_s", "low = 0.1", "expected low <= high"),
    "report scale state": (("diagnosis", "report_scale"), {"omegaa": "2.5e-4 kg*m**2"},
                           "config.diagnosis.report_scale", "'omegaa'", "not a state of the FMU"),
    "report scale quantity": (("diagnosis", "report_scale"), {"omega": "heavy"},
                              "config.diagnosis.report_scale.omega", "'heavy'", "expected a number and a unit"),
    "input between samples": (("roles", "between_samples"), {"u_dcc": "linear"}, "config.roles.between_samples",
                              "'u_dcc'", "not an input of the FMU"),
}


@pytest.mark.parametrize("mistake", sorted(FMU_NAME_MISTAKES))
def test_a_name_the_fmu_does_not_have_is_refused_at_start(tmp_path, outputs, mistake):
    keys, value, field, *words = FMU_NAME_MISTAKES[mistake]

    def edit(config):
        node = config
        for key in keys[:-1]:
            node = node.setdefault(key, {})
        node[keys[-1]] = value
    path = edited_tiny(tmp_path, edit)
    assert_names(config_error(path, outputs), str(path), field, *words, "expected")


def test_torchdiffeq_gradients_with_an_end_stop(tmp_path, outputs):
    """torchdiffeq's fixed-grid solvers have no end stop: refused at start, not in every training job."""
    def edit(config):
        config["training"]["gradients"] = "torchdiffeq"
    path = edited_tiny(tmp_path, edit)
    assert_names(config_error(path, outputs), str(path), "config.training.gradients", "config.model.end_stop",
                 "no end stop", "expected")
