"""The model: URDF read into segments, markers, joints and parameters (Model, Parameters), URDF writing, symbolic
kinematics, the parametric human model, which segments a marker set resolves.

Exports (each imported from its module on first use): Model, Parameters, add_markers, load_model, write_model from
calibrate.model.model; urdf_text, mass_factor from calibrate.model.urdf; ParameterLayout, FrameLayout, Block from
calibrate.model.blocks; Kinematics, build_kinematics, locked_balls from calibrate.model.kinematics; build_human_urdf
from calibrate.model.human; resolve, unresolved from calibrate.model.resolve.
"""

from ..exports import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(__name__, """
.model:Model,Parameters,add_markers,load_model,write_model .urdf:urdf_text,mass_factor
.blocks:ParameterLayout,FrameLayout,Block
.kinematics:Kinematics,build_kinematics,locked_balls .human:build_human_urdf .resolve:resolve,unresolved
""")
