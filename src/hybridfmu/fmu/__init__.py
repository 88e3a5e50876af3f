"""FMU stage: building the demo FMU, and the batched bridge to any FMI 2.0 Model-Exchange FMU.

Bridge API: ``load_fmu`` -> :class:`FmuModel` (batched derivatives, Jacobians, event
indicators, outputs), :class:`FmuRhs` (differentiable right-hand side for PyTorch) and
``simulate_open_loop`` (fixed-step RK4 with state events on the input grid).
"""

from hybridfmu.fmu.build import FmuBuildError, build_fmu
from hybridfmu.fmu.bridge import FmuError, FmuFormatError, FmuModel, FmuNonFiniteError, FmuTerminated, load_fmu, platform_library
from hybridfmu.fmu.simulate import SimulationResult, simulate_open_loop

def __getattr__(name: str):
    # FmuRhs needs torch; import it only when asked for, so that building an FMU stays light.
    if name == "FmuRhs":
        from hybridfmu.fmu.torch_rhs import FmuRhs

        return FmuRhs
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "FmuBuildError",
    "FmuError",
    "FmuFormatError",
    "FmuModel",
    "FmuNonFiniteError",
    "FmuRhs",
    "FmuTerminated",
    "SimulationResult",
    "build_fmu",
    "load_fmu",
    "platform_library",
    "simulate_open_loop",
]
