"""Plausibility checks of ingested logs: isolated outliers, configured ranges, kinematic consistency.

A log can pass every format check and still be wrong: a channel declared in one unit but logged in
another (the file carries no unit), or a single corrupt sample. Three checks catch such logs at ingest:

- **isolated outliers** (:func:`check_outliers`): a sample that departs from *both* neighbours, in the
  same direction, by more than ``factor`` times the signal's own spread (the range between its
  ``quantile`` and ``1 - quantile`` quantiles). Steps (PWM duties, quantised levels) depart from one
  neighbour only and pass.
- **plausible ranges** (:func:`check_range`): ``config.signals.<name>.range: [min, max]``, in the unit
  of ``config.signals.<name>.unit`` (after ``gain``, ``offset`` and unwrapping).
- **kinematic pairs** (:func:`kinematic_pairs`, :func:`check_kinematic_pairs`): where the FMU says
  that one measured state is the time derivative of another (``der(x) = k * y`` with a constant
  ``k``: the ModelStructure lists ``y`` as the only dependency of ``der(x)`` and the FMU's Jacobian
  confirms a constant ``d der(x) / d y`` and no other dependency), the logged position's change over
  windows of the record must equal ``k`` times the integral of the logged rate. A ratio off by a
  common unit factor (57.3 = deg/rad, 9.55 = rpm per rad/s, ...) is named in the error.

Everything is derived from the FMU and the case config; nothing here knows a particular machine.
"""

from __future__ import annotations

import functools
import logging
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hybridfmu.data.errors import DataError

LOG = logging.getLogger(__name__)

#: Common unit factors a wrong declared unit produces, for the hint of the kinematic check.
UNIT_FACTORS: tuple[tuple[float, str], ...] = (
    (180.0 / math.pi, "57.3 = deg per rad (an angle or rate in rad declared deg, or the reverse)"),
    (60.0 / (2.0 * math.pi), "9.55 = rpm per rad/s (a speed in rad/s declared rpm, or the reverse)"),
    (2.0 * math.pi, "6.28 = 2 pi: rev vs rad, or Hz vs rad/s"),
    (60.0, "60 = per minute vs per second"),
    (6.0, "6 = deg/s per rpm"),
    (360.0, "360 = deg per rev"),
    (1000.0, "1000 = a milli prefix (e.g. mm vs m, ms vs s)"),
    (100.0, "100 = percent or a centi prefix (e.g. cm vs m)"),
    (10.0, "10 = a deci prefix (e.g. mm vs cm)"),
    (3.6, "3.6 = km/h per m/s"),
)
#: Relative tolerance for matching a measured ratio to one of UNIT_FACTORS.
HINT_TOLERANCE = 0.05
#: Relative tolerance of the FMU's Jacobian entries of a kinematic pair (constant k, no other dependency).
JACOBIAN_RTOL = 1e-6


@dataclass(frozen=True)
class KinematicPair:
    """``der(position) = gain * rate`` in the FMU's model units, both states measured.

    Attributes:
        position, rate: FMU state names.
        gain: the constant ``d der(position) / d rate`` (1 for a plain kinematic pair).
    """

    position: str
    rate: str
    gain: float


# ---------------------------------------------------------------------------------- outliers, ranges

def check_outliers(path: Path, channel: str, signal: str, unit: str, time_s: np.ndarray, values: np.ndarray,
                   factor: float | None, quantile: float) -> None:
    """Reject a sample that departs from both neighbours (same direction) by over ``factor`` x the spread.

    Args:
        path, channel, signal, unit: for the message (the file, its channel, the case's signal and its
            declared unit ``config.signals.<signal>.unit``).
        time_s, values: (n,) finite samples of the channel (file time, s; raw unit).
        factor: ``config.ingest.outliers.factor``; None disables the check.
        quantile: ``config.ingest.outliers.quantile``; the spread is ``q(1 - quantile) - q(quantile)``.

    Raises:
        DataError: naming file, channel, signal, the time and value of the sample and the threshold.
    """
    if factor is None or len(values) < 3:
        return
    spread = float(np.quantile(values, 1.0 - quantile) - np.quantile(values, quantile))
    jump = _isolated_departure(values)
    index = int(np.argmax(jump))
    if jump[index] > factor * spread:
        neighbours = [f"{values[i]:.6g}" for i in (index - 1, index + 1) if 0 <= i < len(values)]
        raise DataError(
            f"{path}: channel {channel} ({signal}): isolated implausible sample {values[index]:.6g} {unit} at "
            f"t = {time_s[index]:.9g} s (sample {index}; neighbours {', '.join(neighbours)} {unit}): it departs "
            f"from both neighbours by {jump[index]:.4g} {unit}, over config.ingest.outliers.factor = {factor:g} "
            f"x the signal's spread {spread:.4g} {unit} (quantiles {quantile:g}..{1 - quantile:g}); expected "
            "a continuous signal (fix or drop the sample, or raise config.ingest.outliers.factor)")


def _isolated_departure(values: np.ndarray) -> np.ndarray:
    """Per sample (n,): min distance to both neighbours where it lies above or below both, else 0.

    The first and last sample have one neighbour; their distance to it counts.
    """
    jump = np.zeros(len(values))
    up = values[1:-1] - values[:-2]
    down = values[1:-1] - values[2:]
    jump[1:-1] = np.where(up * down > 0, np.minimum(np.abs(up), np.abs(down)), 0.0)
    jump[0] = abs(values[0] - values[1])
    jump[-1] = abs(values[-1] - values[-2])
    return jump


def check_range(path: Path, channel: str, signal: str, unit: str, time_s: np.ndarray, values: np.ndarray,
                bounds: list[float] | None) -> None:
    """Reject a sample outside ``config.signals.<signal>.range`` (``[min, max]``, unit ``unit``).

    Raises:
        DataError: naming file, channel, signal, the first offending sample's time and value and the range.
    """
    if not bounds:
        return
    low, high = float(bounds[0]), float(bounds[1])
    outside = (values < low) | (values > high)
    if outside.any():
        index = int(np.flatnonzero(outside)[0])
        raise DataError(
            f"{path}: channel {channel} ({signal}): sample {values[index]:.6g} {unit} at t = {time_s[index]:.9g} s "
            f"(sample {index}; {int(outside.sum())} sample(s) outside) is outside config.signals.{signal}.range "
            f"= [{low:g}, {high:g}] {unit}; expected values in that range")


# ---------------------------------------------------------------------------------- kinematic pairs

def kinematic_pairs(config: dict[str, Any], measured: list[str]) -> list[KinematicPair]:
    """The kinematic pairs among the measured states ``measured`` of the case's FMU (module docstring).

    Candidates come from the ModelStructure (``der(x)`` depends on exactly one other measured state;
    without declared dependencies every measured state is a candidate); the FMU's Jacobian at a few
    points confirms them. The FMU is loaded only when there is a candidate: ``config.fmu.path`` for
    ``source: path``, else built from its C sources into a temporary folder.

    Raises:
        DataError: the FMU cannot be read, built or evaluated (naming it).
    """
    fmu = config["fmu"]
    parameters = tuple(sorted((str(name), float(value)) for name, value in (fmu.get("parameters") or {}).items()))
    key = (fmu["source"], fmu.get("model_name") or "", fmu.get("path") or "", tuple(measured), parameters)
    if fmu["source"] != "build":
        path = Path(fmu["path"])
        key += (path.stat().st_mtime_ns if path.is_file() else 0,)
    return list(_cached_pairs(key))


@functools.lru_cache(maxsize=16)
def _cached_pairs(key: tuple) -> tuple[KinematicPair, ...]:
    source, model_name, fmu_path, measured, parameters = key[:5]
    from fmpy import read_model_description

    from hybridfmu.data.roles import model_description_path

    config = {"fmu": {"source": source, "model_name": model_name, "path": fmu_path}}
    description_path = model_description_path(config)
    try:
        description = read_model_description(str(description_path), validate=False)
    except Exception as err:
        raise DataError(f"{description_path}: cannot read the model description for the kinematic check: "
                        f"{err}; expected an FMI 2.0 FMU") from None
    candidates = []
    for unknown in description.derivatives:
        position = unknown.variable.derivative.name
        if position not in measured:
            continue
        if unknown.dependencies is None:
            rates = [name for name in measured if name != position]
        else:
            names = [variable.name for variable in unknown.dependencies]
            rates = names if len(names) == 1 and names[0] in measured and names[0] != position else []
        candidates += [(position, rate) for rate in rates]
    if not candidates:
        return ()
    if source == "build":
        from hybridfmu.fmu.build import FmuBuildError, build_fmu

        with tempfile.TemporaryDirectory(prefix="hybridfmu-ingest-") as folder:
            try:
                built = build_fmu(model_name, Path(folder) / f"{model_name}.fmu")
            except FmuBuildError as err:
                raise DataError(f"config.fmu.model_name: building {model_name} for the kinematic check of the "
                                f"logs failed: {err}") from None
            return _confirmed(built, candidates, dict(parameters))
    return _confirmed(Path(fmu_path), candidates, dict(parameters))


def _confirmed(fmu_path: Path, candidates: list[tuple[str, str]],
               parameters: dict[str, float]) -> tuple[KinematicPair, ...]:
    """The candidates whose ``d der(x) / d y`` is one nonzero constant and whose other entries are 0.

    The FMU is evaluated with ``config.fmu.parameters`` where the config passes them (a gain may depend on one).
    """
    from hybridfmu.fmu import FmuError, load_fmu

    try:
        model = load_fmu(fmu_path, parameters or None)
    except (FmuError, OSError, ValueError) as err:
        raise DataError(f"{fmu_path}: cannot load the FMU for the kinematic check of the logs: {err}") from None
    with model:
        index = {name: i for i, name in enumerate(model.state_names)}
        x0 = np.asarray(model.initial_states, dtype=np.float64)
        scale = np.maximum(np.abs(x0), model.state_nominals)
        u0 = np.zeros((1, model.n_inputs)) if model.n_inputs else None
        pairs = []
        for position, rate in candidates:
            i, j = index[position], index[rate]
            # the rate at several values of both signs and magnitudes; every other state at its start value
            points = np.repeat(x0[None, :], 4, axis=0)
            points[:, j] = x0[j] + scale[j] * np.array([-2.0, -0.3, 0.7, 3.0])
            inputs = None if u0 is None else np.repeat(u0, len(points), axis=0)
            try:
                dfdx, dfdu = model.jacobians(points, inputs)
                der = model.derivatives(points, inputs)[:, i]
            except (FmuError, ValueError) as err:
                raise DataError(f"{fmu_path}: evaluating der({position}) for the kinematic check failed: "
                                f"{err}") from None
            gains = dfdx[:, i, j]
            gain = float(np.median(gains))
            others = np.delete(dfdx[:, i, :], j, axis=1)
            secant = np.diff(der) / np.diff(points[:, j])  # constant slope over large steps, not only locally
            if (gain != 0.0 and np.allclose(gains, gain, rtol=JACOBIAN_RTOL, atol=0.0)
                    and np.allclose(secant, gain, rtol=1e-6, atol=0.0)
                    and not np.any(others) and not (dfdu.size and np.any(dfdu[:, i, :]))):
                pairs.append(KinematicPair(position, rate, gain))
                LOG.info("%s: der(%s) = %.6g * %s: the logs of both are cross-checked", fmu_path.name, position,
                         gain, rate)
    return tuple(pairs)


def check_kinematic_pairs(path: Path, pairs: list[KinematicPair], roles, channels: dict[str, str],
                          columns: dict[str, np.ndarray], rate_hz: float, settings: dict[str, Any]) -> None:
    """Check each pair on the grid: change of the position over a window = gain x integral of the rate.

    Args:
        path: the raw log (for messages).
        pairs: the FMU's kinematic pairs (:func:`kinematic_pairs`).
        roles: the case's CaseRoles (signals of the states, units).
        channels: logged signal -> raw channel (for messages).
        columns: signal -> (T,) values on the grid, in model units.
        rate_hz: the grid's rate.
        settings: ``config.ingest.kinematic`` (``tolerance``, ``window_samples``, ``min_fraction``,
            ``min_windows``).

    Raises:
        DataError: naming the file, both signals with their channels and declared units, the measured
            ratio, the expected one and, where it matches, a common unit factor.
    """
    window = int(settings["window_samples"])
    for pair in pairs:
        pos_name, rate_name = roles.states[pair.position], roles.states[pair.rate]
        position, rate = columns[pos_name], columns[rate_name]
        ratio, used = measured_ratio(position, rate, 1.0 / rate_hz, window, float(settings["min_fraction"]))
        if used < int(settings["min_windows"]):
            LOG.info("%s: %s/%s: %d window(s) with significant %s; too few to cross-check %s against it",
                     path.name, pos_name, rate_name, used, rate_name, pos_name)
            continue
        relative = ratio / pair.gain
        tolerance = float(settings["tolerance"])
        LOG.info("%s: d(%s)/dt = %.6g x %s over %d windows (expected %.6g)", path.name, pos_name, ratio,
                 rate_name, used, pair.gain)
        if abs(relative - 1.0) <= tolerance:
            continue
        pos, rat = roles.signals[pos_name], roles.signals[rate_name]
        raise DataError(
            f"{path}: channel {_channel(pos, channels)} ({pos_name}, config.signals.{pos_name}.unit "
            f"{pos.natural_unit!r}) and channel {_channel(rat, channels)} ({rate_name}, config.signals."
            f"{rate_name}.unit {rat.natural_unit!r}) disagree: the FMU says der({pair.position}) = "
            f"{pair.gain:g} * {pair.rate} (model units {pos.unit!r}, {rat.unit!r}), but the logged {pos_name} "
            f"changes {relative:.4g} times as fast as the logged {rate_name} says (over {used} windows of "
            f"{window} samples; tolerance config.ingest.kinematic.tolerance = {tolerance:g}); "
            f"{unit_hint(relative)}expected both in their declared units (check config.signals.{pos_name}.unit "
            f"and config.signals.{rate_name}.unit)")


def measured_ratio(position: np.ndarray, rate: np.ndarray, dt_s: float, window: int,
                   min_fraction: float) -> tuple[float, int]:
    """Median of (position change / integral of the rate) over windows where the rate integral is significant.

    Windows of ``window`` samples (non-overlapping); a window counts when |integral of the rate| is at least
    ``min_fraction`` of the 0.99 quantile over windows. Returns (ratio, number of windows used).
    """
    n = (len(position) - 1) // window
    if n < 1:
        return math.nan, 0
    edges = np.arange(n + 1) * window
    cumulative = np.concatenate(([0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * dt_s)))
    integral = np.diff(cumulative[edges])
    change = np.diff(position[edges])
    magnitude = np.abs(integral)
    level = float(np.quantile(magnitude, 0.99))
    if not level > 0.0:
        return math.nan, 0
    used = magnitude >= min_fraction * level
    return float(np.median(change[used] / integral[used])), int(used.sum())


def unit_hint(relative: float) -> str:
    """A sentence naming the common unit factor ``relative`` (or its inverse) matches, or ""."""
    if not (np.isfinite(relative) and relative != 0.0):
        return ""
    size = abs(relative) if abs(relative) >= 1.0 else 1.0 / abs(relative)
    sign = " and of opposite sign" if relative < 0 else ""
    for factor, meaning in UNIT_FACTORS:
        if abs(size / factor - 1.0) <= HINT_TOLERANCE:
            return f"the factor {size:.4g}{sign} matches {meaning}; "
    if relative < 0 and abs(size - 1.0) <= HINT_TOLERANCE:
        return "the signs disagree (one of the channels counts the other way: gain -1); "
    return ""


def _channel(signal, channels: dict[str, str]) -> str:
    return channels.get(signal.name) or "(derived by config.transforms)"
