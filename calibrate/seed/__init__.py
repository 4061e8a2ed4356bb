"""The starting point: closed-form geometry on marker trajectories, which marker rides on which segment (seed 002),
MTB joint-centre estimation (seed 000).

Exports (each from its module, imported on first use):

    JointEstimate, JointEstimates, JointSpec, estimate_joints, estimate_model_joints,
    write_centres_csv   -- calibrate.seed.joints
    Association, ModelAssociation, associate, associate_to_model   -- calibrate.seed.association
    Seed, seed_parameters, size_from_markers   -- calibrate.seed.seeding
"""

from ..exports import lazy_exports

_EXPORTS = {
    "JointEstimate": ".joints",
    "JointEstimates": ".joints",
    "JointSpec": ".joints",
    "estimate_joints": ".joints",
    "estimate_model_joints": ".joints",
    "write_centres_csv": ".joints",
    "Association": ".association",
    "ModelAssociation": ".association",
    "associate": ".association",
    "associate_to_model": ".association",
    "Seed": ".seeding",
    "seed_parameters": ".seeding",
    "size_from_markers": ".seeding",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
