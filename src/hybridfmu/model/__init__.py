"""Neural-FMU layers (paper Fig. 7): input delay, FMU, pre/post-processing, tanh MLP, gates.

The layers are imported on first use (PEP 562): reading a config setting of this package (e.g.
:mod:`hybridfmu.model.settings`) as the workflow starts does not load PyTorch.
"""

import importlib

_LAYERS = {
    "InputDelay": "delay", "SAMPLE_POSITIONS": "delay", "FmuLayer": "fmu_layer", "Gates": "gates",
    "TanhMLP": "mlp", "STATISTICS_KEYS": "neural_fmu", "FusedDerivative": "neural_fmu", "NeuralFmu": "neural_fmu",
    "ScaleShift": "shift_scale", "ShiftScale": "shift_scale", "EndStop": "spec", "NeuralFmuSpec": "spec",
}

__all__ = list(_LAYERS)


def __getattr__(name: str):
    if name not in _LAYERS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_LAYERS[name]}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAYERS))
