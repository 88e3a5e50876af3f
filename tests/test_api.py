"""The notebook API (hybridfmu.api) on the tanks case's real logs, without a workflow run: a case, its logs, its
FMU open loop, and clear errors for what is missing. Against a whole run's files (trained models, diagnosis):
tests/test_workflow_e2e.py runs docs/api.md after the tiny case's workflow."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridfmu import api
from hybridfmu.config import ConfigError

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def tanks(tmp_path, monkeypatch):
    """The tanks case from a folder of its own (its raw paths are the repository root's; results go here)."""
    (tmp_path / "config").symlink_to(REPO / "config")
    monkeypatch.chdir(tmp_path)
    return api.load_case("config/cases/tanks.yaml")


def test_a_log_is_read_as_rule_ingest_reads_it(tanks):
    from hybridfmu.data.ingest import ingest_log

    frame = api.read_log(tanks, "validation")
    assert frame.columns.tolist() == ["time_s", "u", "level"]
    assert frame.time_s.iloc[0] == 0.0 and np.all(np.diff(frame.time_s) > 0)
    pd.testing.assert_frame_equal(frame, ingest_log(tanks.config["maneuvers"]["validation"]["raw"], tanks.config,
                                                    "validation"))
    assert tanks.maneuvers == {"train": "train", "validation": "validation", "test": "test"}


def test_the_fmu_open_loop_starts_at_the_measurement_and_follows_the_inputs(tanks):
    frame = api.read_log(tanks, "train")
    states = api.simulate_fmu(tanks, frame, "train")
    assert api.fmu_file(tanks).resolve() == (Path.cwd() / "results" / "tanks" / "fmu" / "CascadedTanks.fmu").resolve()
    assert states.columns.tolist() == ["time_s", *tanks.roles.state_names]
    np.testing.assert_array_equal(states.time_s.to_numpy(), frame.time_s.to_numpy())
    measured = tanks.roles.measured_states[0]
    assert states[measured].iloc[0] == pytest.approx(frame[tanks.roles.states[measured]].iloc[0])
    assert np.all(np.isfinite(states[tanks.roles.state_names].to_numpy()))
    error = np.abs(states[measured] - frame[tanks.roles.states[measured]]).mean()
    assert 0 < error < np.ptp(frame[tanks.roles.states[measured]])  # a model of these tanks, not a copy of the data


def test_what_is_missing_is_named(tanks):
    with pytest.raises(ConfigError, match=r"tanks\.yaml: config\.maneuvers: no maneuver 'trian'"):
        api.read_log(tanks, "trian")
    with pytest.raises(ConfigError, match=r"tanks\.yaml: config\.maneuvers: .* missing \['validation', 'test'\]"):
        api.diagnose(tanks, {"train": api.read_log(tanks, "train")})
    with pytest.raises(FileNotFoundError, match=r"results/tanks: no results of case 'tanks'; run the workflow"):
        api.load_run(tanks)
    empty = api.Run(case=tanks, results_dir=Path("results/tanks"))
    with pytest.raises(FileNotFoundError, match=r"best\.json: the run has no chosen model of search 'hybrid'"):
        api.simulate_trained(tanks, api.read_log(tanks, "train"), "hybrid", run=empty)
    with pytest.raises(ValueError, match=r"search: expected one of \['hpo', 'hybrid'\]"):
        api.simulate_trained(tanks, api.read_log(tanks, "train"), "neural", run=empty)


def test_a_bad_config_is_named_with_its_file(tmp_path):
    path = tmp_path / "case.yaml"
    path.write_text((REPO / "config" / "cases" / "tanks.yaml").read_text().replace("role: train", "role: training", 1))
    with pytest.raises(ConfigError, match=r"case\.yaml: .*config\.maneuvers\.train\.role"):
        api.load_case(path)


def test_every_workflow_script_takes_its_functions_from_the_stages_module():
    """The rules call src/ through hybridfmu.api.stages only (the bench's own package aside), and every stage it
    lists is a function of the module it names."""
    import ast
    import inspect

    from hybridfmu.api import stages

    used = set()
    for script in sorted((REPO / "workflow" / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(script.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "hybridfmu":
                assert node.module == "hybridfmu.api.stages", f"{script.name}: from {node.module} import ..."
                used.update(alias.name for alias in node.names)
    assert used and used <= set(stages.STAGES), sorted(used - set(stages.STAGES))
    for name, module in stages.STAGES.items():
        function = getattr(stages, name)
        assert callable(function) and inspect.getmodule(function).__name__.startswith(module), (name, module)
    with pytest.raises(AttributeError, match="has no stage 'train'"):
        stages.train  # noqa: B018
