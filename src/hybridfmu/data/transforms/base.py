"""The interface every derived-signal transform implements."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import numpy as np


class TransformError(ValueError):
    """A transform entry of the case config is inconsistent; the message names the field."""


class Transform(ABC):
    """One kind of derived signal (stateless; its settings come with each call as the config entry)."""

    #: The name a config entry uses in ``kind``.
    kind: str = ""

    @abstractmethod
    def inputs(self, spec: dict[str, Any]) -> list[str]:
        """Names of the signals the transform reads."""

    @abstractmethod
    def outputs(self, spec: dict[str, Any]) -> list[str]:
        """Names of the signals the transform adds."""

    @abstractmethod
    def output_units(self, spec: dict[str, Any], units: dict[str, str], where: str) -> dict[str, str]:
        """Unit of each output from the units of the inputs; raises TransformError naming ``where``."""

    @abstractmethod
    def apply(self, spec: dict[str, Any], columns: dict[str, np.ndarray], units: dict[str, str],
              rate_hz: float) -> dict[str, np.ndarray]:
        """The outputs, each (T,) float64 in its unit, from the input columns (T,) on the grid."""
