"""Running the bench: plant + sensors + controller over a maneuver, then MDF4 log and ground truth.

Timing of one control period k (t_k = k T, T = 1/f_pwm):
1. sensors sample the plant at t_k (quantised angle, speed observer, noisy currents and supply
   voltage; the pressure sensor's lag advances; every ``slow_decimation`` periods a pressure
   and a supply-voltage sample are logged and the pressure trim runs);
2. the controller computes new duties from these measurements;
3. the plant integrates [t_k, t_k+1) with the duties computed in the PREVIOUS period (one
   sample of computation delay); these applied duties are what the duty channels log at t_k
   (stamped t_k + the channel offset of the ``channel_time_offset`` effect).
"""

from __future__ import annotations

import logging
import math
import time
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from hybridfmu.io import write_json_atomic
from hybridfmu.progress import Progress
from .controller import CascadeController
from .hydraulics import PA_PER_BAR
from .maneuvers import References, build_references, check_spread, planned_extremes
from .mdf_writer import Channel, ChannelGroup, write_mdf4
from .plant import Plant
from .sensors import Encoder, PressureSensor, SpeedObserver
from .settings import BenchSettings, parse_bench_settings

LOGGER = logging.getLogger("hybridfmu_bench")

RAD_TO_DEG = 180.0 / math.pi
RAD_S_TO_RPM = 60.0 / (2.0 * math.pi)

#: Logged channels: name -> (unit, comment). Names and units as in the data contracts.
CHANNELS: dict[str, tuple[str, str]] = {
    "MotCtl_DutyA": ("%", "PWM duty cycle of phase A applied by the inverter"),
    "MotCtl_DutyB": ("%", "PWM duty cycle of phase B applied by the inverter"),
    "MotCtl_DutyC": ("%", "PWM duty cycle of phase C applied by the inverter"),
    "MotPos_Angle": ("deg", "multi-turn mechanical rotor angle from the encoder (quantised)"),
    "MotPos_Speed": ("rpm", "rotor speed estimate of the angle-tracking observer"),
    "MotCur_IPhA": ("A", "phase current A (ADC)"),
    "MotCur_IPhB": ("A", "phase current B (ADC)"),
    "MotCur_IPhC": ("A", "phase current C (ADC)"),
    "Hyd_Pressure": ("bar", "brake pressure at the pressure sensor"),
    "Sply_UDc": ("V", "inverter supply voltage"),
}

#: The ECU's references, as its measurement interface records them every control period (the setpoints a
#: controller declared for closed-loop simulation reads): name -> (unit, comment, field of ``References``, factor
#: from the field's unit to the channel's).
REFERENCE_CHANNELS: dict[str, tuple[str, str, str, float]] = {
    "BrkCtl_PressureReq": ("bar", "brake pressure request", "pressure_ref_bar", 1.0),
    "BrkCtl_PressureMode": ("-", "1 while the pressure request is active, 0 in position mode", "pressure_mode", 1.0),
    "MotCtl_AngleRef": ("deg", "rotor angle reference of the position loop", "theta_ref_rad", RAD_TO_DEG),
    "MotCtl_SpeedFf": ("rpm", "speed feed-forward of the motion profile", "omega_ff_rad_s", RAD_S_TO_RPM),
    "MotCtl_AccelFf": ("rad/s^2", "acceleration feed-forward of the motion profile", "alpha_ff_rad_s2", 1.0),
    "MotCtl_SpeedLim": ("rpm", "speed limit in force", "speed_limit_rad_s", RAD_S_TO_RPM),
    "MotCtl_CurrentLim": ("A", "q-current limit in force", "current_limit_a", 1.0),
}


@dataclass
class BenchRun:
    """Result of one emulated maneuver: logged channels and true trajectories.

    Attributes:
        maneuver: name.
        time_s: control instants (N,), s.
        logged: channel name -> samples (N,) or (N_slow,), in the channel's unit.
        slow_time_s: instants of the slow channels (N_slow,), s.
        duty_time_s: time stamps of the duty channels (N_duty,), s (may drop samples stamped < 0).
        truth: name -> true trajectory (N,) at t_k: theta_rad, omega_rad_s, i_d_a, i_q_a,
            tau_load_nm, pressure_bar, tau_e_nm, u_dc_v, theta_ref_rad.
        references: the controller's references.
        stop_contacts: number of times the rotor hit an end stop.
        wall_s: wall time of the simulation loop (s).
    """

    maneuver: str
    time_s: np.ndarray
    logged: dict[str, np.ndarray]
    slow_time_s: np.ndarray
    duty_time_s: np.ndarray
    truth: dict[str, np.ndarray]
    references: References
    stop_contacts: int
    wall_s: float


def maneuver_rng(settings: BenchSettings, maneuver: str) -> np.random.Generator:
    """The maneuver's random generator, seeded from the master seed, the bench seed and the name."""
    sequence = np.random.SeedSequence([settings.master_seed, settings.seed, zlib.crc32(maneuver.encode())])
    return np.random.default_rng(sequence)


def maneuver_references(settings: BenchSettings, maneuver: str, duration_s: float | None = None) -> References:
    """The reference trajectories of a configured maneuver."""
    if maneuver not in settings.maneuvers:
        raise ValueError(f"config.bench.maneuvers: no maneuver {maneuver!r}, expected one of "
                         f"{sorted(settings.maneuvers)}")
    return build_references(settings.maneuvers[maneuver], settings.period_s, settings.rest_angle_rad,
                            settings.ecu_curve(), settings.acceleration_limit_rad_s2, duration_s=duration_s)


def check_planned_spread(settings: BenchSettings, min_relative: float = 0.10,
                         roles: Mapping[str, str] | None = None) -> dict[str, dict[str, float]]:
    """Check that the planned max load and max speed of all maneuvers (with ``roles``: of every two maneuvers of
    different roles) differ by >= ``min_relative``.

    Returns maneuver -> planned extremes. Raises ValueError naming the maneuvers otherwise.
    """
    planned = {name: planned_extremes(maneuver_references(settings, name), settings.displacement_m3_per_rad)
               for name in settings.maneuvers}
    if len(planned) > 1:
        for quantity in ("max_tau_load_nm", "max_abs_omega_rad_s"):
            check_spread({name: values[quantity] for name, values in planned.items()}, f"planned {quantity}",
                         min_relative, roles)
    return planned


def run_maneuver(settings: BenchSettings, maneuver: str, duration_s: float | None = None,
                 progress_interval_s: float = 5.0) -> BenchRun:
    """Emulate one maneuver (optionally truncated to ``duration_s``) and return logs and truth."""
    refs = maneuver_references(settings, maneuver, duration_s)
    n = refs.n_steps
    T = settings.period_s
    decimation = settings.slow_decimation
    sensors = settings.sensors
    rng = maneuver_rng(settings, maneuver)
    n_slow = (n + decimation - 1) // decimation
    noise_i = (rng.standard_normal((3, n)) * sensors.current_noise_a).tolist()
    noise_u = (rng.standard_normal(n) * sensors.u_dc_noise_v).tolist()
    noise_p = (rng.standard_normal(n_slow) * sensors.pressure_noise_bar).tolist()

    plant = Plant(settings.true_parameters, settings.true_curve(), settings.effects, settings.supply, T,
                  settings.substeps, settings.rest_angle_rad)
    controller = CascadeController(settings.controller, settings.nominal_parameters, settings.displacement_m3_per_rad,
                                   T, T * decimation)
    encoder = Encoder(sensors.encoder_counts_per_rev)
    observer = SpeedObserver(sensors.speed_observer_bandwidth_hz, T, encoder.measure_rad(plant.theta))
    pressure_sensor = PressureSensor(sensors.pressure_lag_s, T, sensors.pressure_step_bar)
    i_step = sensors.current_step_a
    inv_i_step = 1.0 / i_step if i_step > 0.0 else 0.0
    u_step = sensors.u_dc_step_v
    inv_u_step = 1.0 / u_step if u_step > 0.0 else 0.0

    mode = refs.pressure_mode.tolist()
    p_ref = refs.pressure_ref_bar.tolist()
    th_ref = refs.theta_ref_rad.tolist()
    w_ff = refs.omega_ff_rad_s.tolist()
    a_ff = refs.alpha_ff_rad_s2.tolist()
    v_lim = refs.speed_limit_rad_s.tolist()
    i_lim = refs.current_limit_a.tolist()
    noise_a, noise_b, noise_c = noise_i

    log_angle, log_speed, log_ia, log_ib, log_ic = [], [], [], [], []
    log_da, log_db, log_dc, log_p, log_u = [], [], [], [], []
    tr_theta, tr_omega, tr_id, tr_iq, tr_load, tr_taue, tr_udc = [], [], [], [], [], [], []
    measure = encoder.measure_rad
    observe = observer.update
    control = controller.update
    advance = plant.advance
    currents = plant.phase_currents
    load = plant.tau_load_nm
    torque_e = plant.electrical_torque_nm
    track = pressure_sensor.track
    torque_to_bar = 1.0 / (settings.displacement_m3_per_rad * PA_PER_BAR)
    d_a = d_b = d_c = 0.5
    chunk = max(int(round(0.1 / T)), 1)
    progress = Progress(n * T, f"bench {maneuver}", unit="simulated s", logger=LOGGER, interval_s=progress_interval_s)
    start = time.perf_counter()
    for k in range(n):
        theta = plant.theta
        theta_m = measure(theta)
        w_hat = observe(theta_m)
        i_a, i_b, i_c = currents()
        if inv_i_step:
            i_a_m = round((i_a + noise_a[k]) * inv_i_step) * i_step
            i_b_m = round((i_b + noise_b[k]) * inv_i_step) * i_step
            i_c_m = round((i_c + noise_c[k]) * inv_i_step) * i_step
        else:
            i_a_m, i_b_m, i_c_m = i_a + noise_a[k], i_b + noise_b[k], i_c + noise_c[k]
        u_dc = plant.u_dc_v
        u_m = round((u_dc + noise_u[k]) * inv_u_step) * u_step if inv_u_step else u_dc + noise_u[k]
        tau_load = load(theta)
        track(tau_load * torque_to_bar)
        if k % decimation == 0:
            p_m = pressure_sensor.sample_bar(noise_p[k // decimation])
            controller.update_pressure(p_m, p_ref[k], mode[k])
            log_p.append(p_m)
            log_u.append(u_m)
        new_duties = control(theta_m, w_hat, i_a_m, i_b_m, i_c_m, u_m, th_ref[k], w_ff[k], a_ff[k], v_lim[k],
                             i_lim[k])
        log_angle.append(theta_m)
        log_speed.append(w_hat)
        log_ia.append(i_a_m)
        log_ib.append(i_b_m)
        log_ic.append(i_c_m)
        log_da.append(d_a)
        log_db.append(d_b)
        log_dc.append(d_c)
        tr_theta.append(theta)
        tr_omega.append(plant.omega)
        tr_id.append(plant.i_d)
        tr_iq.append(plant.i_q)
        tr_load.append(tau_load)
        tr_taue.append(torque_e())
        tr_udc.append(u_dc)
        advance(d_a, d_b, d_c, k * T)
        d_a, d_b, d_c = new_duties
        if (k + 1) % chunk == 0:
            progress.update(chunk * T)
    wall_s = time.perf_counter() - start
    progress.done = n * T
    progress.finish()

    time_s = refs.time_s
    offset_s = settings.duty_log_offset_s()
    duty_time = time_s + offset_s
    keep = duty_time >= 0.0
    logged = {
        "MotCtl_DutyA": 100.0 * np.asarray(log_da)[keep],
        "MotCtl_DutyB": 100.0 * np.asarray(log_db)[keep],
        "MotCtl_DutyC": 100.0 * np.asarray(log_dc)[keep],
        "MotPos_Angle": RAD_TO_DEG * np.asarray(log_angle),
        "MotPos_Speed": RAD_S_TO_RPM * np.asarray(log_speed),
        "MotCur_IPhA": np.asarray(log_ia),
        "MotCur_IPhB": np.asarray(log_ib),
        "MotCur_IPhC": np.asarray(log_ic),
        "Hyd_Pressure": np.asarray(log_p),
        "Sply_UDc": np.asarray(log_u),
        **{name: factor * np.asarray(getattr(refs, field), dtype=float)
           for name, (_, _, field, factor) in REFERENCE_CHANNELS.items()},
    }
    truth = {
        "theta_rad": np.asarray(tr_theta), "omega_rad_s": np.asarray(tr_omega), "i_d_a": np.asarray(tr_id),
        "i_q_a": np.asarray(tr_iq), "tau_load_nm": np.asarray(tr_load), "tau_e_nm": np.asarray(tr_taue),
        "u_dc_v": np.asarray(tr_udc), "theta_ref_rad": refs.theta_ref_rad,
    }
    truth["pressure_bar"] = truth["tau_load_nm"] * torque_to_bar
    return BenchRun(maneuver=maneuver, time_s=time_s, logged=logged, slow_time_s=time_s[::decimation][:n_slow],
                    duty_time_s=duty_time[keep], truth=truth, references=refs,
                    stop_contacts=plant.stop_contacts, wall_s=wall_s)


def channel_groups(run: BenchRun, settings: BenchSettings) -> list[ChannelGroup]:
    """Group the logged channels by time base, as the measurement tool records them."""
    described = {**CHANNELS, **{name: (unit, comment) for name, (unit, comment, _, _) in REFERENCE_CHANNELS.items()}}

    def group(comment: str, timestamps: np.ndarray, names: list[str]) -> ChannelGroup:
        return ChannelGroup(comment, timestamps, [Channel(name, run.logged[name], *described[name])
                                                  for name in names])

    fast = f"{settings.pwm_frequency_hz:g} Hz"
    slow = f"{settings.sensors.slow_rate_hz:g} Hz"
    return [
        group(f"motor position and currents, {fast} raster", run.time_s,
              ["MotPos_Angle", "MotPos_Speed", "MotCur_IPhA", "MotCur_IPhB", "MotCur_IPhC"]),
        group(f"PWM duty cycles, {fast} raster", run.duty_time_s, ["MotCtl_DutyA", "MotCtl_DutyB", "MotCtl_DutyC"]),
        group(f"brake pressure, {slow} raster", run.slow_time_s, ["Hyd_Pressure"]),
        group(f"supply voltage, {slow} raster", run.slow_time_s, ["Sply_UDc"]),
        group(f"ECU references, {fast} raster", run.time_s, list(REFERENCE_CHANNELS)),
    ]


def run_summary(run: BenchRun, settings: BenchSettings) -> dict[str, Any]:
    """Extremes of the true trajectories and RMS torque of each torque effect along them."""
    truth = run.truth
    i_d, i_q = truth["i_d_a"], truth["i_q_a"]
    summary: dict[str, Any] = {
        "duration_s": float(run.time_s.shape[0] * settings.period_s),
        "max_abs_omega_rad_s": float(np.max(np.abs(truth["omega_rad_s"]))),
        "max_tau_load_nm": float(np.max(truth["tau_load_nm"])),
        "max_pressure_bar": float(np.max(truth["pressure_bar"])),
        "max_current_amplitude_a": float(np.max(np.hypot(i_d, i_q))),
        "theta_range_rad": [float(np.min(truth["theta_rad"])), float(np.max(truth["theta_rad"]))],
        "end_stop_contacts": run.stop_contacts,
        "rms_angle_tracking_error_rad": float(np.sqrt(np.mean((truth["theta_rad"] - truth["theta_ref_rad"]) ** 2))),
        "wall_s": run.wall_s,
    }
    sub = slice(None, None, 10)
    rms: dict[str, float] = {}
    for effect in settings.effects:
        if "torque_nm" not in effect.hooks():
            continue
        values = [effect.torque_nm(th, w, tl) for th, w, tl in
                  zip(truth["theta_rad"][sub].tolist(), truth["omega_rad_s"][sub].tolist(),
                      truth["tau_load_nm"][sub].tolist())]
        rms[effect.name] = float(np.sqrt(np.mean(np.square(values)))) if values else 0.0
    summary["effect_torque_rms_nm"] = rms
    return summary


def ground_truth(run: BenchRun, settings: BenchSettings, planned: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The ground-truth record of a run (for checks and the learned-vs-true report only)."""
    offset_s = settings.duty_log_offset_s()
    return {
        "maneuver": run.maneuver,
        "seeds": {"master": settings.master_seed, "bench": settings.seed},
        "nominal_parameters": settings.nominal_parameters,
        "parameter_offsets": settings.parameter_offsets,
        "true_parameters": settings.true_parameters,
        "effects": [effect.describe() for effect in settings.effects],
        "time_offset": {
            "duty_channels_offset_s": offset_s,
            "input_delay_s": offset_s,
            "channels": [name for name in CHANNELS if name.startswith("MotCtl_Duty")],  # the offset ones
            "convention": "the duty applied from time t is logged with time stamp t + offset; "
                          "u_true(t) = u_logged(t + input_delay_s)",
        },
        "hydraulics": {
            "displacement_m3_per_rad": settings.displacement_m3_per_rad,
            "tau_load_nm_per_pa": settings.displacement_m3_per_rad,
            "true_curve": {"dead_travel_rad": settings.hydraulics.dead_travel_rad,
                           "pressure_scale_bar": settings.hydraulics.pressure_scale_bar,
                           "volume_scale_cm3": settings.hydraulics.volume_scale_cm3},
            "ecu_map": {"dead_travel_rad": settings.ecu_map.dead_travel_rad,
                        "pressure_scale_bar": settings.ecu_map.pressure_scale_bar,
                        "volume_scale_cm3": settings.ecu_map.volume_scale_cm3},
        },
        "rest_angle_rad": settings.rest_angle_rad,
        "initial_state": {"i_d": 0.0, "i_q": 0.0, "theta": settings.rest_angle_rad, "omega": 0.0},
        "pwm_frequency_hz": settings.pwm_frequency_hz,
        "substeps": settings.substeps,
        "time_scale": settings.time_scale,
        "sensors": {
            "encoder_counts_per_rev": settings.sensors.encoder_counts_per_rev,
            "encoder_step_rad": 2.0 * math.pi / settings.sensors.encoder_counts_per_rev,
            "speed_observer_bandwidth_hz": settings.sensors.speed_observer_bandwidth_hz,
            "current_noise_a": settings.sensors.current_noise_a,
            "pressure_lag_s": settings.sensors.pressure_lag_s,
            "pressure_noise_bar": settings.sensors.pressure_noise_bar,
            "u_dc_noise_v": settings.sensors.u_dc_noise_v,
            "slow_rate_hz": settings.sensors.slow_rate_hz,
        },
        "supply": {"nominal_v": settings.supply.nominal_v,
                   "source_resistance_ohm": settings.supply.source_resistance_ohm,
                   "ripple_amplitude_v": settings.supply.ripple_amplitude_v,
                   "ripple_frequency_hz": settings.supply.ripple_frequency_hz},
        "summary": run_summary(run, settings),
        "planned": dict(planned or {}),
    }


def emulate_bench(config: Mapping[str, Any], maneuver: str, mdf_path: str | Path, truth_path: str | Path,
                  duration_s: float | None = None, check_spread_of_maneuvers: bool = True,
                  roles: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Emulate ``maneuver`` of the case ``config``; write its MDF4 log and ground-truth JSON.

    Args:
        config: the whole case config (sections ``bench``, ``fmu``, ``seed`` are read).
        maneuver: name of a maneuver of ``bench.maneuvers``.
        mdf_path: output MDF4 file (``{RESULTS}/raw/{maneuver}.mf4``).
        truth_path: output ground-truth JSON (``{RESULTS}/raw/{maneuver}.truth.json``).
        duration_s: emulate only the first ``duration_s`` seconds (tests); default: all.
        check_spread_of_maneuvers: first check that the planned max load and speed differ by >= 10 %
            between the configured maneuvers (with ``roles``, maneuver -> role: between those of different roles).
    Returns:
        The ground-truth record written to ``truth_path``.
    """
    settings = parse_bench_settings(config)
    planned: dict[str, Any] = {}
    if check_spread_of_maneuvers:
        planned = check_planned_spread(settings, roles=roles)[maneuver] if maneuver in settings.maneuvers else {}
    LOGGER.info("bench %s: effects %s, true parameters %s", maneuver,
                [effect.name for effect in settings.effects], settings.true_parameters)
    run = run_maneuver(settings, maneuver, duration_s)
    description = (f"Test-bench recording, maneuver {maneuver}, PWM {settings.pwm_frequency_hz:g} Hz; "
                   f"{len(CHANNELS) + len(REFERENCE_CHANNELS)} channels in 5 groups with their own time bases")
    write_mdf4(mdf_path, channel_groups(run, settings), description)
    truth = ground_truth(run, settings, planned)
    write_json_atomic(truth_path, truth)
    LOGGER.info("bench %s: %.3g s simulated in %.1f s wall; max |omega| %.1f rad/s, max tau_load %.3f N m, "
                "max pressure %.1f bar; wrote %s and %s", maneuver, truth["summary"]["duration_s"], run.wall_s,
                truth["summary"]["max_abs_omega_rad_s"], truth["summary"]["max_tau_load_nm"],
                truth["summary"]["max_pressure_bar"], mdf_path, truth_path)
    return truth


def summarize_bench(truth_paths: Mapping[str, str | Path], output_path: str | Path,
                    min_relative: float = 0.10, roles: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Check the REALISED max load and max speed of the maneuvers differ pairwise by >= ``min_relative``.

    Args:
        truth_paths: maneuver -> its ground-truth JSON.
        output_path: JSON written with the extremes per maneuver (only when the check passes).
        roles: maneuver -> role: only maneuvers of different roles must differ (None: every two).
    Raises:
        ValueError: naming the two maneuvers that are too alike.
    """
    from hybridfmu.io import read_json

    extremes = {}
    for name, path in truth_paths.items():
        summary = read_json(path).get("summary")
        if not isinstance(summary, Mapping) or "max_abs_omega_rad_s" not in summary:
            raise ValueError(f"{path}: expected a ground-truth JSON with summary.max_abs_omega_rad_s")
        extremes[name] = {key: float(summary[key]) for key in
                          ("max_tau_load_nm", "max_abs_omega_rad_s", "max_pressure_bar", "duration_s")}
    for quantity in ("max_tau_load_nm", "max_abs_omega_rad_s"):
        check_spread({name: values[quantity] for name, values in extremes.items()}, quantity, min_relative, roles)
    record = {"min_relative_difference": min_relative, "maneuvers": extremes,
              **({"roles": dict(roles)} if roles else {})}
    write_json_atomic(output_path, record)
    return record
