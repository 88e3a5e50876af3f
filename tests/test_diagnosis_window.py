"""The held-out check's restarted windows: their length chosen on the fitting maneuvers when the config leaves it out."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_models import MassSpringDamper, msd_maneuvers, msd_problem
from hybridfmu.diagnosis.corrected_model import simulator_for
from hybridfmu.diagnosis.open_loop import take_off_times, window_from_data, window_setting
from hybridfmu.diagnosis.run import prepare_all


def prepared_with(model: MassSpringDamper, **diagnosis):
    problem, model = msd_problem(model, **diagnosis)
    measured = msd_maneuvers(None, duration_s=12.0)
    simulate_fn = simulator_for(model)
    prepared, fit_names, _ = prepare_all(problem, model, measured, simulate_fn)
    return problem, model, simulate_fn, prepared, fit_names


def test_a_model_that_leaves_the_data_sooner_gets_shorter_windows():
    """The truth's own model stays near its data for the whole horizon; one with a stiffness 20 % off leaves it
    sooner, and the window is the median of those times, at most a third of the shortest fitting maneuver."""
    problem, model, simulate_fn, prepared, fit_names = prepared_with(MassSpringDamper())
    exact = window_from_data(model, simulate_fn, prepared, fit_names, problem)
    assert exact["window_s"] == pytest.approx(exact["longest_s"]) and exact["longest_s"] == pytest.approx(4.0, abs=0.02)
    assert exact["starts"] == 2 * 32 and set(exact["take_off_s"]) == set(fit_names)

    problem, model, simulate_fn, prepared, fit_names = prepared_with(MassSpringDamper(k=4.8))
    wrong = window_from_data(model, simulate_fn, prepared, fit_names, problem)
    assert 2 * problem.dt_s <= wrong["window_s"] < 0.5 * exact["window_s"]
    times = np.concatenate([take_off_times(model, simulate_fn, prepared[n].measured, prepared[n].starts, problem,
                                           int(round(wrong["longest_s"] / problem.dt_s))) for n in fit_names])
    assert wrong["window_s"] == pytest.approx(max(float(np.median(times)), 2 * problem.dt_s))


@pytest.mark.parametrize("setting, expected", [(0.5, {"window_s": 0.5, "chosen": "config"}), (None, None)])
def test_a_configured_window_or_none_is_kept(setting, expected):
    problem, model, simulate_fn, prepared, fit_names = prepared_with(MassSpringDamper(),
                                                                     open_loop={"window_s": setting})
    assert window_setting(model, simulate_fn, prepared, fit_names, problem) == expected


def test_without_fitting_maneuvers_there_is_no_window_to_choose():
    problem, model, simulate_fn, prepared, _ = prepared_with(MassSpringDamper())
    assert problem.settings["open_loop"]["window_s"] == "auto"
    assert window_setting(model, simulate_fn, prepared, [], problem) is None
    chosen = window_setting(model, simulate_fn, prepared, ["train"], problem)
    assert chosen["chosen"] == "data" and chosen["window_s"] > 0


def test_the_report_says_how_long_the_windows_are_and_why():
    from hybridfmu.diagnosis.report import window_text

    assert window_text(None) == ""
    assert "every 0.5 s (diagnosis.open_loop.window_s)" in window_text({"window_s": 0.5, "chosen": "config"})
    text = window_text({"window_s": 0.35, "chosen": "data", "take_off_s": {"train": 0.37, "validation": 0.34},
                        "longest_s": 3.9, "starts": 64})
    assert "every 0.35 s" in text and "64 points" in text and "train 0.37 s, validation 0.34 s" in text
