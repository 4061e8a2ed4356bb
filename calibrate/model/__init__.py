"""The model: URDF read into segments, markers, joints and parameters (Model, Parameters), URDF writing, symbolic
kinematics, the parametric human model, which segments a marker set resolves.

Exports (each from its module, imported on first use):

    Model, Parameters, add_markers, load_model, write_model   -- calibrate.model.model
    ParameterLayout, FrameLayout, Block   -- calibrate.model.blocks
    Kinematics, build_kinematics   -- calibrate.model.kinematics
    build_human_urdf   -- calibrate.model.human
    resolve, unresolved   -- calibrate.model.resolve
"""

from ..exports import lazy_exports

_EXPORTS = {
    "Model": ".model",
    "Parameters": ".model",
    "add_markers": ".model",
    "load_model": ".model",
    "write_model": ".model",
    "ParameterLayout": ".blocks",
    "FrameLayout": ".blocks",
    "Block": ".blocks",
    "Kinematics": ".kinematics",
    "build_kinematics": ".kinematics",
    "build_human_urdf": ".human",
    "resolve": ".resolve",
    "unresolved": ".resolve",
}
__all__ = sorted(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
