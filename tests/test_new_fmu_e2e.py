"""An FMU the pipeline has never seen, driven through the config alone, end to end through Snakemake.

The test builds a small C model (a mass on a spring with viscous damping, one force input; sources in
tests/fixtures/mass_spring/, on the project's FMU core) into an FMU, writes CSV logs of a "real"
mass-spring whose physics the FMU lacks (Coulomb friction) with the column names and units a
user's logger would choose, writes a case config for them, and runs the whole workflow
(calibration, ingest, segments, baseline, Hyperband, evaluation, report, diagnosis). No code of the
package knows this model.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridfmu.fmu.build import build_fmu_from_description

REPO = Path(__file__).resolve().parents[1]
FIXTURE = REPO / "tests" / "fixtures" / "mass_spring" / "modelDescription.xml"

pytestmark = pytest.mark.slow

#: The FMU's nominal parameters (modelDescription.xml start values) and the "real" system's.
MASS_KG, STIFFNESS_N_M, DAMPING_N_S_M = 1.0, 40.0, 0.8
COULOMB_N = 0.8            # unmodelled: Coulomb friction, smoothed over 5 mm/s
SMOOTHING_M_S = 0.005
RATE_HZ = 500.0


def true_acceleration(x_m: np.ndarray, v_m_s: np.ndarray, force_n: np.ndarray) -> np.ndarray:
    """Acceleration (m/s^2) of the "real" mass-spring: the FMU's equation plus Coulomb friction."""
    friction_n = COULOMB_N * np.tanh(v_m_s / SMOOTHING_M_S)
    return (force_n - STIFFNESS_N_M * x_m - DAMPING_N_S_M * v_m_s - friction_n) / MASS_KG


def force_profile(rng: np.random.Generator, time_s: np.ndarray) -> np.ndarray:
    """A logged force (N): rest, then a sum of random sines and a few steps, then rest."""
    duration_s = time_s[-1]
    force = np.zeros_like(time_s)
    for _ in range(4):
        frequency_hz = rng.uniform(0.3, 3.0)
        force += rng.uniform(1.0, 3.0) * np.sin(2 * np.pi * frequency_hz * time_s + rng.uniform(0, 2 * np.pi))
    for start_s in rng.uniform(0.2 * duration_s, 0.8 * duration_s, size=3):
        force += rng.uniform(-2.0, 2.0) * (time_s >= start_s)
    active = (time_s > 0.1 * duration_s) & (time_s < 0.9 * duration_s)
    return np.where(active, force, 0.0)


def simulate_log(rng: np.random.Generator, duration_s: float) -> pd.DataFrame:
    """The "measured" log: RK4 at 10x the log rate, sampled at RATE_HZ, sensor noise added."""
    substeps = 10
    dt_s = 1.0 / (RATE_HZ * substeps)
    time_s = np.arange(int(duration_s * RATE_HZ) + 1) / RATE_HZ
    force = force_profile(rng, time_s)
    x, v = 0.0, 0.0
    positions, velocities = [], []
    for k in range(time_s.size):
        positions.append(x)
        velocities.append(v)
        f = np.array(force[k])
        for _ in range(substeps):
            def rhs(state):
                return np.array([state[1], true_acceleration(np.array(state[0]), np.array(state[1]), f)])
            s = np.array([x, v])
            k1 = rhs(s)
            k2 = rhs(s + 0.5 * dt_s * k1)
            k3 = rhs(s + 0.5 * dt_s * k2)
            k4 = rhs(s + dt_s * k3)
            x, v = s + dt_s * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
    return pd.DataFrame({
        "time_ms": time_s * 1e3,
        "force_n": force,
        "position_mm": np.asarray(positions) * 1e3 + rng.normal(0.0, 0.01, time_s.size),
        "velocity_mps": np.asarray(velocities) + rng.normal(0.0, 0.002, time_s.size),
    })


def case_config(root: Path, fmu: Path, logs: dict[str, Path]) -> dict:
    """The case config a user would write for this FMU and these logs (nothing else is needed)."""
    return {
        "case": "massspring",
        "results_dir": str(root / "results"),
        "seed": 5,
        "fmu": {"source": "path", "model_name": "MassSpring", "path": str(fmu)},
        "maneuvers": {name: {"role": name, "raw": str(path)} for name, path in logs.items()},
        "signals": {
            "force": {"channel": "force_n", "unit": "N", "label": "applied force"},
            "position": {"channel": "position_mm", "unit": "mm", "label": "position"},
            "velocity": {"channel": "velocity_mps", "unit": "m/s", "label": "velocity"},
        },
        "roles": {"inputs": {"force": "force"}, "states": {"x": "position", "v": "velocity"},
                  "targets": {"x": 0.5, "v": 0.5}},
        "ingest": {"rate_hz": RATE_HZ, "time": {"channel": "time_ms", "unit": "ms"}},
        "model": {"corrected_states": ["v"], "end_stop": None,
                  "input_delay": {"min_s": -0.004, "max_s": 0.004, "init_s": 0.0, "scale_s": 0.002}},
        "training": {"batch_windows": 4, "validation_every_s": None},
        "hpo": {"R": 3, "eta": 3, "max_resource_s": 60.0, "objective": {"loss": "MAE"},
                "search_space": {
                    "lr": {"distribution": "loguniform", "low": 3e-3, "high": 1e-2},
                    "beta1": {"distribution": "fixed", "value": 0.9},
                    "beta2": {"distribution": "fixed", "value": 0.999},
                    "window_s": {"distribution": "uniform", "low": 0.2, "high": 0.5},
                    "loss": {"distribution": "fixed", "value": "MAE"},
                    "width": {"distribution": "fixed", "value": 16},
                    "depth": {"distribution": "fixed", "value": 2},
                    "gate_opening": {"distribution": "fixed", "value": 0.3}}},
        "evaluation": {"zoom": {"length_s": 0.5, "criterion": "mse"},
                       "time_offset": {"length_s": 0.5, "max_lag_s": 0.004}, "plot": {"dpi": 60}},
        "diagnosis": {"kernel_s": 0.02, "smoothing_s": 0.01, "bootstrap_block_s": 0.5,
                      "open_loop": {"window_s": 0.5}, "selection": {"bootstrap_samples": 20},
                      "report_scale": {"v": f"{MASS_KG} kg"}},
    }


@pytest.fixture(scope="module")
def mass_spring_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("mass_spring")
    fmu = build_fmu_from_description(FIXTURE, root / "MassSpring.fmu")
    rng = np.random.default_rng(3)
    logs = {}
    for name, duration_s in (("train", 6.0), ("validation", 4.0), ("test", 4.0)):
        logs[name] = root / "logs" / f"{name}.csv"
        logs[name].parent.mkdir(exist_ok=True)
        simulate_log(rng, duration_s).to_csv(logs[name], index=False)
    configfile = root / "massspring.yaml"
    configfile.write_text(yaml.safe_dump(case_config(root, fmu, logs), sort_keys=False))
    command = [sys.executable, "-m", "snakemake", "-j2", "--snakefile", str(REPO / "Snakefile"),
               "--directory", str(root), "--configfile", str(configfile), "--nocolor"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    result = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=900, env=env)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-8000:]
    return root / "results" / "massspring"


def test_every_stage_runs_on_the_new_fmu(mass_spring_run):
    results = mass_spring_run
    frame = pd.read_parquet(results / "data" / "train.parquet")
    assert list(frame.columns) == ["time_s", "force", "position", "velocity"]
    # logged in mm, ingested in the FMU's declared unit (m)
    assert 0.005 < frame["position"].abs().max() < 1.0
    for name in ("calibration/calibration.json", "hpo/best.json", "report.md", "diagnosis/report.md",
                 "figures/test_position.png", "figures/test_velocity.png"):
        assert (results / name).is_file(), name


def test_the_neural_fmu_beats_the_fmu_on_unseen_data(mass_spring_run):
    metrics = json.loads((mass_spring_run / "metrics" / "test.json").read_text())
    assert set(metrics["fmu"]) == {f"{s}_{m}" for s in ("position", "velocity") for m in ("mae", "mse", "rmse")}
    assert metrics["neural_fmu"]["position_rmse"] < metrics["fmu"]["position_rmse"]
    assert metrics["neural_fmu"]["velocity_rmse"] < metrics["fmu"]["velocity_rmse"]


def test_the_diagnosis_finds_the_friction_the_fmu_lacks(mass_spring_run):
    record = json.loads((mass_spring_run / "diagnosis" / "diagnosis.json").read_text())
    found = record["which"]["found_effects"]
    assert found and found[0].startswith("coulomb(v)"), found
    far = record["how_far"]
    assert far["after"]["position_rmse"] < 0.5 * far["before"]["position_rmse"]
    # the Coulomb level also as the force it is (diagnosis.report_scale: the mass)
    report = (mass_spring_run / "diagnosis" / "report.md").read_text()
    section = report.split("### 1. `coulomb(v)`", 1)[1].split("###", 1)[0]
    assert f"× {MASS_KG} kg |" in section and " N |" in section


def test_the_models_of_the_new_fmu_leave_the_workflow_as_fmus(mass_spring_run):
    """Every trained model of a case no code of the package knows, exported as a Co-Simulation FMU around the
    user's FMU: valid for FMPy, and replayed with FMPy alone it reproduces the evaluation's test trajectory."""
    from export_checks import declared, problems, replay_deviation

    results = mass_spring_run
    frame = pd.read_parquet(results / "data" / "test.parquet")
    trajectories = pd.read_parquet(results / "evaluation" / "trajectories" / "test.parquet")
    for model in ("neural_fmu", "fmu_effects"):
        fmu = results / "export" / f"massspring_{model}.fmu"
        assert problems(fmu) == [], model
        info = declared(fmu)
        assert info["inputs"] == ["force"] and info["outputs"] == ["x", "v"]
        assert "resources/MassSpring.fmu" in info["files"]
        reference = trajectories[[f"{model}_state_{name}" for name in ("x", "v")]].to_numpy(dtype=float)
        deviation = replay_deviation(fmu, frame["time_s"].to_numpy(dtype=float), frame[["force"]].to_numpy(dtype=float),
                                     reference)
        assert np.all(deviation <= 1e-6), (model, deviation)
