"""Maneuver arrays for training and validation: inputs, window initial states, targets, selected spans.

Built once per case from the ingested data (``{RESULTS}/data/<maneuver>.parquet``) read through the
case's roles, its selected segments (``{RESULTS}/segments/<maneuver>.json``) and the calibrated FMU,
and stored as a compressed ``.npz`` that every training job loads quickly.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.io import atomic_path

LOG = logging.getLogger(__name__)


@dataclass
class ManeuverArrays:
    """One maneuver on a uniform grid.

    Attributes:
        name: maneuver name.
        time_s: (T,) sample times (s), uniform step ``sample_period_s``.
        u: (T, n_u) FMU inputs in FMU order (``input_names``), model units of their signals.
        x_init: (T, n_x) states to start a window or segment from (measured where measured, the FMU's
            baseline open loop, started from the calibrated initial values, elsewhere), FMU order.
        targets: (T, n_t) measured target states (the loss and metric targets), order ``target_states``.
        spans: (S, 2) int64 index ranges [start, end) of the selected segments.
        state_names, input_names: the FMU's states and inputs.
        target_states: FMU names of the targets; target_signals: their signals (name the metrics).
        measured_states: names of the states whose ``x_init`` comes from measurements.
    """

    name: str
    time_s: np.ndarray
    u: np.ndarray
    x_init: np.ndarray
    targets: np.ndarray
    spans: np.ndarray
    state_names: list[str]
    input_names: list[str]
    target_states: list[str]
    target_signals: list[str]
    measured_states: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        t = np.shape(self.time_s)[0]
        expected = {"u": (t, len(self.input_names)), "x_init": (t, len(self.state_names)),
                    "targets": (t, len(self.target_states))}
        for key, shape in expected.items():
            if np.shape(getattr(self, key)) != shape:
                raise ValueError(f"maneuver {self.name}: {key} has shape {np.shape(getattr(self, key))}, "
                                 f"expected {shape}")
        if len(self.target_signals) != len(self.target_states):
            raise ValueError(f"maneuver {self.name}: {len(self.target_signals)} target signals for "
                             f"{len(self.target_states)} target states")
        unknown = [name for name in self.target_states if name not in self.state_names]
        if unknown:
            raise ValueError(f"maneuver {self.name}: target state(s) {unknown} are not FMU states {self.state_names}")

    @property
    def sample_period_s(self) -> float:
        return float((self.time_s[-1] - self.time_s[0]) / (self.time_s.size - 1))

    @property
    def target_index(self) -> list[int]:
        """Positions of the target states in the state vector."""
        return [self.state_names.index(name) for name in self.target_states]

    def span_mask(self) -> np.ndarray:
        """(T,) bool, True inside the selected segments."""
        mask = np.zeros(self.time_s.size, dtype=bool)
        for start, end in self.spans:
            mask[start:end] = True
        return mask

    def save(self, path: str | Path) -> Path:
        """Write atomically as ``.npz``."""
        with atomic_path(path, suffix=".npz") as tmp:
            np.savez_compressed(
                tmp, name=self.name, time_s=self.time_s, u=self.u, x_init=self.x_init, targets=self.targets,
                spans=self.spans, state_names=np.array(self.state_names, dtype=str),
                input_names=np.array(self.input_names, dtype=str),
                target_states=np.array(self.target_states, dtype=str),
                target_signals=np.array(self.target_signals, dtype=str),
                measured_states=np.array(self.measured_states, dtype=str))
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "ManeuverArrays":
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: prepared maneuver arrays do not exist (rule hpo_prepare)")
        with np.load(path, allow_pickle=False) as data:
            missing = [key for key in ("time_s", "u", "x_init", "targets", "spans", "state_names", "input_names",
                                       "target_states", "target_signals") if key not in data]
            if missing:
                raise ValueError(f"{path}: field(s) {missing} missing; expected prepared maneuver arrays "
                                 "(rerun rule hpo_prepare)")
            names = {key: [str(s) for s in data[key]] for key in ("state_names", "input_names", "target_states",
                                                                  "target_signals", "measured_states")
                     if key in data}
            time_s = data["time_s"]  # each access of an npz entry reads (and decompresses) it again
            return cls(name=str(data["name"]), time_s=time_s, u=data["u"].reshape(time_s.size, -1),
                       x_init=data["x_init"], targets=data["targets"].reshape(time_s.size, -1),
                       spans=data["spans"].astype(np.int64).reshape(-1, 2), **names)


def spans_to_indices(time_s: np.ndarray, spans_s: list[list[float]], source: str = "segments") -> np.ndarray:
    """Time spans [[t0, t1], ...] (s) -> index ranges [[i0, i1), ...] of the samples t0 <= t <= t1."""
    rows = []
    for t_start, t_end in spans_s:
        if not t_start <= t_end:
            raise ValueError(f"{source}: span [{t_start}, {t_end}] has start after end")
        i0 = int(np.searchsorted(time_s, t_start - 1e-9, side="left"))
        i1 = int(np.searchsorted(time_s, t_end + 1e-9, side="right"))
        if i1 - i0 >= 2:
            rows.append((i0, i1))
    return np.array(rows, dtype=np.int64).reshape(-1, 2)


def check_uniform_grid(time_s: np.ndarray, source: str) -> float:
    """The grid's step (s); raises if ``time_s`` is not uniform to 1e-6 relative."""
    if time_s.ndim != 1 or time_s.size < 2:
        raise ValueError(f"{source}: time_s must have at least 2 samples, got shape {time_s.shape}")
    steps = np.diff(time_s)
    step = float(np.median(steps))
    if not step > 0 or np.max(np.abs(steps - step)) > 1e-6 * step:
        raise ValueError(f"{source}: time_s is not a uniform grid (steps from {steps.min():.6g} to "
                         f"{steps.max():.6g} s); the solver steps on the sample grid")
    return step


def build_maneuver_arrays(name: str, data_path: str | Path, segments_path: str | Path, fmu_model: Any,
                          roles: Any, calibration: Any = None, maneuvers: dict[str, Any] | None = None,
                          baseline_path: str | Path | None = None) -> ManeuverArrays:
    """Read one maneuver's ingested data and segments and return its arrays.

    Args:
        name: maneuver name.
        data_path, segments_path: ``{RESULTS}/data/<name>.parquet`` and ``{RESULTS}/segments/<name>.json``.
        fmu_model: the loaded (calibrated) FMU.
        roles: :class:`hybridfmu.data.roles.CaseRoles`.
        calibration: :class:`hybridfmu.calibration.result.Calibration` (unmeasured initial states); None = empty.
        maneuvers: config ``maneuvers`` (``initial_states_from``).
        baseline_path: the FMU's baseline open loop of this maneuver (columns ``time_s`` + FMU states).

    States that are not measured are taken from the FMU's baseline open loop: ``baseline_path`` if it
    exists, else simulated here from the first sample (measured states, calibrated unmeasured ones).
    """
    from hybridfmu.data.segments import read_segments
    from hybridfmu.training.measured import initial_state, load_calibration, read_measured

    calibration = calibration if calibration is not None else load_calibration(None)
    state_names, input_names = list(fmu_model.state_names), list(fmu_model.input_names)
    if state_names != list(roles.state_names) or input_names != list(roles.input_names):
        raise ValueError(f"FMU states {state_names} / inputs {input_names} differ from the case roles' "
                         f"{roles.state_names} / {roles.input_names}")
    measured = read_measured(data_path, roles)
    time_s = measured.time_s
    check_uniform_grid(time_s, str(data_path))
    x_init = measured.x.copy()
    missing = list(roles.unmeasured_states)
    if missing:
        x0 = initial_state(fmu_model, measured.x[0], roles, calibration, name, maneuvers)
        baseline = _baseline_states(fmu_model, time_s, measured.u, x0, baseline_path, str(data_path))
        for state in missing:
            x_init[:, state_names.index(state)] = baseline[:, state_names.index(state)]
        LOG.info("%s: states %s are not measured; windows start from the FMU's baseline open loop", name, missing)
    if not np.all(np.isfinite(x_init)) or not np.all(np.isfinite(measured.u)):
        raise ValueError(f"{data_path}: non-finite values in the states or inputs")
    record = read_segments(segments_path)
    spans = spans_to_indices(time_s, record["spans_s"], str(segments_path))
    if spans.size == 0:
        raise ValueError(f"{segments_path}: field 'spans_s' selects no samples; training needs at least one segment")
    return ManeuverArrays(name=name, time_s=time_s, u=measured.u, x_init=x_init, targets=measured.targets,
                          spans=spans, state_names=state_names, input_names=input_names,
                          target_states=measured.target_states, target_signals=measured.target_signals,
                          measured_states=measured.measured_states)


def _baseline_states(fmu_model, time_s, u, x0, baseline_path, source) -> np.ndarray:
    import pandas as pd

    state_names = list(fmu_model.state_names)
    if baseline_path is not None and Path(baseline_path).is_file():
        frame = pd.read_parquet(baseline_path)
        missing = [name for name in ["time_s", *state_names] if name not in frame.columns]
        if missing:
            raise ValueError(f"{baseline_path}: column(s) {missing} missing; expected time_s and the FMU states")
        if len(frame) != time_s.size or not np.allclose(frame["time_s"].to_numpy(), time_s, atol=1e-9):
            raise ValueError(f"{baseline_path}: time_s does not match the grid of {source}")
        return frame[state_names].to_numpy(dtype=np.float64)
    from hybridfmu.fmu import simulate_open_loop

    LOG.info("%s: no baseline file; simulating the FMU open loop for the unmeasured states", source)
    return simulate_open_loop(fmu_model, time_s, u, x0).states
