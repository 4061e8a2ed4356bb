"""The global least-squares problem of seed 003: parameters, residuals, priors, gauges and the compiled per-frame
functions.

Exports (each imported from its module on first use): Problem from calibrate.problem.problem; Priors, Settings from
calibrate.problem.settings; SolverOptions from calibrate.problem.options; State from calibrate.problem.state.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.problem:Problem .settings:Priors,Settings .options:SolverOptions .state:State
""")
