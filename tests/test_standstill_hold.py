"""The standstill hold: a velocity held at rest by its diagnosed friction, its band chosen on the fitting maneuvers,
and the same rates on every path a simulation or a training takes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hybridfmu.diagnosis.corrected_model import CorrectedModel
from hybridfmu.diagnosis.standstill_hold import BAND_FRACTIONS, RATE_SAMPLES, StandstillHold, choose_hold, held_rate
from hybridfmu.fmu import load_fmu
from test_effect_program import MotorProblem, motor_terms


def test_the_friction_holds_a_push_up_to_its_value_at_the_edge_and_slides_beyond():
    before = np.array([5.0, -5.0, 12.0, -12.0])  # rate with every term
    friction = np.array([1.0, -1.0, 1.0, -1.0])  # the friction's part of it at the state
    edge = np.array([-10.0, 10.0, -10.0, 10.0])  # the friction at the band's edge the push points to
    x_j = np.array([0.2, -0.2, 0.2, -0.2])
    rate, held = held_rate(before, friction, edge, x_j, 100.0)
    assert held.tolist() == [True, True, False, False]
    np.testing.assert_allclose(rate, [-20.0, 20.0, 1.0, -1.0])  # decays to rest / push 11 less the friction 10


def test_the_band_with_the_smallest_gap_is_chosen_and_no_hold_wins_ties_and_failures():
    gaps = {None: 1.0, 0.03: 0.9, 0.1: 0.5, 0.3: 0.7, 1.0: float("nan")}
    hold, records = choose_hold("v", 1.0, 1e-3, lambda h: gaps[None if h is None else round(h.band, 6)])
    assert hold == StandstillHold("v", 0.1, 1.0 / (RATE_SAMPLES * 1e-3))
    assert [r["band"] for r in records] == [None] + [f * 1.0 for f in BAND_FRACTIONS]
    assert choose_hold("v", 1.0, 1e-3, lambda h: 1.0)[0] is None  # no band beats none
    assert choose_hold("v", 1.0, 1e-3, lambda h: 1.0 if h is None else math.nan)[0] is None


@pytest.fixture()
def held_motor(ipbmotor_fmu):
    with load_fmu(ipbmotor_fmu) as helper:
        yield CorrectedModel(motor_terms(), MotorProblem(), helper, hold=StandstillHold("omega", 2.0, 2000.0)), helper


def motor_points(n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(n, 4) motor states, half of them within the band, and (n, 5) inputs."""
    rng = np.random.default_rng(seed)
    x = np.column_stack([rng.normal(0, 5, n), rng.normal(0, 5, n), rng.uniform(5, 55, n), rng.normal(0, 3, n)])
    x[: n // 2, 3] = rng.uniform(-1.9, 1.9, n // 2)
    u = np.column_stack([rng.uniform(0.3, 0.7, (n, 3)), np.full(n, 24.0), rng.normal(0, 0.1, n)])
    return x, u


def test_the_vectorised_terms_give_the_rates_of_the_row_by_row_ones(held_motor):
    corrected, _ = held_motor
    x, u = motor_points(200)
    np.testing.assert_allclose(corrected.additive_batch(x, u), corrected(x, u), rtol=1e-9, atol=1e-9)
    free = CorrectedModel(motor_terms(), MotorProblem(), held_motor[1])
    changed = np.any(corrected(x, u) != free(x, u), axis=1)
    assert changed[: 100].sum() > 50 and not changed[100:][np.abs(x[100:, 3]) >= 2.0].any()


def test_the_coefficient_regressors_follow_the_hold(held_motor):
    """A hybrid trains the terms' coefficients: their regressors must be the rates' derivatives, zero where the
    friction holds the state and the edge friction's where it slides."""
    corrected, _ = held_motor
    x, u = motor_points(120, seed=4)
    regressors = corrected.coefficient_regressors(x, u)
    arrays = [array for _, array in corrected.row_coefficients]
    flat = np.concatenate(arrays)
    step = 1e-6 * (1.0 + np.abs(flat))
    numeric = np.zeros_like(regressors)
    for k in range(flat.size):
        for sign in (1.0, -1.0):
            values = flat.copy()
            values[k] += sign * step[k]
            start = 0
            for array in arrays:
                array[:] = values[start:start + array.size]
                start += array.size
            numeric[:, :, k] += sign * corrected.additive_batch(x, u) / (2 * step[k])
    start = 0
    for array in arrays:
        array[:] = flat[start:start + array.size]
        start += array.size
    # rows where a perturbation does not cross the hold's switch (nearly all) agree
    agree = np.all(np.isclose(numeric, regressors, rtol=1e-5, atol=1e-5), axis=(1, 2))
    assert agree.mean() > 0.95
    within = np.abs(x[:, 3]) < 2.0
    assert np.any(np.all(regressors[within, 3, :] == 0.0, axis=1))  # held rows depend on no coefficient
