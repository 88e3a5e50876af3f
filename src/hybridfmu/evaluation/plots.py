"""Rule ``plot``: every figure from the saved results (nothing is simulated or trained again)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pandas as pd

from hybridfmu.evaluation.figures import (FURTHER_STYLES, PlotOptions, Trajectories, plot_hyperband, plot_time_offset,
                                          plot_training_curves, plot_trajectory, plot_zooms)
from hybridfmu.evaluation.history import read_histories
from hybridfmu.io import read_json

LOG = logging.getLogger(__name__)


def _trajectories(frame: pd.DataFrame, maneuver: str, signal: Any, zooms: list[dict], path: Path) -> Trajectories:
    columns = ["time_s"] + [f"{source}_{signal.name}" for source in ("data", "fmu", "neural_fmu")]
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise ValueError(f"{path}: column(s) {missing} missing (expected the trajectories written by evaluate)")
    further = {model: frame[f"{model}_{signal.name}"].to_numpy(dtype=float) for model in FURTHER_STYLES
               if f"{model}_{signal.name}" in frame.columns}
    return Trajectories(maneuver, signal, *(frame[c].to_numpy(dtype=float) for c in columns),
                        zooms=[(z["t_start_s"], z["t_end_s"]) for z in zooms
                               if z["maneuver"] == maneuver and z.get("signal") == signal.name], further=further)


def draw_all(figure_paths: dict[str, str], metrics_paths: list[str], trajectory_paths: list[str],
             time_offset_path: str, time_offset_summary_path: str, best_path: str, hpo_dir: str,
             maneuver_roles: dict[str, str], plot_options: dict[str, Any] | None, roles: Any) -> list[Path]:
    """Draw every figure named in ``figure_paths``.

    Args:
        figure_paths: figure name -> PNG path. Names: ``time_offset``, ``training_curves``,
            ``hyperband``, and ``<maneuver>_<signal>``, ``<maneuver>_<signal>_zoom`` per evaluated maneuver
            and target signal.
        metrics_paths: ``metrics/<role>.json`` (zoom intervals).
        trajectory_paths: saved trajectories per maneuver, in the order of ``maneuver_roles``.
        time_offset_path, time_offset_summary_path: the time-offset window and its summary.
        best_path, hpo_dir: the search's best trial and the folder of the per-trial histories.
        plot_options: config ``evaluation.plot``.
        roles: :class:`hybridfmu.data.roles.CaseRoles` (target signals, labels, units).
    """
    options = PlotOptions.from_config(plot_options)
    signals = [roles.signals[name] for name in roles.target_signals]
    zooms = [zoom for path in metrics_paths for zoom in read_json(path).get("zooms", [])]
    drawn: list[Path] = []
    todo = dict(figure_paths)
    for maneuver, path in zip(maneuver_roles, trajectory_paths):
        frame = pd.read_parquet(path)
        role = maneuver_roles[maneuver]
        for signal in signals:
            traj = _trajectories(frame, maneuver, signal, zooms, Path(path))
            name = f"{maneuver}_{signal.name}"
            if name in todo:
                drawn.append(plot_trajectory(traj, todo.pop(name), options,
                                             title=f"{role} maneuver '{maneuver}': {signal.label}, "
                                                   "whole trajectory (open loop)"))
            if f"{name}_zoom" in todo:
                drawn.append(plot_zooms(traj, todo.pop(f"{name}_zoom"), options))
    if "time_offset" in todo:
        window = pd.read_parquet(time_offset_path)
        summary = read_json(time_offset_summary_path)
        names = [signal.name for signal in signals]
        missing = [f"{kind}_{n}" for n in names for kind in ("data", "fmu", "fmu_delayed")
                   if f"{kind}_{n}" not in window.columns]
        if missing:
            raise ValueError(f"{time_offset_path}: column(s) {missing} missing (rerun rule time_offset)")
        drawn.append(plot_time_offset(window["time_s"].to_numpy(), signals,
                                      window[[f"data_{n}" for n in names]].to_numpy(),
                                      window[[f"fmu_{n}" for n in names]].to_numpy(), todo.pop("time_offset"),
                                      window[[f"fmu_delayed_{n}" for n in names]].to_numpy(),
                                      input_delay_s=summary["input_delay_s"], maneuver=summary.get("maneuver", ""),
                                      options=options))
    if "training_curves" in todo or "hyperband" in todo:
        histories = read_histories(hpo_dir, best_path)
        if "training_curves" in todo:
            drawn.append(plot_training_curves(histories, todo.pop("training_curves"), options))
        if "hyperband" in todo:
            drawn.append(plot_hyperband(histories, todo.pop("hyperband"), options))
    if todo:
        raise ValueError(f"plot: no figure function for {sorted(todo)}")
    for path in drawn:
        LOG.info("drew %s", path)
    return drawn
