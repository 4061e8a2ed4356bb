"""A calibrated trial as a C3D file carries it, for the lab's own viewers (Mokka, Vicon Nexus, Visual3D): its markers
as recorded (labelled as the model's), and beside them, as model outputs the way Vicon writes Plug-in Gait's, every
frame's joint centres (``<joint>_JC``), the subject model's markers (``<marker>_model``) and each joint's angles
(``<joint>_angles``: its coordinates in order, degrees in the file; a joint of more than three as
``<joint>_angles2``...).  The joint centres and model markers are the subject model posed by the trial's motion
(calibrate.model.kinematics, the solve's own kinematics), so a viewer shows where calibrate puts each joint among the
markers and how far each model marker sits from its measured one.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..io.trial import Trial
from ..model.blocks import FrameLayout
from ..model.kinematics import build_kinematics

if TYPE_CHECKING:
    from ..io.motion import Motion
    from ..model.model import Model, Parameters
    from .result import Calibration

CENTRE_SUFFIX = "_JC"
MODEL_SUFFIX = "_model"
ANGLES_SUFFIX = "_angles"


def calibrated_trials(cal: Calibration) -> list[Trial]:
    """Each trial of `cal` with calibrate's joint centres, model markers and joint angles as model outputs
    (:attr:`Trial.model_outputs`, SI units: m and rad), in the calibration's frames; write them with
    :func:`calibrate.io.c3d.write_c3d`.  The trial's own model outputs (Plug-in Gait's) are not carried over."""
    kin = build_kinematics(cal.model)
    return [with_model_outputs(cal.model, cal.params, trial, motion, kin)
            for trial, motion in zip(cal.trials, cal.motions, strict=True)]


def with_model_outputs(model: Model, params: Parameters, trial: Trial, motion: Motion, kin=None) -> Trial:
    """`trial` (its markers labelled as `model`'s) with the subject (`model` at `params`) posed by `motion` beside
    it, as :func:`calibrated_trials` gives each trial of a calibration (`calibrate ik`'s trials too); `kin`: the
    model's kinematics, when already built."""
    if motion.n_frames != trial.n_frames:
        raise ValueError(f"{trial.source or 'trial'}: motion of {motion.n_frames} frames for a trial of "
                         f"{trial.n_frames}")
    kin = kin if kin is not None else build_kinematics(model)
    dof = {name: i for i, name in enumerate(model.dof_names)}
    markers, centres = kin.batch(FrameLayout.coordinates(motion.root_translation, motion.angles),
                                 motion.root_quaternion, params)
    entries = [(joint.name + CENTRE_SUFFIX, centres[:, k], "point") for k, joint in enumerate(model.joints)]
    entries += [(name + MODEL_SUFFIX, markers[:, k], "point") for k, name in enumerate(model.marker_names)]
    for joint in model.joints:
        for part in range(0, len(joint.dofs), 3):
            values = np.zeros((motion.n_frames, 3))
            for c, name in enumerate(joint.dofs[part:part + 3]):
                values[:, c] = motion.angles[:, dof[name]]
            entries.append((joint.name + ANGLES_SUFFIX + (str(part // 3 + 1) if part else ""), values, "angle"))
    taken = set(trial.labels)  # (a trial label of the same name keeps it: the output is suffixed)
    entries = [(label + "_calibrate" if label in taken else label, values, kind) for label, values, kind in entries]
    outputs = {label: values for label, values, _ in entries}
    kinds = {label: kind for label, _, kind in entries}
    return Trial(labels=trial.labels, markers=trial.markers, rate=trial.rate, first_frame=trial.first_frame,
                 source=trial.source, model_outputs=outputs, output_kinds=kinds,
                 output_units={label: "m" if kind == "point" else "rad" for label, kind in kinds.items()},
                 measurements=trial.measurements, start_time=trial.start_time, descriptions=trial.descriptions)
