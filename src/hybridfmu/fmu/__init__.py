"""FMU stage: building the demo FMU, and the batched bridge to any FMI 2.0 Model-Exchange FMU.

Bridge API: ``load_fmu`` -> :class:`FmuModel` (batched derivatives, Jacobians, event
indicators, outputs), :class:`FmuRhs` (differentiable right-hand side for PyTorch) and
``simulate_open_loop`` (fixed-step RK4 with state events on the input grid).
"""

from hybridfmu.fmu.bridge import FmuError, FmuFormatError, FmuModel, load_fmu
from hybridfmu.fmu.simulate import SimulationResult, simulate_open_loop
from hybridfmu.fmu.torch_rhs import FmuRhs

__all__ = [
    "FmuError",
    "FmuFormatError",
    "FmuModel",
    "FmuRhs",
    "SimulationResult",
    "load_fmu",
    "simulate_open_loop",
]
