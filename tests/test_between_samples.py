"""How each FMU input passes between the grid's samples: held commands, continuous measurements without a delay."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hybridfmu.config import validate_case_config
from hybridfmu.data.between_samples import (choose_conventions, declared_conventions, frame_conventions,
                                             held_values, repeat_share)
from hybridfmu.data.errors import DataError
from hybridfmu.data.ingest import choose_grid, ingest_log, ingest_to_parquet
from hybridfmu.data.roles import case_roles
from hybridfmu.data.signals import input_array
from hybridfmu.fmu import load_fmu
from hybridfmu.fmu.build import build_fmu_from_description
from hybridfmu.fmu.simulate import simulate_open_loop

REPO = Path(__file__).resolve().parents[1]
FIXTURE = REPO / "tests" / "fixtures" / "mass_spring" / "modelDescription.xml"
RATE_HZ = 1000.0


@pytest.fixture(scope="module")
def mass_spring_fmu(tmp_path_factory) -> Path:
    return build_fmu_from_description(FIXTURE, tmp_path_factory.mktemp("fmu") / "MassSpring.fmu")


def force_n(time_s: np.ndarray) -> np.ndarray:
    """A continuous force (N): two sines."""
    return 2.0 * np.sin(2 * math.pi * 1.3 * time_s) + 1.0 * np.sin(2 * math.pi * 4.1 * time_s + 0.7)


def log_frame(duration_s: float, rng: np.random.Generator) -> pd.DataFrame:
    """A 1 kHz log: the continuous force as sampled, a pump command written at 50 Hz and logged at 1 kHz (it
    repeats), and a position with noise."""
    time_s = np.arange(int(duration_s * RATE_HZ) + 1) / RATE_HZ
    command = np.round(np.sin(2 * math.pi * 0.5 * np.floor(time_s * 50.0) / 50.0), 3)
    return pd.DataFrame({"time_s": time_s, "force_n": force_n(time_s), "command": command,
                         "position_m": 0.01 * np.sin(time_s) + rng.normal(0.0, 1e-5, time_s.size),
                         "velocity_mps": 0.01 * np.cos(time_s) + rng.normal(0.0, 1e-4, time_s.size)})


def case(fmu: Path, logs: dict[str, Path], **roles) -> dict:
    """A mass-spring case: the force from the log's force channel, or from the stepping command."""
    config = {
        "case": "between", "fmu": {"source": "path", "path": str(fmu)},
        "maneuvers": {name: {"role": name, "raw": str(path)} for name, path in logs.items()},
        "signals": {"force": {"channel": "force_n", "unit": "N"}, "command": {"channel": "command", "unit": "N"},
                    "position": {"channel": "position_m", "unit": "m"},
                    "velocity": {"channel": "velocity_mps", "unit": "m/s"}},
        "roles": {"inputs": {"force": "force"}, "states": {"x": "position", "v": "velocity"}, **roles},
        "ingest": {"rate_hz": RATE_HZ},
    }
    return validate_case_config(config)


def test_held_values_keep_a_command_and_hold_a_lines_mean():
    u = np.array([[0.0, 1.0], [1.0, 3.0], [2.0, 2.0], [3.0, 6.0]])
    held = held_values(u, ["hold", "linear"])
    assert np.array_equal(held[:, 0], u[:, 0])
    assert np.allclose(held[:-1, 1], [2.0, 2.5, 4.0])
    # the last row: the line half a step beyond the last sample, so that interpolating between the step centres
    # (the neural FMU's ``hold_center``) gives the last sample itself
    assert held[-1, 1] == pytest.approx(8.0)
    assert 0.5 * (held[-2, 1] + held[-1, 1]) == pytest.approx(u[-1, 1])
    with pytest.raises(ValueError, match="conventions"):
        held_values(u, ["hold", "cubic"])
    with pytest.raises(ValueError, match="shape"):
        held_values(u, ["hold"])


def test_a_stepping_channel_is_held_a_continuous_one_linear(mass_spring_fmu, tmp_path):
    frame = log_frame(2.0, np.random.default_rng(1))
    assert repeat_share(frame["command"].to_numpy()) > 0.9
    assert repeat_share(frame["force_n"].to_numpy()) < 0.01
    assert repeat_share(np.array([1.0])) == 1.0
    log = tmp_path / "train.csv"
    frame.to_csv(log, index=False)
    config = case(mass_spring_fmu, {"train": log})
    roles = case_roles(config)
    chosen = choose_conventions(["force"], {"force": [frame["force_n"].to_numpy()]}, roles)
    assert chosen["force"]["convention"] == "linear" and "moves continuously" in chosen["force"]["text"]
    stepping = case(mass_spring_fmu, {"train": log})
    stepping["roles"]["inputs"] = {"force": "command"}
    roles = case_roles(stepping)
    assert choose_conventions(["force"], {"command": [frame["command"].to_numpy()]},
                              roles)["force"]["convention"] == "hold"


def test_a_declared_convention_wins_and_a_held_resampling_means_held(mass_spring_fmu, tmp_path):
    log = tmp_path / "train.csv"
    log_frame(1.0, np.random.default_rng(2)).to_csv(log, index=False)
    config = case(mass_spring_fmu, {"train": log})
    assert declared_conventions(config, case_roles(config)) == {"force": None}
    declared = case(mass_spring_fmu, {"train": log}, between_samples={"force": "hold"})
    assert declared_conventions(declared, case_roles(declared)) == {"force": "hold"}
    resampled = case(mass_spring_fmu, {"train": log})
    resampled["signals"]["force"]["resample"] = "hold"
    assert declared_conventions(resampled, case_roles(resampled)) == {"force": "hold"}
    wrong = case(mass_spring_fmu, {"train": log})
    wrong["roles"]["between_samples"] = {"thrust": "linear"}
    with pytest.raises(DataError, match=r"config.roles.between_samples.*thrust"):
        declared_conventions(wrong, case_roles(wrong))


def test_the_choice_comes_from_train_and_validation_logs_and_reaches_every_reader(mass_spring_fmu, tmp_path):
    """choose_grid writes the choice; ingest records it in the frame (kept in Parquet); input_array applies it."""
    rng = np.random.default_rng(3)
    logs = {}
    for name in ("train", "validation"):
        logs[name] = tmp_path / f"{name}.csv"
        log_frame(1.0, rng).to_csv(logs[name], index=False)
    config = case(mass_spring_fmu, logs)
    record = choose_grid(logs, config, tmp_path / "grid.json")
    assert record["chosen_from"] == "config" and record["between_samples"]["force"]["convention"] == "linear"
    out = ingest_to_parquet(logs["train"], tmp_path / "data" / "train.parquet", config, "train",
                            between_samples={"force": "linear"})
    frame = pd.read_parquet(out)
    assert frame_conventions(frame, ["force"]) == ["linear"]
    u = input_array(frame, case_roles(config))[:, 0]
    sampled = frame["force"].to_numpy()
    assert np.allclose(u[:-1], 0.5 * (sampled[:-1] + sampled[1:]))
    # declared: held as sampled, whatever the logs say
    held = case(mass_spring_fmu, logs, between_samples={"force": "hold"})
    frame = ingest_log(logs["train"], held, "train")
    assert frame_conventions(frame, ["force"]) == ["hold"]
    assert np.array_equal(input_array(frame, case_roles(held))[:, 0], frame["force"].to_numpy())


def test_a_continuous_input_held_at_its_means_leaves_no_half_sample_delay(mass_spring_fmu):
    """The mass-spring FMU driven by a continuous force logged at 1 kHz, against the same FMU on a 50x finer grid
    (the reference): holding each sample over its step lags the force by half a sample and the position error
    shows it; holding the step's mean leaves an error at least ten times smaller."""
    model = load_fmu(mass_spring_fmu)
    duration_s, fine = 3.0, 50
    time_s = np.arange(int(duration_s * RATE_HZ) + 1) / RATE_HZ
    fine_s = np.arange(int(duration_s * RATE_HZ * fine) + 1) / (RATE_HZ * fine)
    x0 = np.zeros(2)
    reference = simulate_open_loop(model, fine_s, held_values(force_n(fine_s)[:, None], ["linear"]), x0).states
    reference = reference[::fine]
    sampled = force_n(time_s)[:, None]
    errors = {}
    for convention in ("hold", "linear"):
        states = simulate_open_loop(model, time_s, held_values(sampled, [convention]), x0).states
        errors[convention] = float(np.sqrt(np.mean((states[:, 0] - reference[:, 0]) ** 2)))
    assert errors["linear"] * 10.0 < errors["hold"], errors
    # the held samples' error is that of a half-sample delay of the force: shifting the reference by it explains it
    delayed = simulate_open_loop(model, fine_s, held_values(force_n(fine_s - 0.5 / RATE_HZ)[:, None], ["linear"]),
                                 x0).states[::fine]
    sampled_held = simulate_open_loop(model, time_s, sampled, x0).states
    assert np.sqrt(np.mean((sampled_held[:, 0] - delayed[:, 0]) ** 2)) < 0.2 * errors["hold"]
