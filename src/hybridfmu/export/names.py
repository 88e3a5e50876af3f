"""Names of the exported models and their files (no numerical imports: the Snakefile reads them when it parses).

``<results>/<case>/export/<case>_<model>.fmu``, ``<model>`` one of :data:`EXPORT_MODELS`.
"""

from __future__ import annotations

import re

#: The trained models a case can export, in report order: the paper's neural FMU, the FMU plus the diagnosed
#: effects, and the hybrid (FMU + effects + ANN).
EXPORT_MODELS = ("neural_fmu", "fmu_effects", "hybrid")

_NOT_IDENTIFIER = re.compile(r"[^A-Za-z0-9_]")


def identifier_prefix(case: str) -> str:
    """What every exported model identifier of ``case`` starts with: ``<case>_`` with characters that a C
    identifier cannot hold as ``_`` (and ``m_`` before a leading digit)."""
    prefix = _NOT_IDENTIFIER.sub("_", f"{case}_")
    return prefix if not prefix[0].isdigit() else f"m_{prefix}"


def model_identifier(case: str, model: str) -> str:
    """The exported FMU's modelIdentifier (a C identifier): ``<case>_<model>`` (:func:`identifier_prefix`)."""
    if model not in EXPORT_MODELS:
        raise ValueError(f"export: unknown model {model!r}; expected one of {list(EXPORT_MODELS)}")
    return identifier_prefix(case) + model


def fmu_file_name(case: str, model: str) -> str:
    """The exported FMU's file name, ``<identifier>.fmu``."""
    return f"{model_identifier(case, model)}.fmu"


def fmu_file_pattern(case: str) -> str:
    """The exported FMUs' file name with the wildcard ``{model}`` (a Snakemake output pattern)."""
    return identifier_prefix(case) + "{model}.fmu"
