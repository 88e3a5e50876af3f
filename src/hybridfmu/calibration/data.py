"""The arrays the calibration needs from one ingested maneuver: time, FMU inputs, measured states.

An ingested maneuver (``{RESULTS}/data/<maneuver>.parquet``) holds ``time_s`` and one column per
signal in its model unit (:mod:`hybridfmu.data.roles`); the case's roles say which signal feeds which
FMU input and which FMU state each measured signal is.

API::

    maneuvers_with_role(config, role) -> list[str]
    maneuver_arrays(frame, roles, name, source="") -> ManeuverArrays
    load_maneuver(path, roles, name) -> ManeuverArrays
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.data.roles import CaseRoles
from hybridfmu.data.signals import input_array


@dataclass(frozen=True)
class ManeuverArrays:
    """One maneuver, in the FMU's units and orders.

    Attributes:
        name: maneuver name.
        time_s: (T,) sample times in s, strictly increasing.
        inputs: (T, n_u) FMU inputs (order ``roles.input_names``); u[k] holds on [t_k, t_k+1) (each input's
            convention, :mod:`hybridfmu.data.between_samples`).
        measured: (T, n_m) measured states (order ``roles.measured_states``).
        measured_names: the measured FMU states, in the columns' order.
    """

    name: str
    time_s: np.ndarray
    inputs: np.ndarray
    measured: np.ndarray
    measured_names: list[str]

    def state(self, name: str) -> np.ndarray:
        """(T,) measured values of FMU state ``name``."""
        return self.measured[:, self.measured_names.index(name)]

    def truncated(self, duration_s: float | None) -> "ManeuverArrays":
        """The first ``duration_s`` seconds (all samples with t - t_0 <= duration_s); None: unchanged."""
        if duration_s is None:
            return self
        keep = self.time_s - self.time_s[0] <= float(duration_s) + 1e-9
        keep[:2] = True
        return ManeuverArrays(self.name, self.time_s[keep], self.inputs[keep], self.measured[keep],
                              self.measured_names)


def maneuvers_with_role(config: dict[str, Any], role: str) -> list[str]:
    """Names of the case's maneuvers with ``role`` (train, validation, test), in config order."""
    return [name for name, entry in config["maneuvers"].items() if entry.get("role") == role]


def _column(frame, signal: str, source: str, what: str) -> np.ndarray:
    if signal not in frame.columns:
        raise ValueError(f"{source}: no column {signal!r} ({what}); expected the ingested signals "
                         f"{[c for c in frame.columns if c != 'time_s']}")
    values = np.asarray(frame[signal], dtype=np.float64)
    if not np.isfinite(values).all():
        k = int(np.flatnonzero(~np.isfinite(values))[0])
        raise ValueError(f"{source}: column {signal!r} ({what}) holds a non-finite value at row {k}")
    return values


def maneuver_arrays(frame, roles: CaseRoles, name: str, source: str = "") -> ManeuverArrays:
    """Arrays of one ingested maneuver (a DataFrame with ``time_s`` and one column per signal).

    Raises:
        ValueError: a missing or non-finite column, fewer than 2 samples or non-increasing times;
            names ``source`` (the file) and the column.
    """
    source = source or f"maneuver {name!r}"
    time_s = _column(frame, "time_s", source, "sample times in s")
    if time_s.size < 2 or (np.diff(time_s) <= 0).any():
        raise ValueError(f"{source}: column 'time_s' must hold at least 2 strictly increasing times, "
                         f"got {time_s.size} samples")
    for input_name in roles.input_names:
        _column(frame, roles.inputs[input_name], source, f"FMU input {input_name}")
    measured = [_column(frame, roles.states[n], source, f"FMU state {n}") for n in roles.measured_states]
    return ManeuverArrays(
        name=name, time_s=time_s,
        inputs=input_array(frame, roles).reshape(time_s.size, len(roles.input_names)),
        measured=np.stack(measured, axis=1), measured_names=list(roles.measured_states))


def load_maneuver(path: str | Path, roles: CaseRoles, name: str) -> ManeuverArrays:
    """:func:`maneuver_arrays` of the ingested Parquet file ``path``.

    Raises:
        FileNotFoundError: the file does not exist. ValueError: as :func:`maneuver_arrays`.
    """
    import pandas as pd

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: ingested data of maneuver {name!r} not found (rule ingest writes it)")
    return maneuver_arrays(pd.read_parquet(path), roles, name, source=str(path))
