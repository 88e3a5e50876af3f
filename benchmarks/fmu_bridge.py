"""Benchmark of the batched FMU bridge against a plain FMPy per-call loop.

Measures, in one run, evaluations (rows) per second of
  (a) an FMPy loop over the rows (fmpy.fmi2.FMU2Model: setTime, setContinuousStates, setReal,
      getDerivatives per row; for the Jacobian additionally one getDirectionalDerivative per
      state and input column), and
  (b) the bridge (``FmuModel.derivatives`` / ``FmuModel.jacobians``, one call per batch),
at N = 1, 64 and 1024 rows, plus the wall time of an open-loop simulation of 25 s at 10 kHz
(250 000 RK4 steps; with IPBMotor the inputs drive the rotor into its end stops, i.e. events)
without and with a (zero) Python correction.

Works with any FMI 2.0 Model-Exchange FMU: the numbers and names of states and inputs come from
its modelDescription.xml. States and inputs are sampled around their start values, spread by
their nominal values (within their declared min/max). The FMPy loop measures Jacobians only if
the FMU provides directional derivatives.

Usage: python benchmarks/fmu_bridge.py [--fmu any.fmu] [--min-time 0.3] [--sim-duration 25] [--sim-rate 10000]
Without --fmu the IPBMotor FMU is built into a temporary folder. The last line printed is one
JSON object with the figures (``deriv_speedup_n1024``, ``jac_speedup_n1024``, ...).
"""

from __future__ import annotations

import argparse
import ctypes
import json
import tempfile
import time
from pathlib import Path

import numpy as np

BATCH_SIZES = (1, 64, 1024)


def declared_range(variable) -> tuple[float, float]:
    """(min, max) declared for an FMPy model variable (or its type); -inf/inf where none is declared."""
    bounds = []
    for attribute, default in (("min", -np.inf), ("max", np.inf)):
        value = getattr(variable, attribute, None)
        if value is None and getattr(variable, "declaredType", None) is not None:
            value = getattr(variable.declaredType, attribute, None)
        bounds.append(float(value) if value is not None else default)
    return bounds[0], bounds[1]


def spread_around_start(variables, centres: np.ndarray, nominals: np.ndarray, unit_draws: np.ndarray) -> np.ndarray:
    """Values centre + nominal * draw (draws in [-1, 1], shape (N, n)) per variable, clipped to the
    declared min/max. Returns (N, n)."""
    values = centres + nominals * unit_draws
    for j, variable in enumerate(variables):
        low, high = declared_range(variable)
        values[:, j] = np.clip(values[:, j], low, high)
    return values


def input_start_values(model) -> np.ndarray:
    """(n_u,) start values of the FMU's continuous inputs (0 where none is declared)."""
    return np.array([float(model._variables[name].start or 0.0) for name in model.input_names])


def sample_points(model, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(N, n_x) states and (N, n_u) inputs drawn uniformly within one nominal value of the
    states after initialisation and of the inputs' start values (in the FMU's units)."""
    rng = np.random.default_rng(seed)
    x = spread_around_start([model._variables[name] for name in model.state_names], model.initial_states,
                            model.state_nominals, rng.uniform(-1.0, 1.0, (n, model.n_states)))
    u = spread_around_start([model._variables[name] for name in model.input_names], input_start_values(model),
                            model.input_nominals, rng.uniform(-1.0, 1.0, (n, model.n_inputs)))
    return x, u


def rate(fn, rows: int, min_time_s: float) -> float:
    """Rows per second of ``fn()`` (which evaluates ``rows`` rows), best of repeated timings."""
    fn()  # warm up
    best = float("inf")
    total, calls = 0.0, 0
    while total < min_time_s or calls < 3:
        start = time.perf_counter()
        fn()
        elapsed = time.perf_counter() - start
        best = min(best, elapsed)
        total += elapsed
        calls += 1
    return rows / best


class FmpyLoop:
    """The plain FMPy way: one Python-level FMI call after the other, row by row."""

    def __init__(self, fmu_path: Path):
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Model

        self.description = read_model_description(str(fmu_path))
        self.unzip_dir = extract(str(fmu_path))
        self.fmu = FMU2Model(guid=self.description.guid, unzipDirectory=self.unzip_dir,
                             modelIdentifier=self.description.modelExchange.modelIdentifier,
                             instanceName="fmpy_loop")
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()
        while self.fmu.newDiscreteStates()[0]:
            pass
        self.fmu.enterContinuousTimeMode()
        derivatives = [d.variable for d in self.description.derivatives]
        self.vr_dx = [v.valueReference for v in derivatives]
        self.vr_x = [v.derivative.valueReference for v in derivatives]
        # the continuous Real inputs, in the order of the bridge's input_names
        self.vr_u = [v.valueReference for v in self.description.modelVariables
                     if v.causality == "input" and v.type == "Real" and v.variability in (None, "continuous")]
        self.provides_directional_derivative = bool(self.description.modelExchange.providesDirectionalDerivative)
        self.nx = len(self.vr_x)
        self.x_buf = np.zeros(self.nx)
        self.dx_buf = np.zeros(self.nx)
        self.x_ptr = self.x_buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        self.dx_ptr = self.dx_buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    def derivatives(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        fmu, out = self.fmu, np.empty_like(x)
        for r in range(x.shape[0]):
            fmu.setTime(0.0)
            self.x_buf[:] = x[r]
            fmu.setContinuousStates(self.x_ptr, self.nx)
            if self.vr_u:
                fmu.setReal(self.vr_u, u[r].tolist())
            fmu.getDerivatives(self.dx_ptr, self.nx)
            out[r] = self.dx_buf
        return out

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        fmu = self.fmu
        n, nx, nu = x.shape[0], self.nx, len(self.vr_u)
        dfdx, dfdu = np.empty((n, nx, nx)), np.empty((n, nx, nu))
        for r in range(n):
            fmu.setTime(0.0)
            self.x_buf[:] = x[r]
            fmu.setContinuousStates(self.x_ptr, nx)
            if self.vr_u:
                fmu.setReal(self.vr_u, u[r].tolist())
            for j, vr in enumerate(self.vr_x):
                dfdx[r, :, j] = fmu.getDirectionalDerivative(self.vr_dx, [vr], [1.0])
            for j, vr in enumerate(self.vr_u):
                dfdu[r, :, j] = fmu.getDirectionalDerivative(self.vr_dx, [vr], [1.0])
        return dfdx, dfdu

    def close(self) -> None:
        import shutil

        self.fmu.terminate()
        self.fmu.freeInstance()
        shutil.rmtree(self.unzip_dir, ignore_errors=True)


def simulation_inputs(model, duration_s: float = 25.0, rate_hz: float = 10_000.0) -> tuple[np.ndarray, np.ndarray]:
    """The sample times (T,) in s and an input history (T, n_u): each input oscillates around its
    start value by half its nominal value, at its own frequency (3 Hz, 0.2 Hz, 5 Hz, ...), within
    its declared min/max. For IPBMotor this rotates the voltage vector and drives the rotor into
    both end stops now and then."""
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    frequencies_hz = np.resize([3.0, 0.2, 5.0, 0.7, 1.3], model.n_inputs)
    phases = 2.0 * np.pi * np.arange(model.n_inputs) / max(model.n_inputs, 1)
    waves = np.sin(2.0 * np.pi * t[:, None] * frequencies_hz[None, :] + phases[None, :])
    u = spread_around_start([model._variables[name] for name in model.input_names],
                            input_start_values(model), 0.5 * model.input_nominals, waves)
    return t, u


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmu", type=Path, help="FMU to measure (default: build IPBMotor into a temporary folder)")
    parser.add_argument("--min-time", type=float, default=0.3, help="seconds of timing per measurement")
    parser.add_argument("--sim-duration", type=float, default=25.0, help="simulated time of the open-loop run, s")
    parser.add_argument("--sim-rate", type=float, default=10_000.0, help="sample rate of the open-loop run, Hz")
    args = parser.parse_args()

    from hybridfmu.fmu import load_fmu, simulate_open_loop

    with tempfile.TemporaryDirectory() as tmp:
        fmu_path = args.fmu
        if fmu_path is None:
            from hybridfmu.fmu.build import build_fmu

            fmu_path = Path(tmp) / "IPBMotor.fmu"
            build_fmu("IPBMotor", fmu_path)
        model = load_fmu(fmu_path)
        state_names, input_names = list(model.state_names), list(model.input_names)
        loop = FmpyLoop(fmu_path)
        figures: dict[str, float] = {}
        rows = []
        try:
            x_all, u_all = sample_points(model, max(BATCH_SIZES))
            directional = loop.provides_directional_derivative
            # the two paths must agree before their speeds are compared
            np.testing.assert_allclose(model.derivatives(x_all[:64], u_all[:64]),
                                       loop.derivatives(x_all[:64], u_all[:64]), rtol=1e-12, atol=1e-9)
            if directional:
                for a, b in zip(model.jacobians(x_all[:16], u_all[:16]), loop.jacobians(x_all[:16], u_all[:16])):
                    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9)
            for n in BATCH_SIZES:
                x, u = x_all[:n], u_all[:n]
                measured = {
                    "deriv_fmpy": rate(lambda: loop.derivatives(x, u), n, args.min_time),
                    "deriv_bridge": rate(lambda: model.derivatives(x, u), n, args.min_time),
                    "jac_fmpy": rate(lambda: loop.jacobians(x, u), n, args.min_time) if directional else None,
                    "jac_bridge": rate(lambda: model.jacobians(x, u), n, args.min_time),
                }
                model.jacobian_method = "fd"
                measured["jac_fd_bridge"] = rate(lambda: model.jacobians(x, u), n, args.min_time)
                model.jacobian_method = "auto"
                for key, value in measured.items():
                    if value is not None:
                        figures[f"{key}_evals_per_s_n{n}"] = round(value, 1)
                figures[f"deriv_speedup_n{n}"] = round(measured["deriv_bridge"] / measured["deriv_fmpy"], 2)
                if directional:
                    figures[f"jac_speedup_n{n}"] = round(measured["jac_bridge"] / measured["jac_fmpy"], 2)
                rows.append((n, measured))

            t, u_sim = simulation_inputs(model, args.sim_duration, args.sim_rate)
            x0 = model.initial_states.copy()
            start = time.perf_counter()
            result = simulate_open_loop(model, t, u_sim, x0)
            figures["sim_s"] = round(time.perf_counter() - start, 3)
            figures["sim_events"] = len(result.events)
            figures["sim_steps"] = int(t.size - 1)
            zero = np.zeros((1, model.n_states))
            start = time.perf_counter()
            result_c = simulate_open_loop(model, t, u_sim, x0, correction=lambda x, u: zero)
            figures["sim_with_correction_s"] = round(time.perf_counter() - start, 3)
            if not np.array_equal(result.states, result_c.states):
                raise RuntimeError("a zero correction changed the simulation")
        finally:
            loop.close()
            model.close()

    print(f"FMU: {fmu_path.name}: states {state_names}, inputs {input_names}  "
          "(evaluations = rows per second; speedup = bridge / FMPy loop)")
    print(f"{'N':>6} | {'deriv FMPy':>12} {'deriv bridge':>13} {'speedup':>8} | "
          f"{'jac FMPy':>10} {'jac bridge':>11} {'speedup':>8} | {'jac FD bridge':>13}")
    for n, m in rows:
        jac_fmpy = f"{m['jac_fmpy']:>10.0f}" if m["jac_fmpy"] else f"{'n/a':>10}"
        jac_speedup = f"{m['jac_bridge'] / m['jac_fmpy']:>8.1f}" if m["jac_fmpy"] else f"{'n/a':>8}"
        print(f"{n:>6} | {m['deriv_fmpy']:>12.0f} {m['deriv_bridge']:>13.0f} "
              f"{m['deriv_bridge'] / m['deriv_fmpy']:>8.1f} | {jac_fmpy} {m['jac_bridge']:>11.0f} "
              f"{jac_speedup} | {m['jac_fd_bridge']:>13.0f}")
    print(f"open-loop simulation, {args.sim_duration:g} s at {args.sim_rate:g} Hz ({figures['sim_steps']} RK4 steps, "
          f"{figures['sim_events']} events): {figures['sim_s']:.3f} s; with a Python correction: "
          f"{figures['sim_with_correction_s']:.3f} s")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
