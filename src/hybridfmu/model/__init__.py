"""Neural-FMU layers (paper Fig. 7): input delay, FMU, pre/post-processing, tanh MLP, gates."""

from .delay import InputDelay, SAMPLE_POSITIONS
from .fmu_layer import FmuLayer
from .gates import Gates
from .mlp import TanhMLP
from .neural_fmu import STATISTICS_KEYS, FusedDerivative, NeuralFmu
from .shift_scale import ScaleShift, ShiftScale
from .spec import EndStop, NeuralFmuSpec

__all__ = ["InputDelay", "SAMPLE_POSITIONS", "FmuLayer", "Gates", "TanhMLP",
           "STATISTICS_KEYS", "FusedDerivative", "NeuralFmu", "ScaleShift", "ShiftScale", "EndStop",
           "NeuralFmuSpec"]
