"""Calibration stage: parameters and an unmeasured initial state recovered from synthetic data of the tanks
FMU, the 'nothing to fit' path, the record format, errors, and the MLflow run."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridfmu.calibration import Calibration, calibrated_parameters, open_loop_rmse, run_calibration
from hybridfmu.calibration.data import load_maneuver
from hybridfmu.calibration.tracking import flat_metrics, flat_params
from hybridfmu.data.roles import case_roles
from hybridfmu.config import ConfigError, validate_case_config
from hybridfmu.fmu import build_fmu, load_fmu, simulate_open_loop

TRUE = {"k1": 0.045, "k2": 0.065, "k3": 0.08, "k4": 0.055}
TRUE_X1 = {"train": 7.5, "validation": 3.0, "test": 7.5}


def tanks_config(tmp_path: Path, calibration: dict, parameters: dict | None = None) -> dict:
    """A validated tanks case config writing under tmp_path (raw paths are never read here)."""
    config = {
        "case": "tanks_test", "results_dir": str(tmp_path / "results"),
        "fmu": {"source": "build", "model_name": "CascadedTanks", "parameters": parameters or {}},
        "maneuvers": {"train": {"role": "train", "raw": "unused.csv"},
                      "validation": {"role": "validation", "raw": "unused.csv"},
                      "test": {"role": "test", "raw": "unused.csv", "initial_states_from": "train"}},
        "signals": {"u": {"channel": "uEst", "unit": "V", "resample": "hold", "label": "pump voltage"},
                    "level": {"channel": "yEst", "unit": "V", "label": "lower tank level"}},
        "roles": {"inputs": {"u": "u"}, "states": {"x2": "level"}, "targets": {"x2": 1.0}},
        "calibration": calibration,
    }
    return validate_case_config(copy.deepcopy(config))


@pytest.fixture(scope="module")
def tanks_fmu(tmp_path_factory) -> Path:
    return build_fmu("CascadedTanks", tmp_path_factory.mktemp("fmu") / "CascadedTanks.fmu")


def _frame(fmu: Path, n: int, seed: int, x0: list[float]) -> pd.DataFrame:
    """A maneuver of the true tanks on a 4 s grid: staircase pump voltage, simulated level, small noise."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(n) * 4.0
    u = np.repeat(rng.uniform(1.0, 8.0, n // 15 + 1), 15)[:n]
    with load_fmu(fmu, parameters=TRUE) as model:
        states = simulate_open_loop(model, time_s, u[:, None], np.array(x0)).states
    level = states[:, 1] + rng.normal(0.0, 0.005, n)
    return pd.DataFrame({"time_s": time_s, "u": u, "level": level})


@pytest.fixture(scope="module")
def synthetic(tanks_fmu, tmp_path_factory) -> dict[str, Path]:
    """Ingested-like Parquet files of train, validation and test maneuvers of the true tanks."""
    folder = tmp_path_factory.mktemp("data")
    paths = {}
    for seed, (name, n) in enumerate((("train", 400), ("validation", 150), ("test", 200))):
        path = folder / f"{name}.parquet"
        _frame(tanks_fmu, n, seed, [TRUE_X1[name], 4.0 + seed]).to_parquet(path, index=False)
        paths[name] = path
    return paths


def test_recovers_parameters_and_unmeasured_initial_states(tmp_path, tanks_fmu, synthetic):
    # k2 and k4 known: k1, k3 and x1(0) are identifiable from the lower level alone (fitting all four k's
    # leaves a scaling of the unmeasured x1 free)
    config = tanks_config(tmp_path, {"parameters": {"k1": {"min": 1e-4, "max": 1.0}, "k3": {"min": 1e-4, "max": 1.0}},
                                     "initial_states": True, "initial_state_bounds": {"x1": {"min": 0.0, "max": 30.0}},
                                     "max_iterations": 60},
                          parameters={"k2": TRUE["k2"], "k4": TRUE["k4"]})
    out = tmp_path / "calibration"
    data = {"train": synthetic["train"], "validation": synthetic["validation"]}
    calibration = run_calibration(config, tanks_fmu, data, out / "calibration.json", out / "calibration.png",
                                  track=False)
    assert calibration.fitted == ["k1", "k3"]
    for name in ("k1", "k3"):
        assert calibration.parameters[name] == pytest.approx(TRUE[name], rel=0.01), name
    assert calibration.parameters["k2"] == TRUE["k2"] and calibration.parameters["k4"] == TRUE["k4"]
    assert calibration.initial_states["train"]["x1"] == pytest.approx(TRUE_X1["train"], rel=0.02)
    assert calibration.initial_states["validation"]["x1"] == pytest.approx(TRUE_X1["validation"], rel=0.05)
    metrics = calibration.metrics
    for maneuver in ("train", "validation"):
        assert metrics["after"][maneuver]["level_rmse"] < 0.01  # the noise level
        assert metrics["after"][maneuver]["level_rmse"] < metrics["before"][maneuver]["level_rmse"]
    assert metrics["phases"]["train"]["cost"] < metrics["phases"]["train"]["cost_start"]
    # the files: the record round-trips, the figure is a PNG
    loaded = Calibration.load(out / "calibration.json")
    assert loaded.parameters == pytest.approx(calibration.parameters)
    assert (out / "calibration.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # later stages: parameters to load the FMU with, and the open loop of the test maneuver from the
    # train's initial state (initial_states_from)
    assert calibrated_parameters(config, out / "calibration.json") == pytest.approx(calibration.parameters)
    test_rmse = open_loop_rmse(config, tanks_fmu, out / "calibration.json", synthetic["test"], "test")
    assert test_rmse["level_rmse"] < 0.02


def test_nothing_to_fit_writes_the_config_parameters_without_simulating(tmp_path, synthetic):
    config = tanks_config(tmp_path, {"parameters": {}, "initial_states": False}, parameters={"k3": 0.08})
    out = tmp_path / "calibration"
    missing_fmu = tmp_path / "no_such.fmu"  # never opened: nothing is simulated
    calibration = run_calibration(config, missing_fmu, {"train": synthetic["train"],
                                                        "validation": synthetic["validation"]},
                                  out / "calibration.json", out / "calibration.png", track=False)
    record = json.loads((out / "calibration.json").read_text())
    assert set(record) == {"parameters", "fitted", "initial_states", "metrics"}
    assert record["parameters"] == {"k3": 0.08}
    assert record["fitted"] == [] and record["initial_states"] == {}
    assert record["metrics"]["fitted"] is False
    assert Calibration.load(out / "calibration.json").parameters == calibration.parameters
    assert (out / "calibration.png").stat().st_size > 0
    assert calibrated_parameters(config, out / "calibration.json") == {"k3": 0.08}
    assert calibrated_parameters(config, None) == {"k3": 0.08}
    with pytest.raises(FileNotFoundError, match="calibration record not found"):
        calibrated_parameters(config, tmp_path / "missing.json")
    # the test maneuver starts from the FMU's start value of x1 (no calibrated state)
    states = calibration.unmeasured_initial_states("test", config, {"x1": 5.0}, ["x1"])
    assert states == {"x1": 5.0}


def test_unknown_parameter_is_a_config_error_naming_the_field(tmp_path, tanks_fmu, synthetic):
    config = tanks_config(tmp_path, {"parameters": {"k9": {"min": 0.0, "max": 1.0}}})
    with pytest.raises(ConfigError, match=r"config\.calibration\.parameters\.k9.*k1"):
        run_calibration(config, tanks_fmu, dict(synthetic), tmp_path / "c.json", tmp_path / "c.png", track=False)
    assert not (tmp_path / "c.json").exists()


def test_bounds_and_data_errors_name_the_field_and_file(tmp_path, tanks_fmu, synthetic):
    config = tanks_config(tmp_path, {"parameters": {"k1": {"min": 1.0, "max": 0.5}}})
    with pytest.raises(ConfigError, match=r"config\.calibration\.parameters\.k1: min 1 is not below max 0\.5"):
        run_calibration(config, tanks_fmu, dict(synthetic), tmp_path / "c.json", tmp_path / "c.png", track=False)
    bad = tmp_path / "bad.parquet"
    pd.read_parquet(synthetic["train"]).drop(columns="level").to_parquet(bad)
    with pytest.raises(ValueError, match=r"bad\.parquet: no column 'level' \(FMU state x2\)"):
        load_maneuver(bad, case_roles(config), "train")
    config = tanks_config(tmp_path, {"parameters": {"k1": {"min": 0.0, "max": 1.0}}})
    with pytest.raises(ValueError, match=r"no ingested data given for the validation maneuver"):
        run_calibration(config, tanks_fmu, {"train": synthetic["train"]}, tmp_path / "c.json", tmp_path / "c.png",
                        track=False)


def test_mlflow_run_holds_fitted_values_and_rmse(tmp_path, synthetic):
    calibration = Calibration(parameters={"k1": 0.05, "k2": 0.06}, fitted=["k1"],
                              initial_states={"train": {"x1": 7.0}},
                              metrics={"before": {"train": {"level_rmse": 1.0}}, "after": {"train": {"level_rmse": 0.5}},
                                       "phases": {"validation:val": {"cost_start": 2.0, "cost": 1.0}}})
    assert flat_params(calibration) == {"k1": 0.05, "x0/train/x1": 7.0}
    assert flat_metrics(calibration) == {"before/train/level_rmse": 1.0, "after/train/level_rmse": 0.5,
                                         "validation/val/cost_start": 2.0, "validation/val/cost": 1.0}
    from mlflow.tracking import MlflowClient

    config = tanks_config(tmp_path, {"parameters": {}, "initial_states": False})
    out = tmp_path / "calibration"
    run_calibration(config, tmp_path / "unused.fmu", {"train": synthetic["train"], "validation": synthetic["validation"]},
                    out / "calibration.json", out / "calibration.png", track=True)
    client = MlflowClient(tracking_uri=f"sqlite:///{(tmp_path / 'results').resolve() / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("tanks_test")
    runs = client.search_runs([experiment.experiment_id])
    assert [run.info.run_name for run in runs] == ["calibration"]
    assert runs[0].data.tags["hybridfmu.role"] == "calibration"
    artifacts = {a.path for a in client.list_artifacts(runs[0].info.run_id, "calibration")}
    assert artifacts == {"calibration/calibration.json", "calibration/calibration.png"}
