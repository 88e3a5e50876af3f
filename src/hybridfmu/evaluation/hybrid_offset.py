"""The time-offset stage on a hybrid's physical layer: where the hybrid's learned delays start.

The neural FMU's delays start at each input group's time offset estimated with the calibrated FMU
(:func:`hybridfmu.evaluation.offset.run_time_offset`). A hybrid's delays complement its physical layer, the
FMU plus the diagnosed effects (:mod:`hybridfmu.model.physics`), so its start is estimated the same way with
that model: the same short windows after each group's input changes, the same candidates and refinement
(:func:`hybridfmu.evaluation.offset.group_estimates`), simulated with the FMU plus the effects (their input
changes included) instead of the FMU alone. An effect the FMU lacks no longer has to be absorbed by the
estimate (e.g. an actuator's dead time, which also delays a state's response to an input change).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.io import write_json_atomic

LOG = logging.getLogger(__name__)


def physics_group_estimates(physics: Any, measured: Any, roles: Any, x0: np.ndarray, maneuver: str,
                            options: dict[str, Any], delay_config: dict[str, Any], resolution: int = 20
                            ) -> dict[str, Any]:
    """Each input group's time offset of ``measured`` with the physical layer ``physics``.

    Args:
        physics: a :class:`hybridfmu.model.physics.PhysicsModel` (its diagnosed model is simulated open loop,
            input changes included).
        measured: the maneuver (``training.measured.read_measured``: ``time_s`` (T,), ``u`` (T, n_u), ``x``
            (T, n_x) with NaN for unmeasured states).
        roles: the case's roles; x0: (n_x,) the maneuver's initial state for the physical layer (its unmeasured
            states fill ``x`` along the layer's own open loop).
        options: config ``evaluation.time_offset``; delay_config: config ``model.input_delay``.
        resolution: candidates per sampling interval.

    Returns:
        {group: {...}} as :func:`hybridfmu.evaluation.offset.group_estimates`.

    Raises:
        FloatingPointError: the physical layer diverged (names the window).
    """
    from hybridfmu.evaluation.offset import group_estimates, time_offset_settings

    with physics.diagnosed.open_loop(physics.fmu, physics.helper) as open_loop:  # the windows share one set-up

        def simulate(time_s: np.ndarray, u: np.ndarray, start: np.ndarray, label: str) -> np.ndarray:
            states = open_loop(time_s, u, start)
            if not np.all(np.isfinite(states)):
                raise FloatingPointError(f"{label}: the hybrid's physical layer diverged (non-finite state)")
            return states

        x = np.array(measured.x, dtype=float)
        if roles.unmeasured_states:
            x = np.where(np.isfinite(x), x, simulate(measured.time_s, measured.u, np.asarray(x0, dtype=float),
                                                     f"{maneuver} physical layer open loop"))
        step_s = float(np.median(np.diff(measured.time_s)))
        max_lag_s = float(time_offset_settings(options, step_s)["max_lag_s"])
        return group_estimates(simulate, measured, x, roles, maneuver, options, delay_config, max_lag_s,
                               step_s / int(resolution), step_s)


def run_hybrid_time_offset(fmu_path: str | Path, calibration_path: str | Path | None, diagnosed_path: str | Path,
                           data_path: str | Path, summary_path: str | Path, options: dict[str, Any], roles: Any,
                           maneuvers: dict[str, Any] | None, maneuver: str, model_config: dict[str, Any]
                           ) -> dict[str, Any]:
    """Rule ``hybrid_time_offset``: the time-offset stage's group estimates on the hybrid's physical layer.

    Args:
        fmu_path, calibration_path: the FMU and its calibration; diagnosed_path: the diagnosed model
            (``diagnosis/diagnosed_model.pkl``).
        data_path: the maneuver of the time-offset stage; summary_path: the JSON written.
        options: config ``evaluation.time_offset``; roles: the case's roles; maneuvers: config ``maneuvers``;
            maneuver: its name.
        model_config: the validated ``model`` section (``physics_terms`` chooses the effects, as the hybrid's
            search does; ``input_delay`` the groups and range).

    Writes ``summary_path`` (JSON: ``maneuver``, ``physics`` (the physical layer's effects), ``groups`` as the
    time-offset stage's, ``convention``) and returns it.
    """
    from hybridfmu.training.measured import initial_state, load_calibration, read_measured
    from hybridfmu.training.trial import hybrid_physics

    calibration = load_calibration(calibration_path)
    physics = hybrid_physics(model_config, fmu_path, calibration.parameters, diagnosed_path)
    if physics is None:
        raise ValueError("config.model.physics_terms is 'none': there is no hybrid whose delays to estimate")
    measured = read_measured(data_path, roles)
    x0 = physics.diagnosed.initial_state(
        initial_state(physics.fmu, measured.x[0], roles, calibration, maneuver, maneuvers), maneuver)
    groups = physics_group_estimates(physics, measured, roles, x0, maneuver, options, model_config["input_delay"])
    summary = {"maneuver": maneuver, "physics": physics.effects, "groups": groups,
               "convention": "the physical layer sees the logged inputs as u(t + delay_s), as the hybrid's delay"}
    write_json_atomic(summary_path, summary)
    LOG.info("%s: the hybrid's time offsets on its physical layer: %s", maneuver,
             ", ".join(f"{name} {entry['delay_s'] * 1e6:.2f} µs" for name, entry in groups.items()))
    return summary
