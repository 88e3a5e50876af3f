"""The bench plant: same equations as the FMU, hydraulics, end stops, integration accuracy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybridfmu_bench.hydraulics import PressureVolumeCurve, displacement_m3_per_rad
from hybridfmu_bench.parameters import NOMINAL_PARAMETERS, nominal_parameters, true_parameters
from hybridfmu_bench.plant import Plant
from hybridfmu_bench.supply import Supply

PERIOD_S = 1e-4
NO_PRESSURE = PressureVolumeCurve(1e6, 5.0, 1.5, 1.25e-7)
QUIET = Supply(12.0, 0.0, 0.0, 0.0)


def plant_at(theta0_rad: float = 1.0, curve: PressureVolumeCurve = NO_PRESSURE, substeps: int = 2,
             supply: Supply = QUIET) -> Plant:
    return Plant(dict(NOMINAL_PARAMETERS), curve, [], supply, PERIOD_S, substeps, theta0_rad)


def stator_voltages(duties: np.ndarray, u_dc_v: float) -> tuple[float, float]:
    """v_alpha, v_beta (V) of the contracts' phase voltages v_k = u_dc (d_k - mean(d))."""
    v = u_dc_v * (duties - duties.mean())
    return (2 / 3) * (v[0] - v[1] / 2 - v[2] / 2), (v[1] - v[2]) / math.sqrt(3)


def test_plant_without_effects_has_the_fmu_derivatives(ipbmotor_fmu):
    from hybridfmu.fmu import load_fmu

    rng = np.random.default_rng(3)
    n = 64
    x = np.column_stack([rng.uniform(-60, 60, n), rng.uniform(-120, 120, n), rng.uniform(0.5, 59.5, n),
                         rng.uniform(-300, 300, n)])
    u = np.column_stack([rng.uniform(0, 1, (n, 3)), rng.uniform(10, 14, n), rng.uniform(-3, 3, n)])
    with load_fmu(ipbmotor_fmu) as model:
        assert model.state_names == ["i_d", "i_q", "theta", "omega"]
        assert model.input_names == ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
        expected = model.derivatives(x, u)
    plant = plant_at()
    for row in range(n):
        v_al, v_be = stator_voltages(u[row, :3], u[row, 3])
        got = np.array(plant.derivatives(*x[row], v_al, v_be))
        got[3] -= u[row, 4] / NOMINAL_PARAMETERS["J"]  # the FMU takes tau_load as an input
        np.testing.assert_allclose(got, expected[row], rtol=1e-10, atol=1e-9)


def test_true_parameters_are_offsets_of_the_nominal_ones():
    nominal = nominal_parameters({"J": 2.5e-4, "not_a_parameter": 1.0})
    assert nominal["J"] == 2.5e-4 and nominal["R"] == NOMINAL_PARAMETERS["R"]
    true = true_parameters(nominal, {"R": 0.04, "psi": -0.03})
    assert true["R"] == pytest.approx(0.03 * 1.04) and true["psi"] == pytest.approx(6e-3 * 0.97)
    assert true["J"] == 2.5e-4
    with pytest.raises(ValueError, match=r"true_parameter_offsets\.p: unknown parameter"):
        true_parameters(nominal, {"p": 0.1})
    with pytest.raises(ValueError, match=r"true_parameter_offsets\.R: expected a relative offset"):
        true_parameters(nominal, {"R": 2.0})


def test_pressure_volume_curve_geometry_and_inverse():
    displacement = displacement_m3_per_rad(0.02, 0.0025)
    assert displacement == pytest.approx(1.25e-7, rel=1e-12)  # pi 0.01^2 * 0.0025 / (2 pi)
    curve = PressureVolumeCurve(5.3, 4.6, 1.45, displacement)
    theta = np.linspace(0.0, 55.0, 500)
    pressure = curve.pressure_bar_array(theta)
    assert np.all(pressure[theta <= 5.3] == 0.0)
    assert np.all(np.diff(pressure[theta > 5.3]) > 0) and np.all(np.diff(pressure[theta > 5.3], 2) > 0)  # stiffens
    assert 150.0 < curve.pressure_pa(48.0) / 1e5 < 200.0
    np.testing.assert_allclose(curve.angle_for_pressure_rad(pressure[theta > 5.3]), theta[theta > 5.3], rtol=1e-9)
    assert curve.pressure_pa(40.0) == pytest.approx(curve.pressure_bar_array(np.array([40.0]))[0] * 1e5)
    plant = plant_at(40.0, curve)
    assert plant.tau_load_nm() == pytest.approx(curve.pressure_pa(40.0) * 1.25e-7)
    with pytest.raises(ValueError, match="volume_scale_cm3"):
        PressureVolumeCurve(5.0, 4.0, 0.0, displacement)


def test_end_stop_holds_while_pushed_and_releases_when_the_torque_reverses():
    plant = plant_at(0.05)
    half = (0.5, 0.5, 0.5)
    # push towards theta_min: a constant negative q-current through a commutated voltage
    for k in range(300):
        th = plant.params["p"] * plant.theta
        v_q = 0.1 * (-20.0 - plant.i_q) + plant.params["p"] * plant.omega * plant.params["psi"]
        duties = tuple(0.5 + v_q * f / 12.0 for f in (-math.sin(th), -math.sin(th - 2 * math.pi / 3),
                                                     -math.sin(th + 2 * math.pi / 3)))
        plant.advance(*duties, k * PERIOD_S)
    assert plant.theta == NOMINAL_PARAMETERS["theta_min"] and plant.omega == 0.0
    assert plant.stop == -1 and plant.stop_contacts == 1 and plant.i_q < -5.0
    # remove the drive: the current decays, the rotor stays (no torque pulls it away)
    for k in range(50):
        plant.advance(*half, k * PERIOD_S)
    assert plant.theta == 0.0 and plant.omega == 0.0
    # drive away from the stop
    for k in range(100):
        th = plant.params["p"] * plant.theta
        v_q = 0.1 * (20.0 - plant.i_q) + plant.params["p"] * plant.omega * plant.params["psi"]
        duties = tuple(0.5 + v_q * f / 12.0 for f in (-math.sin(th), -math.sin(th - 2 * math.pi / 3),
                                                     -math.sin(th + 2 * math.pi / 3)))
        plant.advance(*duties, k * PERIOD_S)
    assert plant.theta > 0.0 and plant.omega > 0.0 and plant.stop == 0 and plant.stop_contacts == 1


def test_rk4_sub_steps_are_converged():
    rng = np.random.default_rng(0)
    duties = 0.5 + 0.3 * np.sin(np.arange(400)[:, None] * 0.05 + np.array([0.0, 2.1, 4.2])) \
        + 0.01 * rng.standard_normal((400, 3))
    finals = []
    for substeps in (1, 2, 8):
        plant = plant_at(20.0, PressureVolumeCurve(5.3, 4.6, 1.45, 1.25e-7), substeps)
        for k, d in enumerate(duties):
            plant.advance(*d, k * PERIOD_S)
        finals.append(np.array([plant.i_d, plant.i_q, plant.theta, plant.omega]))
    scale = np.abs(finals[2]) + 1.0
    assert np.max(np.abs(finals[1] - finals[2]) / scale) < 1e-5
    assert np.max(np.abs(finals[0] - finals[2]) / scale) < 1e-3


def test_supply_sags_with_the_inverter_current_and_ripples():
    supply = Supply(12.0, 0.02, 0.1, 100.0)
    assert supply.voltage_v(0.0, 50.0) == pytest.approx(11.0)
    assert supply.voltage_v(0.0025, 0.0) == pytest.approx(12.1)
    with pytest.raises(ValueError, match="nominal_v"):
        Supply(-1.0)
