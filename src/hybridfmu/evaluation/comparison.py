"""Comparison of the FMU and the neural FMU with the data on whole maneuvers and zoomed intervals.

Pure array work: the simulations are done elsewhere (``baseline``, ``evaluate``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from hybridfmu.evaluation.metrics import improvement_factors, interval_mask, trajectory_errors
from hybridfmu.evaluation.zoom import choose_zoom_intervals

#: Columns of the saved trajectories used here (the files also hold ``fmu_<state>`` and
#: ``neural_fmu_<state>`` for every FMU state).
TRAJECTORY_COLUMNS = ("time_s", "data_angle_rad", "data_speed_rad_s", "fmu_angle_rad", "fmu_speed_rad_s",
                      "neural_fmu_angle_rad", "neural_fmu_speed_rad_s")


@dataclass
class ManeuverRun:
    """Data and both simulations of one maneuver's angle and speed, on the data's grid (all shape (T,)).

    Attributes:
        maneuver: maneuver name.
        time_s: time grid, s, starting at the maneuver's first sample.
        angle_data_rad, speed_data_rad_s: measured angle (rad) and speed (rad/s).
        angle_fmu_rad, speed_fmu_rad_s: the FMU open loop.
        angle_neural_rad, speed_neural_rad_s: the neural FMU open loop.
    """

    maneuver: str
    time_s: np.ndarray
    angle_data_rad: np.ndarray
    speed_data_rad_s: np.ndarray
    angle_fmu_rad: np.ndarray
    speed_fmu_rad_s: np.ndarray
    angle_neural_rad: np.ndarray
    speed_neural_rad_s: np.ndarray

    def __post_init__(self) -> None:
        t = np.shape(self.time_s)[0]
        for name in ("angle_data_rad", "speed_data_rad_s", "angle_fmu_rad", "speed_fmu_rad_s", "angle_neural_rad",
                     "speed_neural_rad_s"):
            if np.shape(getattr(self, name)) != (t,):
                raise ValueError(f"{self.maneuver}: {name} has shape {np.shape(getattr(self, name))}, expected ({t},)")

    @classmethod
    def from_frame(cls, frame: pd.DataFrame, maneuver: str, source: str = "") -> "ManeuverRun":
        """From saved trajectories (``TRAJECTORY_COLUMNS``); ``source`` names the file in errors."""
        missing = [c for c in TRAJECTORY_COLUMNS if c not in frame.columns]
        if missing:
            raise ValueError(f"{source or maneuver}: column(s) {missing} missing (expected saved trajectories)")
        return cls(maneuver, *(frame[c].to_numpy(dtype=float) for c in TRAJECTORY_COLUMNS))

    def errors(self, model: str, mask: np.ndarray | None = None) -> dict[str, float]:
        """MAE/MSE of ``model`` ("fmu" or "neural_fmu") against the data, over ``mask`` (T,) or everything."""
        angle, speed = ((self.angle_fmu_rad, self.speed_fmu_rad_s) if model == "fmu"
                        else (self.angle_neural_rad, self.speed_neural_rad_s))
        sel = slice(None) if mask is None else mask
        return trajectory_errors(angle[sel], speed[sel], self.angle_data_rad[sel], self.speed_data_rad_s[sel])


def compare(reference: dict[str, float], candidate: dict[str, float]) -> dict[str, dict]:
    """``{"fmu": reference, "neural_fmu": candidate, "improvement": reference / candidate}``."""
    return {"fmu": reference, "neural_fmu": candidate, "improvement": improvement_factors(reference, candidate)}


def zoom_comparisons(run: ManeuverRun, angle_length_s: float, speed_length_s: float,
                     configured: list[dict] | None) -> list[dict]:
    """Metrics of both models on the maneuver's zoomed intervals (chosen from the FMU's error alone)."""
    intervals = choose_zoom_intervals(run.time_s, run.angle_fmu_rad - run.angle_data_rad,
                                      run.speed_fmu_rad_s - run.speed_data_rad_s, angle_length_s, speed_length_s,
                                      configured)
    zooms = []
    for interval in intervals:
        mask = interval_mask(run.time_s, interval.t_start_s, interval.t_end_s)
        zooms.append({"maneuver": run.maneuver, **interval.as_dict(),
                      **compare(run.errors("fmu", mask), run.errors("neural_fmu", mask))})
    return zooms


def pooled_errors(runs: list[ManeuverRun], model: str) -> dict[str, float]:
    """MAE/MSE over all samples of several maneuvers together (each sample weighs the same)."""
    fmu = model == "fmu"
    return trajectory_errors(np.concatenate([r.angle_fmu_rad if fmu else r.angle_neural_rad for r in runs]),
                             np.concatenate([r.speed_fmu_rad_s if fmu else r.speed_neural_rad_s for r in runs]),
                             np.concatenate([r.angle_data_rad for r in runs]),
                             np.concatenate([r.speed_data_rad_s for r in runs]))


def role_metrics(role: str, runs: list[ManeuverRun], zoom_settings: dict, extra: dict) -> dict:
    """The metrics object of one role (``validation.json`` / ``test.json``).

    Args:
        role: "validation" or "test".
        runs: the maneuvers of that role.
        zoom_settings: config ``evaluation.zoom`` (``angle_length_s``, ``speed_length_s``, ``intervals``).
        extra: learned quantities to include (``dt_s``, ``gates``, ``best_trial`` ...).

    Returns:
        ``{"role", "maneuvers", "samples", "duration_s", "fmu", "neural_fmu", "improvement", <extra>,
        "zooms": [...], "per_maneuver": {...}}``; errors over the whole trajectories (SI units).
    """
    if not runs:
        raise ValueError(f"no maneuver with role {role!r} to evaluate")
    intervals = zoom_settings.get("intervals", {}) or {}
    zooms, per_maneuver = [], {}
    for run in runs:
        zooms += zoom_comparisons(run, float(zoom_settings.get("angle_length_s", 2.0)),
                                  float(zoom_settings.get("speed_length_s", 1.0)), intervals.get(run.maneuver))
        per_maneuver[run.maneuver] = {"duration_s": float(run.time_s[-1] - run.time_s[0]),
                                      **compare(run.errors("fmu"), run.errors("neural_fmu"))}
    return {"role": role, "maneuvers": [r.maneuver for r in runs],
            "samples": int(sum(r.time_s.size for r in runs)),
            "duration_s": float(sum(r.time_s[-1] - r.time_s[0] for r in runs)),
            **compare(pooled_errors(runs, "fmu"), pooled_errors(runs, "neural_fmu")),
            **extra, "zooms": zooms, "per_maneuver": per_maneuver}
