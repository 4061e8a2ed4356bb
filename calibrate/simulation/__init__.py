"""Synthetic trials with a known truth: squats, gait, overhead motion, soft-tissue artefact; seed 000's synthetic
chains.

Exports (each from its module, imported on first use):

    Simulation, simulate_gait, simulate_overhead, simulate_realistic, simulate_squats,
    simulate_static, write_simulation   -- calibrate.simulation.simulate
    Corruption, read_corruptions   -- calibrate.simulation.artefacts
    Chain, simulate_chain   -- calibrate.simulation.chains
"""

from ..exports import lazy_exports

_EXPORTS = {
    "Simulation": ".simulate",
    "simulate_gait": ".simulate",
    "simulate_overhead": ".simulate",
    "simulate_realistic": ".simulate",
    "simulate_squats": ".simulate",
    "simulate_static": ".simulate",
    "write_simulation": ".simulate",
    "Corruption": ".artefacts",
    "read_corruptions": ".artefacts",
    "Chain": ".chains",
    "simulate_chain": ".chains",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
