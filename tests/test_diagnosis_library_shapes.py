"""Shapes of state effects fitted to the data: the Coulomb smoothing and Stribeck velocity searched jointly
and refined with standard errors, settings with different numbers of coefficients compared by BIC (a
Stribeck term or a harmonic must earn its coefficients), periodic orders with their harmonic counts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from diagnosis_models import msd_problem
from hybridfmu.diagnosis.derivatives import hann_kernel, smooth_at
from hybridfmu.diagnosis.effects import EffectInputs
from hybridfmu.diagnosis.library import Coulomb, Periodic, ScaledCoulomb, log_grid_bounds
from hybridfmu.diagnosis.selection import (DesignCache, ManeuverFitData, SelectionSettings, Term, best_setting,
                                           count_parameters, fit_terms, select_equation)

KERNEL = hann_kernel(9)


def synthetic_cache(x: np.ndarray, term: np.ndarray, noise: float, seed: int = 0,
                    u: np.ndarray | None = None) -> DesignCache:
    """A design cache over one synthetic maneuver whose velocity equation (index 1) misses ``term`` (M,):
    states ``x`` (M, 2) (also the low-noise states), the kernel-averaged term plus white noise of std ``noise``."""
    m = len(x)
    u = np.zeros((m, 1)) if u is None else u
    inputs = EffectInputs(x, u, x_smooth=x, f=np.zeros_like(x), dfdx=np.zeros((m, 2, 2)), dfdu=np.zeros((m, 2, 1)))
    centres = np.arange(len(KERNEL) // 2, m - len(KERNEL) // 2, len(KERNEL))
    rng = np.random.default_rng(seed)
    target = np.zeros((len(centres), 2))
    target[:, 1] = smooth_at(term, KERNEL, centres) + noise * rng.standard_normal(len(centres))
    data = ManeuverFitData(name="synthetic", inputs=inputs, kernel=KERNEL, centres=centres,
                           span_id=np.arange(len(centres)) // 50, target=target, noise_std=np.array([0.0, noise]))
    return DesignCache([data])


def velocity_states(m: int = 30000, seed: int = 0) -> np.ndarray:
    """(m, 2) position and a velocity sweeping through zero at many rates (spread about 1)."""
    t = np.linspace(0.0, 60.0, m)
    rng = np.random.default_rng(seed)
    v = sum(a * np.sin(2 * math.pi * f * t + rng.uniform(0, 6)) for a, f in [(1.0, 0.11), (0.6, 0.37), (0.3, 1.3)])
    return np.stack([np.cumsum(v) * (t[1] - t[0]), v], axis=1)


def _problem(**effects):
    problem, _ = msd_problem(periodic={"x": 1.0}, effects=effects)
    problem.spread = np.array([1.0, 1.0])
    return problem


# ----------------------------------------------------------------------------- Coulomb and Stribeck

def test_coulomb_smoothing_and_stribeck_velocity_are_fitted_with_standard_errors():
    x = velocity_states()
    eps, v_s = 0.02, 0.15
    v = x[:, 1]
    truth = -(0.3 + 0.25 * np.exp(-(v / v_s) ** 2)) * np.tanh(v / eps)
    cache = synthetic_cache(x, truth, noise=0.002)
    effect = Coulomb(_problem(), 1, 1, {"coulomb_smoothing_relative": [0.001, 0.003, 0.01, 0.03, 0.1],
                                        "stribeck_relative": [0.005, 0.01, 0.02, 0.05, 0.1, 0.2]})
    assert effect.continuous_parameters() == ["smoothing", "stribeck_velocity"]
    assert len(effect.grid()) == 5 * 7
    term, _, profile = best_setting(cache, [], effect, 1, ["synthetic"], 40)
    assert len(profile) == 35 and all("bic" in row for row in profile)
    assert term.setting["smoothing"] == pytest.approx(eps, rel=0.05)  # off the grid: refined
    assert term.setting["stribeck_velocity"] == pytest.approx(v_s, rel=0.05)
    for key, value in (("smoothing", eps), ("stribeck_velocity", v_s)):
        se = term.setting_se[key]
        assert 0 < se < 0.1 * value
        assert abs(term.setting[key] - value) < 5 * se
    fit = fit_terms(cache, [Term(effect, term.setting)], 1, ["synthetic"])
    params = {p["name"]: p for p in effect.physical(fit.coefs[0], fit.cov, term.setting, term.setting_se)}
    assert params["coulomb_level"]["value"] == pytest.approx(0.3, rel=0.02)
    assert params["breakaway_level"]["value"] == pytest.approx(0.55, rel=0.02)
    assert params["smoothing"]["se"] == term.setting_se["smoothing"]
    assert params["stribeck_velocity"]["se"] == term.setting_se["stribeck_velocity"]
    assert count_parameters(term, len(effect.grid())) == 2 + 2


def test_a_stribeck_term_must_earn_its_coefficient_by_bic():
    """Pure Coulomb friction with noise: a Stribeck column lowers the RSS a little on noise alone, but the
    setting without it wins by BIC and no Stribeck velocity is reported."""
    x = velocity_states(seed=1)
    truth = -0.3 * np.tanh(x[:, 1] / 0.02)
    cache = synthetic_cache(x, truth, noise=0.01, seed=1)
    effect = Coulomb(_problem(), 1, 1, {"coulomb_smoothing_relative": [0.01, 0.03],
                                        "stribeck_relative": [0.005, 0.01, 0.02, 0.05, 0.1, 0.2]})
    term, rss, profile = best_setting(cache, [], effect, 1, ["synthetic"], 40)
    assert term.setting["stribeck_velocity"] == 0.0
    assert min(r["rss"] for r in profile if r["setting"]["stribeck_velocity"] > 0) < \
        min(r["rss"] for r in profile if r["setting"]["stribeck_velocity"] == 0)  # RSS alone would take one
    assert effect.coefficient_names(term.setting) == ["coulomb_level"]
    assert count_parameters(term, len(effect.grid())) == 1 + 1
    assert term.setting["smoothing"] == pytest.approx(0.02, rel=0.1)


def test_a_single_smoothing_value_fixes_it():
    effect = Coulomb(_problem(), 1, 1, {"coulomb_smoothing_relative": 0.004, "stribeck_relative": [0.05, 0.1]})
    assert {g["smoothing"] for g in effect.grid()} == {0.004}
    assert effect.refine_bounds("smoothing") is None and effect.refine_bounds("stribeck_velocity") is not None
    row = {p["name"]: p for p in effect.physical(np.array([0.1]), np.zeros((1, 1)),
                                                  {"smoothing": 0.004, "stribeck_velocity": 0.0}, {})}
    assert row["smoothing"]["value"] == 0.004 and "fixed" in row["smoothing"]["description"]
    x = velocity_states(m=6000, seed=2)
    cache = synthetic_cache(x, -0.3 * np.tanh(x[:, 1] / 0.02), noise=0.005, seed=2)
    term, _, _ = best_setting(cache, [], effect, 1, ["synthetic"], 20)
    assert term.setting["smoothing"] == 0.004 and "smoothing" not in term.setting_se


def test_scaled_coulomb_searches_the_smoothing_grid():
    x = velocity_states(seed=3)
    load = (1.0 + 0.5 * np.sin(np.linspace(0, 40, len(x))))[:, None]
    truth = -0.2 * load[:, 0] * np.tanh(x[:, 1] / 0.05)
    cache = synthetic_cache(x, truth, noise=0.002, seed=3, u=load)
    effect = ScaledCoulomb(_problem(), 1, 1, 0, {"coulomb_smoothing_relative": [0.003, 0.01, 0.03, 0.1]})
    assert len(effect.grid()) == 2 * 4
    term, _, _ = best_setting(cache, [], effect, 1, ["synthetic"], 40)
    assert term.setting["asymmetric"] == 0.0
    assert term.setting["smoothing"] == pytest.approx(0.05, rel=0.05)
    assert term.setting_se["smoothing"] > 0


def test_log_grid_bounds_extend_one_grid_ratio_beyond_the_ends():
    assert log_grid_bounds([0.01, 0.1, 1.0]) == pytest.approx((0.001, 10.0))
    assert log_grid_bounds([0.5]) is None


# ----------------------------------------------------------------------------- periodic orders and harmonics

def _angle_states(m: int = 40000) -> np.ndarray:
    t = np.linspace(0.0, 40.0, m)
    speed = 2.0 + np.sin(0.3 * t)  # revolutions of period 1 at a varying rate
    angle = np.cumsum(speed) * (t[1] - t[0])
    return np.stack([angle, speed], axis=1)


def _periodic(max_order: int, harmonics: int) -> Periodic:
    return Periodic(_problem(), 1, 0, 1.0, {"periodic_max_order": max_order, "periodic_harmonics": harmonics})


def _report(effect, cache):
    selection = select_equation(cache, 1, [effect], ["synthetic"], SelectionSettings(bootstrap_samples=0))
    term = selection.terms[0]
    return term, {p["name"]: p["value"] for p in effect.physical(term.coef, selection.fit.cov, term.setting, {})}


def test_a_term_of_order_12_alone_is_order_12_with_one_harmonic():
    """Order 6 with two harmonics (6 and 12) fits it as well, with two useless coefficients: BIC says 12."""
    x = _angle_states()
    cache = synthetic_cache(x, 0.5 * np.sin(2 * math.pi * 12 * x[:, 0] + 0.4), noise=0.01)
    effect = _periodic(48, 2)
    assert {"order": 6.0, "harmonics": 2.0} in effect.grid() and {"order": 12.0, "harmonics": 1.0} in effect.grid()
    term, report = _report(effect, cache)
    assert term.setting == {"order": 12.0, "harmonics": 1.0}
    assert report["order"] == 12 and report["harmonics"] == 1
    assert report["amplitude_12"] == pytest.approx(0.5, rel=0.01)
    assert "amplitude_24" not in report


def test_a_pair_of_orders_24_and_48_is_order_24_with_two_harmonics():
    x = _angle_states()
    term_values = 0.4 * np.sin(2 * math.pi * 24 * x[:, 0]) + 0.25 * np.cos(2 * math.pi * 48 * x[:, 0] + 1.0)
    cache = synthetic_cache(x, term_values, noise=0.01)
    term, report = _report(_periodic(48, 2), cache)
    assert term.setting == {"order": 24.0, "harmonics": 2.0}
    assert report["amplitude_24"] == pytest.approx(0.4, rel=0.02)
    assert report["amplitude_48"] == pytest.approx(0.25, rel=0.02)


def test_a_stribeck_peak_is_never_negative_a_damping_is_not_mistaken_for_one():
    """Coulomb friction plus a damping (friction rising with speed): a negative Stribeck peak would fit the rise
    near zero speed, but the peak adds to the level by definition, so the chosen setting's peak is not negative."""
    x = velocity_states()
    v = x[:, 1]
    truth = -0.3 * np.tanh(v / 0.02) - 0.4 * v * (np.abs(v) < 0.3) - 0.12 * np.sign(v) * (np.abs(v) >= 0.3)
    cache = synthetic_cache(x, truth, noise=0.002)
    effect = Coulomb(_problem(), 1, 1, {"coulomb_smoothing_relative": [0.003, 0.01, 0.03, 0.1],
                                         "stribeck_relative": [0.05, 0.1, 0.2, 0.5]})
    term, _, profile = best_setting(cache, [], effect, 1, ["synthetic"], 40)
    fit = fit_terms(cache, [term], 1, ["synthetic"])
    assert effect.admissible(fit.coefs[0], term.setting)
    assert any(not p["admissible"] for p in profile)  # the grid does hold negative peaks, which were passed over


# ----------------------------------------------------------------------------- periodic orders found in the data

def _searched_periodic(harmonics: int = 3) -> Periodic:
    return Periodic(_problem(), 1, 0, 1.0, {"periodic_max_order": None, "periodic_harmonics": harmonics})


def test_an_unsearched_periodic_effect_has_no_grid():
    with pytest.raises(RuntimeError, match="periodic_max_order null"):
        _searched_periodic().grid()


def test_the_orders_found_in_the_data_are_the_term_and_its_harmonic_beside_a_load_trend():
    """Order 12 with its harmonic 24, on top of a load that rises with the position (a smooth low-order trend):
    the search gives the selection 12 and 24 among its orders, and the selection fits order 12 with 2 harmonics."""
    from hybridfmu.diagnosis.periodic_orders import narrow_periodic_orders

    x = _angle_states()
    term_values = (0.5 * np.sin(2 * math.pi * 12 * x[:, 0] + 0.4) + 0.2 * np.cos(2 * math.pi * 24 * x[:, 0])
                   + 0.8 * x[:, 0] / x[-1, 0])
    cache = synthetic_cache(x, term_values, noise=0.01)
    effect = _searched_periodic()
    kept, searches, skipped = narrow_periodic_orders([effect], cache, ["synthetic"], 3, effect.problem)
    assert kept == [effect] and not skipped
    assert {12, 24} <= set(effect.orders) and len(effect.orders) == 3
    record = searches["periodic(x) in dv/dt"]
    assert record["orders"] == effect.orders and record["max_order_resolved"] > 24
    assert record["explained_share"]["12"] > record["explained_share"]["24"] > 0.01
    term, report = _report(effect, cache)
    assert term.setting == {"order": 12.0, "harmonics": 2.0}
    assert report["amplitude_12"] == pytest.approx(0.5, rel=0.05)


def test_the_resolvable_order_is_where_the_selections_own_designs_lose_the_term():
    """The scan's kernel averages equal the selection's designs of each order (DesignCache): the highest order
    resolved is the last before the designs keep less than MIN_RELATIVE_ENERGY_RETAINED of the term's energy."""
    from hybridfmu.diagnosis.periodic_orders import (MIN_RELATIVE_ENERGY_RETAINED, ORDER_LIMIT, averaged_phasors,
                                                     resolvable_max_order)

    cache = synthetic_cache(_angle_states(), np.zeros(40000), noise=0.01)
    data = cache.maneuvers["synthetic"]
    phasors = averaged_phasors([data], 0, 1.0, ORDER_LIMIT)
    found = resolvable_max_order(phasors, data.kernel)
    assert 24 < found < ORDER_LIMIT
    retained = []
    for k in range(1, found + 2):
        design = cache.design(_periodic(1, 1), {"order": float(k), "harmonics": 1.0}, ["synthetic"])
        np.testing.assert_allclose(design, np.stack([phasors[:, k - 1].imag, phasors[:, k - 1].real], axis=1),
                                   atol=1e-9)
        retained.append(float(np.mean(np.sum(design ** 2, axis=1))))
    assert min(retained[:found]) >= MIN_RELATIVE_ENERGY_RETAINED > retained[found]


def test_a_period_the_kernel_cannot_resolve_leaves_the_effect_out_with_the_reason():
    from hybridfmu.diagnosis.periodic_orders import narrow_periodic_orders

    x = _angle_states()
    x[:, 0] *= 200.0  # hundreds of periods per kernel window
    cache = synthetic_cache(x, np.zeros(len(x)), noise=0.01)
    effect = _searched_periodic()
    kept, searches, skipped = narrow_periodic_orders([effect], cache, ["synthetic"], 3, effect.problem)
    assert kept == [] and searches["periodic(x) in dv/dt"]["max_order_resolved"] == 0
    assert "keeps less than 10% of even order 1" in skipped["periodic(x) in dv/dt"]


def test_the_strongest_peaks_are_local_maxima_highest_first():
    from hybridfmu.diagnosis.periodic_orders import strongest_peaks

    spectrum = np.array([0.5, 0.3, 0.2, 0.1, 0.4, 0.05, 0.35, 0.0])
    assert strongest_peaks(spectrum, 2) == (1, 5)
    assert strongest_peaks(spectrum, 5) == (1, 5, 7)
    assert strongest_peaks(np.linspace(0.5, 0.1, 9), 3) == (1,)  # a smooth trend takes one place
    assert strongest_peaks(np.zeros(4), 3) == ()
