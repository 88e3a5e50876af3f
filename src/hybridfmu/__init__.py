"""hybridfmu: neural FMUs for hybrid modelling, and a diagnosis of the sim-to-real gap.

Stages of the data flow, one subpackage each:
``fmu`` (FMU build and batched bridge), ``bench`` (test-bench emulator), ``data``
(ingestion, segment selection), ``model`` (neural FMU layers), ``training``
(batching, losses, Hyperband), ``evaluation`` (metrics, plots, report),
``diagnosis`` (sim-to-real gap), ``tracking`` (MLflow).
"""

__version__ = "0.1.0"
