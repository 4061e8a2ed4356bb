"""Synthetic trials with a known truth: squats, gait, overhead motion, soft-tissue artefact; seed 000's synthetic
chains.

Exports (each imported from its module on first use): Simulation, simulate_gait, simulate_overhead,
simulate_realistic, simulate_squats, simulate_static, write_simulation from calibrate.simulation.simulate;
Corruption, read_corruptions from calibrate.simulation.artefacts; Chain, simulate_chain from
calibrate.simulation.chains.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.simulate:Simulation,simulate_gait,simulate_overhead,simulate_realistic,simulate_squats,simulate_static,write_simulation
.artefacts:Corruption,read_corruptions .chains:Chain,simulate_chain
""")
