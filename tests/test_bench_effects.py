"""Each effect of the bench catalog changes the plant's trajectory the way physics says.

Short open-loop runs of the plant (no controller): the voltage vector is commutated with the
TRUE rotor angle (an ideal brushless-DC drive), so the steady speed follows the torque balance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybridfmu_bench.effects import EFFECTS, Effect, build_effects, register_effect
from hybridfmu_bench.hydraulics import PressureVolumeCurve
from hybridfmu_bench.parameters import NOMINAL_PARAMETERS
from hybridfmu_bench.plant import Plant
from hybridfmu_bench.supply import Supply

PERIOD_S = 1e-4
NO_PRESSURE = PressureVolumeCurve(dead_travel_rad=1e6, pressure_scale_bar=5.0, volume_scale_cm3=1.5,
                                  displacement_m3_per_rad=1.25e-7)
STIFF_CIRCUIT = PressureVolumeCurve(dead_travel_rad=5.0, pressure_scale_bar=5.0, volume_scale_cm3=1.5,
                                    displacement_m3_per_rad=1.25e-7)
QUIET_SUPPLY = Supply(nominal_v=12.0, source_resistance_ohm=0.0, ripple_amplitude_v=0.0, ripple_frequency_hz=0.0)


def make_plant(effects: dict | None = None, curve: PressureVolumeCurve = NO_PRESSURE, theta0_rad: float = 1.0,
               params: dict | None = None) -> Plant:
    built = build_effects(effects or {}, 1.0 / PERIOD_S)
    true = dict(NOMINAL_PARAMETERS, **(params or {}))
    for effect in built:
        effect.adjust_parameters(true)
    return Plant(true, curve, built, QUIET_SUPPLY, PERIOD_S, 2, theta0_rad)


def commutated_duties(plant: Plant, v_q: float) -> tuple[float, float, float]:
    """Duties that put v_q on the rotor's true q axis and cancel the d-axis coupling (min-max zero sequence).

    The voltage vector is aligned with the mid-period angle, so that the held duties do not leak
    into the d axis.
    v_d = -p omega L_q i_q keeps i_d near 0, so the steady state follows the simple torque balance.
    """
    v_d = -plant.params["p"] * plant.omega * plant.params["L_q"] * plant.i_q
    th = plant.params["p"] * (plant.theta + 0.5 * PERIOD_S * plant.omega)  # mid-period angle
    c, s = math.cos(th), math.sin(th)
    v_al = v_d * c - v_q * s
    v_be = v_d * s + v_q * c
    v = (v_al, -0.5 * v_al + math.sqrt(3) / 2 * v_be, -0.5 * v_al - math.sqrt(3) / 2 * v_be)
    v0 = -0.5 * (max(v) + min(v))
    u_dc = plant.supply.nominal_v
    return tuple(0.5 + (vk + v0) / u_dc for vk in v)


def run_commutated(plant: Plant, v_q: float, duration_s: float) -> dict[str, np.ndarray]:
    """Drive ``plant`` open loop with a commutated q voltage (V); return speed, angle, i_q per period."""
    n = int(round(duration_s / PERIOD_S))
    omega, theta, i_q = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        plant.advance(*commutated_duties(plant, v_q), k * PERIOD_S)
        omega[k], theta[k], i_q[k] = plant.omega, plant.theta, plant.i_q
    return {"omega": omega, "theta": theta, "i_q": i_q}


# Torque balance of the commutated, decoupled drive at steady state (i_d ~ 0):
# k_t i_q = b w + T_f, v_q = R i_q + p psi w  ->  dw = -T_f / (k_t p psi / R + b)
K_T = 1.5 * NOMINAL_PARAMETERS["p"] * NOMINAL_PARAMETERS["psi"]
K_E = NOMINAL_PARAMETERS["p"] * NOMINAL_PARAMETERS["psi"]
DAMPING = K_T * K_E / NOMINAL_PARAMETERS["R"] + NOMINAL_PARAMETERS["b"]


def steady_speed(plant: Plant, v_q: float = 2.0, duration_s: float = 0.06) -> float:
    return float(np.mean(run_commutated(plant, v_q, duration_s)["omega"][-100:]))


def test_registry_holds_the_catalog_and_accepts_a_new_effect():
    for name in ("coulomb_friction", "viscous_friction", "load_dependent_friction", "cogging", "inverter_deadtime",
                 "channel_time_offset", "inertia_mismatch"):
        assert name in EFFECTS and EFFECTS[name].name == name

    @register_effect
    class ConstantDrag(Effect):
        """Test effect: a constant torque."""

        name = "test_constant_drag"
        PARAMETERS = {"torque_nm": 0.1}

        def torque_nm(self, theta_rad, omega_rad_s, tau_load_nm):
            return -self.params["torque_nm"]

    try:
        (effect,) = build_effects({"test_constant_drag": {"torque_nm": 0.2}}, 1e4)
        assert effect.hooks() == ["torque_nm"]
        assert effect.describe()["parameters"] == {"torque_nm": 0.2}
        plant = make_plant({"test_constant_drag": {"torque_nm": 0.2}})
        assert plant.derivatives(0.0, 0.0, 1.0, 0.0, 0.0, 0.0)[3] == pytest.approx(-0.2 / NOMINAL_PARAMETERS["J"])
    finally:
        del EFFECTS["test_constant_drag"]


def test_effects_are_off_unless_configured_and_bad_parameters_name_the_field():
    assert build_effects({}, 1e4) == []
    assert build_effects({"cogging": {"enabled": False}}, 1e4) == []
    with pytest.raises(ValueError, match=r"config\.bench\.effects\.no_such_effect: unknown effect"):
        build_effects({"no_such_effect": {}}, 1e4)
    with pytest.raises(ValueError, match=r"config\.bench\.effects\.coulomb_friction: unknown parameter"):
        build_effects({"coulomb_friction": {"torque": 0.1}}, 1e4)
    with pytest.raises(ValueError, match=r"coulomb_friction\.coulomb_torque_nm: expected a finite number"):
        build_effects({"coulomb_friction": {"coulomb_torque_nm": "a lot"}}, 1e4)
    with pytest.raises(ValueError, match=r"cogging\.harmonics\[0\]\.order_per_rev"):
        build_effects({"cogging": {"harmonics": [{"order_per_rev": 0, "amplitude_nm": 0.01}]}}, 1e4)
    with pytest.raises(ValueError, match=r"inverter_deadtime\.deadtime_s"):
        build_effects({"inverter_deadtime": {"deadtime_s": 2e-5}}, 1e4)


def test_coulomb_friction_lowers_the_speed_at_equal_duty():
    torque_nm = 0.05
    free = steady_speed(make_plant())
    rubbed = steady_speed(make_plant({"coulomb_friction": {"coulomb_torque_nm": torque_nm,
                                                           "breakaway_torque_nm": 0.08}}))
    assert free > 50.0
    assert free - rubbed == pytest.approx(torque_nm / DAMPING, rel=0.05)


def test_coulomb_friction_is_odd_in_speed_with_a_stribeck_peak():
    (effect,) = build_effects({"coulomb_friction": {"coulomb_torque_nm": 0.05, "breakaway_torque_nm": 0.08,
                                                    "stribeck_speed_rad_s": 3.0,
                                                    "smoothing_speed_rad_s": 0.2}}, 1e4)
    assert effect.torque_nm(0.0, 0.0, 0.0) == 0.0
    assert effect.torque_nm(0.0, 50.0, 0.0) == pytest.approx(-0.05, rel=1e-6)
    assert effect.torque_nm(0.0, -50.0, 0.0) == pytest.approx(0.05, rel=1e-6)
    assert effect.torque_nm(0.0, 1.0, 0.0) < -0.07  # near breakaway at low speed


def test_viscous_friction_lowers_the_speed_in_proportion_to_it():
    c = 4e-4
    free = steady_speed(make_plant())
    damped = steady_speed(make_plant({"viscous_friction": {"coefficient_nm_s": c}}))
    assert free - damped == pytest.approx(free * c / (DAMPING + c), rel=0.05)


def test_load_dependent_friction_grows_with_the_load_and_depends_on_direction():
    effects = {"load_dependent_friction": {"coefficient_apply": 0.10, "coefficient_release": 0.05,
                                           "smoothing_speed_rad_s": 0.5}}
    plain, rubbed = make_plant(curve=STIFF_CIRCUIT), make_plant(effects, curve=STIFF_CIRCUIT)
    inv_j = 1.0 / NOMINAL_PARAMETERS["J"]
    losses = []
    for theta in (20.0, 35.0, 45.0):
        load = plain.tau_load_nm(theta)
        apply = plain.derivatives(0.0, 50.0, theta, 50.0, 0.0, 0.0)[3] - rubbed.derivatives(
            0.0, 50.0, theta, 50.0, 0.0, 0.0)[3]
        release = plain.derivatives(0.0, 50.0, theta, -50.0, 0.0, 0.0)[3] - rubbed.derivatives(
            0.0, 50.0, theta, -50.0, 0.0, 0.0)[3]
        assert apply == pytest.approx(0.10 * load * inv_j, rel=1e-6)  # opposes +omega
        assert release == pytest.approx(-0.05 * load * inv_j, rel=1e-6)  # opposes -omega
        losses.append(apply)
    assert losses[0] < losses[1] < losses[2]
    # open loop against the pressure: the friction slows the apply stroke more the higher the load
    free = run_commutated(make_plant(curve=STIFF_CIRCUIT, theta0_rad=5.0), 5.0, 0.15)
    slowed = run_commutated(make_plant(effects, curve=STIFF_CIRCUIT, theta0_rad=5.0), 5.0, 0.15)
    assert np.all(slowed["theta"][200:] < free["theta"][200:])


def test_cogging_torque_is_periodic_in_the_angle_and_ripples_the_speed():
    effects = {"cogging": {"harmonics": [{"order_per_rev": 24, "amplitude_nm": 0.02, "phase_rad": 0.3}]}}
    plant = make_plant(effects)
    inv_j = 1.0 / NOMINAL_PARAMETERS["J"]
    angles = np.linspace(1.0, 1.0 + 2 * np.pi / 24, 50)
    torque = np.array([plant.derivatives(0.0, 0.0, th, 0.0, 0.0, 0.0)[3] for th in angles]) / inv_j
    shifted = np.array([plant.derivatives(0.0, 0.0, th + 2 * np.pi / 24, 0.0, 0.0, 0.0)[3] for th in angles]) / inv_j
    np.testing.assert_allclose(shifted, torque, atol=1e-12)
    assert torque.max() == pytest.approx(0.02, rel=0.01) and torque.min() == pytest.approx(-0.02, rel=0.01)
    # running: speed ripple at 24 periods per revolution, absent without cogging
    run = run_commutated(make_plant(effects), 2.0, 0.08)
    plain = run_commutated(make_plant(), 2.0, 0.08)
    tail = slice(400, None)
    ripple = run["omega"][tail] - plain["omega"][tail]
    phase = 24 * run["theta"][tail]
    fit = np.linalg.lstsq(np.column_stack([np.sin(phase), np.cos(phase), np.ones_like(phase)]), ripple, rcond=None)[0]
    explained = 1 - np.var(ripple - np.column_stack([np.sin(phase), np.cos(phase),
                                                      np.ones_like(phase)]) @ fit) / np.var(ripple)
    # amplitude of a torque ripple T sin(24 theta) on an inertia at speed w: T / (J 24 w)
    expected = 0.02 / (NOMINAL_PARAMETERS["J"] * 24 * np.mean(run["omega"][tail]))
    # measured: the 24th-order sine explains 1 - 3e-8 of the ripple; its amplitude is 1.017 x the expected one
    assert explained > 0.999
    assert np.hypot(fit[0], fit[1]) == pytest.approx(expected, rel=0.05)


def test_inverter_deadtime_lowers_the_effective_voltage():
    deadtime_s = 1e-6
    drag = {"viscous_friction": {"coefficient_nm_s": 2e-3}}  # needs a few amperes, so the dead time bites
    free_speed = steady_speed(make_plant(drag), v_q=3.0)
    dead_speed = steady_speed(make_plant({**drag, "inverter_deadtime": {"deadtime_s": deadtime_s,
                                                                         "current_smoothing_a": 0.2}}), v_q=3.0)
    assert dead_speed < free_speed
    # steady state: v_q_effective = R i_q + K_E w with K_T i_q = (b + c) w; the square-wave duty error
    # -t_dead f_pwm sign(i_k) has a fundamental of (4/pi) t_dead f_pwm U_dc against the current
    per_speed_v = K_E + NOMINAL_PARAMETERS["R"] * (NOMINAL_PARAMETERS["b"] + 2e-3) / K_T
    lost_v = (free_speed - dead_speed) * per_speed_v
    assert lost_v == pytest.approx(4 / math.pi * deadtime_s / PERIOD_S * 12.0, rel=0.15)
    (effect,) = build_effects({"inverter_deadtime": {"deadtime_s": deadtime_s}}, 1e4)
    d_a, d_b, d_c = effect.duty_error(10.0, -5.0, -5.0)
    assert d_a == pytest.approx(-0.01, rel=1e-3) and d_b == pytest.approx(0.01, rel=1e-3)


def test_inertia_mismatch_changes_the_acceleration_at_equal_torque():
    nominal, heavy = make_plant(), make_plant({"inertia_mismatch": {"scale": 1.25}})
    assert heavy.params["J"] == pytest.approx(1.25 * NOMINAL_PARAMETERS["J"])
    a_nominal = nominal.derivatives(0.0, 40.0, 1.0, 0.0, 0.0, 0.0)[3]
    a_heavy = heavy.derivatives(0.0, 40.0, 1.0, 0.0, 0.0, 0.0)[3]
    assert a_nominal / a_heavy == pytest.approx(1.25, rel=1e-9)
    w_nominal = run_commutated(nominal, 6.0, 0.003)["omega"]
    w_heavy = run_commutated(heavy, 6.0, 0.003)["omega"]
    assert w_heavy[-1] < 0.9 * w_nominal[-1]
    # same steady speed: inertia only matters while accelerating
    assert steady_speed(make_plant({"inertia_mismatch": {"scale": 1.25}})) == pytest.approx(
        steady_speed(make_plant()), rel=1e-3)


def test_channel_time_offset_only_moves_the_logged_duty_stamps():
    (effect,) = build_effects({"channel_time_offset": {"offset_s": 4e-5}}, 1e4)
    assert effect.hooks() == ["duty_log_offset_s"] and effect.duty_log_offset_s() == 4e-5
    with pytest.raises(ValueError, match="offset_s"):
        build_effects({"channel_time_offset": {"offset_s": 0.01}}, 1e4)
