"""The options of the fitted effect shapes: defaults, what the schema accepts, config errors that name the
field, and the known-lag compensation still available next to the fitted input lag."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from diagnosis_models import msd_problem
from hybridfmu.config import ConfigError, validate_case_config
from hybridfmu.diagnosis.derivatives import savgol_derivative, savgol_smooth
from hybridfmu.diagnosis.effects import input_derivative
from hybridfmu.diagnosis.library import DEFAULT_KINDS
from hybridfmu.diagnosis.prepare import maneuver_from_frame
from hybridfmu.diagnosis.problem import DEFAULT_EFFECT_OPTIONS, diagnosis_settings
from hybridfmu.diagnosis.selection import SelectionSettings

REPO = Path(__file__).resolve().parents[1]
DEMO_CONFIG = REPO / "config" / "config.yaml"


def test_the_default_kinds_include_the_input_shapes():
    for kind in ("input_lag", "input_deadzone", "input_saturation"):
        assert kind in DEFAULT_KINDS and kind in DEFAULT_EFFECT_OPTIONS["kinds"]
    assert sorted(DEFAULT_EFFECT_OPTIONS["kinds"]) == sorted(DEFAULT_KINDS)
    settings = diagnosis_settings({"diagnosis": {"effects": {"periodic_harmonics": 2}}})["effects"]
    assert isinstance(settings["coulomb_smoothing_relative"], list) and len(settings["coulomb_smoothing_relative"]) > 1
    assert settings["lag_derivative_window_s"] is None and settings["input_quantiles"]
    assert settings["periodic_harmonics"] == 2
    assert settings["periodic_max_order"] is None and settings["periodic_orders"] == 3  # orders found in the data


@pytest.mark.parametrize("field, value", [
    ("coulomb_smoothing_relative", -0.01), ("coulomb_smoothing_relative", []),
    ("coulomb_smoothing_relative", ["a"]), ("stribeck_relative", [0.0]),
    ("input_quantiles", [0.0, 0.5]), ("input_quantiles", [1.2]), ("input_quantiles", 0.3),
    ("lag_derivative_window_s", 0.0), ("lag_derivative_window_s", "5"), ("actuator_lag_samples", [-1]),
    ("periodic_harmonics", 0), ("periodic_max_order", 2.5), ("periodic_orders", 0), ("periodic_orders", True),
])
def test_bad_effect_options_name_the_field(field, value):
    with pytest.raises(ConfigError, match=rf"config\.diagnosis\.effects\.{field}: expected"):
        msd_problem(effects={field: value})


def test_a_scalar_smoothing_and_an_empty_stribeck_grid_are_accepted():
    problem, _ = msd_problem(effects={"coulomb_smoothing_relative": 0.002, "stribeck_relative": [],
                                      "actuator_lag_samples": []})
    assert problem.settings["effects"]["coulomb_smoothing_relative"] == 0.002


def test_selection_thresholds_stay_configurable_and_unknown_ones_are_named():
    settings = SelectionSettings.from_config({"min_bic_drop": 4.0, "max_effects_per_group": 2})
    assert settings.min_bic_drop == 4.0 and settings.max_effects_per_equation == 2
    with pytest.raises(ConfigError, match=r"config\.diagnosis\.selection: unknown \['min_bic'\]"):
        SelectionSettings.from_config({"min_bic": 4.0})
    with pytest.raises(ConfigError, match=r"config\.diagnosis\.selection\.noise_margin: expected"):
        SelectionSettings.from_config({"noise_margin": -1.0})


#: The diagnosis section's schema (``config.schema.yaml`` refers to it for ``diagnosis``).
DIAGNOSIS_SCHEMA = REPO / "src" / "hybridfmu" / "schemas" / "diagnosis.schema.yaml"


@pytest.fixture()
def section():
    """The demo's diagnosis section (validated alone against its schema, as the case schema does)."""
    return yaml.safe_load(DEMO_CONFIG.read_text())["diagnosis"]


def test_the_case_schema_validates_the_diagnosis_section_with_this_schema():
    case_schema = yaml.safe_load((REPO / "src" / "hybridfmu" / "schemas" / "config.schema.yaml").read_text())
    assert case_schema["properties"]["diagnosis"]["$ref"].endswith("diagnosis.schema.yaml")


def test_the_schema_accepts_the_new_options_and_the_defaults(section):
    config = copy.deepcopy(section)
    config.setdefault("effects", {}).update(copy.deepcopy(DEFAULT_EFFECT_OPTIONS))
    config["effects"]["max_time_offset_s"] = 0.0004
    config["plugin_options"] = {"hybridfmu.diagnosis.effects_motor": {
        "duty_inputs": ["d_a", "d_b", "d_c"], "current_states": ["i_d", "i_q"], "angle_state": "theta",
        "pole_pairs_parameter": "p", "current_scale_relative": [0.01, 0.1]}}
    validate_case_config(config, DIAGNOSIS_SCHEMA)
    config = copy.deepcopy(section)
    config.setdefault("effects", {}).update({"coulomb_smoothing_relative": 0.004, "lag_derivative_window_s": 0.0007})
    validate_case_config(config, DIAGNOSIS_SCHEMA)


@pytest.mark.parametrize("field, value", [("coulomb_smoothing_relative", []), ("coulomb_smoothing_relative", -1.0),
                                          ("input_quantiles", [1.5]), ("lag_derivative_window_s", 0),
                                          ("kinds", ["input_lag", "input_sag"]), ("actuator_lag_samples", [0])])
def test_the_schema_rejects_bad_new_options_naming_the_field(section, field, value):
    section.setdefault("effects", {})[field] = value
    with pytest.raises(ConfigError, match=rf"config\.effects\.{field}"):
        validate_case_config(section, DIAGNOSIS_SCHEMA)


def test_a_known_sensor_lag_can_still_be_compensated_before_everything():
    """``diagnosis.input_lag_compensation_s`` (e.g. a datasheet value) still undoes a lag on loading."""
    dt = 0.01
    time_s = np.arange(0.0, 2.0, dt)
    force = np.sin(3.0 * time_s) + (time_s > 1.0)
    frame = pd.DataFrame({"time_s": time_s, "position": np.zeros_like(time_s), "velocity": np.zeros_like(time_s),
                          "force": force})
    problem, _ = msd_problem(input_lag_compensation_s={"F": 0.04})
    loaded = maneuver_from_frame("train", "train", frame, None, problem)
    expected = savgol_smooth(force, 5) + 0.04 * savgol_derivative(force, dt, 5)
    np.testing.assert_allclose(loaded.u[:, 0], expected, rtol=1e-12)
    plain = maneuver_from_frame("train", "train", frame, None, msd_problem()[0])
    np.testing.assert_allclose(plain.u[:, 0], force)
    with pytest.raises(ConfigError, match=r"config\.diagnosis\.input_lag_compensation_s"):
        msd_problem(input_lag_compensation_s={"G": 0.01})


def test_the_lag_derivative_window_defaults_to_5_samples():
    """The window option changes the input rate the lag effect (and the corrected model) uses."""
    u = np.zeros(50)
    u[20:] = 1.0
    default = input_derivative(u, 0.01)
    np.testing.assert_allclose(default, input_derivative(u, 0.01, 0.05))
    assert not np.allclose(default, input_derivative(u, 0.01, 0.09))
