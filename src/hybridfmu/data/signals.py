"""FMU arrays from an ingested frame: time, inputs u in the FMU's order, measured states, i_d/i_q.

The config section ``signals`` maps FMU variables to the ingested columns: ``inputs`` (FMU input ->
column), ``measured_states`` (FMU state -> column), ``angle_state`` / ``speed_state`` (the FMU names of
the mechanical states), ``phase_currents`` (three columns, phases a, b, c) and ``current_states`` (FMU
names of the d- and q-currents), ``pole_pairs`` (electrical angle = pole_pairs * angle).

Currents follow the amplitude-invariant Clarke transform and the Park transform with the MEASURED
angle (``theta_e = pole_pairs * theta``):
``alpha = (2/3)(i_a - i_b/2 - i_c/2)``, ``beta = (i_b - i_c)/sqrt(3)``,
``i_d = alpha cos(theta_e) + beta sin(theta_e)``, ``i_q = -alpha sin(theta_e) + beta cos(theta_e)``.

API::

    time_array(frame) -> (T,)
    input_array(frame, signals, input_names=None) -> (T, n_u)
    state_array(frame, signals, state_names=None, pole_pairs=None) -> (T, n_x)
    currents_dq(frame, signals, pole_pairs=None) -> ((T,), (T,))
    clarke_park(i_a, i_b, i_c, theta_e_rad) -> (i_d, i_q)
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
import pandas as pd

from hybridfmu.data.errors import DataError
from hybridfmu.data.settings import section_settings


def time_array(frame: pd.DataFrame) -> np.ndarray:
    """The frame's time stamps, (T,) float64 seconds."""
    return _column(frame, "time_s")


def input_array(frame: pd.DataFrame, signals_config: dict[str, Any] | None,
                input_names: Sequence[str] | None = None) -> np.ndarray:
    """FMU inputs as one array.

    Args:
        frame: ingested data.
        signals_config: the case's ``signals`` section.
        input_names: FMU input names in the FMU's order (e.g. ``model.input_names``); default: the
            order of ``signals.inputs``.

    Returns:
        (T, n_u) float64, column k = input ``input_names[k]`` (SI units of the ingested columns).

    Raises:
        DataError: an input has no column in ``signals.inputs``, or the column is missing from the frame.
    """
    settings = section_settings(signals_config, "signals")
    mapping = settings["inputs"]
    names = list(input_names) if input_names is not None else list(mapping)
    unmapped = [name for name in names if name not in mapping]
    if unmapped:
        raise DataError(f"config.signals.inputs: no column for FMU input(s) {unmapped}; mapped: {mapping}")
    return np.stack([_column(frame, mapping[name]) for name in names], axis=1)


def state_array(frame: pd.DataFrame, signals_config: dict[str, Any] | None,
                state_names: Sequence[str] | None = None, pole_pairs: int | None = None) -> np.ndarray:
    """Measured FMU states as one array.

    Args:
        frame: ingested data.
        signals_config: the case's ``signals`` section.
        state_names: FMU state names in the wanted order (e.g. ``model.state_names``); states in
            ``signals.current_states`` come from the phase currents via Park. Default: the current
            states (if phase currents are in the frame) followed by ``signals.measured_states``.
        pole_pairs: overrides ``signals.pole_pairs``.

    Returns:
        (T, n_x) float64, column k = state ``state_names[k]`` (A, rad, rad/s ...).

    Raises:
        DataError: a state is neither measured nor a current state, or its columns are missing.
    """
    settings = section_settings(signals_config, "signals")
    measured = settings["measured_states"]
    current_names = list(settings["current_states"])
    if state_names is None:
        has_currents = all(column in frame.columns for column in settings["phase_currents"])
        state_names = (current_names if has_currents else []) + list(measured)
    unknown = [name for name in state_names if name not in measured and name not in current_names]
    if unknown:
        raise DataError(f"config.signals: state(s) {unknown} are neither in measured_states {list(measured)} "
                        f"nor in current_states {current_names}")
    currents: tuple[np.ndarray, np.ndarray] | None = None
    columns = []
    for name in state_names:
        if name in measured:
            columns.append(_column(frame, measured[name]))
            continue
        if currents is None:
            currents = currents_dq(frame, settings, pole_pairs)
        columns.append(currents[current_names.index(name)])
    return np.stack(columns, axis=1)


def currents_dq(frame: pd.DataFrame, signals_config: dict[str, Any] | None,
                pole_pairs: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """d- and q-currents from the phase currents, Park with the measured angle.

    Args:
        frame: ingested data with the ``signals.phase_currents`` columns and the angle column
            (``signals.measured_states[signals.angle_state]``).
        signals_config: the case's ``signals`` section.
        pole_pairs: overrides ``signals.pole_pairs``.

    Returns:
        (i_d, i_q), each (T,) float64 in A.
    """
    settings = section_settings(signals_config, "signals")
    p = int(pole_pairs if pole_pairs is not None else settings["pole_pairs"])
    angle_state = settings["angle_state"]
    if angle_state not in settings["measured_states"]:
        raise DataError(f"config.signals.angle_state {angle_state!r} is not in measured_states "
                        f"{list(settings['measured_states'])}")
    theta_rad = _column(frame, settings["measured_states"][angle_state])
    i_a, i_b, i_c = (_column(frame, column) for column in settings["phase_currents"])
    return clarke_park(i_a, i_b, i_c, p * theta_rad)


def clarke_park(i_a: np.ndarray, i_b: np.ndarray, i_c: np.ndarray,
                theta_e_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude-invariant Clarke then Park transform; all arguments (T,) -> (i_d, i_q) each (T,)."""
    alpha = (2.0 / 3.0) * (i_a - 0.5 * i_b - 0.5 * i_c)
    beta = (i_b - i_c) / np.sqrt(3.0)
    cos_e, sin_e = np.cos(theta_e_rad), np.sin(theta_e_rad)
    return alpha * cos_e + beta * sin_e, -alpha * sin_e + beta * cos_e


def _column(frame: pd.DataFrame, column: str) -> np.ndarray:
    if column not in frame.columns:
        raise DataError(f"ingested frame: column {column!r} missing; the frame has {list(frame.columns)}")
    return frame[column].to_numpy(dtype=np.float64)
