"""Units through pint (hybridfmu.units) and the derived-signal transforms (hybridfmu.data.transforms)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybridfmu.data.transforms import TransformError, apply_transforms, output_units
from hybridfmu.data.transforms.motor import clarke_park, inverse_clarke_park
from hybridfmu.units import UnitError, converter, parse_unit, same_dimension, unit_string


def test_rpm_bar_and_modelica_spellings():
    assert converter("rpm", "rad/s") == pytest.approx((2 * math.pi / 60, 0.0))
    assert converter("1/min", "rpm") == pytest.approx((1.0, 0.0))  # the ECU spelling of rev/min
    assert converter("U/min", "rad/s") == pytest.approx((2 * math.pi / 60, 0.0))
    assert converter("bar", "Pa") == pytest.approx((1e5, 0.0))
    assert converter("%", "") == pytest.approx((0.01, 0.0))
    assert converter("N.m", "N*m") == pytest.approx((1.0, 0.0))
    assert converter("kg.m2", "kg*m**2") == pytest.approx((1.0, 0.0))
    assert converter("deg", "rad")[0] == pytest.approx(math.pi / 180)
    assert unit_string("N.m") == "N*m" and unit_string("rad/s") == "rad/s" and unit_string("1") == ""


def test_degc_is_affine():
    factor, offset = converter("degC", "K")
    assert (factor, offset) == pytest.approx((1.0, 273.15))
    factor, offset = converter("degC", "degF")
    assert factor * 100.0 + offset == pytest.approx(212.0)


def test_force_and_torque_are_refused_with_both_named():
    assert not same_dimension("N", "N*m")
    with pytest.raises(UnitError, match=r"cannot convert 'N' \(\[mass\] \* \[length\] / \[time\] \*\* 2\) to "
                                        r"'N\*m' \(\[mass\] \* \[length\] \*\* 2 / \[time\] \*\* 2\)"):
        converter("N", "N*m")


def test_unknown_unit_is_quoted():
    with pytest.raises(UnitError, match=r"unknown unit 'UpM'"):
        parse_unit("UpM")


def test_scale_unit_algebra_and_values():
    specs = [{"kind": "scale", "input": "p", "output": "torque", "factor": "0.0125 N*m/bar"},
             {"kind": "scale", "input": "p", "output": "force", "factor": "3.1416e-4 m**2"}]
    units = output_units(specs, {"p": "bar"})
    assert units["torque"] == "N*m"
    assert parse_unit(units["force"]).dimensionality == parse_unit("N").dimensionality
    columns = apply_transforms(specs, {"p": np.array([0.0, 100.0])}, units, 1000.0)
    np.testing.assert_allclose(columns["torque"], [0.0, 1.25])
    force_in_n = columns["force"] * converter(units["force"], "N")[0]
    np.testing.assert_allclose(force_in_n, [0.0, 100e5 * 3.1416e-4])


def test_scale_with_a_bad_factor_names_the_field():
    with pytest.raises(TransformError, match=r"config\.transforms\[0\] \(scale\)\.factor"):
        output_units([{"kind": "scale", "input": "p", "output": "t", "factor": "lots"}], {"p": "bar"})
    with pytest.raises(TransformError, match=r"config\.transforms\[0\] \(scale\): input signal\(s\) \['q'\]"):
        output_units([{"kind": "scale", "input": "q", "output": "t", "factor": "1 m"}], {"p": "bar"})


def test_park_against_hand_computed_values():
    # a = 1, b = c = -0.5 (A): alpha = 1, beta = 0. Angle 10 deg mechanical, 3 pole pairs: theta_e = 30 deg
    # -> d = cos 30 deg = 0.8660254, q = -sin 30 deg = -0.5.
    spec = {"kind": "park", "phases": ["a", "b", "c"], "angle": "angle", "pole_pairs": 3, "outputs": ["d", "q"]}
    units = output_units([spec], {"a": "A", "b": "A", "c": "A", "angle": "deg"})
    assert units["d"] == "A" and units["q"] == "A"
    columns = {"a": np.array([1.0]), "b": np.array([-0.5]), "c": np.array([-0.5]), "angle": np.array([10.0])}
    out = apply_transforms([spec], columns, units, 1000.0)
    assert out["d"][0] == pytest.approx(math.sqrt(3) / 2)
    assert out["q"][0] == pytest.approx(-0.5)
    # two phases: c = -a - b gives the same
    two = dict(spec, phases=["a", "b"])
    out2 = apply_transforms([two], {k: v.copy() for k, v in columns.items() if k != "c"},
                            output_units([two], {"a": "A", "b": "A", "angle": "deg"}), 1000.0)
    assert out2["d"][0] == pytest.approx(math.sqrt(3) / 2)


def test_park_inverts_and_checks_the_angle_unit():
    rng = np.random.default_rng(0)
    d, q, angle = rng.normal(size=50), rng.normal(size=50), rng.uniform(0, 10, 50)
    phases = inverse_clarke_park(d, q, angle)
    d_back, q_back = clarke_park(phases[:, 0], phases[:, 1], phases[:, 2], angle)
    np.testing.assert_allclose(d_back, d, atol=1e-12)
    np.testing.assert_allclose(q_back, q, atol=1e-12)
    spec = {"kind": "park", "phases": ["a", "b", "c"], "angle": "x", "pole_pairs": 4, "outputs": ["d", "q"]}
    with pytest.raises(TransformError, match=r"config\.transforms\[0\] \(park\)\.angle: signal 'x'"):
        output_units([spec], {"a": "A", "b": "A", "c": "A", "x": "m"})


def test_derivative_of_a_sine():
    rate_hz = 1000.0
    t = np.arange(2000) / rate_hz
    spec = {"kind": "derivative", "input": "x", "output": "v", "window_s": 0.02}
    units = output_units([spec], {"x": "mm"})
    assert parse_unit(units["v"]) == parse_unit("mm/s")
    out = apply_transforms([spec], {"x": np.sin(2 * math.pi * 2.0 * t)}, units, rate_hz)
    np.testing.assert_allclose(out["v"], 2 * math.pi * 2.0 * np.cos(2 * math.pi * 2.0 * t), atol=0.01 * 4 * math.pi)
