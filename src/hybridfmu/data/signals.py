"""FMU arrays from an ingested frame, by the case's roles (:class:`hybridfmu.data.roles.CaseRoles`).

An ingested frame (:func:`hybridfmu.data.ingest.ingest_log`) holds ``time_s`` and one column per
signal, each in its model unit: the unit of the FMU variable it feeds. These helpers stack the
columns in the order the FMU (and the loss) wants them. No signal is computed here: derived
signals (e.g. a force from a measured pressure) are transforms applied at ingest.

API::

    time_array(frame) -> (T,)
    input_array(frame, roles) -> (T, n_u)                         # FMU input order, the values each step holds
    state_array(frame, roles, state_names=None) -> (T, n_measured) # measured states, FMU order
    target_array(frame, roles) -> (T, n_targets)                   # target states, FMU order
    signal_array(frame, names) -> (T, len(names))
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np

from hybridfmu.data.between_samples import frame_conventions, held_values
from hybridfmu.data.roles import CaseRoles
from hybridfmu.data.errors import DataError

if TYPE_CHECKING:  # annotations only: the workflow's start imports this module without pandas
    import pandas as pd


def time_array(frame: pd.DataFrame) -> np.ndarray:
    """The frame's time stamps, (T,) float64 seconds."""
    return _column(frame, "time_s")


def signal_array(frame: pd.DataFrame, names: Sequence[str]) -> np.ndarray:
    """Columns ``names`` of the frame stacked, (T, len(names)) float64 (each in its model unit).

    Raises:
        DataError: a column is missing (the message lists the frame's columns).
    """
    if not names:
        return np.zeros((len(frame), 0), dtype=np.float64)
    return np.stack([_column(frame, name) for name in names], axis=1)


def input_array(frame: pd.DataFrame, roles: CaseRoles) -> np.ndarray:
    """The FMU's inputs as every simulation holds them, (T, n_u) float64: column k = signal of FMU input
    ``roles.input_names[k]``, row k the value held over [t_k, t_k+1) by the input's convention
    (:func:`hybridfmu.data.between_samples.held_values`, the conventions the frame records).

    Each column is in the unit the FMU declares for its input (the signal's model unit).

    Raises:
        DataError: a signal's column is missing from the frame.
    """
    return held_input_array(frame, roles.input_names, roles.input_signals)


def held_input_array(frame: pd.DataFrame, input_names: Sequence[str], input_signals: Sequence[str]) -> np.ndarray:
    """:func:`input_array` for FMU inputs ``input_names`` fed by the columns ``input_signals``: (T, n_u)."""
    return held_values(signal_array(frame, input_signals), frame_conventions(frame, input_names))


def state_array(frame: pd.DataFrame, roles: CaseRoles, state_names: Sequence[str] | None = None) -> np.ndarray:
    """Measured FMU states, (T, n) float64: column k = signal of state ``state_names[k]``.

    Args:
        frame: ingested data.
        roles: the case's roles.
        state_names: measured states in the wanted order; default ``roles.measured_states`` (FMU order).

    Raises:
        DataError: a state is not measured (names the state and ``config.roles.states``), or its
            signal's column is missing.
    """
    names = list(roles.measured_states) if state_names is None else list(state_names)
    unmeasured = [name for name in names if name not in roles.states]
    if unmeasured:
        raise DataError(f"state(s) {unmeasured} are not measured: config.roles.states maps only "
                        f"{list(roles.states)}; expected measured states")
    return signal_array(frame, [roles.states[name] for name in names])


def target_array(frame: pd.DataFrame, roles: CaseRoles) -> np.ndarray:
    """Target states (compared in loss and metrics), (T, n_targets) float64 in ``roles.target_states`` order."""
    return signal_array(frame, roles.target_signals)


def _column(frame: pd.DataFrame, column: str) -> np.ndarray:
    if column not in frame.columns:
        raise DataError(f"ingested frame: column {column!r} missing; the frame has {list(frame.columns)}")
    return frame[column].to_numpy(dtype=np.float64)
