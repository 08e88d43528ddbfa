"""Calibration: fit the model's uncertain parameters to measured SoC with iSOPT."""

from ebus_env.calibration.calibrate import CalibrationResult, calibrate
from ebus_env.calibration.calibrate_logs import LogCalibration, calibrate_logs
from ebus_env.calibration.isopt import ISOPTSettings, isopt
from ebus_env.calibration.problem import PAPER_PARAMS, CalibrationProblem

__all__ = ["PAPER_PARAMS", "CalibrationProblem", "CalibrationResult", "ISOPTSettings",
           "LogCalibration", "calibrate", "calibrate_logs", "isopt"]
