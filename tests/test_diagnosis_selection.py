"""Sparse selection: the true effect is found among all candidates, two effects are both found, and a
residual of pure noise names nothing."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfmu.diagnosis.effects import EFFECTS, effect_options
from hybridfmu.diagnosis.selection import (DesignCache, SelectionSettings, bic, bootstrap_coefficients,
                                           drop_one_scores, select_group)
from test_diagnosis_effects import fit_data, synthetic  # noqa: F401  (fixture)

OPTIONS = effect_options({"effects": {"cogging_orders": [6, 12, 24]}})
NOISE = np.array([800.0, 800.0, 0.0, 40.0])


def run_selection(inputs, layout, truth: np.ndarray, seed: int = 3):
    data = fit_data(inputs, truth, np.random.default_rng(seed), NOISE)
    cache = DesignCache([data], OPTIONS)
    out = {}
    for group in ("mechanical", "electrical"):
        out[group] = select_group(cache, group, layout.groups[group], list(EFFECTS.values()), ["synthetic"], OPTIONS,
                                  layout, SelectionSettings())
    return cache, out


def term(inputs, name, setting, coef):
    return EFFECTS[name].correction(inputs, np.array(coef), setting, OPTIONS)


@pytest.mark.parametrize("name,setting,coef", [
    ("coulomb_friction", {"stribeck_velocity_rad_s": 5.0}, [0.04, 0.02]),
    ("load_dependent_friction", {"asymmetric": 0.0}, [0.08]),
    ("inertia_mismatch", {}, [-0.08]),
    ("inverter_deadtime", {"current_scale_a": 0.5}, [0.01]),
    ("channel_time_offset", {"offset_s": -4e-5}, []),
])
def test_selection_finds_the_true_effect_among_all(synthetic, name, setting, coef):  # noqa: F811
    _, _, layout, inputs = synthetic
    _, out = run_selection(inputs, layout, term(inputs, name, setting, coef))
    group = EFFECTS[name].group
    other = "electrical" if group == "mechanical" else "mechanical"
    assert [t.effect.name for t in out[group].terms] == [name]
    assert out[other].terms == []
    assert out[group].steps[0].chosen == name


def test_two_effects_are_both_found_and_ranked(synthetic):  # noqa: F811
    _, _, layout, inputs = synthetic
    truth = term(inputs, "coulomb_friction", {"stribeck_velocity_rad_s": 3.0}, [0.05, 0.0]) \
        + term(inputs, "cogging", {"order": 24.0, "harmonics": 2.0}, [0.02, 0.008, 0.0, 0.0])
    cache, out = run_selection(inputs, layout, truth)
    names = [t.effect.name for t in out["mechanical"].terms]
    assert set(names) == {"coulomb_friction", "cogging"}
    scores = drop_one_scores(cache, out["mechanical"], ["synthetic"])
    assert scores["coulomb_friction"] > scores["cogging"] > 0
    cogging = next(t for t in out["mechanical"].terms if t.effect.name == "cogging")
    # order 12 with two harmonics contains order 24 as well: the amplitudes name the orders
    params = {p["name"]: p["value"] for p in cogging.effect.physical(
        cogging.coef, np.zeros((len(cogging.coef),) * 2), cogging.setting, {}, layout, OPTIONS, {})}
    assert params["amplitude_24_nm"] == pytest.approx(np.hypot(0.02, 0.008), rel=0.1)
    assert all(v < 0.002 for k, v in params.items() if k.startswith("amplitude_") and k != "amplitude_24_nm")


def test_noise_only_names_nothing(synthetic):  # noqa: F811
    _, _, layout, inputs = synthetic
    _, out = run_selection(inputs, layout, np.zeros_like(inputs.x), seed=11)
    assert out["mechanical"].terms == [] and out["electrical"].terms == []
    assert out["mechanical"].steps[0].chosen is None
    assert "below" in out["mechanical"].steps[0].reason or "noise" in out["mechanical"].steps[0].reason


def test_bootstrap_spread_is_close_to_the_regression_error(synthetic):  # noqa: F811
    _, _, layout, inputs = synthetic
    cache, out = run_selection(inputs, layout, term(inputs, "viscous_friction", {}, [1e-4]))
    selection = out["mechanical"]
    draws = bootstrap_coefficients(cache, selection.terms, selection.rows, ["synthetic"], 100, seed=0)
    se_boot = float(np.std(draws[0][:, 0], ddof=1))
    se_reg = float(np.sqrt(selection.fit.cov[0, 0]))
    assert 0.3 < se_boot / se_reg < 3.0
    assert selection.terms[0].coef[0] == pytest.approx(1e-4, rel=0.1)


def test_bic_prefers_fewer_parameters_for_the_same_fit():
    assert bic(10.0, 1000, 1) < bic(10.0, 1000, 2)
    assert bic(5.0, 1000, 2) < bic(10.0, 1000, 1)
