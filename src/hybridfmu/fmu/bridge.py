"""Batched access to any FMI 2.0 Model-Exchange FMU.

``load_fmu(path)`` reads and checks the FMU's modelDescription.xml (with FMPy), extracts the
archive into a private temporary folder, loads the shared library, instantiates and initialises
the model. The returned :class:`FmuModel` evaluates the right-hand side, its Jacobians, the
event indicators and any Real variable for a whole batch of points in one call: the batch loop
runs in a small compiled C shim (``shim.c``), which calls the FMU's functions directly.

Every argument is checked in Python before any C code runs; a bad argument raises ``ValueError``
naming the argument and what was expected, a bad file ``FileNotFoundError`` or
:class:`FmuFormatError` (also for an FMU without a binary for this platform: see
:func:`platform_library`), and an FMU function that fails raises :class:`FmuError` with the
messages the FMU logged. Non-finite state derivatives raise :class:`FmuNonFiniteError` naming the
derivative, its state and the time; an FMU that asks to terminate raises :class:`FmuTerminated`.

Thread safety: an ``FmuModel`` owns one FMU instance with mutable state (time, states, inputs)
and is NOT thread-safe; use one ``FmuModel`` per thread or process (each ``load_fmu`` call
extracts and loads its own copy of the shared library, so instances do not share globals).
"""

from __future__ import annotations

import ctypes
import math
import numbers
import os
import shutil
import tempfile
import weakref
import zipfile
from ctypes import c_double, c_void_p
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from hybridfmu.fmu import shim as _shim

LOG_CAPACITY_CHARS = 1 << 16
MAX_LOG_LINES_IN_MESSAGE = 20
# Central differences: the step that balances truncation (h^2) and round-off (eps/h) errors.
DEFAULT_FD_RELATIVE_STEP = float(np.finfo(np.float64).eps ** (1.0 / 3.0))
_STATUS_LABELS = {0: "ok", 1: "warning", 2: "discard", 3: "error", 4: "fatal", 5: "pending"}
#: File extension of the shared library in each FMI 2.0 platform folder ``binaries/<platform>/``.
PLATFORM_LIBRARY_EXTENSIONS = {
    "linux64": ".so", "linux32": ".so", "darwin64": ".dylib", "win64": ".dll", "win32": ".dll",
}
MAX_EVENT_ITERATIONS = 1000


class FmuError(RuntimeError):
    """An FMU function failed, or the FMU cannot be used; carries the FMU's log messages."""

    def __init__(self, message: str, log: Sequence[str] = ()):
        self.log = list(log)
        if self.log:
            shown = self.log[-MAX_LOG_LINES_IN_MESSAGE:]
            skipped = len(self.log) - len(shown)
            message += "\nFMU log" + (f" (last {len(shown)} of {len(self.log)} lines)" if skipped else "") + ":\n  "
            message += "\n  ".join(shown)
        super().__init__(message)


class FmuFormatError(FmuError, ValueError):
    """The file is not a usable FMI 2.0 Model-Exchange FMU (not a zip, wrong version, ...)."""


class FmuNonFiniteError(FmuError, FloatingPointError):
    """The FMU returned a non-finite (NaN or infinite) state derivative.

    Also a FloatingPointError, so callers that treat a diverging simulation as such keep doing so.
    Attributes: ``states`` (the names of the states whose derivatives are not finite) and
    ``time_s`` (the time of the evaluation, s).
    """

    def __init__(self, message: str, log: Sequence[str] = (), *, states: Sequence[str] = (), time_s: float = math.nan):
        super().__init__(message, log)
        self.states = list(states)
        self.time_s = float(time_s)


class FmuTerminated(FmuError):
    """The FMU asked to end the simulation (terminateSimulation) before the requested horizon.

    Attributes: ``path`` (the FMU file), ``time_s`` (when it asked, s), ``reason`` (which FMI
    function asked, and where) and ``result``: the partial result up to ``time_s`` when the
    request came during ``simulate_open_loop`` (else None).
    """

    def __init__(self, message: str, log: Sequence[str] = (), *, path: Path, time_s: float, reason: str,
                 result=None):
        super().__init__(message, log)
        self.path = path
        self.time_s = float(time_s)
        self.reason = reason
        self.result = result


@dataclass(frozen=True)
class EventUpdate:
    """Outcome of one event iteration (fmi2NewDiscreteStates until no new discrete states).

    next_time_event_s: the FMU's next time event in s (inf if it announced none);
    states_changed: the FMU changed the values of the continuous states;
    terminate: the FMU asked to end the simulation (terminateSimulation).
    """

    next_time_event_s: float
    states_changed: bool
    terminate: bool


def platform_library(identifier: str, platform: str | None = None) -> str:
    """Path inside an FMU of the shared library of model ``identifier`` for ``platform``.

    platform: an FMI 2.0 platform folder name (``linux64``, ``darwin64``, ``win64``, ...); default:
    the platform this Python runs on. Returns e.g. ``binaries/linux64/<identifier>.so``,
    ``binaries/darwin64/<identifier>.dylib`` or ``binaries/win64/<identifier>.dll``.
    """
    platform = platform or _library_platform()
    extension = PLATFORM_LIBRARY_EXTENSIONS.get(platform)
    if extension is None:
        raise ValueError(f"platform: expected one of {sorted(PLATFORM_LIBRARY_EXTENSIONS)}, got {platform!r}")
    return f"binaries/{platform}/{identifier}{extension}"


def binary_platforms(unzip_dir: str | os.PathLike, identifier: str) -> list[str]:
    """The platform folders under ``binaries/`` of an extracted FMU that hold a library of ``identifier``
    (any file named ``<identifier>.*``), sorted."""
    binaries = Path(unzip_dir, "binaries")
    if not binaries.is_dir():
        return []
    return sorted(folder.name for folder in binaries.iterdir()
                  if folder.is_dir() and any(folder.glob(f"{identifier}.*")))


def load_fmu(
    path: str | os.PathLike,
    parameters: Mapping[str, float] | None = None,
    *,
    instance_name: str | None = None,
    logging_on: bool = False,
) -> "FmuModel":
    """Load an FMI 2.0 Model-Exchange FMU and initialise it.

    path: the ``.fmu`` file (or a folder holding an extracted FMU).
    parameters: values for parameters (by FMU variable name, SI units as the FMU declares them),
      set before initialisation.
    instance_name: name of the FMU instance (default: the model identifier).
    logging_on: ask the FMU for debug logging (its messages are collected either way).
    """
    return FmuModel(path, parameters=parameters, instance_name=instance_name, logging_on=logging_on)


def _read_description(path: Path):
    """Read and check modelDescription.xml; return FMPy's ModelDescription."""
    import fmpy

    if not path.exists():
        raise FileNotFoundError(f"{path}: FMU file does not exist")
    if path.is_dir():
        if not (path / "modelDescription.xml").is_file():
            raise FmuFormatError(f"{path}: folder has no modelDescription.xml (expected an extracted FMU)")
    else:
        if not zipfile.is_zipfile(path):
            raise FmuFormatError(f"{path}: not an FMU (expected a zip archive holding modelDescription.xml)")
        with zipfile.ZipFile(path) as archive:
            if "modelDescription.xml" not in archive.namelist():
                raise FmuFormatError(f"{path}: zip archive has no modelDescription.xml (expected an FMU)")
    root = _description_root(path)
    version = root.get("fmiVersion")
    if version != "2.0":
        raise FmuFormatError(f"{path}: fmiVersion is {version!r}, expected '2.0' (FMI 2.0 Model Exchange)")
    _check_state_declarations(path, root)
    try:
        description = fmpy.read_model_description(str(path), validate=False)
    except Exception as err:  # FMPy raises plain exceptions for malformed descriptions
        raise FmuFormatError(f"{path}: modelDescription.xml cannot be read: {err}") from None
    if description.modelExchange is None:
        raise FmuFormatError(
            f"{path}: the FMU does not support Model Exchange (expected a <ModelExchange> element; "
            "Co-Simulation-only FMUs cannot be used)"
        )
    return description


def _fmi_version(path: Path) -> str | None:
    """The fmiVersion attribute of modelDescription.xml (read before FMPy parses the rest)."""
    return _description_root(path).get("fmiVersion")


def _description_root(path: Path):
    """The root element of modelDescription.xml of the FMU file or folder ``path``."""
    from xml.etree import ElementTree

    try:
        if path.is_dir():
            root = ElementTree.parse(path / "modelDescription.xml").getroot()
        else:
            with zipfile.ZipFile(path) as archive, archive.open("modelDescription.xml") as stream:
                root = ElementTree.parse(stream).getroot()
    except ElementTree.ParseError as err:
        raise FmuFormatError(f"{path}: modelDescription.xml cannot be read: {err}") from None
    if root.tag != "fmiModelDescription":
        raise FmuFormatError(f"{path}: modelDescription.xml has root <{root.tag}>, expected <fmiModelDescription>")
    return root


def _variable_index(text: str | None) -> int | None:
    """A 1-based ScalarVariable index written in the XML, or None if it is not an integer."""
    try:
        return int(text)
    except (TypeError, ValueError):
        return None


def _check_state_declarations(path: Path, root) -> None:
    """Every state derivative names an existing Real state (its 'derivative' attribute), and every
    <Derivatives> entry of <ModelStructure> is such a derivative; FmuFormatError naming the
    variable otherwise (checked before FMPy, whose own errors do not name it)."""
    variables = root.findall("ModelVariables/ScalarVariable")

    def fail(problem: str) -> FmuFormatError:
        return FmuFormatError(f"{path}: modelDescription.xml: {problem}")

    for variable in variables:
        real = variable.find("Real")
        if real is None or real.get("derivative") is None:
            continue
        name, text = variable.get("name"), real.get("derivative")
        index = _variable_index(text)
        if index is None or not 1 <= index <= len(variables):
            raise fail(f"derivative variable {name!r} declares derivative=\"{text}\", but there is no "
                       f"ScalarVariable {text} (expected the 1-based index of its state, 1..{len(variables)})")
        if variables[index - 1].find("Real") is None:
            raise fail(f"derivative variable {name!r} declares derivative=\"{text}\", but ScalarVariable {index} "
                       f"({variables[index - 1].get('name')!r}) is not a Real state")
    for unknown in root.findall("ModelStructure/Derivatives/Unknown"):
        text = unknown.get("index")
        index = _variable_index(text)
        if index is None or not 1 <= index <= len(variables):
            raise fail(f"ModelStructure/Derivatives lists Unknown index=\"{text}\", but there is no such "
                       f"ScalarVariable (expected 1..{len(variables)})")


def _library_platform() -> str:
    from fmpy import platform

    return platform


def _nominal(variable) -> float:
    """Positive nominal value of a variable (1.0 if none is declared)."""
    for source in (variable, getattr(variable, "declaredType", None)):
        value = getattr(source, "nominal", None) if source is not None else None
        if value is not None:
            try:
                nominal = abs(float(value))
            except ValueError:
                continue
            if np.isfinite(nominal) and nominal > 0:
                return nominal
    return 1.0


def _cleanup(fmu, component_holder, log_pointer, lib, unzip_dir, owns_unzip_dir) -> None:
    """Free the instance, unload the library and remove the extracted files (idempotent)."""
    component = component_holder.pop("component", None)
    if fmu is not None:
        if component:
            try:
                fmu.fmi2FreeInstance(component)
            except Exception:
                pass
        try:
            fmu.freeLibrary()
        except Exception:
            pass
    if log_pointer.get("log"):
        lib.hf_log_free(log_pointer.pop("log"))
    if owns_unzip_dir and unzip_dir and os.path.isdir(unzip_dir):
        shutil.rmtree(unzip_dir, ignore_errors=True)


def _concatenated(programs) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Effect programs side by side for one C call: (codes, code starts (K + 1,), reals, real starts (K + 1,))."""
    codes = np.concatenate([p.code for p in programs]) if programs else np.zeros(1, dtype=np.int64)
    reals = np.concatenate([p.reals for p in programs]) if programs else np.zeros(1)
    code_start = np.cumsum([0] + [p.code.size for p in programs]).astype(np.uintp)
    real_start = np.cumsum([0] + [p.reals.size for p in programs]).astype(np.uintp)
    return codes, code_start, reals, real_start


class FmuModel:
    """One instance of an FMI 2.0 Model-Exchange FMU with batched evaluation (see module doc).

    Attributes (not to be modified): ``path``, ``model_name``, ``state_names`` (continuous
    states in the order of the FMU's state vector), ``derivative_names``, ``input_names``
    (continuous Real inputs), ``output_names`` (all outputs), ``real_output_names`` (the Real
    ones), ``parameter_names``, ``n_states``, ``n_inputs``, ``n_outputs``,
    ``n_event_indicators``, ``provides_directional_derivative``, ``state_nominals`` (n_x,),
    ``input_nominals`` (n_u,), ``initial_states`` (n_x,): the states after initialisation.

    ``jacobian_method`` ("auto", "directional" or "fd") chooses how :meth:`jacobians` works;
    "auto" uses fmi2GetDirectionalDerivative when the FMU provides it, else central finite
    differences with relative step ``fd_relative_step``.

    Not thread-safe: one instance per thread/process.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        parameters: Mapping[str, float] | None = None,
        *,
        instance_name: str | None = None,
        logging_on: bool = False,
    ):
        from fmpy import extract
        from fmpy.fmi2 import FMU2Model, fmi2CallbackFunctions

        self.path = Path(path)
        description = _read_description(self.path)
        self._description = description
        self.model_name = description.modelName
        me = description.modelExchange
        self._identifier = me.modelIdentifier
        self.provides_directional_derivative = bool(me.providesDirectionalDerivative)
        self._collect_variables(description)

        self._lib = _shim.load_shim()
        self._logging_on = bool(logging_on)
        self._closed = False
        self._component_holder: dict = {}
        self._log_holder: dict = {}
        self._fmu = None
        owns_dir = not self.path.is_dir()
        unzip_dir = tempfile.mkdtemp(prefix=f"hybridfmu-{self._identifier}-") if owns_dir else str(self.path)
        # Registered before anything that can fail, so a failed load leaves nothing behind.
        self._finalizer = weakref.finalize(
            self, _cleanup, None, self._component_holder, self._log_holder, self._lib, unzip_dir, owns_dir
        )
        try:
            if owns_dir:
                try:
                    extract(str(self.path), unzipdir=unzip_dir)
                except Exception as err:
                    raise FmuFormatError(f"{self.path}: cannot extract the FMU archive: {err}") from None
            self._unzip_dir = unzip_dir
            library = self._platform_library_file(unzip_dir)
            try:
                self._fmu = FMU2Model(
                    guid=description.guid, unzipDirectory=unzip_dir, modelIdentifier=self._identifier,
                    instanceName=instance_name,
                )
            except Exception as err:
                raise FmuFormatError(f"{self.path}: cannot load the shared library {library.name}: {err}") from None
            self._finalizer.detach()
            self._finalizer = weakref.finalize(
                self, _cleanup, self._fmu, self._component_holder, self._log_holder, self._lib, unzip_dir,
                owns_dir,
            )
            log = self._lib.hf_log_new(LOG_CAPACITY_CHARS)
            if not log:
                raise MemoryError("cannot allocate the FMU log buffer")
            self._log_holder["log"] = log
            callbacks = fmi2CallbackFunctions()
            callbacks.logger = type(callbacks.logger)(_shim.function_address(self._lib, "hf_logger"))
            callbacks.allocateMemory = type(callbacks.allocateMemory)(
                _shim.function_address(self._lib, "hf_allocate"))
            callbacks.freeMemory = type(callbacks.freeMemory)(_shim.function_address(self._lib, "hf_free"))
            callbacks.componentEnvironment = log
            self._callbacks = callbacks
            self._setup_shim_model()
            self.jacobian_method = "auto"
            self.fd_relative_step = DEFAULT_FD_RELATIVE_STEP
            self._parameter_values: dict[str, float] = {}
            if parameters:
                self._parameter_values.update(self._checked_parameters(parameters))
            self._initialise()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ description

    def _platform_library_file(self, unzip_dir: str) -> Path:
        """The FMU's shared library for this platform in the extracted folder; FmuFormatError naming
        the FMU, the platform needed and the platforms the FMU has if there is none."""
        platform = _library_platform()
        relative = platform_library(self._identifier, platform)
        library = Path(unzip_dir, relative)
        if not library.is_file():
            available = binary_platforms(unzip_dir, self._identifier)
            raise FmuFormatError(
                f"{self.path}: no binary for this platform: {platform} needs {relative}; the FMU contains "
                f"binaries for {', '.join(available) if available else 'no platform'}"
            )
        return library

    def _collect_variables(self, description) -> None:
        path = self.path
        variables = description.modelVariables
        self._variables = {v.name: v for v in variables}
        states, derivatives = [], []
        for unknown in description.derivatives:
            der = unknown.variable
            state = der.derivative
            if state is None:
                raise FmuFormatError(
                    f"{path}: derivative variable {der.name!r} names no state (missing 'derivative' attribute)"
                )
            states.append(state)
            derivatives.append(der)
        if description.numberOfContinuousStates not in (0, None) and len(states) != description.numberOfContinuousStates:
            raise FmuFormatError(
                f"{path}: ModelStructure lists {len(states)} derivatives but "
                f"numberOfContinuousStates is {description.numberOfContinuousStates}"
            )
        self._state_vars, self._derivative_vars = states, derivatives
        self.state_names = [v.name for v in states]
        self.derivative_names = [v.name for v in derivatives]
        self._input_vars = [
            v for v in variables
            if v.causality == "input" and v.type == "Real" and v.variability in (None, "continuous")
        ]
        self.input_names = [v.name for v in self._input_vars]
        self.output_names = [v.name for v in variables if v.causality == "output"]
        self.real_output_names = [v.name for v in variables if v.causality == "output" and v.type == "Real"]
        self._parameter_vars = {v.name: v for v in variables if v.causality == "parameter"}
        self.parameter_names = list(self._parameter_vars)
        self.n_states = len(states)
        self.n_inputs = len(self._input_vars)
        self.n_outputs = len(self.output_names)
        self.n_event_indicators = int(description.numberOfEventIndicators or 0)
        self.state_nominals = np.array([_nominal(v) for v in states], dtype=np.float64)
        self.input_nominals = np.array([_nominal(v) for v in self._input_vars], dtype=np.float64)
        self._vr_x = np.array([v.valueReference for v in states], dtype=np.uint32)
        self._vr_dx = np.array([v.valueReference for v in derivatives], dtype=np.uint32)
        self._vr_u = np.array([v.valueReference for v in self._input_vars], dtype=np.uint32)

    def _setup_shim_model(self) -> None:
        """Fill the C record with the FMU's function addresses, sizes and value references."""
        dll = self._fmu.dll

        def address(name: str) -> int:
            try:
                return ctypes.cast(getattr(dll, name), c_void_p).value
            except AttributeError:
                raise FmuFormatError(f"{self.path}: the shared library does not export {name}") from None

        m = _shim.ShimModel()
        m.set_time = address("fmi2SetTime")
        m.set_states = address("fmi2SetContinuousStates")
        m.set_real = address("fmi2SetReal")
        m.get_real = address("fmi2GetReal")
        m.get_derivatives = address("fmi2GetDerivatives")
        m.get_event_indicators = address("fmi2GetEventIndicators")
        m.get_directional_derivative = (
            address("fmi2GetDirectionalDerivative") if self.provides_directional_derivative else None
        )
        m.completed_integrator_step = address("fmi2CompletedIntegratorStep")
        m.enter_event_mode = address("fmi2EnterEventMode")
        m.new_discrete_states = address("fmi2NewDiscreteStates")
        m.enter_continuous_time_mode = address("fmi2EnterContinuousTimeMode")
        m.get_continuous_states = address("fmi2GetContinuousStates")
        m.nx, m.nu, m.nz = self.n_states, self.n_inputs, self.n_event_indicators
        m.vr_u = self._vr_u.ctypes.data_as(ctypes.POINTER(ctypes.c_uint))
        m.vr_x = self._vr_x.ctypes.data_as(ctypes.POINTER(ctypes.c_uint))
        m.vr_dx = self._vr_dx.ctypes.data_as(ctypes.POINTER(ctypes.c_uint))
        self._shim_model = m
        self._m = ctypes.addressof(m)
        self._column = np.empty(max(self.n_states, 1))
        self._t_scalar = np.zeros(1)
        self._t_scalar_address = self._t_scalar.ctypes.data
        self._empty = np.empty(1)

    # ------------------------------------------------------------------ life cycle

    def close(self) -> None:
        """Free the FMU instance, unload its library and delete the extracted files."""
        self._closed = True
        if getattr(self, "_finalizer", None) is not None:
            self._finalizer()

    def __enter__(self) -> "FmuModel":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"FmuModel({str(self.path)!r}, states={self.state_names}, inputs={self.input_names}, "
                f"event_indicators={self.n_event_indicators})")

    def _require_open(self) -> None:
        if self._closed:
            raise FmuError(f"{self.path}: the model was closed")
        if self._needs_reinit:
            self._initialise()

    def _fmi(self, name: str, *args):
        """Call an FMI function through FMPy; a failing status raises FmuError with the log."""
        try:
            return getattr(self._fmu, name)(*args)
        except Exception as err:
            self._needs_reinit = True
            raise FmuError(f"{self.path}: {name} failed: {err}", self.log_messages()) from None

    def _initialise(self, start_time_s: float = 0.0, start_values: Mapping[str, float] | None = None) -> None:
        """(Re)instantiate or reset, apply parameters and start values, initialise, and enter
        continuous-time mode."""
        from fmpy.fmi2 import fmi2ModelExchange

        self._needs_reinit = True
        component = self._component_holder.get("component")
        if component is not None:
            try:
                self._fmu.fmi2Reset(component)
            except Exception:  # a failed reset: start over with a new instance
                self._component_holder.pop("component", None)
                try:
                    self._fmu.fmi2FreeInstance(component)
                except Exception:
                    pass
                component = None
        if component is None:
            self._fmu.callbacks = self._callbacks
            resource_uri = Path(self._unzip_dir, "resources").as_uri()
            component = self._fmu.fmi2Instantiate(
                self._fmu.instanceName.encode(), fmi2ModelExchange, self._description.guid.encode(),
                resource_uri.encode(), ctypes.byref(self._callbacks), 0, 1 if self._logging_on else 0,
            )
            if not component:
                raise FmuError(f"{self.path}: fmi2Instantiate failed", self.log_messages())
            self._component_holder["component"] = component
        self._fmu.component = component
        self._shim_model.component = component
        for name, value in self._parameter_values.items():
            self._set_start_value(name, value)
        for name, value in (start_values or {}).items():
            self._set_start_value(name, value)
        self._fmi("setupExperiment", None, float(start_time_s), None)
        self._fmi("enterInitializationMode")
        self._fmi("exitInitializationMode")
        update = self._event_iteration(float(start_time_s))
        if update.terminate:
            raise self._terminated(float(start_time_s), "fmi2NewDiscreteStates during initialisation")
        self._next_time_event_s = update.next_time_event_s
        self._fmi("enterContinuousTimeMode")
        x = np.empty(self.n_states)
        if self.n_states:
            self._fmi("getContinuousStates", x.ctypes.data_as(ctypes.POINTER(c_double)), self.n_states)
        self.initial_states = x
        self._needs_reinit = False

    def _event_iteration(self, time_s: float) -> EventUpdate:
        """fmi2NewDiscreteStates (in event mode, at time_s in s) until the FMU needs no more
        iterations or asks to terminate; a terminate request leaves the model to be re-initialised."""
        values_changed = False
        for _ in range(MAX_EVENT_ITERATIONS):
            (needed, terminate, _nominals_changed, changed,
             next_defined, next_time) = self._fmi("newDiscreteStates")
            values_changed = values_changed or bool(changed)
            if terminate or not needed:
                if terminate:
                    self._needs_reinit = True
                next_time_s = float(next_time) if next_defined and not terminate else float("inf")
                return EventUpdate(next_time_s, values_changed, bool(terminate))
        raise FmuError(f"{self.path}: event iteration at t = {time_s} s did not converge in "
                       f"{MAX_EVENT_ITERATIONS} iterations (newDiscreteStatesNeeded stayed true)",
                       self.log_messages())

    def _terminated(self, time_s: float, reason: str, result=None) -> FmuTerminated:
        """The error for a terminateSimulation request of the FMU at time_s (s) from ``reason``."""
        self._needs_reinit = True
        return FmuTerminated(
            f"{self.path}: the FMU asked to terminate the simulation (terminateSimulation from {reason}) "
            f"at t = {time_s} s",
            self.log_messages(), path=self.path, time_s=time_s, reason=reason, result=result,
        )

    def _set_start_value(self, name: str, value) -> None:
        variable = self._variables[name]
        vr = [variable.valueReference]
        if variable.type == "Real":
            self._fmi("setReal", vr, [float(value)])
        elif variable.type in ("Integer", "Enumeration"):
            self._fmi("setInteger", vr, [int(value)])
        elif variable.type == "Boolean":
            self._fmi("setBoolean", vr, [bool(value)])
        else:
            raise ValueError(f"{self.path}: variable {name!r} has type {variable.type}; only numbers can be set")

    # ------------------------------------------------------------------ parameters

    def _checked_parameters(self, parameters: Mapping[str, float]) -> dict:
        if not isinstance(parameters, Mapping):
            raise ValueError(f"parameters: expected a mapping name -> value, got {type(parameters).__name__}")
        checked = {}
        for name, value in parameters.items():
            if name not in self._parameter_vars:
                raise ValueError(
                    f"{self.path}: unknown parameter {name!r} (expected one of {self.parameter_names})"
                )
            variable = self._parameter_vars[name]
            if isinstance(value, (bool, np.bool_)) and variable.type != "Boolean":
                raise ValueError(f"parameter {name!r}: expected a number, got {value!r}")
            if not isinstance(value, (numbers.Real, np.number)) or isinstance(value, complex):
                raise ValueError(f"parameter {name!r}: expected a real number, got {value!r}")
            value = float(value)
            if not np.isfinite(value):
                raise ValueError(f"parameter {name!r}: expected a finite number, got {value}")
            if variable.type in ("Integer", "Enumeration") and value != int(value):
                raise ValueError(f"parameter {name!r}: the FMU declares an Integer, got {value}")
            if variable.type == "String":
                raise ValueError(f"parameter {name!r}: String parameters are not supported")
            checked[name] = value
        return checked

    def set_parameters(self, parameters: Mapping[str, float]) -> None:
        """Set parameter values (by FMU name) and re-initialise the FMU with them.

        The values persist over later re-initialisations (e.g. by ``simulate_open_loop``).
        """
        checked = self._checked_parameters(parameters)
        if self._closed:
            raise FmuError(f"{self.path}: the model was closed")
        previous = dict(self._parameter_values)
        self._parameter_values.update(checked)
        try:
            self._initialise()
        except FmuError:
            self._parameter_values = previous
            self._needs_reinit = True
            raise

    def get_parameters(self, names: Iterable[str] | None = None) -> dict[str, float]:
        """Current values of parameters (all by default) as floats."""
        self._require_open()
        names = list(self.parameter_names if names is None else names)
        values = {}
        for name in names:
            if name not in self._parameter_vars:
                raise ValueError(f"{self.path}: unknown parameter {name!r} (expected one of {self.parameter_names})")
            variable = self._parameter_vars[name]
            vr = [variable.valueReference]
            if variable.type == "Real":
                values[name] = float(self._fmi("getReal", vr)[0])
            elif variable.type in ("Integer", "Enumeration"):
                values[name] = float(self._fmi("getInteger", vr)[0])
            elif variable.type == "Boolean":
                values[name] = float(bool(self._fmi("getBoolean", vr)[0]))
        return values

    # ------------------------------------------------------------------ logging and errors

    def log_messages(self) -> list[str]:
        """The messages the FMU logged since the last call (the buffer is cleared)."""
        log = self._log_holder.get("log")
        if not log:
            return []
        buffer = ctypes.create_string_buffer(LOG_CAPACITY_CHARS + 1)
        self._lib.hf_log_take(log, buffer, len(buffer))
        text = buffer.value.decode("utf-8", errors="replace")
        return [line for line in text.splitlines() if line]

    def _raise_shim_error(self, status: int, what: str, row_label: str = "row",
                          derivatives: np.ndarray | None = None, states: np.ndarray | None = None) -> None:
        """Raise the error for a failed shim call. derivatives, states: the (N, n_x) arrays of a
        batch call, to name every non-finite derivative of the failing row and its states."""
        m = self._shim_model
        function = _shim.FUNCTION_NAMES.get(m.failed_function, f"function #{m.failed_function}")
        where = f" at {row_label} {m.failed_row}" if m.failed_row >= 0 else ""
        if status == _shim.ERR_NOT_FINITE:
            message, names = self._non_finite_message(what, where, derivatives, states)
            raise FmuNonFiniteError(message, self.log_messages(), states=names, time_s=m.failed_time)
        if status == _shim.ERR_NO_MEMORY:
            raise MemoryError(f"{self.path}: {what}: out of memory in the FMU shim")
        if status > 2:
            self._needs_reinit = True
        label = _STATUS_LABELS.get(status, str(status))
        raise FmuError(f"{self.path}: {what}: {function} returned {label}{where}", self.log_messages())

    def _non_finite_message(self, what: str, where: str, derivatives: np.ndarray | None,
                            states: np.ndarray | None) -> tuple[str, list[str]]:
        """Message naming the non-finite derivative(s) (and their states), the time and the FMU;
        and the names of those states."""
        m = self._shim_model
        row = m.failed_row
        if derivatives is not None and 0 <= row < len(derivatives):
            columns = np.flatnonzero(~np.isfinite(derivatives[row])).tolist() or [int(m.failed_index)]
            values = [f"{self.derivative_names[j]} = {derivatives[row, j]}" for j in columns]
        else:
            columns = [int(m.failed_index)]
            values = [f"{self.derivative_names[columns[0]]} = {m.failed_value}"]
        named = ", ".join(f"{value} (state {self.state_names[j]!r})" for value, j in zip(values, columns))
        message = (f"{self.path}: {what}: non-finite state derivative {named} at t = {m.failed_time} s{where}; "
                   "expected finite derivatives")
        if states is not None and 0 <= row < len(states):
            message += " (states: " + ", ".join(
                f"{name} = {value}" for name, value in zip(self.state_names, states[row])) + ")"
        return message, [self.state_names[j] for j in columns]

    # ------------------------------------------------------------------ argument checks

    def _as_matrix(self, name: str, value, width: int, names: Sequence[str], rows: int | None) -> np.ndarray:
        """``value`` as a C-contiguous float64 (N, width) array (no copy if it already is one)."""
        if value is None:
            if width == 0:
                return np.empty((rows or 0, 0))
            raise ValueError(f"{name}: expected an array of shape (N, {width}) ({names}), got None")
        try:
            array = np.asarray(value)
        except Exception as err:
            raise ValueError(f"{name}: expected an array of shape (N, {width}), got {type(value).__name__} ({err})") from None
        if array.dtype.kind not in "fiu":
            raise ValueError(
                f"{name}: expected a real floating-point array of shape (N, {width}), got dtype {array.dtype}"
            )
        if array.ndim != 2 or array.shape[1] != width:
            raise ValueError(f"{name}: expected shape (N, {width}) ({', '.join(names)}), got {array.shape}")
        if rows is not None and array.shape[0] != rows:
            raise ValueError(f"{name}: expected {rows} rows (as x), got {array.shape[0]}")
        array = np.ascontiguousarray(array, dtype=np.float64)
        if not np.isfinite(array).all():
            row, col = np.argwhere(~np.isfinite(array))[0]
            raise ValueError(
                f"{name}: non-finite value {array[row, col]} at row {row}, column {col} ({names[col]!r})"
            )
        return array

    def _batch(self, x, u, t_s):
        """Checked (x, u) as float64 C arrays, the time (array, stride 0 for one time) and N."""
        x = self._as_matrix("x", x, self.n_states, self.state_names, None)
        n = x.shape[0]
        u = self._as_matrix("u", u, self.n_inputs, self.input_names, n)
        if type(t_s) is float or type(t_s) is int:  # the common case, without array overhead
            if not math.isfinite(t_s):
                raise ValueError(f"t_s: non-finite time {t_s}")
            self._t_scalar[0] = t_s
            return x, u, self._t_scalar, self._t_scalar_address, 0, n
        t = self._as_time(t_s, n)
        return x, u, t, t.ctypes.data, (1 if t.size > 1 else 0), n

    @staticmethod
    def _as_time(t_s, n: int) -> np.ndarray:
        if isinstance(t_s, (bool, np.bool_)):
            raise ValueError(f"t_s: expected a time in s (scalar or shape ({n},)), got {t_s!r}")
        try:
            t = np.asarray(t_s)
        except Exception:
            raise ValueError(f"t_s: expected a time in s (scalar or shape ({n},)), got {type(t_s).__name__}") from None
        if t.dtype.kind not in "fiu":
            raise ValueError(f"t_s: expected a real time in s, got dtype {t.dtype}")
        if t.ndim == 0:
            t = t.reshape(1)
        elif t.shape != (n,):
            raise ValueError(f"t_s: expected a scalar or shape ({n},), got shape {t.shape}")
        t = np.ascontiguousarray(t, dtype=np.float64)
        if not np.isfinite(t).all():
            raise ValueError(f"t_s: non-finite time at index {int(np.argwhere(~np.isfinite(t))[0, 0])}")
        return t

    @staticmethod
    def _data(array: np.ndarray) -> int:
        return array.ctypes.data if array.size else 0

    # ------------------------------------------------------------------ batched evaluation

    def derivatives(self, x, u=None, t_s=0.0) -> np.ndarray:
        """State derivatives f(t, x, u) for a batch.

        x: (N, n_x) states; u: (N, n_u) inputs (None if the FMU has none); t_s: time in s,
        scalar or (N,). Returns (N, n_x) float64 in the units of the states per second.
        """
        self._require_open()
        x, u, _t, t_ptr, t_stride, n = self._batch(x, u, t_s)
        return self._derivatives_of(x, u, t_ptr, t_stride, n)

    def derivatives_and_jacobians(self, x, u=None, t_s=0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``derivatives`` and ``jacobians`` of one batch, the arguments checked once: (dx, dfdx, dfdu)."""
        self._require_open()
        x, u, _t, t_ptr, t_stride, n = self._batch(x, u, t_s)
        dx = self._derivatives_of(x, u, t_ptr, t_stride, n)
        return (dx, *self._jacobians_of(x, u, t_ptr, t_stride, n))

    def effect_jacobians_kernel(self, program, relative_step: float, unit_programs=(), band_state: int = -1,
                                band: float = 0.0, pair_programs=(), pair_steps=()):
        """An effect program's additive terms and their central differences at t = 0 in C (``hf_effect_jacobians``),
        for many calls (the training's call per solver stage; the programs are laid out once).

        Args:
            program: the :class:`~hybridfmu.fmu.effect_program.EffectProgram` of the terms (installed per call).
            relative_step: each variable's step, relative to 1 + |value|.
            unit_programs: K programs evaluated at each row as they are, at the FMU's derivatives there (a term
                with one unit coefficient: its regressor).
            band_state, band: the rows with |x[:, band_state]| < band (band_state -1: none) also get the
                differences of the pair programs.
            pair_programs: 2 P programs, up and down in turn; pair_steps (P,) the half distance of each pair.

        Returns:
            A function ``(x (N, n_x), u (N, n_u)) -> (terms (N, n_x), d terms / dx (N, n_x, n_x), d terms / du
            (N, n_x, n_u), unit values (N, n_x, K), pair differences (N, n_x, P) (set in the rows within the band,
            zero elsewhere), within the band (N,) bool)``: buffers of the function, overwritten by its next call.
        """
        nx, nu, n_units, n_pairs = self.n_states, self.n_inputs, len(unit_programs), len(pair_steps)
        if len(pair_programs) != 2 * n_pairs:
            raise ValueError(f"effect_jacobians_kernel: {len(pair_programs)} pair programs for {n_pairs} steps; "
                             "expected two programs per step")
        units, pairs = _concatenated(unit_programs), _concatenated(pair_programs)
        steps = np.ascontiguousarray(pair_steps, dtype=np.float64).reshape(n_pairs)
        work = np.empty(2 * (nx + nu) + 3 * nx)
        fixed = (n_units, *(self._data(a) for a in units))
        band_part = (int(band_state), float(band), n_pairs, *(self._data(a) for a in pairs), self._data(steps))
        buffers: dict[int, tuple] = {}
        call = self._lib.hf_effect_jacobians

        def kernel(x, u):
            self._require_open()
            x, u, _t, _t_ptr, _t_stride, n = self._batch(x, u, 0.0)
            if n not in buffers:
                arrays = (np.empty((n, nx)), np.empty((n, nx, nx)), np.empty((n, nx, nu)),
                          np.empty((n, nx, n_units)), np.zeros((n, nx, n_pairs)), np.zeros(n, dtype=np.uint8))
                data = [self._data(a) for a in arrays]
                buffers[n] = arrays, (*data[:3], *fixed, data[3], *band_part, *data[4:], self._data(work))
            (terms, term_x, term_u, unit_values, pair_values, in_band), addresses = buffers[n]
            if n:
                pair_values.fill(0.0)
                installed = program.install(self._shim_model)
                try:
                    status = call(self._m, n, self._data(x), self._data(u), float(relative_step), *addresses)
                finally:
                    program.remove(self._shim_model)
                    del installed
                if status:
                    self._raise_shim_error(status, "effect terms and their Jacobians", states=x)
            return terms, term_x, term_u, unit_values, pair_values, in_band.view(bool)

        kernel.keep_alive = (units, pairs, steps, work)  # the C call reads them by address
        return kernel

    def _derivatives_of(self, x, u, t_ptr, t_stride, n) -> np.ndarray:
        """``derivatives`` of checked arguments (from ``_batch``)."""
        dx = np.empty((n, self.n_states))
        if n:
            status = self._lib.hf_derivatives(self._m, n, t_ptr, t_stride,
                                              self._data(x), self._data(u), self._data(dx))
            if status:
                self._raise_shim_error(status, "derivatives", derivatives=dx, states=x)
        return dx

    def derivatives_kernel(self, n: int):
        """``derivatives`` at t = 0 for many calls on batches of ``n`` rows, with less overhead per call.

        Returns a function ``(x (n, n_x), u (n, n_u)) -> dx (n, n_x)``: x and u are copied into buffers of
        the function and ``dx`` is its own buffer, overwritten by the next call (copy it to keep it). The
        values, checks and errors are those of ``derivatives`` (a call that does not pass the checks is
        handed on to it).
        """
        shape_x, shape_u = (n, self.n_states), (n, self.n_inputs)
        x_buf, u_buf, dx = np.empty(shape_x), np.empty(shape_u), np.empty(shape_x)
        addresses = (self._data(x_buf), self._data(u_buf), self._data(dx))
        call = self._lib.hf_derivatives
        isfinite, float64 = np.isfinite, np.dtype(np.float64)

        def kernel(x, u):
            if (self._closed or self._needs_reinit or n == 0 or getattr(x, "shape", None) != shape_x
                    or getattr(u, "shape", None) != shape_u or x.dtype != float64 or u.dtype != float64):
                return self.derivatives(x, u)
            np.copyto(x_buf, x)
            np.copyto(u_buf, u)
            if not (isfinite(x_buf).all() and isfinite(u_buf).all()):
                return self.derivatives(x, u)
            self._t_scalar[0] = 0.0
            status = call(self._m, n, self._t_scalar_address, 0, *addresses)
            if status:
                self._raise_shim_error(status, "derivatives", derivatives=dx, states=x_buf)
            return dx

        return kernel

    def derivatives_and_jacobians_kernel(self, n: int):
        """``derivatives_and_jacobians`` at t = 0 for many calls on batches of ``n`` rows, with less overhead
        per call (the training's reverse sweep needs both at every solver stage).

        Returns a function ``(x (n, n_x), u (n, n_u)) -> (dx (n, n_x), dfdx (n, n_x, n_x), dfdu (n, n_x, n_u))``;
        the three arrays are buffers of the function, overwritten by the next call (copy them to keep them).
        Values, checks and errors are those of ``derivatives_and_jacobians`` (a call that does not pass the
        checks is handed on to it); the Jacobian method is resolved once, when the kernel is made.
        """
        nx, nu = self.n_states, self.n_inputs
        shape_x, shape_u = (n, nx), (n, nu)
        x_buf, u_buf, dx = np.empty(shape_x), np.empty(shape_u), np.empty(shape_x)
        dfdx, dfdu = np.empty((n, nx, nx)), np.empty((n, nx, nu))
        x_addr, u_addr, dx_addr = self._data(x_buf), self._data(u_buf), self._data(dx)
        dfdx_addr, dfdu_addr = self._data(dfdx), self._data(dfdu) or self._empty.ctypes.data
        method = self._resolved_jacobian_method() if nx else "none"
        if method == "directional":
            column_addr = self._column.ctypes.data
            jacobian_call = lambda: self._lib.hf_jacobians_directional(  # noqa: E731
                self._m, n, self._t_scalar_address, 0, x_addr, u_addr, dfdx_addr, dfdu_addr, column_addr)
        elif method == "fd":
            rel = float(self.fd_relative_step)
            if not (np.isfinite(rel) and 0 < rel < 1):
                raise ValueError(f"fd_relative_step: expected a number in (0, 1), got {self.fd_relative_step}")
            nominals = (self.state_nominals.ctypes.data,
                        self._data(self.input_nominals) or self._empty.ctypes.data)
            jacobian_call = lambda: self._lib.hf_jacobians_fd(  # noqa: E731
                self._m, n, self._t_scalar_address, 0, x_addr, u_addr, *nominals, rel, dfdx_addr, dfdu_addr)
        derivative_call = self._lib.hf_derivatives
        isfinite, float64 = np.isfinite, np.dtype(np.float64)

        def kernel(x, u):
            if (self._closed or self._needs_reinit or n == 0 or nx == 0 or getattr(x, "shape", None) != shape_x
                    or getattr(u, "shape", None) != shape_u or x.dtype != float64 or u.dtype != float64):
                return self.derivatives_and_jacobians(x, u)
            np.copyto(x_buf, x)
            np.copyto(u_buf, u)
            if not (isfinite(x_buf).all() and isfinite(u_buf).all()):
                return self.derivatives_and_jacobians(x, u)
            self._t_scalar[0] = 0.0
            status = derivative_call(self._m, n, self._t_scalar_address, 0, x_addr, u_addr, dx_addr)
            if status:
                self._raise_shim_error(status, "derivatives", derivatives=dx, states=x_buf)
            status = jacobian_call()
            if status:
                self._raise_shim_error(status, f"jacobians ({method})")
            return dx, dfdx, dfdu

        return kernel

    def neural_rollout(self, x0: np.ndarray, u_grid: np.ndarray, u_half: np.ndarray, z_grid: np.ndarray,
                       z_half: np.ndarray, weights, h_s: float, method: str,
                       clamp: tuple[int, int, float, float] | None = None, row_steps=None) -> np.ndarray:
        """Gradient-free rollout of a neural FMU around this FMU, the whole loop in C
        (:func:`hybridfmu.fmu.neural.rollout`; ``weights`` a :class:`hybridfmu.fmu.neural.NeuralWeights`)."""
        from hybridfmu.fmu.neural import rollout

        return rollout(self, x0, u_grid, u_half, z_grid, z_half, weights, h_s, method, clamp, row_steps)

    def neural_recorder(self, weights, h_s: float, method: str, clamp: tuple[int, int, float, float] | None = None):
        """A recorded training rollout of a neural FMU around this FMU with its reverse sweep, both in C
        (:class:`hybridfmu.fmu.neural.RecordedRollout`)."""
        from hybridfmu.fmu.neural import RecordedRollout

        return RecordedRollout(self, weights, h_s, method, clamp)

    def event_indicators(self, x, u=None, t_s=0.0) -> np.ndarray:
        """Event indicators for a batch: (N, n_event_indicators) float64 (arguments as derivatives)."""
        self._require_open()
        x, u, _t, t_ptr, t_stride, n = self._batch(x, u, t_s)
        z = np.empty((n, self.n_event_indicators))
        if n and self.n_event_indicators:
            status = self._lib.hf_event_indicators(self._m, n, t_ptr, t_stride,
                                                   self._data(x), self._data(u), self._data(z))
            if status:
                self._raise_shim_error(status, "event_indicators")
        return z

    def outputs(self, x, u=None, names: Sequence[str] | None = None, t_s=0.0) -> np.ndarray:
        """Real variables ``names`` (default: all Real outputs, ``real_output_names``) for a batch.

        Returns (N, len(names)) float64. Any Real variable of the FMU may be named; Integer and
        Boolean variables (discrete, constant between events) are not evaluated per row.
        """
        self._require_open()
        if names is None:
            names = self.real_output_names
        if isinstance(names, str):
            raise ValueError(f"names: expected a list of variable names, got the string {names!r}")
        names = list(names)
        vrs = []
        for name in names:
            variable = self._variables.get(name)
            if variable is None:
                raise ValueError(
                    f"{self.path}: unknown variable {name!r} (outputs are {self.output_names}; "
                    "any Real variable of the FMU may be named)"
                )
            if variable.type != "Real":
                raise ValueError(f"{self.path}: variable {name!r} has type {variable.type}, expected a Real "
                                 f"variable (Real outputs: {self.real_output_names})")
            vrs.append(variable.valueReference)
        x, u, _t, t_ptr, t_stride, n = self._batch(x, u, t_s)
        y = np.empty((n, len(names)))
        vr = np.array(vrs, dtype=np.uint32)
        if n and names:
            status = self._lib.hf_outputs(self._m, n, t_ptr, t_stride, self._data(x),
                                          self._data(u), vr.ctypes.data, len(vrs), self._data(y))
            if status:
                self._raise_shim_error(status, "outputs")
        return y

    def jacobians(self, x, u=None, t_s=0.0) -> tuple[np.ndarray, np.ndarray]:
        """Jacobians of the derivatives for a batch.

        Returns dfdx (N, n_x, n_x) with dfdx[r, i, j] = d f_i / d x_j and dfdu (N, n_x, n_u),
        from fmi2GetDirectionalDerivative where the FMU provides it, else from central finite
        differences with step h_j = fd_relative_step * max(|v_j|, nominal_j).
        """
        self._require_open()
        x, u, _t, t_ptr, t_stride, n = self._batch(x, u, t_s)
        return self._jacobians_of(x, u, t_ptr, t_stride, n)

    def _jacobians_of(self, x, u, t_ptr, t_stride, n) -> tuple[np.ndarray, np.ndarray]:
        """``jacobians`` of checked arguments (from ``_batch``)."""
        nx, nu = self.n_states, self.n_inputs
        dfdx = np.empty((n, nx, nx))
        dfdu = np.empty((n, nx, nu))
        if n == 0 or nx == 0:
            return dfdx, dfdu
        method = self._resolved_jacobian_method()
        if method == "directional":
            status = self._lib.hf_jacobians_directional(
                self._m, n, t_ptr, t_stride, self._data(x), self._data(u), self._data(dfdx),
                self._data(dfdu) or self._empty.ctypes.data, self._column.ctypes.data)
        else:
            rel = float(self.fd_relative_step)
            if not (np.isfinite(rel) and 0 < rel < 1):
                raise ValueError(f"fd_relative_step: expected a number in (0, 1), got {self.fd_relative_step}")
            status = self._lib.hf_jacobians_fd(
                self._m, n, t_ptr, t_stride, self._data(x), self._data(u),
                self.state_nominals.ctypes.data, self._data(self.input_nominals) or self._empty.ctypes.data,
                rel, self._data(dfdx), self._data(dfdu) or self._empty.ctypes.data)
        if status:
            self._raise_shim_error(status, f"jacobians ({method})")
        return dfdx, dfdu

    def _resolved_jacobian_method(self) -> str:
        method = self.jacobian_method
        if method not in ("auto", "directional", "fd"):
            raise ValueError(f"jacobian_method: expected 'auto', 'directional' or 'fd', got {method!r}")
        if method == "directional" and not self.provides_directional_derivative:
            raise ValueError(
                f"{self.path}: jacobian_method 'directional' but the FMU does not provide directional derivatives"
            )
        if method == "auto":
            return "directional" if self.provides_directional_derivative else "fd"
        return method
