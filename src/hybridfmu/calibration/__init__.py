"""Calibration stage: FMU parameters and unmeasured initial states fitted on the training data."""

from hybridfmu.calibration.result import Calibration

__all__ = ["Calibration"]
