"""The starting point: closed-form geometry on marker trajectories, which marker rides on which segment (seed 002),
MTB joint-centre estimation (seed 000).

Exports (each imported from its module on first use): JointEstimate, JointEstimates, JointSpec, estimate_joints,
estimate_model_joints, write_centres_csv from calibrate.seed.joints; Association, ModelAssociation, associate,
associate_to_model from calibrate.seed.association; Seed, seed_parameters, size_from_markers from
calibrate.seed.seeding.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.joints:JointEstimate,JointEstimates,JointSpec,estimate_joints,estimate_model_joints,write_centres_csv
.association:Association,ModelAssociation,associate,associate_to_model
.seeding:Seed,seed_parameters,size_from_markers
""")
