"""Bench emulation end to end: closed loop, MDF4 channels, determinism, time offset, maneuver rules."""

from __future__ import annotations

import copy
import dataclasses
import json
import logging
from pathlib import Path

import numpy as np
import pytest
import yaml

from hybridfmu_bench.controller import ControllerSettings
from hybridfmu_bench.emulate import (CHANNELS, check_planned_spread, emulate_bench, run_maneuver,
                                     summarize_bench)
from hybridfmu_bench.maneuvers import check_spread
from hybridfmu_bench.settings import (EcuMapSettings, HydraulicsSettings, SensorSettings,
                                      parse_bench_settings)
from hybridfmu_bench.supply import Supply
from hybridfmu.config import load_case_config, validate_case_config

ROOT = Path(__file__).resolve().parents[1]
DEMO_CONFIG = ROOT / "config" / "config.yaml"
SCHEMA = ROOT / "src" / "hybridfmu" / "schemas" / "bench.schema.yaml"

SHORT_SEGMENTS = [
    {"kind": "rest", "duration_s": 0.1},
    {"kind": "ramp", "to_bar": 60, "duration_s": 0.3},
    {"kind": "hold", "duration_s": 0.2},
    {"kind": "step", "to_bar": 0, "duration_s": 0.15},
    {"kind": "rest", "duration_s": 11.5},  # pads to the 12 s minimum; the tests truncate the run
]


def short_config(offset_s: float = 3e-5, seed: int = 7) -> dict:
    """A case config with the demo's bench, plus a short maneuver 'quick' (run truncated to 0.8 s)."""
    config = copy.deepcopy(load_case_config(DEMO_CONFIG))
    config["bench"]["seed"] = seed
    config["bench"]["effects"]["channel_time_offset"] = {"offset_s": offset_s}
    config["bench"]["maneuvers"]["quick"] = {"speed_limit_rad_s": 150, "segments": copy.deepcopy(SHORT_SEGMENTS)}
    return config


def read_mdf(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray, str, str]]:
    from asammdf import MDF

    with MDF(path) as mdf:
        return {name: (sig.samples.copy(), sig.timestamps.copy(), sig.unit, sig.comment)
                for name in CHANNELS for sig in [mdf.get(name)]}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    truth = emulate_bench(short_config(), "quick", out / "quick.mf4", out / "quick.truth.json", duration_s=0.8,
                          check_spread_of_maneuvers=False)
    return out, truth


def test_demo_config_validates_and_parses():
    config = load_case_config(DEMO_CONFIG)
    settings = parse_bench_settings(config)
    assert set(settings.maneuvers) == set(config["maneuvers"])
    assert {e.name for e in settings.effects} >= {"coulomb_friction", "load_dependent_friction", "cogging",
                                                  "inverter_deadtime", "channel_time_offset"}
    assert 1e-5 <= settings.duty_log_offset_s() <= 1e-4
    kinds = {seg["kind"] for m in settings.maneuvers.values() for seg in m["segments"]}
    assert kinds == {"rest", "position", "ramp", "hold", "step", "sine"}
    for maneuver in settings.maneuvers.values():  # each has an end-stop approach below theta_min
        assert any(seg["kind"] == "position" and seg["to_rad"] < 0.0 for seg in maneuver["segments"])


def test_schema_defaults_equal_the_dataclass_defaults():
    schema = yaml.safe_load(SCHEMA.read_text())["properties"]
    pairs = [(HydraulicsSettings, schema["hydraulics"]), (Supply, schema["supply"]), (SensorSettings, schema["sensors"]),
             (ControllerSettings, schema["controller"]), (EcuMapSettings, schema["controller"]["properties"]["ecu_map"])]
    for cls, section in pairs:
        fields = {f.name: f.default for f in dataclasses.fields(cls)}
        props = {k: v for k, v in section["properties"].items() if k not in ("ecu_map", "acceleration_limit_rad_s2")}
        assert set(props) == set(fields), cls.__name__
        for name, default in fields.items():
            assert props[name]["default"] == default, f"{cls.__name__}.{name}"


def test_bad_bench_config_names_the_field():
    config = short_config()
    config["bench"]["sensors"]["encoder_bits"] = 12
    with pytest.raises(Exception, match=r"config\.bench\.sensors"):
        validate_case_config(config)
    config = short_config()
    config["bench"]["maneuvers"]["quick"]["segments"][0]["kind"] = "ramp"
    config["bench"]["maneuvers"]["quick"]["segments"][0]["to_bar"] = 10
    with pytest.raises(ValueError, match=r"config\.bench\.maneuvers\.quick\.segments: the first and the last"):
        parse_bench_settings(config)
    config = short_config()
    config["bench"]["maneuvers"]["quick"]["segments"][-1]["duration_s"] = 30.0
    with pytest.raises(ValueError, match=r"maneuvers\.quick\.segments: total duration"):
        parse_bench_settings(config)
    config = short_config()
    config["bench"]["maneuvers"]["quick"]["segments"][1]["to_rad"] = 3.0
    with pytest.raises(ValueError, match=r"maneuvers\.quick\.segments\[1\]: unknown key"):
        parse_bench_settings(config)
    with pytest.raises(ValueError, match=r"config\.bench: the case config has no bench section"):
        parse_bench_settings({"case": "x"})
    with pytest.raises(ValueError, match=r"no maneuver 'nope'"):
        emulate_bench(short_config(), "nope", "/nonexistent/a.mf4", "/nonexistent/a.json",
                      check_spread_of_maneuvers=False)


def test_mdf4_has_the_contract_channels_units_and_rates(quick_run):
    out, truth = quick_run
    channels = read_mdf(out / "quick.mf4")
    units = {"MotCtl_DutyA": "%", "MotCtl_DutyB": "%", "MotCtl_DutyC": "%", "MotPos_Angle": "deg",
             "MotPos_Speed": "rpm", "MotCur_IPhA": "A", "MotCur_IPhB": "A", "MotCur_IPhC": "A",
             "Hyd_Pressure": "bar", "Sply_UDc": "V"}
    rates = {name: 10000.0 for name in units}
    rates.update({"Hyd_Pressure": 1000.0, "Sply_UDc": 1000.0})
    for name, unit in units.items():
        samples, stamps, got_unit, comment = channels[name]
        assert got_unit == unit and comment, name
        assert np.all(np.isfinite(samples)) and samples.size == stamps.size
        assert np.allclose(np.diff(stamps), 1.0 / rates[name]), name
        assert stamps[-1] == pytest.approx(0.8 - 1.0 / rates[name], abs=1e-4)
    angle_deg = channels["MotPos_Angle"][0]
    step_deg = 360.0 / 16384
    np.testing.assert_allclose(angle_deg / step_deg, np.round(angle_deg / step_deg), atol=1e-6)  # quantised
    assert angle_deg[0] == pytest.approx(np.degrees(0.5), abs=step_deg)  # the rest angle
    duty = channels["MotCtl_DutyA"][0]
    assert 0.0 <= duty.min() and duty.max() <= 100.0 and duty.std() > 1.0
    pressure = channels["Hyd_Pressure"][0]
    assert pressure.max() == pytest.approx(60.0, abs=4.0)  # the ramp to 60 bar was tracked
    u_dc = channels["Sply_UDc"][0]
    assert 11.0 < u_dc.min() and u_dc.max() < 13.0
    assert not np.allclose(channels["MotCur_IPhA"][0] + channels["MotCur_IPhB"][0] + channels["MotCur_IPhC"][0],
                           0.0)  # independent sensor noise


def test_ground_truth_lists_effects_parameters_and_offset(quick_run):
    out, truth = quick_run
    stored = json.loads((out / "quick.truth.json").read_text())
    assert stored == json.loads(json.dumps(truth))
    assert stored["time_offset"]["duty_channels_offset_s"] == pytest.approx(3e-5)
    assert stored["true_parameters"]["R"] == pytest.approx(0.03 * 1.04)
    assert stored["true_parameters"]["J"] == pytest.approx(2e-4 * 1.06)  # inertia_mismatch
    names = [effect["name"] for effect in stored["effects"]]
    assert "coulomb_friction" in names and "channel_time_offset" in names
    assert stored["hydraulics"]["tau_load_nm_per_pa"] == pytest.approx(1.25e-7)
    assert stored["rest_angle_rad"] == 0.5
    summary = stored["summary"]
    assert 55.0 < summary["max_pressure_bar"] < 70.0
    assert summary["max_abs_omega_rad_s"] <= 150.0 * 1.1
    assert summary["max_current_amplitude_a"] < 120.0


def test_same_seed_gives_identical_signals_and_another_seed_other_noise(tmp_path):
    def signals(seed: int, name: str) -> dict:
        emulate_bench(short_config(seed=seed), "quick", tmp_path / f"{name}.mf4", tmp_path / f"{name}.json",
                      duration_s=0.15, check_spread_of_maneuvers=False)
        return read_mdf(tmp_path / f"{name}.mf4")

    first, again, other = signals(11, "a"), signals(11, "b"), signals(12, "c")
    for name in CHANNELS:
        np.testing.assert_array_equal(first[name][0], again[name][0])
        np.testing.assert_array_equal(first[name][1], again[name][1])
    assert not np.array_equal(first["MotCur_IPhA"][0], other["MotCur_IPhA"][0])


def test_time_offset_shifts_only_the_logged_duty_stamps():
    runs = {}
    for offset_s in (0.0, 4e-5):
        settings = parse_bench_settings(short_config(offset_s=offset_s))
        runs[offset_s] = run_maneuver(settings, "quick", duration_s=0.2)
    plain, shifted = runs[0.0], runs[4e-5]
    np.testing.assert_allclose(shifted.duty_time_s - plain.duty_time_s, 4e-5, atol=1e-12)
    np.testing.assert_array_equal(shifted.time_s, plain.time_s)
    for name in CHANNELS:
        np.testing.assert_array_equal(shifted.logged[name], plain.logged[name])  # same physics, same noise
    # negative offsets drop the samples stamped before the recording start
    settings = parse_bench_settings(short_config(offset_s=-3e-5))
    early = run_maneuver(settings, "quick", duration_s=0.05)
    assert early.duty_time_s[0] == pytest.approx(7e-5) and early.logged["MotCtl_DutyA"].size == 499


def test_spread_rule_checks_every_pair():
    check_spread({"a": 100.0, "b": 111.2, "c": 130.0}, "max speed")
    with pytest.raises(ValueError, match=r"'a' and 'b': max speed 100 and 105 differ by 4\.8 %"):
        check_spread({"a": 100.0, "b": 105.0, "c": 130.0}, "max speed")


def test_demo_maneuvers_differ_by_ten_percent_in_max_load_and_speed():
    config = load_case_config(DEMO_CONFIG)
    roles = {name: item["role"] for name, item in config["maneuvers"].items()}
    planned = check_planned_spread(parse_bench_settings(config), roles=roles)
    assert set(planned) == set(roles) and sum(role == "test" for role in roles.values()) >= 6
    config["bench"]["maneuvers"]["test"]["speed_limit_rad_s"] = config["bench"]["maneuvers"]["train"][
        "speed_limit_rad_s"] - 5
    with pytest.raises(ValueError, match="planned max_abs_omega_rad_s"):
        check_planned_spread(parse_bench_settings(config), roles=roles)


def test_maneuvers_of_one_role_may_resemble_each_other():
    values = {"train": 100.0, "validation": 130.0, "test": 115.0, "test_b": 116.0}
    roles = {"train": "train", "validation": "validation", "test": "test", "test_b": "test"}
    check_spread(values, "max speed", roles=roles)
    with pytest.raises(ValueError, match="'test' and 'test_b'"):
        check_spread(values, "max speed")
    with pytest.raises(ValueError, match="'train' and 'test_b'"):
        check_spread({**values, "test_b": 105.0}, "max speed", roles=roles)


def test_realised_spread_is_checked_from_the_ground_truth(tmp_path):
    def truth(name: str, load: float, speed: float) -> Path:
        path = tmp_path / f"{name}.truth.json"
        path.write_text(json.dumps({"summary": {"max_tau_load_nm": load, "max_abs_omega_rad_s": speed,
                                                "max_pressure_bar": load / 0.0125, "duration_s": 15.0}}))
        return path

    paths = {"train": truth("train", 2.3, 240.0), "validation": truth("validation", 1.6, 180.0),
             "test": truth("test", 1.9, 214.0)}
    record = summarize_bench(paths, tmp_path / "summary.json")
    assert record["maneuvers"]["test"]["max_abs_omega_rad_s"] == 214.0
    assert (tmp_path / "summary.json").is_file()
    paths["test"] = truth("test", 1.9, 235.0)
    with pytest.raises(ValueError, match="'test' and 'train': max_abs_omega_rad_s"):
        summarize_bench(paths, tmp_path / "summary2.json")
    assert not (tmp_path / "summary2.json").exists()


def test_progress_lines_are_logged(caplog):
    settings = parse_bench_settings(short_config())
    with caplog.at_level(logging.INFO, logger="hybridfmu_bench"):
        run_maneuver(settings, "quick", duration_s=0.05)
    assert any("bench quick: done 0.05 simulated s" in record.getMessage() for record in caplog.records)


def test_fmu_reproduces_the_bench_without_effects_but_not_with_the_demo_effects(ipbmotor_fmu):
    from hybridfmu.fmu import load_fmu, simulate_open_loop

    def open_loop_gap(config: dict) -> float:
        """RMS speed error (rad/s) of the FMU run open loop on the bench's TRUE inputs, 20 ms windows."""
        run = run_maneuver(parse_bench_settings(config), "quick", duration_s=0.5)
        truth = run.truth
        duties = np.column_stack([run.logged[f"MotCtl_Duty{k}"] / 100.0 for k in "ABC"])  # as applied
        u = np.column_stack([duties, truth["u_dc_v"], truth["tau_load_nm"]])
        x = np.column_stack([truth["i_d_a"], truth["i_q_a"], truth["theta_rad"], truth["omega_rad_s"]])
        errors = []
        with load_fmu(ipbmotor_fmu) as model:
            for k0 in range(1000, 4800, 200):
                window = slice(k0, k0 + 200)
                result = simulate_open_loop(model, run.time_s[window], u[window], x[k0])
                errors.append(np.sqrt(np.mean((result.states[:, 3] - x[window, 3]) ** 2)))
        return float(np.mean(errors))

    ideal = short_config()
    ideal["bench"]["effects"] = {}
    ideal["bench"]["true_parameter_offsets"] = {}
    gap_ideal = open_loop_gap(ideal)
    gap_demo = open_loop_gap(short_config())
    assert gap_ideal < 0.05
    assert gap_demo > 20 * gap_ideal and gap_demo > 0.5


def test_raw_paths_must_be_the_bench_outputs():
    from hybridfmu_bench.settings import check_raw_paths

    config = load_case_config(DEMO_CONFIG)
    check_raw_paths(config, "results/ipb")
    config["maneuvers"]["test"]["raw"] = "logs/test.mf4"
    with pytest.raises(ValueError, match=r"config\.maneuvers\.test\.raw: .*'results/ipb/raw/test\.mf4'"):
        check_raw_paths(config, "results/ipb")
    config = load_case_config(DEMO_CONFIG)
    config["maneuvers"]["extra"] = {"role": "train", "raw": "results/ipb/raw/extra.mf4"}
    with pytest.raises(ValueError, match=r"config\.bench\.maneuvers: no maneuver 'extra'"):
        check_raw_paths(config, "results/ipb")


def test_time_scale_compresses_the_maneuvers_but_keeps_the_checks():
    config = load_case_config(ROOT / "config" / "cases" / "tiny.yaml")
    scale = config["bench"]["time_scale"]
    settings = parse_bench_settings(config)
    for name, designed in config["bench"]["maneuvers"].items():
        designed_s = sum(seg["duration_s"] for seg in designed["segments"])
        scaled_s = sum(seg["duration_s"] for seg in settings.maneuvers[name]["segments"])
        assert 12.0 <= designed_s <= 25.0 and 2.0 <= scaled_s <= 4.0
        assert scaled_s == pytest.approx(scale * designed_s)
        assert [seg.get("to_bar") for seg in settings.maneuvers[name]["segments"]] == \
            [seg.get("to_bar") for seg in designed["segments"]]
    check_planned_spread(settings)  # the 10 % rule holds for the compressed maneuvers too
    too_short = copy.deepcopy(config)
    too_short["bench"]["maneuvers"]["train"]["segments"][1]["duration_s"] = 0.1  # design below 12 s
    with pytest.raises(ValueError, match=r"config\.bench\.maneuvers\.train\.segments: total duration"):
        parse_bench_settings(too_short)
    for bad in (0.0, 1.5, True):
        wrong = copy.deepcopy(config)
        wrong["bench"]["time_scale"] = bad
        with pytest.raises(ValueError, match=r"config\.bench\.time_scale"):
            parse_bench_settings(wrong)
