"""Check an exported FMU with FMPy alone: validation, and its replay of the workflow's own open loop.

:func:`replay` runs the FMU in ``fmpy.simulate_fmu``'s co-simulation loop with the communication step equal to
the model's sample period, driven by the logged inputs of one maneuver from the model's initial state (its
``<state>_start`` parameters), and compares its outputs, shifted back by the FMU's declared ``output_delay_s``,
with the trajectory the evaluation simulated (``evaluation/trajectories/<maneuver>.parquet``). The deviation is
reported per state relative to the state's range over the compared samples; the last ``output_delay_s`` of the
record cannot be compared (the FMU has not yet received the samples after the record's end that the workflow
holds at its last value).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

#: The largest deviation of a replay from the workflow's trajectory, relative to each state's range.
REPLAY_TOLERANCE = 1e-6


@dataclass
class ReplayResult:
    """One replay: ``deviation`` {state: max |FMU - workflow| / range}, ``compared_samples``, ``wall_s`` (the
    replay's wall time), ``ok`` (every deviation within ``tolerance``) and ``problems`` (validation messages)."""

    maneuver: str
    deviation: dict[str, float]
    compared_samples: int
    wall_s: float
    ok: bool
    tolerance: float
    problems: list[str]

    def as_dict(self) -> dict:
        return asdict(self)


def validation_problems(fmu_path: str | Path) -> list[str]:
    """``fmpy.validation.validate_fmu``'s messages for the FMU (empty: valid)."""
    from fmpy.validation import validate_fmu

    return [str(problem) for problem in validate_fmu(str(fmu_path))]


def simulate_exported(fmu_path: str | Path, time_s: np.ndarray, u: np.ndarray, input_names: Sequence[str],
                      x0: np.ndarray, state_names: Sequence[str], label: str = "replay") -> np.ndarray:
    """The exported FMU's outputs (T, n_x) at the samples ``time_s`` (T,), driven by ``u`` (T, n_u), from the start
    values ``x0`` (n_x,), in FMPy's co-simulation loop with the communication step ``time_s[1] - time_s[0]``;
    progress lines (simulated seconds, rate, time left) under ``label``."""
    from fmpy import simulate_fmu

    from hybridfmu.progress import Progress

    time_s = np.asarray(time_s, dtype=float)
    step_s = float(time_s[1] - time_s[0])
    signals = np.zeros(time_s.size, dtype=[("time", float)] + [(name, float) for name in input_names])
    # the samples stamped with FMPy's own communication points (start + n * step): at those instants FMPy hands the
    # FMU each sample as it is, not an interpolation between stamps that differ from them in their last digits
    signals["time"] = np.arange(time_s.size) * step_s
    for column, name in enumerate(input_names):
        signals[name] = u[:, column]
    progress = Progress(float(time_s[-1] - time_s[0]), label, unit="simulated s", interval_s=10.0)
    reached = [0.0]

    def step_finished(time: float, recorder) -> bool:
        progress.update(time - reached[0])
        reached[0] = time
        return True

    result = simulate_fmu(str(fmu_path), start_time=0.0, stop_time=float(time_s[-1] - time_s[0]), step_size=step_s,
                          output_interval=step_s, input=signals, output=list(state_names),
                          start_values={f"{name}_start": float(value) for name, value in zip(state_names, x0)},
                          step_finished=step_finished)
    progress.finish()
    states = np.stack([np.asarray(result[name], dtype=float) for name in state_names], axis=1)
    if states.shape[0] < time_s.size:
        raise RuntimeError(f"{fmu_path}: FMPy returned {states.shape[0]} samples, expected {time_s.size}")
    return states[:time_s.size]


def replay(fmu_path: str | Path, maneuver: str, time_s: np.ndarray, u: np.ndarray, input_names: Sequence[str],
           reference: np.ndarray, state_names: Sequence[str], output_delay_samples: int,
           tolerance: float = REPLAY_TOLERANCE) -> ReplayResult:
    """Replay one maneuver (see the module docstring): ``reference`` (T, n_x) is the workflow's trajectory of the
    model, whose first row is the start state."""
    reference = np.asarray(reference, dtype=float)
    start = time.perf_counter()
    outputs = simulate_exported(fmu_path, time_s, u, input_names, reference[0], state_names, f"replay of {maneuver}")
    wall_s = time.perf_counter() - start
    lag = int(output_delay_samples)
    compared = reference.shape[0] - lag
    if compared < 2:
        raise ValueError(f"{maneuver}: {reference.shape[0]} samples are too few to compare with an output delay of "
                         f"{lag} samples")
    difference = np.abs(outputs[lag:] - reference[:compared])
    spread = np.ptp(reference[:compared], axis=0)
    spread = np.where(spread > 0, spread, 1.0)
    deviation = np.max(difference, axis=0) / spread
    deviation = np.where(np.isfinite(deviation), deviation, np.inf)
    values = {name: float(value) for name, value in zip(state_names, deviation)}
    return ReplayResult(maneuver, values, int(compared), wall_s, bool(np.all(deviation <= tolerance)), tolerance,
                        validation_problems(fmu_path))
