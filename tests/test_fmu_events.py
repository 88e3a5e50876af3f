"""Events in the FMU bridge: several time and state events within one sample interval, terminate
requests, and non-finite derivatives.

The test models are the project's own C models in tests/fixtures/ (staircase: time events;
bouncing_ball: state events; terminate: terminateSimulation), built here on the common core. The
bridge's open-loop simulation is compared with FMPy's own CVode run of the same FMU.
"""

from __future__ import annotations

from pathlib import Path

import fmpy
import numpy as np
import pytest

from hybridfmu.fmu import FmuError, FmuNonFiniteError, FmuTerminated, load_fmu, simulate_open_loop
from hybridfmu.fmu.build import build_fmu_from_description

FIXTURES = Path(__file__).parent / "fixtures"
GRAVITY = 9.81
RESTITUTION = 0.7
# CVode in FMPy at this relative tolerance (FMPy sets the absolute one to rtol / 1000): its root
# finding places the four bounces within 3.5e-9 s of the closed form (measured; 3e-8 s at rtol 1e-8,
# 3e-6 s at rtol 1e-6, so its error scales with rtol).
CVODE_RTOL = 1e-9
# Bounce times of the two runs: CVode's 3.5e-9 s plus the bridge's own error with a margin of ~25.
# The bridge's RK4 is exact for the ball's constant-acceleration flight and its bisection locates a
# crossing to event_tolerance_s = 1e-10 s, so its bounces sit within 4 x 1e-10 s of the closed form
# (measured 3.5e-10 s), checked with CLOSED_FORM_TOLERANCE_S.
BOUNCE_TIME_TOLERANCE_S = 1e-7
CLOSED_FORM_TOLERANCE_S = 1e-9
# States on the grid: measured differences 4e-9 m (h) and 4.5e-8 m/s (v) at rtol 1e-9.
BALL_STATE_TOLERANCE = 1e-6


def build(folder: str, out_dir: Path) -> Path:
    description = FIXTURES / folder / "modelDescription.xml"
    return build_fmu_from_description(description, out_dir / f"{folder}.fmu")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> dict[str, Path]:
    out_dir = tmp_path_factory.mktemp("event_fmus")
    return {folder: build(folder, out_dir) for folder in ("staircase", "bouncing_ball", "terminate")}


def fmpy_run(path: Path, stop_time: float, output_interval: float, **options) -> np.ndarray:
    return fmpy.simulate_fmu(str(path), solver="CVode", stop_time=stop_time, output_interval=output_interval,
                             relative_tolerance=CVODE_RTOL, **options)


def fmpy_event_times(result: np.ndarray) -> np.ndarray:
    """FMPy writes a row before and one after each event at the same time stamp."""
    time = result["time"]
    return time[1:][np.diff(time) == 0.0]


def fmpy_on_grid(result: np.ndarray, grid: np.ndarray, name: str) -> np.ndarray:
    """FMPy's value of ``name`` at the grid times (after the event where one falls on the grid)."""
    time = result["time"]
    rows = [np.flatnonzero(np.isclose(time, t, rtol=0.0, atol=1e-12))[-1] for t in grid]
    return result[name][rows]


# ---------------------------------------------------------------------------- time events


def test_staircase_handles_several_time_events_per_sample_interval(fmus):
    """Steps every 0.1 s on a 0.35 s grid: three or four time events per interval, each at its time."""
    period, step_s = 0.1, 0.35
    grid = np.arange(4) * step_s
    with load_fmu(fmus["staircase"]) as model:
        result = simulate_open_loop(model, grid, None, [0.0])

    reference = fmpy_run(fmus["staircase"], grid[-1], step_s, output=["x", "y"])
    ours = np.array([t for t, what in result.events if what == "time event"])
    theirs = fmpy_event_times(reference)
    # both simulators stop exactly at the nextEventTime the FMU announces: equal up to round-off
    np.testing.assert_allclose(ours, theirs, rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(ours, period * np.arange(1, 11), rtol=0.0, atol=1e-12)
    per_interval = np.histogram(ours, bins=grid)[0]
    assert per_interval.min() >= 3, per_interval
    # x integrates the staircase: x(t) = height * period * sum over passed steps; the kinks sit at
    # the event times, so a late or skipped event changes x
    x_fmpy = fmpy_on_grid(reference, grid, "x")
    np.testing.assert_allclose(result.states[:, 0], x_fmpy, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(result.states[:, 0], [0.0, 0.45, 2.1, 5.0], rtol=0.0, atol=1e-9)


# ---------------------------------------------------------------------------- state events


def closed_form_bounces(h0: float, until_s: float) -> list[float]:
    """Impact times of a ball dropped from rest at height h0 (m), up to until_s (s)."""
    t = np.sqrt(2.0 * h0 / GRAVITY)
    v = RESTITUTION * GRAVITY * t
    times = []
    while t <= until_s:
        times.append(t)
        t += 2.0 * v / GRAVITY
        v *= RESTITUTION
    return times


def test_bouncing_ball_state_events_match_fmpy_on_a_coarse_grid(fmus):
    """A 0.5 s grid over 2 s: four bounces, two of them within the last interval (1.5 s, 2 s]."""
    grid = np.arange(5) * 0.5
    with load_fmu(fmus["bouncing_ball"]) as model:
        result = simulate_open_loop(model, grid, None, [1.0, 0.0])

    reference = fmpy_run(fmus["bouncing_ball"], grid[-1], 0.5)
    ours = np.array([t for t, what in result.events if what.startswith("state event")])
    theirs = fmpy_event_times(reference)
    assert len(ours) == len(theirs) == 4, (ours, theirs)
    np.testing.assert_allclose(ours, theirs, rtol=0.0, atol=BOUNCE_TIME_TOLERANCE_S)
    np.testing.assert_allclose(ours, closed_form_bounces(1.0, grid[-1]), rtol=0.0, atol=CLOSED_FORM_TOLERANCE_S)
    assert np.histogram(ours, bins=grid)[0].tolist() == [1, 0, 1, 2]
    assert all("states re-initialised" in what for t, what in result.events)
    for j, name in enumerate(["h", "v"]):
        np.testing.assert_allclose(result.states[:, j], fmpy_on_grid(reference, grid, name), rtol=0.0,
                                   atol=BALL_STATE_TOLERANCE, err_msg=name)


def test_chattering_is_stopped_with_a_clear_error(fmus):
    """An interval with more events than max_events_per_step ends the run naming the FMU and time."""
    grid = np.array([0.0, 2.0])
    with load_fmu(fmus["bouncing_ball"]) as model, pytest.raises(FmuError) as info:
        simulate_open_loop(model, grid, None, [1.0, 0.0], max_events_per_step=3)
    message = str(info.value)
    assert str(fmus["bouncing_ball"]) in message and "more than 3 events" in message and "t = 2.0 s" in message


# ---------------------------------------------------------------------------- terminate


def test_terminate_at_a_time_event_returns_the_partial_trajectory(fmus):
    grid = np.arange(9) * 0.25
    with load_fmu(fmus["terminate"], parameters={"t_stop": 0.6}) as model:
        result = simulate_open_loop(model, grid, None, [0.0], allow_termination=True)
        with pytest.raises(FmuTerminated) as info:
            simulate_open_loop(model, grid, None, [0.0])
    assert result.terminated and result.terminated_at_s == pytest.approx(0.6, abs=1e-12)
    assert "fmi2NewDiscreteStates" in result.termination_reason
    np.testing.assert_allclose(result.time_s, [0.0, 0.25, 0.5, 0.6])
    np.testing.assert_allclose(result.states[:, 0], result.time_s, atol=1e-12)  # dx/dt = 1
    # FMPy's CVode run ends at the same time
    assert fmpy_run(fmus["terminate"], 2.0, 0.25, start_values={"t_stop": 0.6})["time"][-1] == pytest.approx(0.6)
    # callers that need the whole grid get an error naming the FMU and the time, with the partial result
    error = info.value
    assert str(fmus["terminate"]) in str(error) and "t = 0.6 s" in str(error)
    assert error.time_s == pytest.approx(0.6) and error.result.states.shape == (4, 1)


def test_terminate_after_an_integrator_step(fmus):
    grid = np.arange(9) * 0.25
    with load_fmu(fmus["terminate"], parameters={"x_stop": 0.6}) as model:
        result = simulate_open_loop(model, grid, None, [0.0], allow_termination=True)
        # the model stays usable afterwards
        np.testing.assert_allclose(model.derivatives([[0.0]]), [[1.0]])
    assert result.terminated_at_s == pytest.approx(0.75)
    assert "fmi2CompletedIntegratorStep" in result.termination_reason
    np.testing.assert_allclose(result.time_s, grid[:4])
    with pytest.raises(FmuTerminated, match=r"ended at t = 0\.75 s"):
        result.require_full_horizon()


def test_terminate_at_the_start(fmus):
    """t_stop at the start time: the FMU asks to terminate in its initial event iteration."""
    with load_fmu(fmus["terminate"], parameters={"t_stop": 1.0}) as model:
        result = simulate_open_loop(model, np.array([1.0, 1.5, 2.0]), None, [0.0], allow_termination=True)
    assert result.terminated_at_s == 1.0 and result.time_s.tolist() == [1.0]
    assert "initialisation" in result.termination_reason


# ---------------------------------------------------------------------------- non-finite derivatives


def test_non_finite_derivative_names_the_state_time_and_fmu(tmp_path):
    path = build("mass_spring", tmp_path)
    with load_fmu(path) as model:
        x = np.array([[0.1, 0.0], [1e308, 0.0]])
        with pytest.raises(FmuNonFiniteError) as info:
            model.derivatives(x, [[0.0], [0.0]], t_s=0.5)
        message = str(info.value)
        assert str(path) in message and "der(v) = -inf" in message and "state 'v'" in message
        assert "t = 0.5 s" in message and "row 1" in message and "x = 1e+308" in message
        assert info.value.states == ["v"] and info.value.time_s == 0.5
        # a diverging model is a floating-point failure to callers that catch those
        assert isinstance(info.value, FloatingPointError) and isinstance(info.value, FmuError)
        # also from inside the integration
        with pytest.raises(FmuError, match=r"der\(v\).*state 'v'.*t = 0\.0 s"):
            simulate_open_loop(model, np.array([0.0, 0.1]), np.zeros((2, 1)), [1e308, 0.0])
