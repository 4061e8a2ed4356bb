"""Shared fixtures: the bundled model, its kinematics, and short simulated trials."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import add_markers, load_model, write_model

ROOT = Path(__file__).resolve().parent.parent
HUMAN = ROOT / "models" / "human.urdf"


@pytest.fixture(scope="session")
def human():
    return load_model(HUMAN)


@pytest.fixture(scope="session")
def human_kin(human):
    return build_kinematics(human)


NUMBER = r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?"


def assert_same_text_and_numbers(got: str, want: str, rtol: float = 1e-12) -> None:
    """The same text with its numbers equal to `rtol`: the last digit of a float printed from a
    product of floats may differ between numpy builds (it did: ...83599994 vs ...83600014)."""
    assert re.split(NUMBER, got) == re.split(NUMBER, want)
    assert np.allclose([float(x) for x in re.findall(NUMBER, got)], [float(x) for x in re.findall(NUMBER, want)],
                       rtol=rtol, atol=1e-15)


def prior_jacobian_by_differences(problem, p: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """The prior residuals' Jacobian (n_prior, n_free) at full parameters `p` by central differences through the
    parameters' retraction: what Problem.prior's analytic Jacobian must equal."""
    fd = np.zeros((problem.prior(p, jacobian=False)[0].size, problem.n_free))
    for k in range(problem.n_free):
        e = np.zeros(problem.n_free)
        e[k] = h
        fd[:, k] = (problem.prior(problem.retract_parameters(p, e), jacobian=False)[0]
                    - problem.prior(problem.retract_parameters(p, -e), jacobian=False)[0]) / (2 * h)
    return fd


def markers_in_world(model, params, motion, tmp_path: Path, name: str) -> np.ndarray:
    """Every marker of the subject written with `params` (as `name` in `tmp_path`), read back by Pinocchio, at each
    frame of `motion` (n_frames, n_markers, 3): a fit checked through the written file, not our kinematics."""
    import pinocchio as pin

    subject = load_model(write_model(model, tmp_path / name, params))
    data = subject.pin.createData()
    ids = [subject.pin.getFrameId(n, pin.FrameType.BODY) for n in subject.marker_names]
    out = np.zeros((motion.n_frames, len(ids), 3))
    for f in range(motion.n_frames):
        q = subject.pin_configuration(motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        pin.framesForwardKinematics(subject.pin, data, q)
        out[f] = [data.oMf[i].translation for i in ids]
    return out


def with_medial_markers(model, joint: str, lateral: str, name: str, beyond: float):
    """`model` with a medial marker `name` on each side's `joint` hinge (L / R + name): the lateral marker (L / R +
    `lateral`) reflected through the plane across the hinge's axis at its centre, then `beyond` (m) further out."""
    p = model.parameters()
    new = {}
    for side in "LR":
        j = model.joints[model.joint_index(f"{joint}_{side.lower()}")]
        R = next(u.rotation for u in model.urdf_joints if u.name == j.urdf_joints[0])
        a = R @ p.axis[model.dof_index(j.dofs[0])]
        at = p.marker[model.marker_index(f"{side}{lateral}")]
        c = p.centre[model.joint_index(j.name)]
        out = float(a @ (at - c))
        new[f"{side}{name}"] = (j.parent, at - (2 * out + math.copysign(beyond, out)) * a)
    return add_markers(model, new)
