"""Maneuver arrays for training and validation: inputs, window initial states, targets, selected spans.

Built once per case from the ingested data (``{RESULTS}/data/<maneuver>.parquet``), its selected
segments (``{RESULTS}/segments/<maneuver>.json``) and the FMU (state and input names), and stored as a
compressed ``.npz`` that every training job loads quickly.
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
        u: (T, n_u) FMU inputs in FMU order (``input_names``).
        x_init: (T, n_x) states to start a window or segment from (measured where measured, the FMU's
            baseline open loop elsewhere), FMU order (``state_names``).
        angle, speed: (T,) measured angle (rad) and speed (rad/s): the loss targets.
        spans: (S, 2) int64 index ranges [start, end) of the selected segments.
        measured_states: names of the states whose ``x_init`` comes from measurements.
    """

    name: str
    time_s: np.ndarray
    u: np.ndarray
    x_init: np.ndarray
    angle: np.ndarray
    speed: np.ndarray
    spans: np.ndarray
    state_names: list[str]
    input_names: list[str]
    angle_state: str
    speed_state: str
    measured_states: list[str] = field(default_factory=list)

    @property
    def sample_period_s(self) -> float:
        return float((self.time_s[-1] - self.time_s[0]) / (self.time_s.size - 1))

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
                tmp, name=self.name, time_s=self.time_s, u=self.u, x_init=self.x_init, angle=self.angle,
                speed=self.speed, spans=self.spans, state_names=np.array(self.state_names),
                input_names=np.array(self.input_names), angle_state=self.angle_state, speed_state=self.speed_state,
                measured_states=np.array(self.measured_states, dtype=str))
        return Path(path)

    @classmethod
    def load(cls, path: str | Path) -> "ManeuverArrays":
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: prepared maneuver arrays do not exist (rule hpo_prepare)")
        with np.load(path, allow_pickle=False) as data:
            missing = [key for key in ("time_s", "u", "x_init", "angle", "speed", "spans") if key not in data]
            if missing:
                raise ValueError(f"{path}: field(s) {missing} missing; expected prepared maneuver arrays")
            return cls(name=str(data["name"]), time_s=data["time_s"], u=data["u"], x_init=data["x_init"],
                       angle=data["angle"], speed=data["speed"], spans=data["spans"].astype(np.int64).reshape(-1, 2),
                       state_names=[str(s) for s in data["state_names"]],
                       input_names=[str(s) for s in data["input_names"]], angle_state=str(data["angle_state"]),
                       speed_state=str(data["speed_state"]),
                       measured_states=[str(s) for s in data["measured_states"]])


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
                          signals_config: dict[str, Any] | None, baseline_path: str | Path | None = None,
                          ) -> ManeuverArrays:
    """Read one maneuver's ingested data and segments and return its arrays.

    States that the ``signals`` section cannot provide from measurements are taken from the FMU's
    baseline open loop: ``baseline_path`` (columns time_s + FMU state names) if it exists, else simulated
    here with ``simulate_open_loop`` from the first sample.
    """
    import pandas as pd

    from hybridfmu.data.segments import read_segments
    from hybridfmu.data.settings import section_settings
    from hybridfmu.data.signals import input_array, state_array, time_array

    data_path = Path(data_path)
    if not data_path.is_file():
        raise FileNotFoundError(f"{data_path}: ingested data do not exist (rule ingest)")
    frame = pd.read_parquet(data_path)
    signals = section_settings(signals_config, "signals")
    state_names, input_names = list(fmu_model.state_names), list(fmu_model.input_names)
    time_s = time_array(frame)
    check_uniform_grid(time_s, str(data_path))
    u = input_array(frame, signals, input_names)
    measurable = set(signals["measured_states"])
    if all(column in frame.columns for column in signals["phase_currents"]):
        measurable |= set(signals["current_states"])
    measured = [state for state in state_names if state in measurable]
    x_init = np.full((time_s.size, len(state_names)), np.nan)
    if measured:
        x_init[:, [state_names.index(s) for s in measured]] = state_array(frame, signals, measured)
    missing = [state for state in state_names if state not in measurable]
    if missing:
        baseline = _baseline_states(fmu_model, time_s, u, x_init, baseline_path, str(data_path))
        for state in missing:
            x_init[:, state_names.index(state)] = baseline[:, state_names.index(state)]
        LOG.info("%s: states %s are not measured; windows start from the FMU's baseline open loop", name, missing)
    for key in ("angle_state", "speed_state"):
        if signals[key] not in signals["measured_states"]:
            raise ValueError(f"config.signals.{key}: {signals[key]!r} must be a measured state (it is a loss target)")
    angle = x_init[:, state_names.index(signals["angle_state"])].copy()
    speed = x_init[:, state_names.index(signals["speed_state"])].copy()
    if not np.all(np.isfinite(x_init)) or not np.all(np.isfinite(u)):
        raise ValueError(f"{data_path}: non-finite values in the states or inputs")
    record = read_segments(segments_path)
    spans = spans_to_indices(time_s, record["spans_s"], str(segments_path))
    if spans.size == 0:
        raise ValueError(f"{segments_path}: field 'spans_s' selects no samples; training needs at least one segment")
    return ManeuverArrays(name=name, time_s=time_s, u=u, x_init=x_init, angle=angle, speed=speed, spans=spans,
                          state_names=state_names, input_names=input_names, angle_state=signals["angle_state"],
                          speed_state=signals["speed_state"], measured_states=measured)


def _baseline_states(fmu_model, time_s, u, x_measured, baseline_path, source) -> np.ndarray:
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

    x0 = np.where(np.isfinite(x_measured[0]), x_measured[0], np.asarray(fmu_model.initial_states, dtype=float))
    LOG.info("%s: no baseline file; simulating the FMU open loop for the unmeasured states", source)
    return simulate_open_loop(fmu_model, time_s, u, x0).states
