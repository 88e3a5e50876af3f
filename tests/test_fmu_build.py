"""Building the demo FMUs: archive layout, determinism, atomic output, FMPy validation and simulation."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy.validation import validate_fmu
from scipy.integrate import solve_ivp

from hybridfmu.fmu.build import (
    FmuBuildError,
    available_models,
    build_fmu,
    compile_shared_library,
    model_source,
    source_files,
)

FMI2_ME_FUNCTIONS = """
fmi2GetTypesPlatform fmi2GetVersion fmi2SetDebugLogging fmi2Instantiate fmi2FreeInstance
fmi2SetupExperiment fmi2EnterInitializationMode fmi2ExitInitializationMode fmi2Terminate fmi2Reset
fmi2GetReal fmi2GetInteger fmi2GetBoolean fmi2GetString fmi2SetReal fmi2SetInteger fmi2SetBoolean
fmi2SetString fmi2GetFMUstate fmi2SetFMUstate fmi2FreeFMUstate fmi2SerializedFMUstateSize
fmi2SerializeFMUstate fmi2DeSerializeFMUstate fmi2GetDirectionalDerivative fmi2EnterEventMode
fmi2NewDiscreteStates fmi2EnterContinuousTimeMode fmi2CompletedIntegratorStep fmi2SetTime
fmi2SetContinuousStates fmi2GetDerivatives fmi2GetEventIndicators fmi2GetContinuousStates
fmi2GetNominalsOfContinuousStates fmi2SetRealInputDerivatives fmi2GetRealOutputDerivatives fmi2DoStep
fmi2CancelStep fmi2GetStatus fmi2GetRealStatus fmi2GetIntegerStatus fmi2GetBooleanStatus fmi2GetStringStatus
""".split()


@pytest.fixture(params=["IPBMotor", "Oscillator"])
def any_fmu(request, ipbmotor_fmu, oscillator_fmu) -> tuple[str, Path]:
    return request.param, {"IPBMotor": ipbmotor_fmu, "Oscillator": oscillator_fmu}[request.param]


def test_available_models_and_sources():
    models = available_models()
    assert set(models) == {"IPBMotor", "Oscillator", "CascadedTanks"}
    files = source_files("IPBMotor")
    assert any(f.endswith("IPBMotor.c") for f in files)
    assert any(f.endswith("fmu_core.c") for f in files)
    assert any(f.endswith("modelDescription.xml") for f in files)
    assert all(Path(f).is_file() for f in files)


def test_unknown_model_is_named_with_the_available_ones(tmp_path):
    with pytest.raises(FmuBuildError, match=r"unknown FMU model 'Nope'.*IPBMotor.*Oscillator"):
        build_fmu("Nope", tmp_path / "Nope.fmu")
    assert not (tmp_path / "Nope.fmu").exists()


def test_archive_layout(any_fmu):
    name, path = any_fmu
    with zipfile.ZipFile(path) as archive:
        infos = archive.infolist()
        names = [info.filename for info in infos]
        assert names == sorted(names) == ["binaries/linux64/" + name + ".so", "modelDescription.xml"]
        assert all(info.date_time == (1980, 1, 1, 0, 0, 0) for info in infos)
        library = archive.read(f"binaries/linux64/{name}.so")
    # no build paths in the binary
    for fragment in (str(Path.cwd()), "/tmp/", str(Path(fmpy.__file__).parent), "hybridfmu-build"):
        assert fragment.encode() not in library, fragment


def test_build_is_byte_identical_across_folders(tmp_path, ipbmotor_fmu, oscillator_fmu):
    again_ipb = build_fmu("IPBMotor", tmp_path / "first" / "IPBMotor.fmu")
    again_osc = build_fmu("Oscillator", tmp_path / "second" / "deeper" / "Oscillator.fmu")
    assert again_ipb.read_bytes() == ipbmotor_fmu.read_bytes()
    assert again_osc.read_bytes() == oscillator_fmu.read_bytes()


def test_compiles_without_warnings(tmp_path):
    for name in ("IPBMotor", "Oscillator"):
        diagnostics = compile_shared_library(model_source(name), tmp_path / f"{name}.so")
        assert diagnostics == "", diagnostics


def test_failed_build_leaves_the_destination_untouched(tmp_path, monkeypatch):
    destination = tmp_path / "IPBMotor.fmu"
    destination.write_bytes(b"previous")
    fake = tmp_path / "failing-cc"
    fake.write_text("#!/bin/sh\necho 'fatal: no compiling today' >&2\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setenv("CC", str(fake))
    with pytest.raises(FmuBuildError, match=r"IPBMotor: compiling .* failed \(exit code 3\):\nfatal: no compiling"):
        build_fmu("IPBMotor", destination)
    assert destination.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["IPBMotor.fmu", "failing-cc"]


def test_missing_compiler_is_reported(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", "no-such-compiler-here")
    with pytest.raises(FmuBuildError, match="C compiler 'no-such-compiler-here' not found"):
        build_fmu("Oscillator", tmp_path / "Oscillator.fmu")


def path_with_a_foreign_python_first(tmp_path: Path) -> dict[str, str]:
    """The environment with a folder first on PATH whose ``python`` is not this interpreter (it
    fails), as when the test environment's interpreter is not first on PATH."""
    folder = tmp_path / "foreign-bin"
    folder.mkdir()
    foreign = folder / "python"
    foreign.write_text("#!/bin/sh\necho 'not the test interpreter' >&2\nexit 97\n")
    foreign.chmod(0o755)
    return {**os.environ, "PATH": f"{folder}{os.pathsep}{os.environ.get('PATH', '')}"}


def test_command_line_builds(tmp_path):
    out = tmp_path / "cli" / "Oscillator.fmu"
    env = path_with_a_foreign_python_first(tmp_path)
    result = subprocess.run(
        [sys.executable, "-m", "hybridfmu.fmu.build", "Oscillator", str(out)], capture_output=True, text=True,
        check=False, env=env,
    )
    assert result.returncode == 0, result.stderr
    assert validate_fmu(str(out)) == []
    bad = subprocess.run(
        [sys.executable, "-m", "hybridfmu.fmu.build", "Nope", str(tmp_path / "x.fmu")], capture_output=True,
        text=True, check=False, env=env,
    )
    assert bad.returncode == 1 and "unknown FMU model 'Nope'" in bad.stderr


def test_fmpy_validation_finds_no_problems(any_fmu):
    _, path = any_fmu
    assert validate_fmu(str(path)) == []


def test_exports_the_whole_fmi2_api_and_nothing_else(any_fmu, tmp_path):
    name, path = any_fmu
    with zipfile.ZipFile(path) as archive:
        archive.extractall(tmp_path)
    library_path = tmp_path / "binaries" / "linux64" / f"{name}.so"
    library = ctypes.CDLL(str(library_path))
    missing = [function for function in FMI2_ME_FUNCTIONS if not hasattr(library, function)]
    assert missing == []
    for internal in ("model_calculate", "fmu_log", "model_variables", "model_event_update"):
        assert not hasattr(library, internal), internal
    exported = subprocess.run(["nm", "-D", "--defined-only", str(library_path)], capture_output=True, text=True,
                              check=True).stdout.split()
    assert sorted(s for s in exported if s.startswith("fmi2")) == sorted(FMI2_ME_FUNCTIONS)


def test_model_description_facts(ipbmotor_fmu, oscillator_fmu):
    ipb = fmpy.read_model_description(str(ipbmotor_fmu))
    assert ipb.fmiVersion == "2.0" and ipb.modelExchange is not None and ipb.coSimulation is None
    me = ipb.modelExchange
    assert me.providesDirectionalDerivative and me.canGetAndSetFMUstate and me.canSerializeFMUstate
    assert [d.variable.derivative.name for d in ipb.derivatives] == ["i_d", "i_q", "theta", "omega"]
    inputs = [v.name for v in ipb.modelVariables if v.causality == "input"]
    assert inputs == ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
    parameters = {v.name: float(v.start) for v in ipb.modelVariables if v.causality == "parameter"}
    assert parameters == {"p": 4.0, "R": 0.03, "L_d": 60e-6, "L_q": 60e-6, "psi": 6e-3, "J": 2e-4, "b": 2e-5,
                          "theta_min": 0.0, "theta_max": 60.0}
    assert all(v.variability == "tunable" and v.unit for v in ipb.modelVariables if v.causality == "parameter")
    outputs = [v.name for v in ipb.modelVariables if v.causality == "output"]
    assert outputs == ["tau_e", "i_a", "i_b", "i_c", "v_d", "v_q", "stop_mode"]
    assert ipb.numberOfEventIndicators == 3

    osc = fmpy.read_model_description(str(oscillator_fmu))
    assert not osc.modelExchange.providesDirectionalDerivative
    assert [d.variable.derivative.name for d in osc.derivatives] == ["x", "v"]
    assert [v for v in osc.modelVariables if v.causality == "input"] == []


# ----------------------------------------------------------------------------- simulation with FMPy


def _reference_motor_rhs(par, u_of_t):
    """NumPy right-hand side of the motor equations (free rotor), independent of the C code."""
    sqrt3 = np.sqrt(3.0)

    def rhs(t, x):
        i_d, i_q, theta, omega = x
        d = u_of_t(t)
        duty, u_dc, tau_load = d[:3], d[3], d[4]
        v_abc = u_dc * (duty - duty.mean())
        alpha = 2.0 / 3.0 * (v_abc[0] - v_abc[1] / 2 - v_abc[2] / 2)
        beta = (v_abc[1] - v_abc[2]) / sqrt3
        th = par["p"] * theta
        v_d = alpha * np.cos(th) + beta * np.sin(th)
        v_q = -alpha * np.sin(th) + beta * np.cos(th)
        tau_e = 1.5 * par["p"] * (par["psi"] * i_q + (par["L_d"] - par["L_q"]) * i_d * i_q)
        return [
            (v_d - par["R"] * i_d + par["p"] * omega * par["L_q"] * i_q) / par["L_d"],
            (v_q - par["R"] * i_q - par["p"] * omega * (par["L_d"] * i_d + par["psi"])) / par["L_q"],
            omega,
            (tau_e - par["b"] * omega - tau_load) / par["J"],
        ]

    return rhs


INPUT_NAMES = ["d_a", "d_b", "d_c", "u_dc", "tau_load"]
#: Input samples (time_s, d_a, d_b, d_c, u_dc_v, tau_load_nm): constant, then a step of every input at
#: 15 ms (a repeated time point, which FMPy treats as an input event). Piecewise constant, because
#: FMPy's CVode driver applies continuous inputs only when it evaluates the event indicators, so a
#: ramp would reach the right-hand side with a lag.
MOTOR_INPUT_ROWS = [
    (0.0, 0.65, 0.45, 0.40, 12.0, 0.05),
    (0.015, 0.65, 0.45, 0.40, 12.0, 0.05),
    (0.015, 0.30, 0.55, 0.60, 11.5, 0.20),
    (0.03, 0.30, 0.55, 0.60, 11.5, 0.20),
]


def _motor_input():
    """Structured input array for fmpy.simulate_fmu."""
    return np.array(MOTOR_INPUT_ROWS, dtype=[("time", float)] + [(n, float) for n in INPUT_NAMES])


def _motor_input_segment(first_row, second_row):
    """u(t) of the linear segment between two input rows."""
    a, b = np.array(MOTOR_INPUT_ROWS[first_row]), np.array(MOTOR_INPUT_ROWS[second_row])
    return lambda t: a[1:] + (b[1:] - a[1:]) * (t - a[0]) / (b[0] - a[0])


@pytest.mark.parametrize("solver", ["CVode", "Euler"])
def test_motor_simulates_with_fmpy_like_the_reference(ipbmotor_fmu, solver):
    # FMPy's Euler takes one step per output interval
    if solver == "CVode":
        options = {"relative_tolerance": 1e-9, "output_interval": 1e-3}
    else:
        options = {"output_interval": 2e-6, "step_size": 2e-6}
    result = fmpy.simulate_fmu(str(ipbmotor_fmu), stop_time=0.03, solver=solver,
                               start_values={"theta": 30.0, "omega": 5.0, "L_q": 70e-6}, input=_motor_input(),
                               record_events=False, output=["i_d", "i_q", "theta", "omega", "stop_mode"], **options)
    par = {"p": 4, "R": 0.03, "L_d": 60e-6, "L_q": 70e-6, "psi": 6e-3, "J": 2e-4, "b": 2e-5}
    first = result["time"] <= 0.015 + 1e-12
    reference = []
    x0 = [0.0, 0.0, 30.0, 5.0]
    for (row_a, row_b), (t0, t1), mask in (((0, 1), (0.0, 0.015), first), ((2, 3), (0.015, 0.03), ~first)):
        segment = solve_ivp(_reference_motor_rhs(par, _motor_input_segment(row_a, row_b)), (t0, t1), x0,
                            method="LSODA", dense_output=True, rtol=1e-11, atol=1e-11, max_step=2e-5)
        assert segment.success
        reference.append(segment.sol(result["time"][mask]))
        x0 = segment.y[:, -1]
    reference = np.concatenate(reference, axis=1)
    assert np.all(result["stop_mode"] == 0)
    tolerance = 1e-6 if solver == "CVode" else 2e-3  # Euler: first order, h = 2 us
    for k, name in enumerate(["i_d", "i_q", "theta", "omega"]):
        scale = np.max(np.abs(reference[k])) + 1e-3
        error = np.max(np.abs(result[name] - reference[k])) / scale
        assert error < tolerance, (name, error)
    assert np.ptp(result["omega"]) > 1.0  # the motor did move


@pytest.mark.parametrize("solver", ["CVode", "Euler"])
def test_oscillator_simulates_with_fmpy_like_the_reference(oscillator_fmu, solver):
    if solver == "CVode":
        options = {"relative_tolerance": 1e-9, "output_interval": 0.05}
    else:  # FMPy's Euler takes one step per output interval
        options = {"output_interval": 1e-4, "step_size": 1e-4}
    result = fmpy.simulate_fmu(str(oscillator_fmu), stop_time=5.0, solver=solver,
                               start_values={"mu": 0.8, "omega_0": 2.0, "x": 1.0, "v": 0.5},
                               output=["x", "v", "energy"], **options)
    mu, w = 0.8, 2.0
    reference = solve_ivp(lambda t, y: [y[1], mu * w * (1 - y[0] ** 2) * y[1] - w * w * y[0]], (0, 5.0), [1.0, 0.5],
                          t_eval=result["time"], rtol=1e-11, atol=1e-11)
    tolerance = 1e-6 if solver == "CVode" else 1e-3
    np.testing.assert_allclose(result["x"], reference.y[0], atol=tolerance * 3)
    np.testing.assert_allclose(result["v"], reference.y[1], atol=tolerance * 10)
    np.testing.assert_allclose(result["energy"], 0.5 * (result["v"] ** 2 + w * w * result["x"] ** 2), rtol=1e-12)


def test_rule_output_location_is_atomic_file(tmp_path):
    destination = tmp_path / "nested" / "dir" / "IPBMotor.fmu"
    build_fmu("IPBMotor", destination)
    assert destination.is_file() and oct(destination.stat().st_mode & 0o777) == "0o644"
    assert sorted(os.listdir(destination.parent)) == ["IPBMotor.fmu"]
