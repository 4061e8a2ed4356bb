"""Solvers: one Levenberg-Marquardt loop (minimise, over a StepProblem), run with the Schur complement over
frames (levenberg_marquardt, its compiled per-frame kernels) and frame by frame (inverse_kinematics).

Exports (each imported from its module on first use): Covariance, StepProblem, SolverSummary, covariance,
levenberg_marquardt, minimise from calibrate.solve.lm; IKResult, inverse_kinematics from calibrate.solve.ik.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.lm:Covariance,StepProblem,SolverSummary,covariance,levenberg_marquardt,minimise .ik:IKResult,inverse_kinematics
""")
