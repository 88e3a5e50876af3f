"""The output-error fitter shared by the calibration and the diagnosis' recalibration."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfmu.output_error import FAILED_RESIDUAL, Variable, fit_output_error, target_spread

TIME_S = np.linspace(0.0, 4.0, 81)


def decay(rate: float, start: float) -> np.ndarray:
    """(T, 1) a first-order decay x(t) = start * exp(-rate t)."""
    return (start * np.exp(-rate * TIME_S))[:, None]


def test_a_shared_parameter_and_one_initial_state_per_maneuver_are_recovered():
    measured = [decay(0.7, 2.0), decay(0.7, 5.0)]
    calls = []

    def simulate(values, m):
        calls.append(m)
        return decay(values["rate"], values[f"x0@{m}"])

    variables = [Variable("rate", 0.3, 0.01, 5.0), Variable("x0@0", 1.0, 0.0, 10.0, maneuver=0),
                 Variable("x0@1", 1.0, 0.0, 10.0, maneuver=1)]
    fit = fit_output_error(variables, simulate, measured, np.ones(1), target_spread(measured), relative_step=1e-6,
                           tolerance=1e-12, max_evaluations=100, label="decay")
    assert fit.values == pytest.approx({"rate": 0.7, "x0@0": 2.0, "x0@1": 5.0}, rel=1e-6)
    assert fit.cost < 1e-14 < fit.cost_start
    # a Jacobian simulates both maneuvers for the shared rate and one maneuver for each initial state
    per_jacobian = 2 + 1 + 1
    assert fit.simulations == 2 * fit.evaluations + per_jacobian * fit.iterations == len(calls)


def test_a_failed_simulation_is_a_bad_point_not_an_abort():
    """A simulation that raises one of the named failures (or returns NaN) costs FAILED_RESIDUAL per sample and the
    fit returns; any other exception propagates."""
    measured = [decay(0.7, 2.0)]

    def simulate(values, m):
        if values["rate"] > 1.5:
            raise RuntimeError("the solver gave up")
        return decay(values["rate"], 2.0) * (np.nan if values["rate"] < 0.1 else 1.0)

    for start in (2.0, 0.05):
        fit = fit_output_error([Variable("rate", start, 0.01, 5.0)], simulate, measured, np.ones(1), np.ones(1),
                               relative_step=1e-6, tolerance=1e-10, max_evaluations=5, label="decay",
                               failures=(RuntimeError,))
        assert fit.cost_start == pytest.approx(0.5 * FAILED_RESIDUAL ** 2)
    with pytest.raises(ValueError, match="other"):
        fit_output_error([Variable("rate", 1.0, 0.01, 5.0)],
                         lambda values, m: (_ for _ in ()).throw(ValueError("other")), measured, np.ones(1),
                         np.ones(1), relative_step=1e-6, tolerance=1e-10, max_evaluations=5, label="decay",
                         failures=(RuntimeError,))


def test_the_lowest_of_several_starts_wins():
    """A cost with two valleys (a rate and its mirror through a periodic simulation): the start in the right valley
    wins, whichever order the starts are given in."""
    measured = [np.cos(1.0 * TIME_S)[:, None]]

    def simulate(values, m):
        return np.cos(values["w"] * TIME_S)[:, None]

    variables = [Variable("w", 1.2, 0.1, 10.0)]
    for starts in ([{"w": 4.0}, {"w": 1.2}], [{"w": 1.2}, {"w": 4.0}]):
        fit = fit_output_error(variables, simulate, measured, np.ones(1), np.ones(1), relative_step=1e-6,
                               tolerance=1e-12, max_evaluations=100, label="cos", starts=starts)
        assert fit.values["w"] == pytest.approx(1.0, rel=1e-6)
        assert len(fit.start_costs) == 2 and fit.cost == min(fit.start_costs)


def test_nothing_to_fit_returns_the_start_cost():
    measured = [decay(0.7, 2.0)]
    fit = fit_output_error([], lambda values, m: decay(0.5, 2.0), measured, np.ones(1), np.ones(1),
                           relative_step=1e-6, tolerance=1e-10, max_evaluations=5, label="none")
    assert fit.values == {} and fit.cost == fit.cost_start > 0 and fit.simulations == 1
