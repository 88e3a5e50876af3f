"""Bad input to the FMU bridge: clear Python exceptions, never a crash.

Uses a tiny FMU built here ("Probe": a ball with height h, speed v, input acceleration a) whose
fmi2GetDerivatives returns fmi2Error with a log message when h exceeds its parameter hmax, so the
error path does not depend on the demo FMU.
"""

from __future__ import annotations

import subprocess
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
import torch

from hybridfmu.fmu import FmuError, FmuFormatError, FmuRhs, load_fmu, platform_library, simulate_open_loop

PROBE_C = r"""
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

typedef struct {
    double h, v, a, e, hmax;
    const fmi2CallbackFunctions *cb;
    char name[64];
} Probe;

#define P ((Probe *)c)

static void reset_values(Probe *p) { p->h = 1.0; p->v = 0.0; p->a = -9.81; p->e = 0.7; p->hmax = 1000.0; }

static double *slot(Probe *p, fmi2ValueReference vr) {
    switch (vr) {
    case 0: return &p->h;
    case 1: return &p->v;
    case 3: return &p->a;
    case 4: return &p->e;
    case 5: return &p->hmax;
    default: return NULL;
    }
}

fmi2Component fmi2Instantiate(fmi2String n, fmi2Type t, fmi2String g, fmi2String r,
                              const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    Probe *p = calloc(1, sizeof(Probe));
    p->cb = cb;
    strncpy(p->name, n, 63);
    reset_values(p);
    return p;
}
void fmi2FreeInstance(fmi2Component c) { free(c); }
const char *fmi2GetTypesPlatform(void) { return "default"; }
const char *fmi2GetVersion(void) { return "2.0"; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean l, size_t n, const fmi2String k[]) { return fmi2OK; }
fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean a, fmi2Real b, fmi2Real t0, fmi2Boolean d, fmi2Real e) { return fmi2OK; }
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { reset_values(P); return fmi2OK; }
fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    for (size_t i = 0; i < n; i++) {
        if (vr[i] == 6) { v[i] = P->a; continue; }
        if (vr[i] == 7) { v[i] = 0.5 * P->v * P->v - P->a * P->h; continue; }
        double *s = slot(P, vr[i]);
        if (!s) return fmi2Error;
        v[i] = *s;
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    for (size_t i = 0; i < n; i++) {
        double *s = slot(P, vr[i]);
        if (!s) return fmi2Error;
        *s = v[i];
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
    const fmi2ValueReference b[], size_t nb, const fmi2Real dv[], fmi2Real o[]) { return fmi2Error; }
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
    memset(info, 0, sizeof *info);
    if (P->h <= 0 && P->v < 0) {
        P->h = 0;
        P->v = -P->e * P->v;
        info->valuesOfContinuousStatesChanged = fmi2True;
    }
    return fmi2OK;
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean a, fmi2Boolean *e, fmi2Boolean *t) { *e = 0; *t = 0; return fmi2OK; }
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t n) { P->h = x[0]; P->v = x[1]; return fmi2OK; }
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t n) {
    if (P->h > P->hmax) {
        if (P->cb && P->cb->logger)
            P->cb->logger(P->cb->componentEnvironment, P->name, fmi2Error, "logStatusError",
                          "height h = %g m exceeds hmax = %g m", P->h, P->hmax);
        return fmi2Error;
    }
    dx[0] = P->v;
    dx[1] = P->a;
    return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t n) { z[0] = P->h; return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = P->h; x[1] = P->v; return fmi2OK; }
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t n) { x[0] = 1; x[1] = 1; return fmi2OK; }
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], const fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer o[], fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real a, fmi2Real b, fmi2Boolean d) { return fmi2Error; }
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) { return fmi2Error; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) { return fmi2Error; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) { return fmi2Error; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) { return fmi2Error; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) { return fmi2Error; }
"""

INTERFACE_ME = '<ModelExchange modelIdentifier="Probe"/>'
INTERFACE_CS = '<CoSimulation modelIdentifier="Probe"/>'


def probe_description(fmi_version: str = "2.0", interface: str = INTERFACE_ME) -> str:
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="{fmi_version}" modelName="Probe" guid="{{5b0c1d2e-0000-4000-8000-000000000001}}"
    numberOfEventIndicators="1">
  {interface}
  <ModelVariables>
    <ScalarVariable name="h" valueReference="0" causality="local" variability="continuous" initial="exact"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="der(h)" valueReference="1" causality="local" variability="continuous"><Real derivative="1"/></ScalarVariable>
    <ScalarVariable name="v" valueReference="1" causality="local" variability="continuous" initial="exact"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="der(v)" valueReference="6" causality="local" variability="continuous"><Real derivative="3"/></ScalarVariable>
    <ScalarVariable name="a" valueReference="3" causality="input" variability="continuous"><Real start="-9.81"/></ScalarVariable>
    <ScalarVariable name="e" valueReference="4" causality="parameter" variability="fixed" initial="exact"><Real start="0.7"/></ScalarVariable>
    <ScalarVariable name="hmax" valueReference="5" causality="parameter" variability="fixed" initial="exact"><Real start="1000"/></ScalarVariable>
    <ScalarVariable name="energy" valueReference="7" causality="output" variability="continuous"><Real/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="8"/></Outputs>
    <Derivatives><Unknown index="2"/><Unknown index="4"/></Derivatives>
    <InitialUnknowns><Unknown index="8"/><Unknown index="2"/><Unknown index="4"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


@pytest.fixture(scope="module")
def probe_library(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("probe")
    source = folder / "probe.c"
    source.write_text(PROBE_C)
    library = folder / "Probe.so"
    include = Path(fmpy.__file__).parent / "c-code"
    subprocess.run(["gcc", "-shared", "-fPIC", "-O1", "-I", str(include), "-o", str(library), str(source)],
                   check=True, capture_output=True)
    return library


def write_fmu(path: Path, library: Path | None, description: str | None) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        if description is not None:
            archive.writestr("modelDescription.xml", description)
        if library is not None:
            archive.write(library, "binaries/linux64/Probe.so")
    return path


@pytest.fixture(scope="module")
def probe_fmu(probe_library, tmp_path_factory) -> Path:
    return write_fmu(tmp_path_factory.mktemp("probe_fmu") / "Probe.fmu", probe_library, probe_description())


@pytest.fixture()
def probe(probe_fmu):
    model = load_fmu(probe_fmu)
    yield model
    model.close()


X_OK = np.array([[1.0, 0.5], [2.0, -1.0]])
U_OK = np.array([[-9.81], [-1.0]])


# ---------------------------------------------------------------- files


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="Missing.fmu"):
        load_fmu(tmp_path / "Missing.fmu")


def test_file_that_is_no_zip(tmp_path):
    path = tmp_path / "NotAZip.fmu"
    path.write_text("this is plain text")
    with pytest.raises(FmuFormatError, match="NotAZip.fmu.*zip"):
        load_fmu(path)


def test_zip_without_model_description(tmp_path, probe_library):
    path = write_fmu(tmp_path / "NoDescription.fmu", probe_library, None)
    with pytest.raises(FmuFormatError, match="no modelDescription.xml"):
        load_fmu(path)


def test_malformed_model_description(tmp_path, probe_library):
    path = write_fmu(tmp_path / "Broken.fmu", probe_library, "<fmiModelDescription fmiVersion='2.0'")
    with pytest.raises(FmuFormatError, match="Broken.fmu.*cannot be read"):
        load_fmu(path)


def test_not_fmi_2(tmp_path, probe_library):
    path = write_fmu(tmp_path / "Fmi1.fmu", probe_library, probe_description(fmi_version="1.0"))
    with pytest.raises(FmuFormatError, match="fmiVersion.*1.0.*expected '2.0'"):
        load_fmu(path)


def test_no_model_exchange(tmp_path, probe_library):
    path = write_fmu(tmp_path / "CoSimOnly.fmu", probe_library, probe_description(interface=INTERFACE_CS))
    with pytest.raises(FmuFormatError, match="CoSimOnly.fmu.*Model Exchange"):
        load_fmu(path)


def test_missing_binary(tmp_path):
    path = write_fmu(tmp_path / "NoBinary.fmu", None, probe_description())
    with pytest.raises(FmuFormatError, match="no binary for this platform.*Probe.so"):
        load_fmu(path)


def test_binary_only_for_other_platforms(tmp_path, probe_library):
    """An FMU built for Windows and macOS only: the error names the FMU, what it has and what is needed."""
    path = tmp_path / "ForeignOnly.fmu"
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("modelDescription.xml", probe_description())
        archive.write(probe_library, "binaries/win64/Probe.dll")
        archive.write(probe_library, "binaries/darwin64/Probe.dylib")
    with pytest.raises(FmuFormatError) as info:
        load_fmu(path)
    message = str(info.value)
    for part in (str(path), "darwin64, win64", "linux64 needs binaries/linux64/Probe.so"):
        assert part in message, message


@pytest.mark.parametrize("platform, expected", [
    ("linux64", "binaries/linux64/M.so"),
    ("darwin64", "binaries/darwin64/M.dylib"),
    ("win64", "binaries/win64/M.dll"),
])
def test_platform_library_names(platform, expected):
    assert platform_library("M", platform) == expected


def test_platform_library_of_this_platform_and_unknown_ones():
    assert platform_library("M") == f"binaries/{fmpy.platform}/M{fmpy.sharedLibraryExtension}"
    with pytest.raises(ValueError, match="platform: expected one of .*'amiga68k'"):
        platform_library("M", "amiga68k")


def test_format_errors_are_value_errors(tmp_path):
    path = tmp_path / "x.fmu"
    path.write_bytes(b"\x00\x01")
    with pytest.raises(ValueError):
        load_fmu(path)


# ---------------------------------------------------------------- names


def test_unknown_parameter_name(probe_fmu, probe):
    with pytest.raises(ValueError, match="unknown parameter 'hmx'.*'hmax'"):
        load_fmu(probe_fmu, parameters={"hmx": 3.0})
    with pytest.raises(ValueError, match="unknown parameter 'nope'"):
        probe.set_parameters({"nope": 1.0})
    with pytest.raises(ValueError, match="parameter 'e': expected a finite number"):
        probe.set_parameters({"e": float("nan")})
    with pytest.raises(ValueError, match="parameter 'e': expected a real number"):
        probe.set_parameters({"e": "0.5"})


def test_unknown_output_name(probe):
    with pytest.raises(ValueError, match="unknown variable 'energi'.*energy"):
        probe.outputs(X_OK, U_OK, ["energi"])
    with pytest.raises(ValueError, match="list of variable names"):
        probe.outputs(X_OK, U_OK, "energy")


# ---------------------------------------------------------------- arrays


@pytest.mark.parametrize(
    "x, u, pattern",
    [
        (np.ones((2, 3)), U_OK, r"x: expected shape \(N, 2\)"),
        (np.ones(2), U_OK[:1], r"x: expected shape \(N, 2\)"),
        (np.ones((2, 2, 1)), U_OK, r"x: expected shape \(N, 2\)"),
        (X_OK, np.ones((2, 2)), r"u: expected shape \(N, 1\)"),
        (X_OK, np.ones((3, 1)), "u: expected 2 rows"),
        (X_OK, None, r"u: expected an array of shape \(N, 1\)"),
        (X_OK.astype(complex), U_OK, "x: expected a real floating-point array.*complex"),
        (np.array([["a", "b"]]), U_OK[:1], "x: expected a real floating-point array"),
        (np.ones((2, 2), dtype=bool), U_OK, "x: expected a real floating-point array.*bool"),
        (np.array([[1.0, np.nan], [0.0, 0.0]]), U_OK, r"x: non-finite value nan at row 0, column 1 \('v'\)"),
        (np.array([[1.0, 0.0], [np.inf, 0.0]]), U_OK, r"x: non-finite value inf at row 1, column 0 \('h'\)"),
        (X_OK, np.array([[np.nan], [0.0]]), r"u: non-finite value nan at row 0, column 0 \('a'\)"),
    ],
)
def test_bad_arrays(probe, x, u, pattern):
    for method in (probe.derivatives, probe.jacobians, probe.event_indicators):
        with pytest.raises(ValueError, match=pattern):
            method(x, u)


@pytest.mark.parametrize(
    "t_s, pattern",
    [
        (np.zeros(3), r"t_s: expected a scalar or shape \(2,\)"),
        (np.nan, "t_s: non-finite time"),
        ("0", "t_s: expected a real time"),
        (True, "t_s: expected a time"),
    ],
)
def test_bad_time(probe, t_s, pattern):
    with pytest.raises(ValueError, match=pattern):
        probe.derivatives(X_OK, U_OK, t_s)


def test_float32_and_int_arrays_are_accepted(probe):
    x32, u32 = X_OK.astype(np.float32), U_OK.astype(np.float32)
    expected = probe.derivatives(x32.astype(np.float64), u32.astype(np.float64))
    np.testing.assert_array_equal(probe.derivatives(x32, u32), expected)
    np.testing.assert_array_equal(probe.derivatives(np.ones((2, 2), dtype=int), U_OK), probe.derivatives(np.ones((2, 2)), U_OK))
    assert probe.derivatives(np.empty((0, 2)), np.empty((0, 1))).shape == (0, 2)


def test_torch_rhs_bad_shapes(probe):
    rhs = FmuRhs(probe)
    with pytest.raises(ValueError, match=r"x: expected a floating-point tensor of shape \(\.\.\., 2\)"):
        rhs(torch.ones(3, 3), torch.ones(3, 1))
    with pytest.raises(ValueError, match=r"u: expected a floating-point tensor of shape \(3, 1\)"):
        rhs(torch.ones(3, 2), torch.ones(2, 1))
    with pytest.raises(ValueError, match="u: the FMU has inputs"):
        rhs(torch.ones(3, 2))
    with pytest.raises(ValueError, match="model: expected an FmuModel"):
        FmuRhs("Probe.fmu")


def test_simulate_bad_arguments(probe):
    t = np.linspace(0.0, 0.1, 11)
    u = np.full((11, 1), -9.81)
    with pytest.raises(ValueError, match="time_s: expected strictly increasing"):
        simulate_open_loop(probe, t[::-1], u, [1.0, 0.0])
    with pytest.raises(ValueError, match=r"u: expected 11 rows"):
        simulate_open_loop(probe, t, u[:5], [1.0, 0.0])
    with pytest.raises(ValueError, match=r"x0: expected a real array of shape \(2,\)"):
        simulate_open_loop(probe, t, u, [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"x0: non-finite value nan"):
        simulate_open_loop(probe, t, u, [np.nan, 0.0])
    with pytest.raises(ValueError, match="correction: expected a callable"):
        simulate_open_loop(probe, t, u, [1.0, 0.0], correction=3.0)


def test_correction_errors_propagate(probe):
    t = np.linspace(0.0, 0.1, 11)
    u = np.full((11, 1), -9.81)

    def broken(x, u):
        raise ZeroDivisionError("no correction today")

    with pytest.raises(ZeroDivisionError, match="no correction today"):
        simulate_open_loop(probe, t, u, [1.0, 0.0], correction=broken)
    with pytest.raises(ValueError, match=r"correction: expected an array of shape \(1, 2\)"):
        simulate_open_loop(probe, t, u, [1.0, 0.0], correction=lambda x, u: np.zeros(3))
    # the model is usable afterwards
    np.testing.assert_allclose(probe.derivatives(X_OK, U_OK), [[0.5, -9.81], [-1.0, -1.0]])


# ---------------------------------------------------------------- FMU errors


def test_fmu_error_carries_log_message(probe):
    probe.set_parameters({"hmax": 1.5})
    with pytest.raises(FmuError) as info:
        probe.derivatives(X_OK, U_OK)
    message = str(info.value)
    assert "fmi2GetDerivatives returned error at row 1" in message
    assert "height h = 2 m exceeds hmax = 1.5 m" in message
    assert info.value.log and "exceeds hmax" in info.value.log[0]
    # the failing FMU is re-initialised and usable again, the parameter kept
    np.testing.assert_allclose(probe.derivatives(X_OK[:1], U_OK[:1]), [[0.5, -9.81]])
    assert probe.get_parameters(["hmax"]) == {"hmax": 1.5}


def test_fmu_error_in_fd_jacobian_and_simulation(probe):
    probe.set_parameters({"hmax": 1.5})
    with pytest.raises(FmuError, match="jacobians.*returned error at row 1"):
        probe.jacobians(X_OK, U_OK)
    t = np.linspace(0.0, 1.0, 101)
    with pytest.raises(FmuError, match="exceeds hmax"):
        simulate_open_loop(probe, t, np.full((101, 1), 20.0), [1.0, 0.0])


def test_directional_method_refused_without_support(probe):
    probe.jacobian_method = "directional"
    with pytest.raises(ValueError, match="does not provide directional derivatives"):
        probe.jacobians(X_OK, U_OK)
    probe.jacobian_method = "adjoint"
    with pytest.raises(ValueError, match="jacobian_method: expected"):
        probe.jacobians(X_OK, U_OK)


def test_closed_model(probe_fmu):
    model = load_fmu(probe_fmu)
    model.close()
    with pytest.raises(FmuError, match="closed"):
        model.derivatives(X_OK, U_OK)
    model.close()  # closing twice is harmless
