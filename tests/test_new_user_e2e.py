"""A new user's first run: their FMU, their 1 kHz CSV logs, a config that names only what only they can know.

The mass-spring FMU of tests/fixtures/mass_spring/ (viscous damping only) against CSV logs of a "real" mass-spring
with Coulomb friction, sampled at 1 kHz (not the demo's 10 kHz), with a continuously varying force logged
without a hold and a time column named ``time_s``. The case config sets the case, the FMU, the maneuvers, the
signals' channels and units, the roles and ``model.corrected_states``, nothing else: the grid, the time column,
the force's convention between samples, the delay bounds, the time-offset window, the search's budget and windows
are all chosen from the data. The whole workflow must run, the neural FMU must beat the FMU on the unseen test
maneuver, and the identified input delay must lie within one sample of 0 (the logs have none).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from hybridfmu.fmu.build import build_fmu_from_description
from test_workflow_e2e import snakemake

REPO = Path(__file__).resolve().parents[1]
FIXTURE = REPO / "tests" / "fixtures" / "mass_spring" / "modelDescription.xml"

pytestmark = pytest.mark.slow

RATE_HZ = 1000.0
#: The "real" mass-spring: the FMU's nominal mass, stiffness and damping plus Coulomb friction (N, smoothed over
#: a velocity in m/s) that the FMU lacks.
MASS_KG, STIFFNESS_N_M, DAMPING_N_S_M, COULOMB_N, SMOOTHING_M_S = 1.0, 40.0, 0.8, 0.8, 0.005


def force_n(time_s: float, waves: list[tuple[float, float, float]]) -> float:
    """The applied force (N) at ``time_s``: a sum of sines (amplitude N, frequency Hz, phase rad), continuous."""
    return sum(amplitude * math.sin(2.0 * math.pi * frequency * time_s + phase) for amplitude, frequency, phase in waves)


def measured_log(rng: np.random.Generator, duration_s: float) -> pd.DataFrame:
    """The log a 1 kHz logger writes: the force sampled as it is (no hold), position (mm) and velocity (m/s) of the
    real system (RK4 at ten steps per sample, the force evaluated at each stage's time) with sensor noise."""
    waves = [(rng.uniform(1.0, 3.0), rng.uniform(0.3, 3.0), rng.uniform(0.0, 2.0 * math.pi)) for _ in range(4)]
    substeps, dt = 10, 1.0 / (RATE_HZ * 10)

    def acceleration(x: float, v: float, t: float) -> float:
        friction = COULOMB_N * math.tanh(v / SMOOTHING_M_S)
        return (force_n(t, waves) - STIFFNESS_N_M * x - DAMPING_N_S_M * v - friction) / MASS_KG

    count = int(duration_s * RATE_HZ) + 1
    time_s = np.arange(count) / RATE_HZ
    positions, velocities = np.empty(count), np.empty(count)
    x = v = 0.0
    for k in range(count):
        positions[k], velocities[k] = x, v
        for n in range(substeps):
            t = time_s[k] + n * dt
            a1 = acceleration(x, v, t)
            x2, v2 = x + 0.5 * dt * v, v + 0.5 * dt * a1
            a2 = acceleration(x2, v2, t + 0.5 * dt)
            x3, v3 = x + 0.5 * dt * v2, v + 0.5 * dt * a2
            a3 = acceleration(x3, v3, t + 0.5 * dt)
            x4, v4 = x + dt * v3, v + dt * a3
            a4 = acceleration(x4, v4, t + dt)
            x += dt / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4)
            v += dt / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
    return pd.DataFrame({"time_s": time_s, "force_n": [force_n(t, waves) for t in time_s],
                         "position_mm": positions * 1e3 + rng.normal(0.0, 0.01, count),
                         "velocity_mps": velocities + rng.normal(0.0, 0.002, count)})


def new_user_config(root: Path, fmu: Path, logs: dict[str, Path]) -> dict:
    """Only what the user alone knows: the FMU, the logs and their roles, the channels and units, which signal
    is which FMU variable, the state equation to correct."""
    return {
        "case": "newuser",
        "results_dir": str(root / "results"),
        "fmu": {"source": "path", "path": str(fmu)},
        "maneuvers": {name: {"role": name, "raw": str(path)} for name, path in logs.items()},
        "signals": {"force": {"channel": "force_n", "unit": "N"},
                    "position": {"channel": "position_mm", "unit": "mm"},
                    "velocity": {"channel": "velocity_mps", "unit": "m/s"}},
        "roles": {"inputs": {"force": "force"}, "states": {"x": "position", "v": "velocity"}},
        "model": {"corrected_states": ["v"]},
    }


@pytest.fixture(scope="module")
def new_user_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("new_user")
    fmu = build_fmu_from_description(FIXTURE, root / "MassSpring.fmu")
    rng = np.random.default_rng(7)
    logs = {}
    for name, duration_s in (("train", 8.0), ("validation", 5.0), ("test", 5.0)):
        logs[name] = root / "logs" / f"{name}.csv"
        logs[name].parent.mkdir(exist_ok=True)
        measured_log(rng, duration_s).to_csv(logs[name], index=False)
    config = new_user_config(root, fmu, logs)
    configfile = root / "newuser.yaml"
    configfile.write_text(yaml.safe_dump(config, sort_keys=False))
    snakemake(root, configfile, timeout_s=1200)
    return config, root / "results" / "newuser"


def test_the_config_names_nothing_but_the_users_knowledge(new_user_run):
    config, _ = new_user_run
    assert set(config) == {"case", "results_dir", "fmu", "maneuvers", "signals", "roles", "model"}
    assert config["model"] == {"corrected_states": ["v"]}


def test_every_stage_runs_with_defaults_chosen_from_the_data(new_user_run):
    """The grid is the logs' own 1 kHz (the time column found by its name), the force between samples linear,
    the search's budget and windows and the delay and time-offset ranges are sized by it; the report says what
    was chosen."""
    _, results = new_user_run
    for name in ("data/grid.json", "hpo/best.json", "metrics/test.json", "report.md", "summary.md",
                 "diagnosis/diagnosis.json", "diagnosis/report.md", "figures/test_position.png"):
        assert (results / name).is_file(), name
    grid = json.loads((results / "data" / "grid.json").read_text())
    assert grid["rate_hz"] == 1000.0 and grid["chosen_from"] == "data"
    # the force is logged as it is, without a hold: linear, each simulation step holds its mean over the step
    assert grid["between_samples"]["force"]["convention"] == "linear"
    frame = pd.read_parquet(results / "data" / "train.parquet")
    assert np.allclose(np.diff(frame["time_s"].to_numpy()), 1e-3) and len(frame) == 8001
    assert pd.read_parquet(results / "data" / "test.parquet").attrs["between_samples"] == {"force": "linear"}
    plan = json.loads((results / "hpo" / "plan.json").read_text())
    assert plan["max_resource_s"] == pytest.approx(10 * 8.0, rel=0.05)
    windows = [c["hyperparameters"]["window_s"] for b in plan["brackets"] for c in b["configs"]]
    assert all(0.1 - 1e-9 <= w <= 0.4 + 1e-9 for w in windows)
    offset = json.loads((results / "evaluation" / "time_offset.json").read_text())
    assert offset["max_lag_s"] == pytest.approx(0.01)
    report = (results / "report.md").read_text()
    chosen = report.split("## Chosen from the data", 1)[1]
    for text in ("ingest.rate_hz = 1000 Hz", "roles.between_samples.force = linear", "hpo.max_resource_s",
                 "window_samples", "model.input_delay", "evaluation.time_offset.max_lag_s = 10 ms"):
        assert text in chosen, text


def test_a_notebook_reads_a_log_as_the_run_did(new_user_run):
    """hybridfmu.api.read_log takes what the config leaves out (the grid's rate, the force's convention between
    samples) from the run's choice, so the frame in memory is the run's ingested test maneuver."""
    from hybridfmu import api

    _, results = new_user_run
    case = api.load_case(results.parents[1] / "newuser.yaml")
    frame = api.read_log(case, "test")
    ingested = pd.read_parquet(results / "data" / "test.parquet")
    assert frame.attrs == ingested.attrs == {"between_samples": {"force": "linear"}}
    pd.testing.assert_frame_equal(frame, ingested)


def test_the_neural_fmu_beats_the_fmu_on_the_unseen_test_maneuver(new_user_run):
    _, results = new_user_run
    metrics = json.loads((results / "metrics" / "test.json").read_text())
    for signal in ("position", "velocity"):
        assert metrics["neural_fmu"][f"{signal}_mae"] < metrics["fmu"][f"{signal}_mae"], signal
    assert not [line for line in metrics.get("warnings", []) if "neural_fmu" in line]


def test_the_identified_input_delay_is_within_one_sample_of_zero(new_user_run):
    """The logs have no offset between channels: the time-offset stage's estimate of the input group and the
    neural FMU's learned delay both lie within one 1 ms sample of 0."""
    _, results = new_user_run
    offset = json.loads((results / "evaluation" / "time_offset.json").read_text())
    for group, entry in offset["groups"].items():
        assert abs(entry["delay_s"]) <= 1e-3, (group, entry)
    metrics = json.loads((results / "metrics" / "test.json").read_text())
    for group, delay_s in metrics["dt_s"].items():
        assert abs(delay_s) <= 1e-3, (group, delay_s)


def markdown_rows(text: str, header_start: str) -> list[dict[str, str]]:
    """The rows of the first Markdown table whose header row starts with ``header_start``: column -> cell."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    header = [cell.strip() for cell in lines[start].strip("|").split("|")]
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(header, (cell.strip() for cell in line.strip("|").split("|")))))
    return rows


def number(cell: str) -> float:
    """The leading number of a table cell ("0.0247 m", "0.000322 m (×76.7)", "×10.5")."""
    return float(cell.lstrip("×").split()[0])


def agrees(coarse: str, fine: float) -> bool:
    """Whether a number printed with fewer digits is ``fine`` rounded to those digits."""
    mantissa = coarse.lstrip("×").split()[0].split("e")[0].lstrip("-").replace(".", "").lstrip("0")
    return f"{fine:.{max(len(mantissa), 1)}g}" == f"{number(coarse):.{max(len(mantissa), 1)}g}"


def test_the_report_the_summary_and_the_diagnosis_quote_the_same_figures(new_user_run):
    """Every figure that appears twice is the same figure: the test errors of each model in report.md (improvement
    and all-models tables) and summary.md against metrics/test.json, the factors over the maneuvers in both, and
    the diagnosis' held-out errors in diagnosis/report.md against diagnosis.json."""
    _, results = new_user_run
    metrics = json.loads((results / "metrics" / "test.json").read_text())
    report, summary = (results / "report.md").read_text(), (results / "summary.md").read_text()
    models = {"FMU": "fmu", "neural FMU": "neural_fmu", "FMU + diagnosed effects": "fmu_effects"}
    compared = 0
    for row in markdown_rows(summary, "| signal | model | RMSE | MAE |"):
        key = next(value for label, value in models.items() if row["model"] == label or
                   (label == "FMU + diagnosed effects" and row["model"].startswith(label)))
        for measure in ("RMSE", "MAE"):
            assert agrees(row[measure], metrics[key][f"{row['signal']}_{measure.lower()}"]), (row, measure)
            compared += 1
    for row in markdown_rows(report, "| data | signal | measure | FMU | FMU + diagnosed effects |"):
        if row["data"] != "test":
            continue
        for label, key in models.items():
            assert agrees(row[label], metrics[key][f"{row['signal']}_{row['measure'].lower()}"]), (row, label)
            compared += 1
    for row in markdown_rows(report, "| data | signal | measure | FMU | neural FMU |"):
        if row["data"] == "test":
            assert agrees(row["neural FMU"], metrics["neural_fmu"][f"{row['signal']}_{row['measure'].lower()}"])
            compared += 1
    spread_report = [row for row in markdown_rows(report, "| data | maneuvers | model |") if row["data"] == "test"]
    assert spread_report == markdown_rows(summary, "| data | maneuvers | model |")
    record = json.loads((results / "diagnosis" / "diagnosis.json").read_text())
    diagnosis_report = (results / "diagnosis" / "report.md").read_text()
    steps = {step["model"]: step for step in record["how_far"]["steps"]}
    for row in markdown_rows(diagnosis_report, "| model | position RMS"):
        step = steps[row["model"].replace("\\|", "|")]
        assert agrees(row["position RMS [m]"], step["position_rmse"]) and agrees(row["normalised gap"], step["gap"])
        compared += 1
    assert compared >= 20
