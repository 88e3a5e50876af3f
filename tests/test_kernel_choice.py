"""The diagnosis' kernel length chosen from the data when diagnosis.kernel_s is null (hybridfmu.diagnosis.kernel_choice)."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_models import msd_maneuvers, msd_problem
from hybridfmu.diagnosis.corrected_model import simulator_for
from hybridfmu.diagnosis.kernel_choice import MIN_KERNEL_SAMPLES, choose_kernel, kernel_lengths
from hybridfmu.diagnosis.report import kernel_note
from hybridfmu.diagnosis.run import prepare_all

DT_S = 1e-3


def _residual(noise_std: float, seed: int = 0, n: int = 40000) -> np.ndarray:
    """(n, 1) raw equation error: a slow gap (two sines of 0.5 s and 0.13 s period) plus the difference quotient of
    white measurement noise of ``noise_std`` (what a state differentiated from a noisy measurement leaves)."""
    time_s = np.arange(n) * DT_S
    gap = 3.0 * np.sin(2 * np.pi * time_s / 0.5) + 1.0 * np.sin(2 * np.pi * time_s / 0.13)
    noise = np.diff(np.random.default_rng(seed).standard_normal(n + 1) * noise_std) / DT_S
    return (gap + noise)[:, None]


def _choose(noise_std: float, span_samples: float = 40000.0, seed: int = 0):
    residual = _residual(noise_std, seed)
    return choose_kernel([residual], [np.ones(len(residual), dtype=bool)], [0], ["v"], DT_S, span_samples)


def test_noise_free_data_keep_the_shortest_kernel():
    choice = _choose(0.0)
    assert choice.samples == MIN_KERNEL_SAMPLES
    assert choice.kernel_s == pytest.approx(MIN_KERNEL_SAMPLES * DT_S)


def test_noisier_data_get_a_longer_kernel_that_averages_the_noise_below_the_gap():
    chosen = [_choose(noise).samples for noise in (1e-3, 1e-2, 3e-2)]
    assert chosen[0] < chosen[1] < chosen[2]
    # the chosen length is the first at which a doubling no longer lowers the residual RMS by 2 %; before, it did
    choice = _choose(1e-2)
    k = choice.lengths.index(choice.samples)
    falls = 1.0 - choice.rms[1:, 0] / choice.rms[:-1, 0]
    assert k > 0 and falls[k] < 0.02 <= falls[k - 1]
    assert "less than 2%" in choice.reason or "raises" in choice.reason


def test_the_kernel_stops_before_it_averages_the_gap_away():
    # so much noise that the RMS still falls by more than 2 % where the kernel starts to swallow the 0.13 s sine:
    # the fall grows again there, and the kernel stays shorter than that period
    choice = _choose(3e-2)
    assert "average the gap away" in choice.reason
    assert choice.kernel_s < 0.13 and choice.samples < choice.lengths[-1]


def test_the_kernel_stays_within_a_twentieth_of_the_median_segment():
    choice = _choose(1.0, span_samples=800.0)
    assert choice.samples <= 40 and choice.samples == choice.lengths[-1]
    assert "still falls" in choice.reason
    assert kernel_lengths(40) == [9, 17, 33]


def test_the_diagnosis_chooses_the_kernel_when_the_config_leaves_it_out_and_says_so():
    measured = msd_maneuvers(noise=(1e-4, 0.0), duration_s=20.0)
    problem, model = msd_problem(kernel_s=None, state_from_derivative={"v": "x"})
    prepared, fit_names, _ = prepare_all(problem, model, measured, simulator_for(model))
    choice = problem.kernel_choice
    assert choice is not None and choice["samples"] > MIN_KERNEL_SAMPLES
    assert problem.settings["kernel_s"] == pytest.approx(choice["samples"] * problem.dt_s)
    assert all(len(p.error.kernel) == choice["samples"] for p in prepared.values())
    note = kernel_note({"kernel_s": problem.settings["kernel_s"], "kernel_choice": choice})
    assert "chosen from the fitting maneuvers" in note and f"{choice['samples']} samples" in note
    # a configured kernel is used as it is, and nothing is chosen
    problem, model = msd_problem()
    prepared, _, _ = prepare_all(problem, model, msd_maneuvers(noise=(1e-4, 0.0), duration_s=20.0),
                                 simulator_for(model))
    assert problem.kernel_choice is None and all(len(p.error.kernel) == 9 for p in prepared.values())
    assert "config diagnosis.kernel_s" in kernel_note({"kernel_s": 0.09, "kernel_choice": None})
