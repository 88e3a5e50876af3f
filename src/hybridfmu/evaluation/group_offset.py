"""Each input group's time offset against the measured states, over many short windows.

The figure of the time-offset stage (paper Fig. 6) shows one window of the targets, where the error of
the model itself adds to the shift the offset causes. An input's offset is seen best right after the
input changes: the FMU, started from the measured state, responds within a few samples, before the
model's other errors accumulate. So, for every group of inputs (``model.input_delay.groups``), the
windows of ``window_samples`` steps that start where the group's inputs change most are simulated with
the group's inputs shifted by each candidate delay (the other groups at their current estimates); the
delay whose measured states fit best (each state divided by its spread) is the group's estimate. Two
sweeps over the groups, each with a bounded scalar refinement within one grid step.

The fit compares the change of every measured state from the window's start, the simulated change
scaled by one least-squares gain per state over all windows: a model whose response is a few percent
too fast or too slow (an inductance, an inertia slightly off) would otherwise shift the estimate to
make up for it.

An estimate on the edge of the searched range, or one that lowers the group's cost by less than
``min_improvement`` (a fraction of its cost at delay 0, the other groups at their estimates), is not an
offset the data identify: the fit moves the group's inputs to absorb some other error of the model near
those windows (an input that follows the states, such as a supply voltage that sags with the current,
invites it). Such a group is reported as not identified and estimated 0.

How precisely the windows fix an identified group's delay is measured by a bootstrap over its windows
(``standard_errors_s``): the windows are simulated once more on a fine local grid around the estimate, each
resample of the windows (with replacement) gets its own minimum (parabola through the grid's three best
points), and the standard deviation of those minima is the estimate's standard error. The learned delays
may be held within a few of them (``model.input_delay.within_standard_errors``): the training loss compares
only the target states, where a delay trades off against the model's other errors, while these windows see
every measured state right after the inputs change.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.optimize import minimize_scalar

LOG = logging.getLogger(__name__)

#: Sweeps of the coordinate search over the groups.
SWEEPS = 2
#: Half-width of the bootstrap's local grid, in its own steps (a quarter of the search grid's step each).
LOCAL_GRID_HALF_STEPS = 12


@dataclass
class GroupDelayEstimate:
    """The estimates, in s, and how they were found.

    Attributes:
        delays_s: group -> estimated delay (s).
        windows: group -> number of windows its estimate used.
        identified: group -> False when the search ran to the edge of the range (the estimate is then 0).
        cost_without_delay, cost_with_delay: group -> mean normalised squared error of the measured states'
            changes on its windows after the gains (all delays 0 / all at their estimates).
        gains: group -> the least-squares gain of each measured state's simulated change at the estimate.
        improvement: group -> relative cost reduction of its delay against 0 (the others at their estimates).
        reasons: group -> why it is not identified (only groups that are not).
        standard_errors_s: group -> bootstrap standard error of the estimate (s); only identified groups
            (and only when a bootstrap ran).
        bootstrap_on_edge: group -> share of the bootstrap's minima on the edge of its local grid (a share
            above a few percent means the standard error is understated).
    """

    delays_s: dict[str, float]
    windows: dict[str, int]
    identified: dict[str, bool]
    cost_without_delay: dict[str, float]
    cost_with_delay: dict[str, float]
    gains: dict[str, list[float]]
    improvement: dict[str, float]
    reasons: dict[str, str]
    standard_errors_s: dict[str, float]
    bootstrap_on_edge: dict[str, float]


def change_windows(u: np.ndarray, columns: list[int], window_samples: int, count: int, margin: int,
                   lead_samples: int = 2) -> list[int]:
    """Starts of up to ``count`` non-overlapping windows where the inputs ``columns`` change most.

    A window opens ``lead_samples`` samples before the sample its change leads into, so the state's
    response falls inside it whether the offset moves the change earlier or later.

    Args:
        u: (T, n_u) inputs; columns: the group's input columns.
        window_samples: steps of a window; margin: samples kept free at both ends of the record.
        lead_samples: samples between a window's start and the sample of its change.

    Returns:
        window starts (sample indices), largest change first; windows without any change are left out.
    """
    values = np.asarray(u, dtype=float)[:, columns]
    spread = values.std(axis=0)
    spread = np.where(spread > 0, spread, 1.0)
    change = (np.abs(np.diff(values, axis=0)) / spread).sum(axis=1)  # (T-1,) change from sample c to c+1
    starts: list[int] = []
    taken = np.zeros(values.shape[0], dtype=bool)
    for c in np.argsort(-change, kind="stable"):
        if change[c] <= 0 or len(starts) >= count:
            break
        start = int(c) + 1 - lead_samples
        if start < margin or start + window_samples + margin >= values.shape[0]:
            continue
        if taken[start:start + window_samples + 1].any():
            continue
        taken[start:start + window_samples + 1] = True
        starts.append(start)
    return starts


def gain_fit_cost(simulated: np.ndarray, measured: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean squared error after one least-squares gain per column: (cost, gains (n_s,)).

    Args:
        simulated, measured: (N, n_s) changes of the states from their windows' starts (normalised).
    """
    power = np.sum(simulated * simulated, axis=0)
    gains = np.where(power > 0, np.sum(simulated * measured, axis=0) / np.where(power > 0, power, 1.0), 1.0)
    return float(np.mean((gains * simulated - measured) ** 2)), gains


def window_statistics(simulated: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """The sums of one window that the gain fit needs, per state: (3, n_s) of sum(sim^2), sum(sim meas),
    sum(meas^2) over the window's steps (``simulated``, ``measured``: (W, n_s))."""
    return np.stack([np.sum(simulated * simulated, axis=0), np.sum(simulated * measured, axis=0),
                     np.sum(measured * measured, axis=0)])


def residual_energy(sums: np.ndarray) -> np.ndarray:
    """Squared error left after one least-squares gain per state, summed over the states.

    Args:
        sums: (..., 3, n_s) summed ``window_statistics`` of some windows.

    Returns:
        (...,) sum over states of sum(meas^2) - sum(sim meas)^2 / sum(sim^2) (a state never simulated to move
        keeps the gain 1: sum((sim - meas)^2)).
    """
    power, cross, data = sums[..., 0, :], sums[..., 1, :], sums[..., 2, :]
    fitted = data - cross * cross / np.where(power > 0, power, 1.0)
    unit_gain = power - 2.0 * cross + data
    return np.sum(np.where(power > 0, fitted, unit_gain), axis=-1)


def parabola_minimum(costs: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The minimum of each row of ``costs`` over the uniform grid ``candidates``, refined by the parabola
    through the grid's best point and its two neighbours.

    Args:
        costs: (M, K) costs of M resamples at the K candidates; candidates: (K,) uniform grid (s).

    Returns:
        ((M,) minima in s, (M,) True where the grid's best point is one of its two ends).
    """
    best = np.argmin(costs, axis=1)
    on_edge = (best == 0) | (best == costs.shape[1] - 1)
    inner = np.clip(best, 1, costs.shape[1] - 2)
    rows = np.arange(costs.shape[0])
    left, middle, right = costs[rows, inner - 1], costs[rows, inner], costs[rows, inner + 1]
    curvature = left - 2.0 * middle + right
    step = float(candidates[1] - candidates[0])
    shift = np.where(curvature > 0, 0.5 * (left - right) / np.where(curvature > 0, curvature, 1.0), 0.0)
    shift = np.where(on_edge, 0.0, np.clip(shift, -0.5, 0.5))
    return candidates[best] + shift * step, on_edge


def bootstrap_delays(statistics: np.ndarray, candidates: np.ndarray, samples: int,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The delay's minimum for each bootstrap resample of the windows.

    Args:
        statistics: (n_windows, K, 3, n_s) ``window_statistics`` of every window at every local candidate.
        candidates: (K,) uniform local grid (s).
        samples: number of resamples; rng: their random generator.

    Returns:
        ((samples,) minima in s, (samples,) True where a resample's minimum lies on the grid's edge).
    """
    n_windows = statistics.shape[0]
    counts = np.stack([np.bincount(rng.integers(0, n_windows, n_windows), minlength=n_windows)
                       for _ in range(samples)]).astype(float)  # (samples, n_windows)
    sums = np.tensordot(counts, statistics, axes=(1, 0))  # (samples, K, 3, n_s)
    return parabola_minimum(residual_energy(sums), candidates)


def estimate_group_delays(simulate_window: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]],
                          u: np.ndarray,
                          groups: dict[str, list[int]], window_samples: int, windows: int,
                          candidates_s: np.ndarray, margin: int, lead_samples: int = 2,
                          min_improvement: float = 0.05, bootstrap_samples: int = 200,
                          seed: int = 0) -> GroupDelayEstimate:
    """Coordinate search of one delay per group of inputs.

    Args:
        simulate_window: (start, input delays (n_u,) in s) -> (simulated, measured) changes of the measured
            states from the window's start over its steps 1..window_samples, each (window_samples, n_s) and
            divided by the state's spread; the FMU starts from the measured state at ``start``.
        u: (T, n_u) the maneuver's inputs (to choose the windows).
        groups: group name -> input columns.
        window_samples: steps per window; windows: windows per group; lead_samples: steps of a window
            before its input change (``change_windows``).
        min_improvement: the least relative cost reduction of an identified group's delay.
        candidates_s: (K,) the delays tried (s), sorted.
        margin: samples kept free at the record's ends (for the shifted inputs).
        bootstrap_samples: resamples of the windows for an identified group's standard error (0: none);
            seed: their random generator's seed.

    Returns:
        the estimates; a group whose inputs never change keeps delay 0 (and 0 windows).
    """
    n_u = np.asarray(u).shape[1]
    input_delays = np.zeros(n_u)
    starts = {name: change_windows(u, columns, window_samples, windows, margin, lead_samples)
              for name, columns in groups.items()}

    def fit(name: str, delays: np.ndarray) -> tuple[float, np.ndarray]:
        if not starts[name]:
            return 0.0, np.ones(0)
        pairs = [simulate_window(start, delays) for start in starts[name]]
        return gain_fit_cost(np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs]))

    def cost(name: str, delays: np.ndarray) -> float:
        return fit(name, delays)[0]

    without = {name: cost(name, input_delays) for name in groups}
    step = float(np.min(np.diff(candidates_s))) if len(candidates_s) > 1 else 0.0
    for sweep in range(SWEEPS):
        for name, columns in groups.items():
            if not starts[name]:
                continue

            def group_cost(delay_s: float) -> float:
                trial = input_delays.copy()
                trial[columns] = delay_s
                return cost(name, trial)

            costs = [group_cost(float(d)) for d in candidates_s]
            best = float(candidates_s[int(np.argmin(costs))])
            if step > 0:
                low = max(best - step, float(candidates_s[0]))
                high = min(best + step, float(candidates_s[-1]))
                refined = minimize_scalar(group_cost, bounds=(low, high), method="bounded",
                                          options={"xatol": step * 1e-3})
                if refined.fun < min(costs):
                    best = float(refined.x)
            input_delays[columns] = best
            LOG.info("time offset of input group %r (sweep %d): %.3f µs over %d windows", name, sweep + 1,
                     best * 1e6, len(starts[name]))
    identified = {}
    improvement = {}
    reasons = {}
    for name, columns in groups.items():
        value = float(input_delays[columns[0]])
        at_zero = input_delays.copy()
        at_zero[columns] = 0.0
        before = cost(name, at_zero)
        improvement[name] = (before - cost(name, input_delays)) / before if before > 0 else 0.0
        on_edge = step > 0 and min(value - candidates_s[0], candidates_s[-1] - value) < step
        identified[name] = bool(starts[name]) and not on_edge and improvement[name] >= min_improvement
        if not starts[name]:
            reasons[name] = "its inputs never change"
        elif not identified[name]:
            why = ("the search ran to the edge of the range" if on_edge else
                   f"it lowers the cost by {100 * improvement[name]:.3g} % only (< {100 * min_improvement:.3g} %)")
            reasons[name] = why
            LOG.warning("time offset of input group %r: %.3f µs is not identified (%s); estimated 0",
                        name, value * 1e6, why)
    for name, columns in groups.items():
        if not identified[name]:
            input_delays[columns] = 0.0
    delays = {name: float(input_delays[columns[0]]) for name, columns in groups.items()}
    fits = {name: fit(name, input_delays) for name in groups}
    standard_errors: dict[str, float] = {}
    on_edge_share: dict[str, float] = {}
    rng = np.random.default_rng(seed)
    for name, columns in groups.items():
        if not identified[name] or bootstrap_samples <= 0 or step <= 0:
            continue
        local = delays[name] + np.arange(-LOCAL_GRID_HALF_STEPS, LOCAL_GRID_HALF_STEPS + 1) * (0.25 * step)

        def statistics_at(start: int, delay_s: float) -> np.ndarray:
            trial = input_delays.copy()
            trial[columns] = delay_s
            return window_statistics(*simulate_window(start, trial))

        statistics = np.stack([np.stack([statistics_at(start, float(d)) for d in local]) for start in starts[name]])
        minima, edges = bootstrap_delays(statistics, local, int(bootstrap_samples), rng)
        standard_errors[name] = float(np.std(minima, ddof=1))
        on_edge_share[name] = float(np.mean(edges))
        LOG.info("time offset of input group %r: standard error %.3f µs (%d bootstrap resamples of %d windows)",
                 name, standard_errors[name] * 1e6, int(bootstrap_samples), len(starts[name]))
        if on_edge_share[name] > 0.05:
            LOG.warning("time offset of input group %r: %.0f %% of the bootstrap minima lie on the edge of the "
                        "local grid (±%.3g µs); its standard error is understated", name,
                        100 * on_edge_share[name], 1e6 * LOCAL_GRID_HALF_STEPS * 0.25 * step)
    return GroupDelayEstimate(delays_s=delays, windows={name: len(s) for name, s in starts.items()},
                              identified=identified, cost_without_delay=without,
                              cost_with_delay={name: value[0] for name, value in fits.items()},
                              gains={name: value[1].tolist() for name, value in fits.items()},
                              improvement=improvement, reasons=reasons, standard_errors_s=standard_errors,
                              bootstrap_on_edge=on_edge_share)
