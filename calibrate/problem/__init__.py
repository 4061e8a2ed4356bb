"""The global least-squares problem of seed 003: parameters, residuals, priors, gauges and the compiled per-frame
functions.

Exports (each imported from its module on first use): Problem from calibrate.problem.problem; Settings (the user's
flat options) from calibrate.problem.settings; Priors, ProblemOptions, SolverOptions (its typed views for the problem
and the solver) from calibrate.problem.options; State from calibrate.problem.state.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.problem:Problem .settings:Settings .options:Priors,ProblemOptions,SolverOptions .state:State
""")
