"""Automatic segment selection from the case roles: rest spans excluded, every brake application kept, Fig. 8."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from hybridfmu.data.roles import CaseRoles, Signal
from hybridfmu.data.errors import DataError
from hybridfmu.data.segments import (
    read_segments, select_segments, span_mask, spans_from_mask,
)
from hybridfmu.data.segments_stage import select_segments_to_files

RATE_HZ = 10_000.0
DURATION_S = 12.0
#: brake applications (start, end) in s: build-up, hold, release
PULSES_S = [(2.0, 3.2), (4.5, 5.0), (6.0, 8.0), (9.6, 10.0)]
REST_THETA_RAD = 5.0


def smooth_step(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def maneuver_frame(seed=0, scale=1.0, pulses=PULSES_S):
    """A maneuver like the bench's: rest, pressure pulses (ramp up, hold, ramp down), rest; noisy sensors."""
    rng = np.random.default_rng(seed)
    time_s = np.arange(int(DURATION_S * RATE_HZ)) / RATE_HZ
    theta = np.full_like(time_s, REST_THETA_RAD)
    for index, (start, end) in enumerate(pulses):
        ramp = min(0.15, (end - start) / 3)
        stroke = 5.0 + 1.0 * index
        theta += stroke * (smooth_step((time_s - start) / ramp) - smooth_step((time_s - end + ramp) / ramp))
    omega = np.gradient(theta, time_s)
    pressure_bar = np.where(theta > 6.0, 4.6 * np.expm1((theta - 6.0) / 2.0), 0.0)
    tau_load = 0.0125 * pressure_bar
    # differential duties ~ (R i + back-EMF) / U_dc; i ~ load torque; plus PWM-resolution noise
    amplitude = 0.02 * tau_load + 0.0009 * omega
    angle_e = 4 * theta
    duties = [0.5 + amplitude * np.cos(angle_e - k * 2 * math.pi / 3) + rng.normal(0, 2e-4, time_s.size)
              for k in range(3)]
    return pd.DataFrame({
        "time_s": time_s,
        "duty_a": duties[0], "duty_b": duties[1], "duty_c": duties[2],
        "u_dc": 12.0 + rng.normal(0, 0.02, time_s.size) + 0.1 * np.sin(2 * math.pi * 90.0 * time_s),
        "load_torque": scale * (tau_load + rng.normal(0, 0.0025, time_s.size)),
        "angle": scale * (theta + np.floor(rng.uniform(0, 1, time_s.size) * 2) * 2 * math.pi / 16384),
        "speed": scale * (omega + rng.normal(0, 0.5, time_s.size)),
    })


def motor_roles() -> CaseRoles:
    """Roles of the demo motor (FMU names arbitrary here: the selection only reads the signals)."""
    units = {"duty_a": "", "duty_b": "", "duty_c": "", "u_dc": "V", "load_torque": "N*m", "angle": "rad",
             "speed": "rad/s"}
    signals = {name: Signal(name, unit, unit, name.replace("_", " "), channel=name) for name, unit in units.items()}
    inputs = {"d_a": "duty_a", "d_b": "duty_b", "d_c": "duty_c", "u_dc": "u_dc", "tau_load": "load_torque"}
    return CaseRoles(signals=signals, transforms=[], state_names=["theta", "omega", "i_q"],
                     input_names=list(inputs), inputs=inputs, states={"theta": "angle", "omega": "speed"},
                     target_weights={"theta": 0.5, "omega": 0.5})


ROLES = motor_roles()


@pytest.fixture(scope="module")
def frame():
    return maneuver_frame()


def test_keeps_every_brake_application_and_drops_rest(frame):
    selection = select_segments(frame, ROLES, {})
    time_s = frame["time_s"].to_numpy()
    kept = span_mask(time_s, selection.spans_s)
    for start, end in PULSES_S:
        inside = (time_s >= start) & (time_s <= end)
        assert kept[inside].all(), f"brake application {start}-{end} s not fully kept: {selection.spans_s}"
    for start, end in [(0.0, 1.7), (10.4, 12.0)]:  # rest before and after the test
        rest = (time_s >= start) & (time_s <= end)
        assert not kept[rest].any(), f"rest {start}-{end} s kept: {selection.spans_s}"
    # the rest between the first two applications (1.3 s) is dropped as well
    assert not kept[(time_s > 3.5) & (time_s < 4.2)].any()
    assert 0.25 < selection.fraction_kept < 0.6
    assert selection.fraction_kept == pytest.approx(kept.mean(), abs=0.01)
    for key in ("angle", "speed", "duty_a", "u_dc", "load_torque", "level_load_torque", "relative", "merge_gap_s",
                "pad_s"):
        assert key in selection.thresholds


def test_thresholds_follow_the_data_scale(frame):
    """Relative thresholds: the same data in other units gives the same spans."""
    scaled = maneuver_frame(scale=37.0)
    reference = select_segments(frame, ROLES, {})
    other = select_segments(scaled, ROLES, {})
    for name in ("speed", "angle", "load_torque", "level_load_torque"):
        assert other.thresholds[name] == pytest.approx(37.0 * reference.thresholds[name], rel=1e-6), name
    np.testing.assert_allclose(other.spans_s, reference.spans_s, atol=2e-4)


def test_pure_rest_selects_nothing():
    rest = maneuver_frame(pulses=[])
    selection = select_segments(rest, ROLES, {})
    assert selection.spans_s == [] and selection.fraction_kept == 0.0


def test_held_load_is_kept_by_the_input_levels():
    """A long hold under load (no motion, constant input): kept through the input's distance from rest."""
    held = maneuver_frame(pulses=[(2.0, 9.0)])
    time_s = held["time_s"].to_numpy()
    middle = (time_s > 4.0) & (time_s < 7.0)
    with_levels = select_segments(held, ROLES, {})
    without = select_segments(held, ROLES, {"input_levels": False})
    assert span_mask(time_s, with_levels.spans_s)[middle].all()
    assert not span_mask(time_s, without.spans_s)[middle].any()


def test_chosen_signals(frame):
    only_motion = select_segments(frame, ROLES, {"signals": ["speed"]})
    assert set(only_motion.thresholds) & set(ROLES.signals) == {"speed"}
    everything = select_segments(frame, ROLES, {})
    assert only_motion.fraction_kept <= everything.fraction_kept + 1e-12
    with pytest.raises(DataError, match=r"config\.segments\.signals: \['torque'\] are not signals of the case"):
        select_segments(frame, ROLES, {"signals": ["torque"]})


def test_spans_from_mask_merges_drops_and_pads():
    time_s = np.arange(0, 10.0, 0.01)
    active = np.zeros(time_s.size, dtype=bool)
    active[(time_s >= 1.0) & (time_s <= 2.0)] = True
    active[(time_s >= 2.1) & (time_s <= 2.5)] = True  # 0.1 s gap: merged
    active[(time_s >= 5.0) & (time_s <= 5.02)] = True  # short: dropped
    active[(time_s >= 9.9)] = True                      # padding clipped at the end
    spans = spans_from_mask(time_s, active, merge_gap_s=0.2, min_span_s=0.05, pad_s=0.3)
    assert spans == [(pytest.approx(0.7), pytest.approx(2.8)), (pytest.approx(9.6), pytest.approx(9.99))]
    # padded spans that overlap are merged (1.0-2.5 and 5.0-5.02 padded by 1.5 s), start clipped at 0
    spans = spans_from_mask(time_s, active, merge_gap_s=0.0, min_span_s=0.0, pad_s=1.5)
    assert spans == [(0.0, pytest.approx(6.52, abs=0.011)), (pytest.approx(8.4), pytest.approx(9.99))]


def test_files_contract_and_plot(frame, tmp_path):
    data = tmp_path / "data" / "train.parquet"
    data.parent.mkdir()
    frame.to_parquet(data, index=False)
    json_path, png_path = tmp_path / "segments" / "train.json", tmp_path / "segments" / "train.png"
    selection = select_segments_to_files(data, json_path, png_path, "train", {"segments": {}}, ROLES)
    record = json.loads(json_path.read_text())
    assert set(record) == {"maneuver", "spans_s", "thresholds", "fraction_kept"}
    assert record["maneuver"] == "train"
    assert record["spans_s"] == [[pytest.approx(a), pytest.approx(b)] for a, b in selection.spans_s]
    assert read_segments(json_path)["fraction_kept"] == pytest.approx(selection.fraction_kept)
    import matplotlib.image

    image = matplotlib.image.imread(png_path)
    assert image.shape[0] > 400 and image.shape[1] > 800
    # the shaded spans are green: some pixels are clearly greener than red and blue
    rgb = image[..., :3]
    assert ((rgb[..., 1] > rgb[..., 0] + 0.05) & (rgb[..., 1] > rgb[..., 2] + 0.05)).mean() > 0.05


def test_bad_inputs_name_the_file(frame, tmp_path):
    data = tmp_path / "data.parquet"
    frame.drop(columns=["load_torque"]).to_parquet(data, index=False)
    with pytest.raises(DataError, match=r"data.parquet: .*columns \['load_torque'\] missing"):
        select_segments_to_files(data, tmp_path / "s.json", tmp_path / "s.png", "x", {}, ROLES)
    assert not (tmp_path / "s.json").exists() and not (tmp_path / "s.png").exists()
    broken = tmp_path / "broken.json"
    broken.write_text('{"maneuver": "x", "spans_s": [[2, 1]], "thresholds": {}, "fraction_kept": 0}')
    with pytest.raises(DataError, match="broken.json: field 'spans_s'"):
        read_segments(broken)
