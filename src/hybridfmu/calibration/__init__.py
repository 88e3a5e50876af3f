"""Calibration stage: FMU parameters and unmeasured initial states fitted on the training data.

API::

    run_calibration(config, fmu_path, data_paths, calibration_path, figure_path, track=True) -> Calibration
    calibrated_parameters(config, calibration_path) -> {parameter: value}   # for load_fmu(..., parameters=)
    open_loop_rmse(config, fmu_path, calibration_path, data_path, maneuver) -> {"<signal>_rmse": value}
    Calibration                                                            # the record (result.py)
"""

from hybridfmu.calibration.result import Calibration
from hybridfmu.calibration.stage import calibrated_parameters, open_loop_rmse, run_calibration

__all__ = ["Calibration", "calibrated_parameters", "open_loop_rmse", "run_calibration"]
