"""The diagnosis' kernel length from the model's own time scale when diagnosis.kernel_s is null
(hybridfmu.diagnosis.kernel_choice)."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_models import msd_maneuvers, msd_problem
from hybridfmu.diagnosis.corrected_model import simulator_for
from hybridfmu.diagnosis.kernel_choice import MIN_KERNEL_SAMPLES, choose_kernel, fastest_time_scales
from hybridfmu.diagnosis.report import kernel_note
from hybridfmu.diagnosis.run import prepare_all

DT_S = 1e-4
M = 5000


def _jacobians(block: np.ndarray, n_x: int = 3, examined=(0, 1)) -> np.ndarray:
    """(M, n_x, n_x) Jacobians equal to ``block`` on the examined states, a slow unexamined state beside them."""
    jac = np.zeros((M, n_x, n_x))
    jac[:, -1, -1] = -1e6  # a fast state that is not examined must not set the scale
    index = np.ix_(list(examined), list(examined))
    jac[:, index[0], index[1]] = block
    return jac


def _choose(jacobian: np.ndarray, span_samples: float = 1e6, examined=(0, 1)):
    return choose_kernel([jacobian], [np.ones(len(jacobian), dtype=bool)], list(examined), DT_S, span_samples)


def test_the_kernel_spans_two_of_the_fastest_decay_times_of_the_examined_equations():
    # modes decaying in 2 ms and 50 ms: the 2 ms one sets the kernel, 4 ms = 40 samples -> 41 (odd)
    choice = _choose(_jacobians(np.array([[-500.0, 0.0], [30.0, -20.0]])))
    assert choice.tau_s == pytest.approx(2e-3)
    assert choice.samples == 41 and choice.kernel_s == pytest.approx(41 * DT_S)
    assert "fastest time scale" in choice.reason


def test_a_lightly_damped_oscillation_counts_by_its_frequency():
    # x'' = -w^2 x - 2 zeta w x' with w = 1000 rad/s, zeta = 0.01: decay time 0.1 s, but |lambda| = w
    w, zeta = 1000.0, 0.01
    choice = _choose(_jacobians(np.array([[0.0, 1.0], [-w ** 2, -2 * zeta * w]])))
    assert choice.tau_s == pytest.approx(1 / w, rel=1e-6)
    assert choice.samples == 21


def test_the_kernel_stays_between_the_shortest_and_a_twentieth_of_the_median_segment():
    fast = _choose(_jacobians(np.diag([-1e5, -1e5])))
    assert fast.samples == MIN_KERNEL_SAMPLES and "raised to the shortest" in fast.reason
    slow = _choose(_jacobians(np.diag([-1.0, -2.0])), span_samples=1000.0)
    assert slow.samples == 49 and "held to 5% of the median segment" in slow.reason
    still = _choose(_jacobians(np.zeros((2, 2))))
    assert still.samples == MIN_KERNEL_SAMPLES and still.tau_s is None and "no dynamics" in still.reason


def test_only_samples_inside_the_segments_count():
    jac = _jacobians(np.diag([-500.0, -500.0]))
    jac[: M // 2, 0, 0] = -50.0  # outside the segments the model is faster
    inside = np.arange(M) >= M // 2
    scales = fastest_time_scales([jac], [inside], [0, 1])
    assert np.allclose(scales, 2e-3)


def test_the_diagnosis_chooses_the_kernel_when_the_config_leaves_it_out_and_says_so():
    measured = msd_maneuvers(noise=(1e-4, 0.0), duration_s=20.0)
    problem, model = msd_problem(kernel_s=None, state_from_derivative={"v": "x"})
    prepared, _, _ = prepare_all(problem, model, measured, simulator_for(model))
    choice = problem.kernel_choice
    assert choice is not None and choice["samples"] >= MIN_KERNEL_SAMPLES and choice["tau_s"] > 0
    assert problem.settings["kernel_s"] == pytest.approx(choice["samples"] * problem.dt_s)
    assert all(len(p.error.kernel) == choice["samples"] for p in prepared.values())
    note = kernel_note({"kernel_s": problem.settings["kernel_s"], "kernel_choice": choice})
    assert "config diagnosis.kernel_s is null" in note and f"{choice['samples']} samples" in note
    # a configured kernel is used as it is, and nothing is chosen
    problem, model = msd_problem()
    prepared, _, _ = prepare_all(problem, model, msd_maneuvers(noise=(1e-4, 0.0), duration_s=20.0),
                                 simulator_for(model))
    assert problem.kernel_choice is None and all(len(p.error.kernel) == 9 for p in prepared.values())
    assert "(config diagnosis.kernel_s)" in kernel_note({"kernel_s": 0.09, "kernel_choice": None})
