"""The pipeline (seed, start, solve, outliers, learnt noise), its result, and the report.

Exports (each from its module, imported on first use):

    calibrate   -- calibrate.calibration.pipeline
    Calibration, NewMarker, Outlier   -- calibrate.calibration.result
    Identified, ParameterChange, Progress, StillNote, LimitNote   -- calibrate.calibration.records
    TruthComparison, compare_to_truth   -- calibrate.calibration.evaluate
"""

from ..exports import lazy_exports

_EXPORTS = {
    "calibrate": ".pipeline",
    "Calibration": ".result",
    "NewMarker": ".result",
    "Outlier": ".result",
    "Identified": ".records",
    "ParameterChange": ".records",
    "Progress": ".records",
    "StillNote": ".records",
    "LimitNote": ".records",
    "TruthComparison": ".evaluate",
    "compare_to_truth": ".evaluate",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
