"""Compile, cache and load the C shim (``shim.c``) that evaluates an FMU over a whole batch.

The shim (with the diagnosed effects of ``effects.c``) is compiled with gcc at first use into a cache folder
keyed by the hash of its sources, the compiler and the flags: ``$HYBRIDFMU_CACHE`` if set, else ``~/.cache/hybridfmu`` (a folder in
the system's temp folder if that one is not writable). The
library is compiled into a temporary file in that folder and renamed over the final name, so
several processes that start at once are safe (each may compile; the last rename wins, and every
one of them loads a complete file).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from ctypes import POINTER, c_char_p, c_double, c_int, c_longlong, c_size_t, c_uint, c_void_p
from pathlib import Path

SOURCE_PATH = Path(__file__).with_name("shim.c")
#: the C sources compiled into the shim, and the header they share (all part of the cache key)
SOURCE_PATHS = (SOURCE_PATH, Path(__file__).with_name("effects.c"))
HEADER_PATHS = (Path(__file__).with_name("effects.h"),)
#: ISO C without floating-point contraction: every expression rounds as written (the effects of ``effects.c``
#: compute the same values as their Python forms)
COMPILE_FLAGS = ("-O2", "-std=c99", "-ffp-contract=off", "-shared", "-fPIC", "-Wall")

# Codes of the FMI function that failed (mirror of the enum in shim.c).
FUNCTION_NAMES = {
    0: "(none)",
    1: "fmi2SetTime",
    2: "fmi2SetContinuousStates",
    3: "fmi2SetReal",
    4: "fmi2GetReal",
    5: "fmi2GetDerivatives",
    6: "fmi2GetEventIndicators",
    7: "fmi2GetDirectionalDerivative",
    8: "fmi2CompletedIntegratorStep",
    9: "the correction callback",
    10: "memory allocation",
    11: "the diagnosed effects' program",
    12: "fmi2EnterEventMode",
    13: "fmi2NewDiscreteStates",
    14: "fmi2EnterContinuousTimeMode",
    15: "fmi2GetContinuousStates",
}
ERR_CALLBACK = -1
ERR_NO_MEMORY = -2
ERR_NOT_FINITE = -3
ERR_EFFECT_PROGRAM = -4

# Why hf_simulate returned (mirror of shim.c).
SIM_DONE = 0
SIM_STATE_EVENT = 1
SIM_INPUT_EVENT = 2
SIM_TIME_EVENT = 3
SIM_STEP_EVENT = 4
SIM_TERMINATE = 5

# The event log's kinds and hf_run_grid's outcomes (mirror of shim.c).
EV_SETTLE, EV_INPUT, EV_STATE, EV_TIME, EV_STEP = 0, 1, 2, 3, 4
OUT_DONE, OUT_PAUSE, OUT_TERMINATE, OUT_TOO_MANY_EVENTS, OUT_TIME_EVENT_PAST, OUT_NONFINITE_STATES, \
    OUT_NO_CONVERGENCE = range(7)
TERM_NEW_DISCRETE_STATES, TERM_COMPLETED_STEP = 1, 2

CORRECTION_FN = ctypes.CFUNCTYPE(c_int)
_DOUBLE_P = POINTER(c_double)
_UINT_P = POINTER(c_uint)


class ShimModel(ctypes.Structure):
    """Mirror of ``hf_model`` in shim.c: the FMU's function addresses, its component and sizes."""

    _fields_ = [
        ("component", c_void_p),
        ("set_time", c_void_p),
        ("set_states", c_void_p),
        ("set_real", c_void_p),
        ("get_real", c_void_p),
        ("get_derivatives", c_void_p),
        ("get_event_indicators", c_void_p),
        ("get_directional_derivative", c_void_p),
        ("completed_integrator_step", c_void_p),
        ("nx", c_size_t),
        ("nu", c_size_t),
        ("nz", c_size_t),
        ("vr_u", _UINT_P),
        ("vr_x", _UINT_P),
        ("vr_dx", _UINT_P),
        ("correction", CORRECTION_FN),
        ("cb_x", _DOUBLE_P),
        ("cb_u", _DOUBLE_P),
        ("cb_dx", _DOUBLE_P),
        ("effect_code", c_void_p),
        ("effect_n_code", c_size_t),
        ("effect_reals", c_void_p),
        ("effect_out", c_void_p),
        ("effect_work", c_void_p),
        ("effect_sets_inputs", c_int),
        ("failed_function", c_int),
        ("failed_row", c_longlong),
        ("failed_status", c_int),
        ("failed_index", c_longlong),
        ("failed_time", c_double),
        ("failed_value", c_double),
        ("enter_event_mode", c_void_p),
        ("new_discrete_states", c_void_p),
        ("enter_continuous_time_mode", c_void_p),
        ("get_continuous_states", c_void_p),
    ]


class ShimEvents(ctypes.Structure):
    """Mirror of ``hf_events`` in shim.c: the event handling's settings, its log and how the run ended."""

    _fields_ = [
        ("tolerance_s", c_double),
        ("max_events", c_longlong),
        ("max_iterations", c_longlong),
        ("next_time_event", c_double),
        ("capacity", c_size_t),
        ("count", c_size_t),
        ("total", c_longlong),
        ("log_time", c_void_p),
        ("log_kind", c_void_p),
        ("log_reinit", c_void_p),
        ("log_crossed", c_void_p),
        ("outcome", c_int),
        ("terminate_source", c_int),
        ("terminate_kind", c_int),
        ("terminate_reinit", c_int),
        ("outcome_time", c_double),
        ("outcome_value", c_double),
        ("outcome_x", c_void_p),
    ]


class ShimBuildError(RuntimeError):
    """The C shim could not be compiled or loaded."""


_lock = threading.Lock()
_library: ctypes.CDLL | None = None


def cache_dir() -> Path:
    """The folder holding compiled shims: ``$HYBRIDFMU_CACHE`` or ``~/.cache/hybridfmu``."""
    env = os.environ.get("HYBRIDFMU_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "hybridfmu"


def _compiler() -> str:
    compiler = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if not compiler:
        raise ShimBuildError("no C compiler found (need gcc or cc on PATH, or $CC) to build the FMU shim")
    return compiler


def _compiler_version(compiler: str) -> str:
    try:
        out = subprocess.run([compiler, "--version"], capture_output=True, text=True, timeout=60)
    except OSError as err:
        raise ShimBuildError(f"cannot run the C compiler {compiler!r}: {err}") from None
    return out.stdout.splitlines()[0] if out.stdout else ""


def shim_path() -> Path:
    """Path of the compiled shim for the current source, compiler and flags (built if missing)."""
    compiler = _compiler()
    source = b"".join(path.read_bytes() for path in SOURCE_PATHS + HEADER_PATHS)
    key = hashlib.sha256(
        source + _compiler_version(compiler).encode() + " ".join(COMPILE_FLAGS).encode()
    ).hexdigest()[:16]
    target = cache_dir() / f"fmushim-{key}.so"
    if target.is_file():
        return target
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=target.parent, prefix=".probe-")
        probe.close()
    except OSError:
        # the cache folder is not writable (e.g. a read-only home): use one in the temp folder
        fallback = Path(tempfile.gettempdir()) / f"hybridfmu-cache-{os.getuid()}"
        fallback.mkdir(parents=True, exist_ok=True)
        target = fallback / target.name
        if target.is_file():
            return target
    handle, tmp_name = tempfile.mkstemp(prefix=".fmushim-", suffix=".so", dir=target.parent)
    os.close(handle)
    try:
        proc = subprocess.run(
            [compiler, *COMPILE_FLAGS, "-o", tmp_name, *(str(path) for path in SOURCE_PATHS), "-lm"],
            capture_output=True, text=True, timeout=300,
        )
        if proc.returncode != 0:
            raise ShimBuildError(f"compiling {', '.join(str(p) for p in SOURCE_PATHS)} with {compiler} failed:\n"
                                 f"{proc.stderr}")
        os.replace(tmp_name, target)
    finally:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
    return target


def load_shim() -> ctypes.CDLL:
    """Load the compiled shim (compiling it at first use) and declare its functions."""
    global _library
    with _lock:
        if _library is None:
            lib = ctypes.CDLL(str(shim_path()))
            _declare(lib)
            _library = lib
        return _library


def _declare(lib: ctypes.CDLL) -> None:
    # Pointers are passed as plain addresses (int) for speed; callers keep the arrays alive.
    ptr = c_void_p
    batch = [ptr, c_size_t, ptr, c_size_t, ptr, ptr]
    signatures = {
        "hf_log_new": (c_void_p, [c_size_t]),
        "hf_log_free": (None, [c_void_p]),
        "hf_log_take": (c_size_t, [c_void_p, c_char_p, c_size_t]),
        "hf_derivatives": (c_int, batch + [ptr]),
        "hf_event_indicators": (c_int, batch + [ptr]),
        "hf_outputs": (c_int, batch + [ptr, c_size_t, ptr]),
        "hf_jacobians_directional": (c_int, batch + [ptr, ptr, ptr]),
        "hf_jacobians_fd": (c_int, batch + [ptr, ptr, c_double, ptr, ptr]),
        "hf_rk4_step": (c_int, [ptr, c_double, c_double, ptr, ptr, ptr, ptr, ptr]),
        "hf_completed_step": (c_int, [ptr, ptr]),
        "hf_effects_add": (c_int, [ptr, c_size_t, ptr, c_size_t, c_size_t, ptr, ptr, ptr, ptr, ptr, ptr, ptr]),
        "hf_effect_jacobians": (c_int, [ptr, c_size_t, ptr, ptr, c_double, ptr, ptr, ptr, c_size_t, ptr, ptr, ptr,
                                        ptr, ptr, c_longlong, c_double, c_size_t, ptr, ptr, ptr, ptr, ptr, ptr, ptr,
                                        ptr]),
        "hf_simulate": (c_int, [ptr, c_size_t, ptr, ptr, c_size_t, c_double, ptr, ptr, ptr, ptr]),
        "hf_settle": (c_int, [ptr, ptr, c_double, ptr, ptr, ptr]),
        "hf_run_grid": (c_int, [ptr, ptr, c_size_t, ptr, ptr, c_size_t, ptr, ptr, ptr, ptr]),
        "hf_neural_rollout": (c_int, [ptr, c_size_t, c_size_t, c_double, c_int, ptr, ptr, ptr, ptr, ptr, c_size_t,
                                      ptr, ptr, c_longlong, c_longlong, c_double, c_double, ptr, ptr, ptr, ptr]),
        "hf_neural_forward_record": (c_int, [ptr, c_size_t, c_size_t, c_double, c_int, ptr, ptr, ptr, ptr, ptr,
                                             c_size_t, ptr, ptr, c_longlong, c_longlong, c_double, c_double, ptr,
                                             ptr, ptr, c_int, ptr, ptr, c_double, ptr, ptr, ptr, ptr]),
        "hf_neural_backward": (c_int, [c_size_t, c_size_t, c_size_t, c_size_t, c_double, c_int, c_size_t, ptr, ptr,
                                       ptr, ptr, ptr, ptr, c_longlong, c_longlong, ptr, ptr, ptr, ptr, ptr, ptr,
                                       ptr, ptr]),
    }
    for name, (restype, argtypes) in signatures.items():
        fn = getattr(lib, name)
        fn.restype = restype
        fn.argtypes = argtypes


def function_address(lib: ctypes.CDLL, name: str) -> int:
    """Address of the exported C function ``name`` of ``lib``."""
    return ctypes.cast(getattr(lib, name), c_void_p).value
