"""Generic transforms: a signal times a physical factor, the time derivative of a signal."""

from __future__ import annotations

from typing import Any

import numpy as np

from hybridfmu.data.resample import smoothing_derivative
from hybridfmu.data.transforms.base import Transform, TransformError
from hybridfmu.units import UnitError, parse_quantity, parse_unit, unit_string


#: Without ``window_s``, a derivative's Savitzky-Golay window spans this many samples of the grid.
DERIVATIVE_WINDOW_SAMPLES = 20


class Scale(Transform):
    """``output = input * factor``; config: ``{kind: scale, input, output, factor: "<number> <unit>"}``.

    The output's unit is the input's unit times the factor's, simplified (``bar * N*m/bar`` -> ``N*m``).
    """

    kind = "scale"

    def inputs(self, spec: dict[str, Any]) -> list[str]:
        return [spec["input"]]

    def outputs(self, spec: dict[str, Any]) -> list[str]:
        return [spec["output"]]

    def _product(self, spec: dict[str, Any], input_unit: str, where: str):
        try:
            factor = parse_quantity(spec["factor"])
        except UnitError as err:
            raise TransformError(f"{where}.factor: {err}") from None
        product = (1.0 * parse_unit(input_unit) * factor).to_reduced_units()
        return product

    def output_units(self, spec: dict[str, Any], units: dict[str, str], where: str) -> dict[str, str]:
        product = self._product(spec, units[spec["input"]], where)
        return {spec["output"]: unit_string(product.units)}

    def apply(self, spec: dict[str, Any], columns: dict[str, np.ndarray], units: dict[str, str],
              rate_hz: float) -> dict[str, np.ndarray]:
        product = self._product(spec, units[spec["input"]], f"config.transforms ({self.kind})")
        factor = float(product.to(parse_unit(unit_string(product.units))).magnitude)
        return {spec["output"]: factor * np.asarray(columns[spec["input"]], dtype=np.float64)}


class Derivative(Transform):
    """``output = d input / dt``; config: ``{kind: derivative, input, output, window_s, polyorder}``.

    Savitzky-Golay differentiation over ``window_s`` (default: :data:`DERIVATIVE_WINDOW_SAMPLES` samples of the
    grid) with polynomial degree ``polyorder`` (default 2), zero phase. The output's unit is the input's per second.
    """

    kind = "derivative"

    def inputs(self, spec: dict[str, Any]) -> list[str]:
        return [spec["input"]]

    def outputs(self, spec: dict[str, Any]) -> list[str]:
        return [spec["output"]]

    def output_units(self, spec: dict[str, Any], units: dict[str, str], where: str) -> dict[str, str]:
        window_s = float(spec.get("window_s") or 1.0)  # the default is sized by the grid in apply
        if window_s <= 0:
            raise TransformError(f"{where}.window_s: {window_s}; expected a positive window (s)")
        rate = parse_unit(units[spec["input"]]) / parse_unit("s")
        return {spec["output"]: unit_string(rate)}

    def apply(self, spec: dict[str, Any], columns: dict[str, np.ndarray], units: dict[str, str],
              rate_hz: float) -> dict[str, np.ndarray]:
        values = np.asarray(columns[spec["input"]], dtype=np.float64)
        window_s = spec.get("window_s")
        window_s = DERIVATIVE_WINDOW_SAMPLES / rate_hz if window_s is None else float(window_s)
        rate = smoothing_derivative(values, rate_hz, window_s, int(spec.get("polyorder", 2)))
        return {spec["output"]: rate}
