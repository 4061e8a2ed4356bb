"""Solvers: Levenberg-Marquardt with the Schur complement over frames, its compiled per-frame kernels, frame-wise
inverse kinematics.

Exports (each imported from its module on first use): Covariance, SolverSummary, covariance, levenberg_marquardt
from calibrate.solve.lm; IKResult, inverse_kinematics from calibrate.solve.ik.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.lm:Covariance,SolverSummary,covariance,levenberg_marquardt .ik:IKResult,inverse_kinematics
""")
