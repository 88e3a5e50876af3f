"""The demo FMUs through the FMI 2.0 API (FMPy's low-level FMU2Model): equations against an
independent NumPy implementation, exact directional derivatives against central differences,
end stops as state events, parameter checks, error handling and FMU states."""

from __future__ import annotations

import ctypes
import math
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import calloc, free
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Model,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)

STATES = ["i_d", "i_q", "theta", "omega"]
DERIVATIVES = ["der(i_d)", "der(i_q)", "der(theta)", "der(omega)"]
INPUTS = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
REAL_OUTPUTS = ["tau_e", "i_a", "i_b", "i_c", "v_d", "v_q"]
NOMINAL = {"p": 4.0, "R": 0.03, "L_d": 60e-6, "L_q": 60e-6, "psi": 6e-3, "J": 2e-4, "b": 2e-5,
           "theta_min": 0.0, "theta_max": 60.0}
SQRT3 = math.sqrt(3.0)


# ----------------------------------------------------------------------------- helpers


class Instance:
    """One FMU instance driven through FMPy's FMU2Model; keeps every logger message.

    Args:
        path: the .fmu file (only its model description is read).
        unzip_dir: folder where the FMU is extracted.
        guid: GUID passed to fmi2Instantiate (default: the model description's).
    """

    def __init__(self, path: Path, unzip_dir: str, guid: str | None = None, logging_on: bool = False):
        self.md = fmpy.read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.messages: list[tuple[int, str, str]] = []  # (status, category, message)
        self.fmu = FMU2Model(guid=guid or self.md.guid, unzipDirectory=unzip_dir,
                             modelIdentifier=self.md.modelExchange.modelIdentifier, instanceName="probe")
        self._logger = fmi2CallbackLoggerTYPE(self._log)
        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = self._logger
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        self.fmu.instantiate(callbacks=self.callbacks, loggingOn=logging_on)
        self.nx = self.md.numberOfContinuousStates
        self.nz = self.md.numberOfEventIndicators

    def _log(self, env, name, status, category, message):
        self.messages.append((status, category.decode(), message.decode()))

    def errors(self) -> list[str]:
        return [m for status, _, m in self.messages if status >= 3]

    def initialize(self, values: dict[str, float] | None = None) -> None:
        """Set values before initialisation, run initialisation and the first event iteration."""
        self.fmu.setupExperiment(startTime=0.0)
        if values:
            self.set(values)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        self.event_iteration()
        self.fmu.enterContinuousTimeMode()

    def event_iteration(self) -> bool:
        """fmi2NewDiscreteStates until converged; return valuesOfContinuousStatesChanged."""
        changed = False
        while True:
            needed, terminate, _, values_changed, _, _ = self.fmu.newDiscreteStates()
            changed |= values_changed
            assert not terminate
            if not needed:
                return changed

    def event(self) -> bool:
        """Handle an event from continuous-time mode; return valuesOfContinuousStatesChanged."""
        self.fmu.enterEventMode()
        changed = self.event_iteration()
        self.fmu.enterContinuousTimeMode()
        return changed

    def set(self, values: dict[str, float]) -> None:
        self.fmu.setReal([self.vr[n] for n in values], [float(v) for v in values.values()])

    def get(self, names: list[str]) -> np.ndarray:
        return np.array(self.fmu.getReal([self.vr[n] for n in names]))

    def stop_mode(self) -> int:
        return self.fmu.getInteger([self.vr["stop_mode"]])[0]

    def set_x(self, x) -> None:
        array = (ctypes.c_double * self.nx)(*[float(v) for v in x])
        self.fmu.setContinuousStates(array, self.nx)

    def x(self) -> np.ndarray:
        array = (ctypes.c_double * self.nx)()
        self.fmu.getContinuousStates(array, self.nx)
        return np.array(array)

    def dx(self) -> np.ndarray:
        array = (ctypes.c_double * self.nx)()
        self.fmu.getDerivatives(array, self.nx)
        return np.array(array)

    def z(self) -> np.ndarray:
        array = (ctypes.c_double * max(self.nz, 1))()
        self.fmu.getEventIndicators(array, self.nz)
        return np.array(array[: self.nz])

    def directional(self, unknowns: list[str], knowns: list[str], seed) -> np.ndarray:
        return np.array(self.fmu.getDirectionalDerivative([self.vr[n] for n in unknowns],
                                                          [self.vr[n] for n in knowns], list(map(float, seed))))

    def close(self) -> None:
        self.fmu.freeInstance()


@pytest.fixture(scope="module")
def ipb_dir(ipbmotor_fmu, tmp_path_factory) -> tuple[Path, str]:
    return ipbmotor_fmu, fmpy.extract(str(ipbmotor_fmu), unzipdir=str(tmp_path_factory.mktemp("ipb")))


@pytest.fixture(scope="module")
def osc_dir(oscillator_fmu, tmp_path_factory) -> tuple[Path, str]:
    return oscillator_fmu, fmpy.extract(str(oscillator_fmu), unzipdir=str(tmp_path_factory.mktemp("osc")))


@pytest.fixture()
def motor(ipb_dir):
    instance = Instance(*ipb_dir)
    yield instance
    instance.close()


@pytest.fixture()
def oscillator(osc_dir):
    instance = Instance(*osc_dir)
    yield instance
    instance.close()


def reference_motor(x, u, par, held=False):
    """The motor equations of the team contract, in NumPy, independent of the C code.

    Returns a dict: "der" (4,), and tau_e, i_a, i_b, i_c, v_d, v_q.
    """
    i_d, i_q, theta, omega = x
    d = np.asarray(u[:3], dtype=float)
    u_dc, tau_load = u[3], u[4]
    v_abc = u_dc * (d - d.sum() / 3.0)
    v_alpha = 2.0 / 3.0 * (v_abc[0] - v_abc[1] / 2.0 - v_abc[2] / 2.0)
    v_beta = (v_abc[1] - v_abc[2]) / SQRT3
    theta_e = par["p"] * theta
    c, s = np.cos(theta_e), np.sin(theta_e)
    v_d = v_alpha * c + v_beta * s
    v_q = -v_alpha * s + v_beta * c
    tau_e = 1.5 * par["p"] * (par["psi"] * i_q + (par["L_d"] - par["L_q"]) * i_d * i_q)
    der = np.array([
        (v_d - par["R"] * i_d + par["p"] * omega * par["L_q"] * i_q) / par["L_d"],
        (v_q - par["R"] * i_q - par["p"] * omega * (par["L_d"] * i_d + par["psi"])) / par["L_q"],
        0.0 if held else omega,
        0.0 if held else (tau_e - par["b"] * omega - tau_load) / par["J"],
    ])
    i_alpha, i_beta = i_d * c - i_q * s, i_d * s + i_q * c
    return {"der": der, "tau_e": tau_e, "i_a": i_alpha, "i_b": -i_alpha / 2 + SQRT3 / 2 * i_beta,
            "i_c": -i_alpha / 2 - SQRT3 / 2 * i_beta, "v_d": v_d, "v_q": v_q}


def random_parameters(rng) -> dict[str, float]:
    return {"p": float(rng.integers(1, 7)), "R": rng.uniform(0.01, 0.1), "L_d": rng.uniform(30e-6, 120e-6),
            "L_q": rng.uniform(30e-6, 120e-6), "psi": rng.uniform(1e-3, 1e-2), "J": rng.uniform(1e-4, 5e-4),
            "b": rng.uniform(0.0, 1e-4), "theta_min": rng.uniform(-5.0, 0.0), "theta_max": rng.uniform(10.0, 70.0)}


def random_point(rng, par) -> tuple[np.ndarray, np.ndarray]:
    x = np.array([rng.uniform(-120, 120), rng.uniform(-120, 120),
                  rng.uniform(par["theta_min"], par["theta_max"]), rng.uniform(-450, 450)])
    u = np.array([*rng.uniform(0.0, 1.0, 3), rng.uniform(9.0, 15.0), rng.uniform(-3.0, 3.0)])
    return x, u


def set_parameters_in_event_mode(instance: Instance, par: dict[str, float]) -> None:
    """Tunable parameters: set them in event mode (rotor parked mid-range, at rest)."""
    instance.set_x([0.0, 0.0, 5.0, 0.0])
    instance.fmu.enterEventMode()
    instance.set(par)
    instance.event_iteration()
    instance.fmu.enterContinuousTimeMode()
    assert instance.stop_mode() == 0


# ----------------------------------------------------------------------------- model description vs C


@pytest.mark.parametrize("which", ["ipb", "osc"])
def test_values_after_instantiation_are_the_start_values(which, ipb_dir, osc_dir):
    instance = Instance(*(ipb_dir if which == "ipb" else osc_dir))
    try:
        instance.fmu.enterInitializationMode()
        for variable in instance.md.modelVariables:
            if variable.type == "Real" and variable.start is not None:
                assert instance.get([variable.name])[0] == float(variable.start), variable.name
        nominals = (ctypes.c_double * instance.nx)()
        instance.fmu.getNominalsOfContinuousStates(nominals, instance.nx)
        expected = [float(d.variable.derivative.nominal) for d in instance.md.derivatives]
        assert list(nominals) == expected
        for variable in instance.md.modelVariables:  # calculated variables cannot be set
            if variable.type == "Real" and (variable.causality == "output" or variable.derivative is not None):
                with pytest.raises(FMICallException):
                    instance.set({variable.name: 1.0})
                assert "is calculated and cannot be set" in instance.errors()[-1]
    finally:
        instance.close()


# ----------------------------------------------------------------------------- equations


def test_motor_derivatives_and_outputs_match_numpy_reference(motor):
    rng = np.random.default_rng(7)
    motor.initialize()
    parameter_sets = [NOMINAL] + [random_parameters(rng) for _ in range(5)]
    for par in parameter_sets:
        set_parameters_in_event_mode(motor, par)
        for _ in range(20):
            x, u = random_point(rng, par)
            motor.set_x(x)
            motor.set(dict(zip(INPUTS, u)))
            ref = reference_motor(x, u, par)
            np.testing.assert_allclose(motor.dx(), ref["der"], rtol=1e-11, atol=1e-9)
            got = motor.get(REAL_OUTPUTS)
            want = np.array([ref[n] for n in REAL_OUTPUTS])
            np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-9)
            # the phase currents are balanced and Clarke/Park of them gives back (i_d, i_q)
            i_a, i_b, i_c = got[1:4]
            assert abs(i_a + i_b + i_c) < 1e-9
            alpha, beta = 2 / 3 * (i_a - i_b / 2 - i_c / 2), (i_b - i_c) / SQRT3
            theta_e = par["p"] * x[2]
            np.testing.assert_allclose([alpha * np.cos(theta_e) + beta * np.sin(theta_e),
                                        -alpha * np.sin(theta_e) + beta * np.cos(theta_e)], x[:2], atol=1e-9)
    assert motor.errors() == []


def test_oscillator_derivatives_match_numpy_reference(oscillator):
    rng = np.random.default_rng(3)
    oscillator.initialize({"mu": 0.7, "omega_0": 3.0})
    for _ in range(20):
        x = rng.uniform(-3, 3, 2)
        oscillator.set_x(x)
        mu, w = 0.7, 3.0
        np.testing.assert_allclose(oscillator.dx(), [x[1], mu * w * (1 - x[0] ** 2) * x[1] - w * w * x[0]],
                                   rtol=1e-13, atol=1e-13)
        assert oscillator.get(["energy"])[0] == pytest.approx(0.5 * (x[1] ** 2 + w * w * x[0] ** 2), rel=1e-13)
    # parameters are tunable in event mode, not in continuous-time mode
    with pytest.raises(FMICallException):
        oscillator.set({"mu": 1.0})
    assert 'parameter "mu" cannot be set in continuous-time mode' in oscillator.errors()[-1]
    oscillator.fmu.enterEventMode()
    oscillator.set({"mu": 0.0})
    oscillator.event_iteration()
    oscillator.fmu.enterContinuousTimeMode()
    oscillator.set_x([1.0, 2.0])
    np.testing.assert_allclose(oscillator.dx(), [2.0, -9.0])


# ----------------------------------------------------------------------------- directional derivatives

#: typical magnitude of each known (states then inputs) for step sizes and error floors
KNOWN_SCALE = {"i_d": 100.0, "i_q": 100.0, "theta": 1.0, "omega": 400.0, "d_a": 1.0, "d_b": 1.0, "d_c": 1.0,
               "u_dc": 12.0, "tau_load": 1.0}


def _unknowns(instance: Instance) -> np.ndarray:
    return np.concatenate([instance.dx(), instance.get(REAL_OUTPUTS)])


def central_difference_jacobian(instance: Instance, x, u, knowns: list[str]) -> np.ndarray:
    """d(derivatives, Real outputs)/d(knowns) by central differences, steps 1e-6 x typical magnitude."""
    columns = []
    for name in knowns:
        h = 1e-6 * KNOWN_SCALE[name]
        values = []
        for sign in (1.0, -1.0):
            xp, up = np.array(x, dtype=float), np.array(u, dtype=float)
            if name in STATES:
                xp[STATES.index(name)] += sign * h
            else:
                up[INPUTS.index(name)] += sign * h
            instance.set_x(xp)
            instance.set(dict(zip(INPUTS, up)))
            values.append(_unknowns(instance))
        columns.append((values[0] - values[1]) / (2 * h))
    instance.set_x(x)
    instance.set(dict(zip(INPUTS, u)))
    return np.stack(columns, axis=1)


def exact_jacobian(instance: Instance, knowns: list[str]) -> np.ndarray:
    unknowns = DERIVATIVES + REAL_OUTPUTS
    return np.stack([instance.directional(unknowns, knowns, np.eye(len(knowns))[j]) for j in range(len(knowns))],
                    axis=1)


def assert_jacobians_agree(exact: np.ndarray, finite: np.ndarray, knowns: list[str]) -> None:
    """Relative error < 1e-6 per entry; near-zero entries are compared against 1e-3 of their row's
    largest sensitivity (both scaled by the typical magnitude of the known)."""
    scale = np.array([KNOWN_SCALE[n] for n in knowns])
    exact_scaled, finite_scaled = exact * scale, finite * scale
    floor = 1e-3 * np.max(np.abs(finite_scaled), axis=1, keepdims=True)
    reference = np.maximum(np.abs(finite_scaled), np.maximum(floor, 1e-12))
    relative = np.abs(exact_scaled - finite_scaled) / reference
    assert relative.max() < 1e-6, (relative.max(), np.unravel_index(relative.argmax(), relative.shape))


def test_directional_derivatives_match_central_differences(motor):
    rng = np.random.default_rng(11)
    motor.initialize()
    knowns = STATES + INPUTS
    for par in [NOMINAL] + [random_parameters(rng) for _ in range(3)]:
        set_parameters_in_event_mode(motor, par)
        for _ in range(6):
            x, u = random_point(rng, par)
            motor.set_x(x)
            motor.set(dict(zip(INPUTS, u)))
            exact = exact_jacobian(motor, knowns)
            assert_jacobians_agree(exact, central_difference_jacobian(motor, x, u, knowns), knowns)
            # a seed vector gives the Jacobian-vector product; subsets and orderings work
            seed = rng.normal(size=len(knowns))
            np.testing.assert_allclose(motor.directional(DERIVATIVES + REAL_OUTPUTS, knowns, seed), exact @ seed,
                                       rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(motor.directional(["der(omega)", "der(i_d)"], ["tau_load", "theta"], [1, 2]),
                                       [exact[3, 8] + 2 * exact[3, 2], exact[0, 8] + 2 * exact[0, 2]], rtol=1e-12)
    assert motor.errors() == []


def test_directional_derivatives_while_held_at_a_stop(motor):
    motor.initialize({"theta_max": 1.0})
    x = np.array([5.0, 40.0, 1.0, 0.0])  # i_q > 0: tau_e > 0 pushes into theta_max
    u = np.array([0.6, 0.3, 0.5, 12.0, 0.1])
    motor.set_x(x + np.array([0, 0, 1e-3, 2.0]))  # just past the stop, moving into it
    motor.set(dict(zip(INPUTS, u)))
    assert motor.event() is True
    assert motor.stop_mode() == 1
    np.testing.assert_array_equal(motor.x(), x)
    np.testing.assert_allclose(motor.dx(), reference_motor(x, u, NOMINAL, held=True)["der"], rtol=1e-12)
    knowns = STATES + INPUTS
    exact = exact_jacobian(motor, knowns)
    assert np.all(exact[2:4] == 0.0)  # der(theta), der(omega) are 0 while held
    finite = central_difference_jacobian(motor, x, u, knowns)
    assert_jacobians_agree(exact[[0, 1, 4, 5, 6, 7, 8, 9]], finite[[0, 1, 4, 5, 6, 7, 8, 9]], knowns)


def test_directional_derivative_rejects_unsupported_variables(motor, oscillator):
    motor.initialize()
    with pytest.raises(FMICallException):
        motor.directional(["theta"], ["omega"], [1.0])
    assert 'unknown "theta" is not supported' in motor.errors()[-1]
    with pytest.raises(FMICallException):
        motor.directional(["der(omega)"], ["J"], [1.0])
    assert 'known "J" is not supported: knowns must be continuous states or inputs' in motor.errors()[-1]
    with pytest.raises(FMICallException):
        motor.fmu.getDirectionalDerivative([4], [999], [1.0])
    assert "unknown value reference 999" in motor.errors()[-1]
    oscillator.initialize()
    with pytest.raises(FMICallException):
        oscillator.directional(["der(x)"], ["x"], [1.0])
    assert 'does not provide directional derivatives (providesDirectionalDerivative="false")' in \
        oscillator.errors()[-1]


# ----------------------------------------------------------------------------- end stops


def _stop_input(push_nm: float) -> np.ndarray:
    """tau_load pushing with push_nm until 0.3 s, then the opposite (a step at 0.3 s)."""
    rows = [(0.0, push_nm), (0.3, push_nm), (0.3, -push_nm), (0.4, -push_nm)]
    return np.array(rows, dtype=[("time", float), ("tau_load", float)])


@pytest.mark.parametrize("solver", ["CVode", "Euler"])
@pytest.mark.parametrize("side", ["max", "min"])
def test_end_stop_holds_while_pushed_and_releases_when_torque_reverses(ipbmotor_fmu, solver, side):
    if side == "max":  # negative load torque drives the rotor forward into theta_max = 0.6 rad
        start, push, stop_angle, held_mode = {"theta": 0.5, "theta_max": 0.6}, -0.05, 0.6, 1
    else:  # positive load torque drives it back into theta_min = 0.4 rad
        start, push, stop_angle, held_mode = {"theta": 0.5, "theta_min": 0.4}, 0.05, 0.4, -1
    messages = []
    options = {"output_interval": 1e-3} if solver == "CVode" else {"output_interval": 2e-5, "step_size": 2e-5}
    result = fmpy.simulate_fmu(
        str(ipbmotor_fmu), stop_time=0.4, solver=solver, start_values=start, input=_stop_input(push),
        output=["theta", "omega", "stop_mode", "tau_e"], record_events=False, debug_logging=True,
        logger=lambda env, name, status, category, message: messages.append(message.decode()), **options)
    t, theta, omega, mode = result["time"], result["theta"], result["omega"], result["stop_mode"]
    direction = 1.0 if side == "max" else -1.0
    # never beyond the stop
    assert np.all(direction * (theta - stop_angle) <= 0.0)
    # reaches the stop, then held exactly there, at rest, until the torque reverses at 0.3 s
    held = np.flatnonzero(mode == held_mode)
    assert held.size > 0
    t_hit = t[held[0]]
    assert 0.05 < t_hit < 0.25
    hold = (t >= t_hit) & (t < 0.3 - 1e-9)
    assert np.all(mode[hold] == held_mode)
    assert np.all(theta[hold] == stop_angle)
    assert np.all(omega[hold] == 0.0)
    # after the reversal: free and moving away
    after = t > 0.301
    assert np.all(mode[after] == 0)
    assert direction * (theta[-1] - stop_angle) < -0.05
    assert direction * omega[-1] < -0.5
    side_name = f"theta_{side}"
    assert any(f"held at {side_name}" in m for m in messages), messages
    assert any(f"released from {side_name}" in m for m in messages), messages


def test_stop_events_through_the_api(motor):
    motor.initialize({"theta_min": -1.0, "theta_max": 2.0})
    # free: indicators are the distances to the stops, and a constant 1
    motor.set_x([0.0, 0.0, 1.5, 10.0])
    motor.set({"tau_load": -0.2})  # pushes forward
    np.testing.assert_allclose(motor.z(), [2.5, 0.5, 1.0])
    assert motor.fmu.completedIntegratorStep() == (False, False)
    # a step past theta_max: z1 < 0, completedIntegratorStep asks for an event
    motor.set_x([0.0, 0.0, 2.01, 10.0])
    assert motor.z()[1] < 0
    assert motor.fmu.completedIntegratorStep() == (True, False)
    assert motor.event() is True  # clamped and stopped
    np.testing.assert_array_equal(motor.x(), [0.0, 0.0, 2.0, 0.0])
    assert motor.stop_mode() == 1
    # held: z2 is the net torque tau_e - tau_load (> 0 pushes into theta_max)
    np.testing.assert_allclose(motor.z(), [3.0, 1.0, 0.2])
    assert motor.event() is False  # nothing changes at a repeated event
    assert motor.stop_mode() == 1
    # the torque reverses: z2 < 0 and the rotor is released without a state jump
    motor.set({"tau_load": 0.1})
    assert motor.z()[2] == pytest.approx(-0.1)
    assert motor.fmu.completedIntegratorStep() == (True, False)
    assert motor.event() is False
    assert motor.stop_mode() == 0
    assert motor.dx()[3] == pytest.approx(-0.1 / NOMINAL["J"])
    np.testing.assert_allclose(motor.z(), [3.0, 0.0, 1.0])
    # hitting a stop while the torque already pulls away: stopped but not held
    motor.set_x([0.0, 0.0, -1.001, -3.0])
    motor.set({"tau_load": -0.1})
    assert motor.event() is True
    np.testing.assert_array_equal(motor.x(), [0.0, 0.0, -1.0, 0.0])
    assert motor.stop_mode() == 0
    # pushed into theta_min: held; raising theta_min in event mode keeps it at the (moved) stop
    motor.set({"tau_load": 0.1})
    assert motor.event() is False and motor.stop_mode() == -1
    np.testing.assert_allclose(motor.z(), [1.0, 3.0, 0.1])
    motor.fmu.enterEventMode()
    motor.set({"theta_min": -0.5})
    assert motor.event_iteration() is True
    motor.fmu.enterContinuousTimeMode()
    np.testing.assert_array_equal(motor.x(), [0.0, 0.0, -0.5, 0.0])
    # lowering it again leaves the rotor free where it is
    motor.fmu.enterEventMode()
    motor.set({"theta_min": -2.0})
    assert motor.event_iteration() is False
    motor.fmu.enterContinuousTimeMode()
    assert motor.stop_mode() == 0
    # states set off the stop while held are detected after the step
    motor.set_x([0.0, 0.0, -2.5, 0.0])
    assert motor.event() is True and motor.stop_mode() == -1
    motor.set_x([0.0, 0.0, -1.0, 0.0])
    assert motor.fmu.completedIntegratorStep() == (True, False)
    assert motor.errors() == []


def test_event_log_only_with_debug_logging(ipb_dir):
    for logging_on in (False, True):
        instance = Instance(*ipb_dir, logging_on=logging_on)
        try:
            instance.initialize({"theta_max": 1.0})
            instance.set_x([0.0, 0.0, 1.01, 1.0])
            instance.set({"tau_load": -0.1})
            instance.event()
            events = [m for _, category, m in instance.messages if category == "logEvents"]
            assert bool(events) == logging_on
            if logging_on:
                assert "theta_max reached at omega = 1 rad/s" in events[0]
        finally:
            instance.close()


# ----------------------------------------------------------------------------- bad parameters and calls

BAD_VALUES = [
    ("L_d", 0.0, "must be > 0 H"),
    ("L_d", -6e-5, "must be > 0 H"),
    ("L_q", 0.0, "must be > 0 H"),
    ("J", 0.0, "must be > 0 kg m2"),
    ("J", -2e-4, "must be > 0 kg m2"),
    ("p", 0.0, "whole number >= 1"),
    ("p", 2.5, "whole number >= 1"),
    ("R", -0.01, "must be >= 0 ohm"),
    ("psi", -1e-3, "must be >= 0 Wb"),
    ("b", -1e-5, "must be >= 0 N m s/rad"),
    ("R", float("nan"), "is not a finite number"),
    ("theta_max", float("inf"), "is not a finite number"),
]


@pytest.mark.parametrize(("name", "value", "expected"), BAD_VALUES)
def test_bad_parameter_value_is_an_error_naming_it(motor, name, value, expected):
    with pytest.raises(FMICallException, match="fmi2SetReal failed with status 3"):
        motor.set({name: value})
    message = motor.errors()[-1]
    assert f'"{name}"' in message and expected in message, message
    # the failed call changed nothing: the instance initialises with the default
    motor.initialize()
    assert motor.get([name])[0] == NOMINAL[name]
    # also refused in event mode
    motor.fmu.enterEventMode()
    with pytest.raises(FMICallException):
        motor.set({name: value})


def test_bad_parameter_through_simulate_fmu_raises(ipbmotor_fmu):
    messages = []
    with pytest.raises(FMICallException):
        fmpy.simulate_fmu(str(ipbmotor_fmu), stop_time=0.01, start_values={"J": -1.0},
                          logger=lambda env, name, status, category, message: messages.append(message.decode()))
    assert any('parameter "J" = -1 is invalid' in m for m in messages), messages
    with pytest.raises(FMICallException, match="fmi2ExitInitializationMode"):
        fmpy.simulate_fmu(str(ipbmotor_fmu), stop_time=0.01, start_values={"theta_min": 5.0, "theta_max": 5.0},
                          logger=lambda env, name, status, category, message: messages.append(message.decode()))
    assert any('"theta_min" = 5 and "theta_max" = 5 are invalid' in m for m in messages), messages


def test_inconsistent_stops_are_refused_at_initialisation_and_events(motor):
    motor.set({"theta_min": 10.0, "theta_max": 3.0})  # each value alone is fine
    motor.fmu.enterInitializationMode()
    with pytest.raises(FMICallException):
        motor.fmu.exitInitializationMode()
    assert "theta_min must be < theta_max" in motor.errors()[-1]
    motor.set({"theta_max": 30.0, "theta": 12.0})  # still in initialisation mode: correct and retry
    motor.fmu.exitInitializationMode()
    motor.event_iteration()
    motor.fmu.enterContinuousTimeMode()
    motor.fmu.enterEventMode()
    motor.set({"theta_max": 9.0})
    with pytest.raises(FMICallException, match="fmi2NewDiscreteStates"):
        motor.fmu.newDiscreteStates()
    with pytest.raises(FMICallException, match="fmi2EnterContinuousTimeMode"):
        motor.fmu.enterContinuousTimeMode()


def test_oscillator_bad_parameters(oscillator):
    with pytest.raises(FMICallException):
        oscillator.set({"omega_0": 0.0})
    assert 'parameter "omega_0" = 0 is invalid' in oscillator.errors()[-1]
    with pytest.raises(FMICallException):
        oscillator.set({"mu": -1.0})
    assert 'parameter "mu" = -1 is invalid' in oscillator.errors()[-1]


def test_calls_in_the_wrong_state_and_bad_arguments_are_errors(motor):
    fmu = motor.fmu
    calls = [
        (lambda: motor.dx(), "fmi2GetDerivatives: not allowed in the instantiated state"),
        (lambda: motor.get(["omega"]), "fmi2GetReal: not allowed in the instantiated state"),
        (lambda: fmu.enterEventMode(), "fmi2EnterEventMode: not allowed in the instantiated state"),
        (lambda: fmu.exitInitializationMode(), "fmi2ExitInitializationMode: not allowed"),
        (lambda: fmu.terminate(), "fmi2Terminate: not allowed"),
        (lambda: fmu.setReal([999], [1.0]), "fmi2SetReal: unknown value reference 999"),
        (lambda: fmu.setBoolean([0], [True]), "has no Boolean variables"),
        (lambda: fmu.setDebugLogging(True, ["logEverything"]), 'unknown log category "logEverything"'),
    ]
    for call, expected in calls:
        with pytest.raises(FMICallException):
            call()
        assert expected in motor.errors()[-1], (expected, motor.errors()[-1])
    do_step = fmu.dll.fmi2DoStep
    do_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int]
    assert do_step(fmu.component, 0.0, 0.1, 1) == 3
    assert "fmi2DoStep: this is a Model-Exchange FMU; co-simulation functions are not supported" in \
        motor.errors()[-1]
    motor.initialize()
    calls = [
        (lambda: fmu.setupExperiment(startTime=0.0), "fmi2SetupExperiment: not allowed in continuous-time mode"),
        (lambda: fmu.newDiscreteStates(), "fmi2NewDiscreteStates: not allowed in continuous-time mode"),
        (lambda: motor.set({"R": 0.05}), 'parameter "R" cannot be set in continuous-time mode'),
        (lambda: motor.set({"theta": 1.0}), "(use fmi2SetContinuousStates)"),
        (lambda: motor.set({"tau_e": 1.0}), 'output "tau_e" is calculated and cannot be set'),
        (lambda: motor.set({"d_a": float("nan")}), 'input "d_a" = nan is not a finite number'),
        (lambda: motor.set_x([0.0, float("inf"), 0.0, 0.0]), 'state 1 ("i_q") = inf is not a finite number'),
        (lambda: fmu.setContinuousStates((ctypes.c_double * 3)(), 3), "nx = 3, but IPBMotor has 4"),
        (lambda: fmu.getEventIndicators((ctypes.c_double * 2)(), 2), "ni = 2, but IPBMotor has 3"),
        (lambda: fmu.getReal([motor.vr["stop_mode"]]), "is an Integer variable, not Real"),
        (lambda: fmu.fmi2GetReal(fmu.component, None, 1, None), "argument vr is NULL"),
        (lambda: fmu.fmi2GetDerivatives(fmu.component, None, 4), "argument derivatives is NULL"),
        (lambda: fmu.fmi2NewDiscreteStates(fmu.component, None), "not allowed in continuous-time mode"),
        (lambda: fmu.fmi2GetFMUstate(fmu.component, None), "argument FMUstate is NULL"),
        (lambda: fmu.fmi2SetFMUstate(fmu.component, None), "argument FMUstate is NULL"),
        (lambda: fmu.setTime(float("nan")), "fmi2SetTime: time nan is not finite"),
    ]
    for call, expected in calls:
        with pytest.raises(FMICallException):
            call()
        assert expected in motor.errors()[-1], (expected, motor.errors()[-1])
    # after all those refused calls the instance works normally
    x, u = np.array([3.0, -4.0, 2.0, 50.0]), np.array([0.7, 0.2, 0.4, 12.0, 0.3])
    motor.set_x(x)
    motor.set(dict(zip(INPUTS, u)))
    np.testing.assert_allclose(motor.dx(), reference_motor(x, u, NOMINAL)["der"], rtol=1e-12)
    fmu.terminate()
    with pytest.raises(FMICallException):
        motor.set_x(x)
    fmu.reset()  # back to the instantiated state with the start values
    motor.initialize({"R": 0.05})
    np.testing.assert_array_equal(motor.x(), [0.0, 0.0, 0.1, 0.0])
    assert motor.get(["R"])[0] == 0.05


def test_instantiate_refuses_wrong_guid_and_co_simulation(ipb_dir):
    path, unzip_dir = ipb_dir
    instance = None
    with pytest.raises(Exception, match="Failed to instantiate model"):
        instance = Instance(path, unzip_dir, guid="{00000000-0000-0000-0000-000000000000}")
    assert instance is None
    probe = Instance(path, unzip_dir)
    try:
        fmu = probe.fmu
        component = fmu.fmi2Instantiate(b"cs", 1, probe.md.guid.encode(), b"", ctypes.byref(probe.callbacks), 0, 0)
        assert component is None
        assert "supports Model Exchange only" in probe.errors()[-1]
        component = fmu.fmi2Instantiate(b"wrong", 0, b"{not-it}", b"", ctypes.byref(probe.callbacks), 0, 0)
        assert component is None
        assert 'GUID "{not-it}" does not match' in probe.errors()[-1]
        component = fmu.fmi2Instantiate(b"", 0, probe.md.guid.encode(), b"", ctypes.byref(probe.callbacks), 0, 0)
        assert component is None and "instanceName is empty" in probe.errors()[-1]
        assert fmu.fmi2Instantiate(b"x", 0, probe.md.guid.encode(), b"", None, 0, 0) is None
    finally:
        probe.close()


# ----------------------------------------------------------------------------- FMU state


def test_fmu_state_get_set_and_serialize_round_trip(motor, ipb_dir):
    motor.initialize({"theta_max": 1.0, "J": 2.5e-4})
    x_free = [4.0, 20.0, 0.7, 30.0]
    u = {"d_a": 0.7, "d_b": 0.4, "d_c": 0.3, "u_dc": 11.0, "tau_load": -0.3}
    motor.set_x(x_free)
    motor.set(u)
    motor.fmu.setTime(0.25)
    dx_free = motor.dx()
    free_state = motor.fmu.getFMUstate()
    # move into the stop (held), save that too
    motor.set_x([4.0, 20.0, 1.2, 30.0])  # i_q > 0: tau_e pushes forward
    motor.event()
    assert motor.stop_mode() == 1
    dx_held = motor.dx()
    held_state = motor.fmu.getFMUstate()
    # restore the free state: states, inputs, discrete mode and derivatives come back
    motor.fmu.setFMUstate(free_state)
    np.testing.assert_array_equal(motor.x(), x_free)
    assert motor.stop_mode() == 0
    np.testing.assert_array_equal(motor.dx(), dx_free)
    np.testing.assert_array_equal(motor.get(INPUTS), list(u.values()))
    # fmi2GetFMUstate with an existing state overwrites it
    motor.set_x([1.0, 2.0, 0.5, -3.0])
    motor.fmu.fmi2GetFMUstate(motor.fmu.component, ctypes.byref(free_state))
    motor.set_x(x_free)
    motor.fmu.setFMUstate(free_state)
    np.testing.assert_array_equal(motor.x(), [1.0, 2.0, 0.5, -3.0])
    # serialize the held state and restore it in a fresh instance
    data = motor.fmu.serializeFMUstate(held_state)
    other = Instance(*ipb_dir)
    try:
        restored = other.fmu.deSerializeFMUstate(data)
        other.fmu.setFMUstate(restored)
        assert other.stop_mode() == 1
        np.testing.assert_array_equal(other.x(), [4.0, 20.0, 1.0, 0.0])
        np.testing.assert_array_equal(other.dx(), dx_held)
        assert other.get(["J"])[0] == 2.5e-4
        other.set_x([0.0, 0.0, 1.0, 0.0])  # continuous-time mode was restored too
        # corrupt or truncated bytes are refused
        broken = bytearray(data)
        broken[3] ^= 0xFF
        with pytest.raises(FMICallException):
            other.fmu.deSerializeFMUstate(bytes(broken))
        assert "not a serialized state of IPBMotor" in other.errors()[-1]
        with pytest.raises(FMICallException):
            other.fmu.deSerializeFMUstate(data[:-8])
        assert "a serialized state of IPBMotor has" in other.errors()[-1]
        other.fmu.freeFMUstate(restored)
    finally:
        other.close()
    motor.fmu.freeFMUstate(free_state)
    motor.fmu.freeFMUstate(held_state)
    assert motor.errors() == []


def test_oscillator_fmu_state_round_trip(oscillator):
    oscillator.initialize()
    oscillator.set_x([0.3, -0.2])
    state = oscillator.fmu.getFMUstate()
    oscillator.set_x([1.0, 1.0])
    oscillator.fmu.setFMUstate(state)
    np.testing.assert_array_equal(oscillator.x(), [0.3, -0.2])
    data = oscillator.fmu.serializeFMUstate(state)
    oscillator.fmu.setFMUstate(oscillator.fmu.deSerializeFMUstate(data))
    np.testing.assert_array_equal(oscillator.x(), [0.3, -0.2])
    oscillator.fmu.freeFMUstate(state)
