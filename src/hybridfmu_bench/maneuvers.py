"""Maneuvers of the bench: segment lists -> reference trajectories for the controller.

A maneuver (``bench.maneuvers.<name>``) is a list of segments, each with ``kind`` and
``duration_s``:

- ``rest``: hold the rest angle (position mode);
- ``position``: move to ``to_rad`` (position mode; e.g. into an end stop with a low
  ``current_limit_a`` and ``speed_limit_rad_s``);
- ``ramp``: pressure request from the previous request to ``to_bar`` (linear);
- ``hold``: keep the previous pressure request;
- ``step``: pressure request jumps to ``to_bar`` (fast apply or release);
- ``sine``: ``mean_bar + amplitude_bar sin(2 pi phi(t))``, frequency sweeping linearly
  from ``frequency_hz`` to ``frequency_end_hz`` (default: constant).
Every segment may set ``speed_limit_rad_s`` and ``current_limit_a`` (default: the maneuver's).
Pressure requests become angle targets through the ECU's nominal pressure-volume map; a
motion profile (speed and acceleration limited) turns the targets into the angle reference
with its speed and acceleration feed-forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .hydraulics import PressureVolumeCurve

SEGMENT_KINDS = ("rest", "position", "ramp", "hold", "step", "sine")
REQUIRED_KEYS = {
    "rest": (), "position": ("to_rad",), "ramp": ("to_bar",), "hold": (), "step": ("to_bar",),
    "sine": ("mean_bar", "amplitude_bar", "frequency_hz"),
}
OPTIONAL_KEYS = {"sine": ("frequency_end_hz",)}
COMMON_KEYS = ("kind", "duration_s", "speed_limit_rad_s", "current_limit_a")

#: Allowed total duration of a maneuver (s).
DURATION_RANGE_S = (12.0, 25.0)
#: Highest pressure request accepted (bar).
MAX_PRESSURE_BAR = 220.0
#: Maneuver-level limits when the config gives none.
DEFAULT_SPEED_LIMIT_RAD_S = 230.0
DEFAULT_CURRENT_LIMIT_A = 120.0


@dataclass
class References:
    """Reference trajectories on the control grid (all arrays of shape (N,)).

    Attributes:
        time_s: control instants t_k = k T (s).
        pressure_mode: True where the pressure request is active.
        pressure_ref_bar: pressure request (bar; 0 in position mode).
        theta_ref_rad, omega_ff_rad_s, alpha_ff_rad_s2: angle reference (rad) and its speed (rad/s)
            and acceleration (rad/s^2) from the motion profile.
        speed_limit_rad_s, current_limit_a: limits in force.
    """

    time_s: np.ndarray
    pressure_mode: np.ndarray
    pressure_ref_bar: np.ndarray
    theta_ref_rad: np.ndarray
    omega_ff_rad_s: np.ndarray
    alpha_ff_rad_s2: np.ndarray
    speed_limit_rad_s: np.ndarray
    current_limit_a: np.ndarray

    @property
    def n_steps(self) -> int:
        return int(self.time_s.shape[0])


def _number(segment: Mapping[str, Any], key: str, where: str) -> float:
    value = segment.get(key)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{where}.{key}: expected a finite number, got {value!r}")
    return float(value)


def validate_maneuver(maneuver: Mapping[str, Any], where: str, theta_limits_rad: tuple[float, float]) -> None:
    """Check a maneuver definition; errors name the field (``where`` = its config path).

    Requires a rest segment first and last, known kinds with their keys, positive durations,
    a total duration within :data:`DURATION_RANGE_S`, pressures within 0..MAX_PRESSURE_BAR.
    """
    segments = maneuver.get("segments")
    if not isinstance(segments, list) or len(segments) < 3:
        raise ValueError(f"{where}.segments: expected a list of at least 3 segments")
    total_s = 0.0
    for index, segment in enumerate(segments):
        at = f"{where}.segments[{index}]"
        if not isinstance(segment, Mapping):
            raise ValueError(f"{at}: expected a mapping with kind and duration_s")
        kind = segment.get("kind")
        if kind not in SEGMENT_KINDS:
            raise ValueError(f"{at}.kind: expected one of {list(SEGMENT_KINDS)}, got {kind!r}")
        allowed = set(COMMON_KEYS) | set(REQUIRED_KEYS[kind]) | set(OPTIONAL_KEYS.get(kind, ()))
        unknown = sorted(set(segment) - allowed)
        if unknown:
            raise ValueError(f"{at}: unknown key(s) {unknown} for kind {kind!r}, expected some of {sorted(allowed)}")
        duration = _number(segment, "duration_s", at)
        if duration <= 0.0:
            raise ValueError(f"{at}.duration_s: expected > 0, got {duration}")
        total_s += duration
        for key in REQUIRED_KEYS[kind] + tuple(k for k in OPTIONAL_KEYS.get(kind, ()) if k in segment):
            _number(segment, key, at)
        for key in ("speed_limit_rad_s", "current_limit_a"):
            if key in segment and _number(segment, key, at) <= 0.0:
                raise ValueError(f"{at}.{key}: expected > 0, got {segment[key]}")
        for key in ("to_bar", "mean_bar"):
            if key in segment and not 0.0 <= segment[key] <= MAX_PRESSURE_BAR:
                raise ValueError(f"{at}.{key}: expected 0..{MAX_PRESSURE_BAR} bar, got {segment[key]}")
        if kind == "sine":
            low = segment["mean_bar"] - abs(segment["amplitude_bar"])
            high = segment["mean_bar"] + abs(segment["amplitude_bar"])
            if low < 0.0 or high > MAX_PRESSURE_BAR:
                raise ValueError(f"{at}: the sine spans {low}..{high} bar, expected within 0..{MAX_PRESSURE_BAR}")
            if segment["frequency_hz"] <= 0.0 or segment.get("frequency_end_hz", 1.0) <= 0.0:
                raise ValueError(f"{at}.frequency_hz: expected > 0")
        if kind == "position":
            low, high = theta_limits_rad
            if not low - 1.0 <= segment["to_rad"] <= high + 1.0:
                raise ValueError(f"{at}.to_rad: expected within [{low - 1.0}, {high + 1.0}] rad, got "
                                 f"{segment['to_rad']}")
    if segments[0].get("kind") != "rest" or segments[-1].get("kind") != "rest":
        raise ValueError(f"{where}.segments: the first and the last segment must be of kind 'rest'")
    low_s, high_s = DURATION_RANGE_S
    if not low_s <= total_s <= high_s:
        raise ValueError(f"{where}.segments: total duration {total_s:g} s, expected {low_s:g}..{high_s:g} s")
    unknown = sorted(set(maneuver) - {"segments", "speed_limit_rad_s", "current_limit_a"})
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}, expected segments, speed_limit_rad_s, current_limit_a")
    for key in ("speed_limit_rad_s", "current_limit_a"):
        if key in maneuver and _number(maneuver, key, where) <= 0.0:
            raise ValueError(f"{where}.{key}: expected > 0, got {maneuver[key]}")


def scale_maneuver(maneuver: Mapping[str, Any], time_scale: float) -> dict[str, Any]:
    """A copy of a (validated) maneuver with every segment's ``duration_s`` multiplied by ``time_scale``.

    Shortened test maneuvers (``bench.time_scale`` < 1): the design is checked at full length
    (:data:`DURATION_RANGE_S`), the bench runs it compressed in time. Pressures, angles, limits
    and sine frequencies stay as designed (a sine segment then has fewer periods).
    """
    if time_scale == 1.0:
        return dict(maneuver)
    segments = [{**segment, "duration_s": float(segment["duration_s"]) * time_scale}
                for segment in maneuver["segments"]]
    return {**maneuver, "segments": segments}


def build_references(maneuver: Mapping[str, Any], period_s: float, rest_angle_rad: float,
                     ecu_curve: PressureVolumeCurve, acceleration_limit_rad_s2: float,
                     profile_gain_1_s: float = 150.0, duration_s: float | None = None) -> References:
    """Sample a maneuver's segments on the control grid and run the motion profile.

    Args:
        maneuver: {speed_limit_rad_s, current_limit_a, segments: [...]} (validated).
        period_s: control period (s).
        rest_angle_rad: angle of the rest segments (rad).
        ecu_curve: the ECU's nominal pressure-volume map (pressure -> angle target).
        acceleration_limit_rad_s2: acceleration limit of the profile (rad/s^2).
        profile_gain_1_s: gain of the profile's final approach (1/s).
        duration_s: truncate the maneuver to this duration (s; tests); default: all segments.
    """
    chunks: dict[str, list[np.ndarray]] = {key: [] for key in ("mode", "pressure", "target", "v_lim", "i_lim")}
    speed_limit = float(maneuver.get("speed_limit_rad_s", DEFAULT_SPEED_LIMIT_RAD_S))
    current_limit = float(maneuver.get("current_limit_a", DEFAULT_CURRENT_LIMIT_A))
    pressure_prev = 0.0
    t0 = 0.0
    n_done = 0
    for segment in maneuver["segments"]:
        t0 += float(segment["duration_s"])
        n_end = int(round(t0 / period_s))
        n = n_end - n_done
        n_done = n_end
        if n <= 0:
            continue
        t = np.arange(n) * period_s
        kind = segment["kind"]
        if kind in ("rest", "position"):
            target = rest_angle_rad if kind == "rest" else float(segment["to_rad"])
            mode = np.zeros(n, dtype=bool)
            pressure = np.zeros(n)
            targets = np.full(n, target)
            pressure_prev = 0.0
        else:
            if kind == "ramp":
                duration = float(segment["duration_s"])
                pressure = pressure_prev + (float(segment["to_bar"]) - pressure_prev) * np.minimum(t / duration, 1.0)
                pressure_end = float(segment["to_bar"])
            elif kind == "hold":
                pressure = np.full(n, pressure_prev)
                pressure_end = pressure_prev
            elif kind == "step":
                pressure = np.full(n, float(segment["to_bar"]))
                pressure_end = float(segment["to_bar"])
            else:  # sine (linear frequency sweep)
                f0 = float(segment["frequency_hz"])
                f1 = float(segment.get("frequency_end_hz", f0))
                duration = float(segment["duration_s"])
                phase = f0 * t + 0.5 * (f1 - f0) * t * t / duration
                pressure = float(segment["mean_bar"]) + float(segment["amplitude_bar"]) * np.sin(2 * np.pi * phase)
                phase_end = f0 * duration + 0.5 * (f1 - f0) * duration
                pressure_end = float(segment["mean_bar"]) + float(segment["amplitude_bar"]) * math.sin(
                    2 * math.pi * phase_end)
            mode = np.ones(n, dtype=bool)
            targets = ecu_curve.angle_for_pressure_rad(pressure)
            pressure_prev = pressure_end
        chunks["mode"].append(mode)
        chunks["pressure"].append(pressure)
        chunks["target"].append(targets)
        chunks["v_lim"].append(np.full(n, float(segment.get("speed_limit_rad_s", speed_limit))))
        chunks["i_lim"].append(np.full(n, float(segment.get("current_limit_a", current_limit))))
    arrays = {key: np.concatenate(value) for key, value in chunks.items()}
    if duration_s is not None:
        n_keep = int(round(duration_s / period_s))
        if n_keep < 1:
            raise ValueError(f"duration_s: {duration_s} s is shorter than one control period")
        arrays = {key: value[:n_keep] for key, value in arrays.items()}
    theta_ref, omega_ff, alpha_ff = motion_profile(arrays["target"], arrays["v_lim"], period_s, rest_angle_rad,
                                                   acceleration_limit_rad_s2, profile_gain_1_s)
    n_total = arrays["target"].shape[0]
    return References(
        time_s=np.arange(n_total) * period_s, pressure_mode=arrays["mode"], pressure_ref_bar=arrays["pressure"],
        theta_ref_rad=theta_ref, omega_ff_rad_s=omega_ff, alpha_ff_rad_s2=alpha_ff,
        speed_limit_rad_s=arrays["v_lim"], current_limit_a=arrays["i_lim"],
    )


def motion_profile(target_rad: np.ndarray, speed_limit_rad_s: np.ndarray, period_s: float, start_rad: float,
                   acceleration_limit_rad_s2: float, gain_1_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed- and acceleration-limited tracking of an angle target (shape (N,) each, rad and rad/s).

    The profile follows the target's own speed where the target moves continuously and
    approaches jumps at the speed limit, braking along sqrt(a |e|) and finally with
    ``gain_1_s``. Returns (angle (rad), speed (rad/s), acceleration (rad/s^2)), each (N,).
    """
    n = target_rad.shape[0]
    target_speed = np.zeros(n)
    if n > 1:
        target_speed[1:] = np.diff(target_rad) / period_s
    jumps = np.abs(target_speed) > speed_limit_rad_s
    target_speed[jumps] = 0.0
    target_speed = np.clip(target_speed, -speed_limit_rad_s, speed_limit_rad_s)
    targets = target_rad.tolist()
    target_speeds = target_speed.tolist()
    limits = speed_limit_rad_s.tolist()
    a_step = acceleration_limit_rad_s2 * period_s
    a_max = acceleration_limit_rad_s2
    angle = np.empty(n)
    speed = np.empty(n)
    accel = np.empty(n)
    pos = float(start_rad)
    vel = 0.0
    for k in range(n):
        error = targets[k] - pos
        mag = abs(error)
        correction = min(math.sqrt(a_max * mag), gain_1_s * mag)
        desired = target_speeds[k] + (correction if error > 0.0 else -correction)
        limit = limits[k]
        desired = limit if desired > limit else (-limit if desired < -limit else desired)
        dv = desired - vel
        dv = a_step if dv > a_step else (-a_step if dv < -a_step else dv)
        vel += dv
        pos += vel * period_s
        angle[k] = pos
        speed[k] = vel
        accel[k] = dv / period_s
    return angle, speed, accel


def planned_extremes(references: References, torque_per_pa: float) -> dict[str, float]:
    """Largest planned load torque (N m, from the pressure request) and speed (rad/s) of a maneuver."""
    return {
        "max_tau_load_nm": float(np.max(references.pressure_ref_bar) * 1.0e5 * torque_per_pa),
        "max_abs_omega_rad_s": float(np.max(np.abs(references.omega_ff_rad_s))),
    }


def check_spread(values: Mapping[str, float], quantity: str, min_relative: float = 0.10,
                 roles: Mapping[str, str] | None = None) -> None:
    """Check that every two maneuvers differ in ``quantity`` by at least ``min_relative``.

    The difference is relative to the larger value: |a - b| / max(a, b) >= min_relative. With ``roles``
    (maneuver -> role), only maneuvers of different roles must differ: the held-out maneuvers of one role may
    resemble each other, but none of them the train or validation maneuvers.

    Raises:
        ValueError: naming the two maneuvers, their values and the difference.
    """
    names = sorted(values, key=lambda name: values[name])
    roles = roles or {}
    for i, low in enumerate(names):
        for high in names[i + 1:]:
            if roles and roles.get(low, low) == roles.get(high, high):
                continue
            a, b = float(values[low]), float(values[high])
            relative = (b - a) / b if b > 0.0 else 0.0
            if relative < min_relative:
                raise ValueError(f"bench maneuvers {low!r} and {high!r}: {quantity} {a:.4g} and {b:.4g} differ by "
                                 f"{100 * relative:.1f} %, expected at least {100 * min_relative:.0f} %")
