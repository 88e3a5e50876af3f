"""A maneuver's measurements in the FMU's terms, and the calibrated FMU it is compared with.

Every stage that simulates the FMU (baseline, time offset, training data, evaluation) reads the
ingested frame through the case's roles (:mod:`hybridfmu.data.roles`) and loads the FMU with the
calibrated parameters (:class:`hybridfmu.calibration.result.Calibration`, rule ``calibrate``).

API::

    read_measured(data_path, roles) -> MeasuredManeuver
    measured_from_frame(frame, roles) -> MeasuredManeuver  # the same for a frame in memory
    load_calibration(path) -> Calibration
    load_calibrated_fmu(fmu_path, calibration) -> FmuModel
    initial_state(model, measured_x0, roles, calibration, maneuver, maneuvers) -> (n_x,)
    read_baseline(path, state_names, time_s) -> (T, n_x)   # the calibrated FMU's open loop (rule simulate_baseline)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.calibration.result import Calibration


@dataclass
class MeasuredManeuver:
    """One ingested maneuver in the FMU's orders, in the model units of the signals.

    Attributes:
        time_s: (T,) sample times, s.
        u: (T, n_u) FMU inputs, FMU order (``input_names``).
        x: (T, n_x) FMU states, FMU order (``state_names``); NaN in the columns of unmeasured states.
        targets: (T, n_t) the target states, order ``target_states`` (signals ``target_signals``).
    """

    time_s: np.ndarray
    u: np.ndarray
    x: np.ndarray
    targets: np.ndarray
    state_names: list[str]
    input_names: list[str]
    measured_states: list[str]
    target_states: list[str]
    target_signals: list[str]


def read_measured(data_path: str | Path, roles: Any) -> MeasuredManeuver:
    """Read an ingested maneuver (``time_s`` plus one column per signal) through the case's roles
    (:func:`measured_from_frame`).

    Args:
        data_path: ``{RESULTS}/data/<maneuver>.parquet``.
        roles: :class:`hybridfmu.data.roles.CaseRoles` of the case.

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: a column is missing, or fewer than 2 samples (the message names the file).
    """
    import pandas as pd

    data_path = Path(data_path)
    if not data_path.is_file():
        raise FileNotFoundError(f"{data_path}: ingested maneuver does not exist (rule ingest)")
    return measured_from_frame(pd.read_parquet(data_path), roles, data_path)


def measured_from_frame(frame: Any, roles: Any, source: str | Path = "the frame") -> MeasuredManeuver:
    """An ingested maneuver's frame (pandas; ``time_s`` (s) plus one column per signal in its model unit, as
    :func:`hybridfmu.data.ingest.ingest_log` returns it) in the FMU's terms, through the case's roles.

    Raises:
        ValueError: a column is missing, or fewer than 2 samples (the message names ``source``).
    """
    from hybridfmu.data.signals import input_array, state_array, time_array

    measured = list(roles.measured_states)
    try:
        time_s = np.asarray(time_array(frame), dtype=np.float64)
        u = np.asarray(input_array(frame, roles), dtype=np.float64).reshape(time_s.size, len(roles.input_names))
        columns = np.asarray(state_array(frame, roles, measured), dtype=np.float64).reshape(time_s.size, len(measured))
    except ValueError as err:
        raise type(err)(f"{source}: {err}") from None
    if time_s.size < 2:
        raise ValueError(f"{source}: column 'time_s' holds {time_s.size} sample(s), at least 2 are needed")
    x = np.full((time_s.size, len(roles.state_names)), np.nan)
    for k, name in enumerate(measured):
        x[:, roles.state_names.index(name)] = columns[:, k]
    targets = x[:, [roles.state_names.index(name) for name in roles.target_states]].copy()
    return MeasuredManeuver(time_s=time_s, u=u, x=x, targets=targets, state_names=list(roles.state_names),
                            input_names=list(roles.input_names), measured_states=measured,
                            target_states=list(roles.target_states), target_signals=list(roles.target_signals))


def load_calibration(path: str | Path | None) -> Calibration:
    """The calibration result at ``path`` (rule ``calibrate``); an empty one (FMU as configured) for None."""
    if path is None:
        return Calibration()
    if not Path(path).is_file():
        raise FileNotFoundError(f"{path}: calibration result does not exist (rule calibrate)")
    return Calibration.load(path)


def load_calibrated_fmu(fmu_path: str | Path, calibration: Calibration):
    """The FMU at ``fmu_path`` with the calibrated parameters set (``calibration.parameters``)."""
    from hybridfmu.fmu import load_fmu

    return load_fmu(fmu_path, parameters=dict(calibration.parameters) or None)


def start_values(model: Any) -> dict[str, float]:
    """State name -> the FMU's value after initialisation (its start values), of a loaded FMU."""
    return {name: float(value) for name, value in zip(model.state_names, np.asarray(model.initial_states))}


def initial_state(model: Any, measured_x0: np.ndarray, roles: Any, calibration: Calibration, maneuver: str,
                  maneuvers: dict[str, Any] | None) -> np.ndarray:
    """The FMU's initial state of a maneuver: measured states from the data, unmeasured ones calibrated.

    Args:
        model: the loaded FMU (state names and start values).
        measured_x0: (n_x,) the first sample of ``MeasuredManeuver.x`` (NaN where unmeasured).
        roles: the case's roles.
        calibration: the calibration result.
        maneuver: maneuver name; maneuvers: config ``maneuvers`` (``initial_states_from``).

    Returns:
        (n_x,) float64, FMU order.
    """
    x0 = np.asarray(measured_x0, dtype=np.float64).copy()
    unmeasured = list(roles.unmeasured_states)
    if unmeasured:
        values = calibration.unmeasured_initial_states(maneuver, {"maneuvers": dict(maneuvers or {})},
                                                       start_values(model), unmeasured)
        for name, value in values.items():
            x0[list(model.state_names).index(name)] = value
    if not np.all(np.isfinite(x0)):
        bad = [name for name, value in zip(model.state_names, x0) if not np.isfinite(value)]
        raise ValueError(f"maneuver {maneuver!r}: initial state(s) {bad} are not finite (measured NaN?)")
    return x0


def read_baseline(path: str | Path, state_names: list[str], time_s: np.ndarray) -> np.ndarray:
    """FMU states (T, n_x) of a baseline trajectory, checked against the data's time grid ``time_s`` (T,)."""
    import pandas as pd

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: baseline trajectory does not exist (rule simulate_baseline)")
    frame = pd.read_parquet(path)
    missing = [name for name in ["time_s", *state_names] if name not in frame.columns]
    if missing:
        raise ValueError(f"{path}: column(s) {missing} missing; expected time_s and the FMU states {state_names}")
    if len(frame) != time_s.size or not np.allclose(frame["time_s"].to_numpy(), time_s, rtol=0, atol=1e-9):
        raise ValueError(f"{path}: time_s does not match the ingested maneuver's grid ({len(frame)} vs "
                         f"{time_s.size} samples); rerun simulate_baseline")
    return frame[state_names].to_numpy(dtype=float)
