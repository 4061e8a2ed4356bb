"""The model: URDF read into segments, markers, joints and parameters (Model, Parameters), URDF writing, symbolic
kinematics, the parametric human model, which segments a marker set resolves."""
