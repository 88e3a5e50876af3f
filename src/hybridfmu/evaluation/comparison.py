"""Comparison of the FMU and the neural FMU with the data on whole maneuvers and zoomed intervals.

Pure array work: the simulations are done elsewhere (``baseline``, ``evaluate``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from hybridfmu.evaluation.metrics import improvement_factors, interval_mask, trajectory_errors
from hybridfmu.evaluation.zoom import choose_zoom_intervals

#: Columns of the saved trajectories (besides ``fmu_<state>`` and ``neural_fmu_<state>`` for every state).
TRAJECTORY_COLUMNS = ("time_s", "data_angle_rad", "data_speed_rad_s", "fmu_angle_rad", "fmu_speed_rad_s",
                      "neural_fmu_angle_rad", "neural_fmu_speed_rad_s")


@dataclass
class ManeuverRun:
    """Data and both simulations of one maneuver, on the data's grid.

    Attributes:
        maneuver: maneuver name.
        time_s: time grid (T,), s, starting at the maneuver's first sample.
        angle_data_rad, speed_data_rad_s: measured angle (rad) and speed (rad/s), (T,).
        state_names: FMU state names, length n_x.
        fmu_states, neural_fmu_states: open-loop simulations (T, n_x), SI units.
        angle_index, speed_index: positions of the angle and speed states in ``state_names``.
    """

    maneuver: str
    time_s: np.ndarray
    angle_data_rad: np.ndarray
    speed_data_rad_s: np.ndarray
    state_names: list[str]
    fmu_states: np.ndarray
    neural_fmu_states: np.ndarray
    angle_index: int
    speed_index: int

    def __post_init__(self) -> None:
        t = self.time_s.shape[0]
        for name in ("angle_data_rad", "speed_data_rad_s"):
            if getattr(self, name).shape != (t,):
                raise ValueError(f"{self.maneuver}: {name} has shape {getattr(self, name).shape}, expected ({t},)")
        for name in ("fmu_states", "neural_fmu_states"):
            if getattr(self, name).shape != (t, len(self.state_names)):
                raise ValueError(f"{self.maneuver}: {name} has shape {getattr(self, name).shape}, "
                                 f"expected ({t}, {len(self.state_names)}) for states {self.state_names}")

    def errors(self, model: str, mask: np.ndarray | None = None) -> dict[str, float]:
        """MAE/MSE of ``model`` ("fmu" or "neural_fmu") against the data, over ``mask`` (T,) or everything."""
        states = self.fmu_states if model == "fmu" else self.neural_fmu_states
        sel = slice(None) if mask is None else mask
        return trajectory_errors(states[sel, self.angle_index], states[sel, self.speed_index],
                                 self.angle_data_rad[sel], self.speed_data_rad_s[sel])

    def frame(self) -> pd.DataFrame:
        """The trajectories to save (plotting reads them instead of simulating again)."""
        columns = {
            "time_s": self.time_s, "data_angle_rad": self.angle_data_rad, "data_speed_rad_s": self.speed_data_rad_s,
            "fmu_angle_rad": self.fmu_states[:, self.angle_index],
            "fmu_speed_rad_s": self.fmu_states[:, self.speed_index],
            "neural_fmu_angle_rad": self.neural_fmu_states[:, self.angle_index],
            "neural_fmu_speed_rad_s": self.neural_fmu_states[:, self.speed_index],
        }
        for i, name in enumerate(self.state_names):
            columns[f"fmu_{name}"] = self.fmu_states[:, i]
            columns[f"neural_fmu_{name}"] = self.neural_fmu_states[:, i]
        return pd.DataFrame(columns)


def compare(reference: dict[str, float], candidate: dict[str, float]) -> dict[str, dict]:
    """``{"fmu": reference, "neural_fmu": candidate, "improvement": reference / candidate}``."""
    return {"fmu": reference, "neural_fmu": candidate, "improvement": improvement_factors(reference, candidate)}


def zoom_comparisons(run: ManeuverRun, angle_length_s: float, speed_length_s: float,
                     configured: list[dict] | None) -> list[dict]:
    """Metrics of both models on the maneuver's zoomed intervals (chosen from the FMU's error alone)."""
    fmu_angle = run.fmu_states[:, run.angle_index]
    fmu_speed = run.fmu_states[:, run.speed_index]
    intervals = choose_zoom_intervals(run.time_s, fmu_angle - run.angle_data_rad, fmu_speed - run.speed_data_rad_s,
                                      angle_length_s, speed_length_s, configured)
    zooms = []
    for interval in intervals:
        mask = interval_mask(run.time_s, interval.t_start_s, interval.t_end_s)
        zooms.append({"maneuver": run.maneuver, **interval.as_dict(),
                      **compare(run.errors("fmu", mask), run.errors("neural_fmu", mask))})
    return zooms


def pooled_errors(runs: list[ManeuverRun], model: str) -> dict[str, float]:
    """MAE/MSE over all samples of several maneuvers together (each sample weighs the same)."""
    sims = np.concatenate([(r.fmu_states if model == "fmu" else r.neural_fmu_states) for r in runs])
    angle_index, speed_index = runs[0].angle_index, runs[0].speed_index
    return trajectory_errors(sims[:, angle_index], sims[:, speed_index],
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
