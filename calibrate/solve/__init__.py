"""Solvers: Levenberg-Marquardt with the Schur complement over frames, its compiled per-frame kernels, frame-wise
inverse kinematics.

Exports (each from its module, imported on first use):

    Covariance, SolverSummary, covariance, levenberg_marquardt   -- calibrate.solve.lm
    IKResult, inverse_kinematics   -- calibrate.solve.ik
"""

from ..exports import lazy_exports

_EXPORTS = {
    "Covariance": ".lm",
    "SolverSummary": ".lm",
    "covariance": ".lm",
    "levenberg_marquardt": ".lm",
    "IKResult": ".ik",
    "inverse_kinematics": ".ik",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
