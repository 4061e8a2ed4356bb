"""Hinge joints' lines in the world over a motion (centre and axis direction per frame), by Pinocchio's forward
kinematics of the written model: the reference for axis estimates (calibrate.calibration.evaluate, the Plug-in Gait
knee check).  Here, not in calibrate.simulation, so that a calibration's checks do not import scipy with the
simulator."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..io.motion import Motion
from .model import Model, Parameters, write_model


def joint_axes_world(model: Model, params: Parameters, motion: Motion) -> dict[str, np.ndarray]:
    """World direction (n_frames, 3) of every hinge joint's axis over a motion, for the model with
    parameters `params` (e.g. a simulation's truth): the reference for axis estimates."""
    return {name: axis for name, (_, axis) in hinge_lines_world(model, params, motion).items()}


def hinge_lines_world(model: Model, params: Parameters, motion: Motion) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Every hinge joint's line in the world over a motion, for the model with parameters `params`: its centre
    and its axis's direction, each (n_frames, 3), by Pinocchio's forward kinematics of the written model."""
    import tempfile

    import pinocchio as pin

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "subject.urdf"
        write_model(model, path, params)
        subject = Model(path)
    pm = subject.pin
    data = pm.createData()
    hinges = [j for j in subject.joints if j.kind == "hinge"]
    dofs = [subject.dofs[subject.dof_index(j.dofs[0])] for j in hinges]
    fids = [pm.getFrameId(d.name) for d in dofs]
    n = len(motion.times)
    out = {j.name: (np.zeros((n, 3)), np.zeros((n, 3))) for j in hinges}
    for f in range(n):
        q = subject.pin_configuration(motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        pin.framesForwardKinematics(pm, data, q)
        for j, d, fid in zip(hinges, dofs, fids, strict=True):
            out[j.name][0][f] = data.oMf[fid].translation
            out[j.name][1][f] = data.oMf[fid].rotation @ d.axis
    return out
