"""The global least-squares problem of seed 003: parameters, residuals, priors, gauges and the compiled per-frame
functions.

Exports (each from its module, imported on first use):

    Problem   -- calibrate.problem.problem
    Priors, Settings   -- calibrate.problem.settings
    SolverOptions   -- calibrate.problem.options
    State   -- calibrate.problem.state
"""

from ..exports import lazy_exports

_EXPORTS = {
    "Problem": ".problem",
    "Priors": ".settings",
    "Settings": ".settings",
    "SolverOptions": ".options",
    "State": ".state",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
