"""The score formula, calibrations and their fitting (docs/semantics.md §5); the shipped
calibrations are the JSON files beside these modules."""

from .fit import KFoldStability, calibrate, component_rows, kfold_stability, rows_compat
from .formula import normalise, sgc_score, transform
from .model import (
                    BUILTIN,
                    COMPONENTS,
                    DEFAULT_CALIBRATION,
                    LOG1P_COMPONENTS,
                    UNITS,
                    Calibration,
                    CalibrationMismatchError,
                    default_calibration,
)

__all__ = ["BUILTIN", "COMPONENTS", "Calibration", "CalibrationMismatchError", "DEFAULT_CALIBRATION", "KFoldStability",
           "LOG1P_COMPONENTS", "UNITS", "calibrate", "component_rows", "default_calibration", "kfold_stability",
           "normalise", "rows_compat", "sgc_score", "transform"]
