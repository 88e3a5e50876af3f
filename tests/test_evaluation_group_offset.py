"""The time-offset stage's estimate per group of inputs (many short windows after the inputs change)."""

import numpy as np
import pytest

from hybridfmu.evaluation.group_offset import change_windows, estimate_group_delays
from hybridfmu.evaluation.offset import shift_inputs

H = 1e-3
RATE = 40.0          # 1/s, decay of the state
GAINS = (30.0, 20.0, 0.0)  # the third input does not act on the state at all


def piecewise_inputs(n: int, seed: int) -> np.ndarray:
    """(n, 3) inputs held between random switching instants."""
    rng = np.random.default_rng(seed)
    u = np.zeros((n, 3))
    for j in range(3):
        switches = np.sort(rng.choice(np.arange(20, n - 20), size=60, replace=False))
        levels = rng.uniform(-1, 1, size=switches.size + 1)
        u[:, j] = levels[np.searchsorted(switches, np.arange(n), side="right")]
    return u


def simulate(x0: float, u: np.ndarray, speed: float = 1.0) -> np.ndarray:
    """Explicit Euler of x' = speed * (-RATE x + sum_j GAINS_j u_j) on the grid: (n,) from x0 with inputs (n, 3)
    (``speed`` != 1: a model that responds too fast or too slow, as with a wrong time constant)."""
    x = np.empty(u.shape[0])
    x[0] = x0
    for k in range(u.shape[0] - 1):
        x[k + 1] = x[k] + H * speed * (-RATE * x[k] + u[k] @ np.array(GAINS))
    return x


def measured(true_delays_s: np.ndarray, n: int = 3000, noise: float = 0.0, seed: int = 3):
    u = piecewise_inputs(n, seed)
    x = simulate(0.0, shift_inputs(u, true_delays_s, H))
    x = x + noise * np.random.default_rng(seed + 1).standard_normal(n)
    return u, x


def estimator(u, x, window_samples=5, margin=8, model_gain=1.0):
    """The windows' (simulated, measured) changes; ``model_gain`` scales the model's input gains (a model
    that responds too fast or too slow)."""
    spread = x.std()

    def simulate_window(start, delays_s):
        shifted = shift_inputs(u[start - margin:start + window_samples + 1 + margin], delays_s, H)
        sim = simulate(x[start], shifted[margin:margin + window_samples + 1], model_gain)
        return (((sim[1:] - x[start]) / spread)[:, None],
                ((x[start + 1:start + window_samples + 1] - x[start]) / spread)[:, None])

    return simulate_window


GROUPS = {"first": [0], "second": [1], "idle": [2]}
CANDIDATES = np.arange(-5, 6) * (H / 2)  # -2.5 .. 2.5 ms in half samples


def test_each_group_gets_its_own_offset():
    true = np.array([1.3e-3, -0.4e-3, 0.0])
    u, x = measured(true, noise=1e-4)
    estimate = estimate_group_delays(estimator(u, x), u, GROUPS, 5, 30, CANDIDATES, margin=8, lead_samples=3)
    assert estimate.delays_s["first"] == pytest.approx(1.3e-3, abs=0.05e-3)
    assert estimate.delays_s["second"] == pytest.approx(-0.4e-3, abs=0.05e-3)
    assert estimate.identified["first"] and estimate.identified["second"]
    assert estimate.windows["first"] == 30
    assert estimate.cost_with_delay["first"] < 0.1 * estimate.cost_without_delay["first"]
    # an input that does not act on the states has no offset to find: not identified, estimated 0
    assert not estimate.identified["idle"] and estimate.delays_s["idle"] == 0.0
    assert estimate.improvement["first"] > 0.9
    # a delay that lowers the cost by less than min_improvement does not count either
    strict = estimate_group_delays(estimator(u, x), u, GROUPS, 5, 30, CANDIDATES, margin=8, lead_samples=3,
                                   min_improvement=1.0)
    assert not strict.identified["first"] and strict.delays_s["first"] == 0.0


def test_a_model_that_responds_too_fast_does_not_shift_the_estimate():
    true = np.array([0.6e-3, 0.0, 0.0])
    u, x = measured(true, noise=1e-4)
    estimate = estimate_group_delays(estimator(u, x, model_gain=1.15), u, GROUPS, 5, 30, CANDIDATES, margin=8,
                                     lead_samples=3)
    assert estimate.delays_s["first"] == pytest.approx(0.6e-3, abs=0.05e-3)
    assert estimate.gains["first"][0] == pytest.approx(1 / 1.15, rel=0.02)
    # the same fit without the gain (the plain error of the changes) is pulled away from the truth
    from hybridfmu.evaluation import group_offset

    plain = lambda simulated, measured: (float(np.mean((simulated - measured) ** 2)), np.ones(1))  # noqa: E731
    original, group_offset.gain_fit_cost = group_offset.gain_fit_cost, plain
    try:
        biased = estimate_group_delays(estimator(u, x, model_gain=1.15), u, GROUPS, 5, 30, CANDIDATES, margin=8,
                                       lead_samples=3)
    finally:
        group_offset.gain_fit_cost = original
    assert abs(biased.delays_s["first"] - 0.6e-3) > 0.1e-3


def test_an_offset_beyond_the_range_is_not_reported_as_found():
    true = np.array([4.0e-3, 0.0, 0.0])  # outside the searched +-2.5 ms
    u, x = measured(true)
    estimate = estimate_group_delays(estimator(u, x), u, GROUPS, 5, 30, CANDIDATES, margin=8, lead_samples=3)
    assert not estimate.identified["first"] and estimate.delays_s["first"] == 0.0
    assert estimate.delays_s["second"] == pytest.approx(0.0, abs=0.1e-3)


def test_windows_start_where_the_group_changes_and_do_not_overlap():
    u = np.zeros((200, 2))
    u[50:, 0] = 1.0
    u[120:, 0] = 3.0
    u[80:, 1] = -1.0
    starts = change_windows(u, [0], 4, 10, margin=5)
    # the step into sample 120 (the larger one) first, each window opening two samples before its step
    assert starts == [118, 48]
    assert change_windows(u, [0], 4, 10, margin=5, lead_samples=0) == [120, 50]
    assert change_windows(np.zeros((50, 1)), [0], 4, 10, margin=5) == []


def test_the_bootstrap_standard_error_follows_the_noise():
    """The estimate's standard error grows with the measurement noise, and the truth lies within a few of it;
    the bootstrap draws only from the seed (same seed, same error)."""
    true = np.array([1.3e-3, -0.4e-3, 0.0])
    errors = {}
    for noise in (2e-3, 2e-2):
        u, x = measured(true, noise=noise)
        estimate = estimate_group_delays(estimator(u, x), u, GROUPS, 5, 30, CANDIDATES, margin=8, lead_samples=3,
                                         bootstrap_samples=100, seed=5)
        error_s = estimate.standard_errors_s["first"]
        assert error_s > 0
        assert abs(estimate.delays_s["first"] - 1.3e-3) < 4 * error_s + 1e-6
        assert estimate.bootstrap_on_edge["first"] < 0.05
        assert "idle" not in estimate.standard_errors_s  # not identified: no error to report
        errors[noise] = error_s
    assert errors[2e-2] > 3 * errors[2e-3]
    again = estimate_group_delays(estimator(u, x), u, GROUPS, 5, 30, CANDIDATES, margin=8, lead_samples=3,
                                  bootstrap_samples=100, seed=5)
    assert again.standard_errors_s["first"] == errors[2e-2]
    none = estimate_group_delays(estimator(u, x), u, GROUPS, 5, 30, CANDIDATES, margin=8, lead_samples=3,
                                 bootstrap_samples=0)
    assert none.standard_errors_s == {}


def test_the_window_sums_give_the_gain_fit_cost_and_the_parabola_its_minimum():
    from hybridfmu.evaluation.group_offset import (gain_fit_cost, parabola_minimum, residual_energy,
                                                   window_statistics)

    rng = np.random.default_rng(0)
    simulated, data = rng.normal(size=(6, 2)), rng.normal(size=(6, 2))
    simulated[:, 1] = 0.0  # a state the model never moves keeps the gain 1
    assert residual_energy(window_statistics(simulated, data)) / simulated.size == pytest.approx(
        gain_fit_cost(simulated, data)[0], rel=1e-12)
    grid = np.linspace(-1.0, 1.0, 11)
    minima, on_edge = parabola_minimum(np.stack([(grid - 0.13) ** 2, (grid + 3.0) ** 2]), grid)
    assert minima[0] == pytest.approx(0.13, abs=1e-12) and not on_edge[0]
    assert minima[1] == -1.0 and on_edge[1]
