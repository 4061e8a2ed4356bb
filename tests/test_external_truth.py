"""End to end against a truth calibrate did not make.

The subject is models/human.urdf edited by hand here (three joint centres moved 20 mm, the knee's with its
lateral marker, two hinge axes tilted 4 and 3 degrees); its marker trajectories come from Pinocchio alone (the
URDF parsed by pinocchio.buildModelFromUrdf, smooth random joint motion, framesForwardKinematics of the marker
frames), with 1 mm noise, written as C3D by ezc3d.  Calibrating models/human.urdf to that file must
find the edits: joint centres and hinge axes compared in the world, frame by frame (so no
segment-frame convention of calibrate's enters the truth)."""

from __future__ import annotations

import math
import re

import ezc3d
import numpy as np
import pinocchio as pin
import pytest
from conftest import HUMAN

from calibrate.calibration.pipeline import calibrate
from calibrate.io.read import read_trial
from calibrate.model.model import load_model

FRAMES, RATE = 300, 100.0
# The hand edits: URDF joint -> new origin xyz (m, parent frame) or new axis (unit, joint frame).
# Base model: hip_r_flexion 0 -0.088 0; knee_l 0 0.002 -0.424 (axis ~y, so the move is across it:
# along a hinge's axis no motion shows a centre); shoulder_r_flexion, see the URDF.
MOVE = {"hip_r_flexion": np.array([0.012, 0.0, -0.016]),   # 20 mm
        "knee_l": np.array([0.016, 0.0, 0.012]),           # 20 mm, perpendicular to the knee axis
        "shoulder_r_flexion": np.array([0.0, -0.012, 0.016])}  # 20 mm
TILT = {"knee_r": (4.0, np.array([1.0, 0.0, 0.0])), "elbow_l": (3.0, np.array([0.0, 0.0, 1.0]))}


def _rotate(v: np.ndarray, about: np.ndarray, deg: float) -> np.ndarray:
    """Rodrigues: v turned by deg about the part of `about` perpendicular to v (a tilt of deg)."""
    k = about - (about @ v) / (v @ v) * v
    k = k / np.linalg.norm(k)
    t = math.radians(deg)
    return v * math.cos(t) + np.cross(k, v) * math.sin(t) + k * (k @ v) * (1 - math.cos(t))


def _edit(text: str, joint: str, tag: str, attr: str, fn) -> tuple[str, np.ndarray, np.ndarray]:
    """Replace `attr` of `<tag>` in `<joint name=joint>` by fn(old); returns text, old, new."""
    i = text.index(f'<joint name="{joint}"')
    j = text.index("</joint>", i)
    block = text[i:j]
    m = re.search(rf'<{tag} [^>]*{attr}="([^"]*)"', block)
    old = np.array([float(x) for x in m.group(1).split()])
    new = fn(old)
    block = block[:m.start(1)] + " ".join(repr(float(x)) for x in new) + block[m.end(1):]
    return text[:i] + block + text[j:], old, new


@pytest.fixture(scope="module")
def external(tmp_path_factory):
    """The hand-edited subject URDF, its Pinocchio model, the true q per frame, and the C3D path."""
    d = tmp_path_factory.mktemp("external")
    text = HUMAN.read_text()
    truth_axes = {}
    for joint, dxyz in MOVE.items():
        text, old, new = _edit(text, joint, "origin", "xyz", lambda o, dxyz=dxyz: o + dxyz)
        assert np.linalg.norm(new - old) == pytest.approx(0.020)
    # The knee's lateral marker moves with it: it sits over the epicondyle the flexion axis passes through
    # (Priors.knee_landmark holds a calibrated knee so; a knee moved away from its epicondyles is no subject's).
    text, _, _ = _edit(text, "LKNE_marker", "origin", "xyz", lambda o: o + MOVE["knee_l"])
    for joint, (deg, about) in TILT.items():
        text, old, new = _edit(text, joint, "axis", "xyz", lambda a, deg=deg, about=about: _rotate(a, about, deg))
        assert math.degrees(math.acos(abs(old @ new) / np.linalg.norm(old) / np.linalg.norm(new))) == \
            pytest.approx(deg, abs=1e-9)
        truth_axes[joint] = new / np.linalg.norm(new)
    urdf = d / "subject.urdf"
    urdf.write_text(text)
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    data = pm.createData()
    # Smooth random motion: each joint about the middle of its range, two sines of 0.4-1.1 Hz whose
    # amplitudes reach 40 % of the range (at most 60 deg) without leaving it; the pelvis turns and sways.
    rng = np.random.default_rng(11)
    t = np.arange(FRAMES) / RATE
    q = np.zeros((FRAMES, pm.nq))
    for jid in range(2, pm.njoints):
        iq = pm.joints[jid].idx_q
        lo, hi = pm.lowerPositionLimit[iq], pm.upperPositionLimit[iq]
        mid, amp = 0.5 * (lo + hi), min(0.4 * (hi - lo), math.radians(60)) / 2
        f, phase = rng.uniform(0.4, 1.1, 2), rng.uniform(0, 2 * np.pi, 2)
        q[:, iq] = mid + amp * (np.sin(2 * np.pi * f[0] * t + phase[0]) + np.sin(2 * np.pi * f[1] * t + phase[1]))
        assert lo <= q[:, iq].min() and q[:, iq].max() <= hi
    q[:, :3] = np.column_stack([0.2 * np.sin(0.5 * t), 0.1 * np.sin(0.7 * t), 1.0 + 0.05 * np.sin(1.3 * t)])
    yaw, roll = 0.6 * np.sin(0.4 * t), 0.15 * np.sin(0.9 * t)
    for f in range(FRAMES):
        R = pin.utils.rotate("z", yaw[f]) @ pin.utils.rotate("x", roll[f])
        q[f, 3:7] = pin.Quaternion(R).coeffs()  # x, y, z, w
    names = [pm.frames[i].name for i in range(pm.nframes) if pm.frames[i].name.endswith("_marker")]
    labels = [n[:-len("_marker")] for n in names]
    fids = [pm.getFrameId(n) for n in names]
    xyz = np.zeros((FRAMES, len(fids), 3))
    for f in range(FRAMES):
        pin.framesForwardKinematics(pm, data, q[f])
        xyz[f] = [data.oMf[i].translation for i in fids]
    xyz += rng.normal(0, 0.001, xyz.shape)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [RATE]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    points = np.ones((4, len(labels), FRAMES))
    points[:3] = 1000 * xyz.transpose(2, 1, 0)
    c3d["data"]["points"] = points
    path = d / "subject.c3d"
    c3d.write(str(path))
    return urdf, pm, q, truth_axes, path


def _world(pm, q: np.ndarray, joints: list[str], axes: dict[str, np.ndarray]) -> tuple[dict, dict]:
    """Per frame: world position of each URDF joint, and world direction of the given joint-frame axes."""
    data = pm.createData()
    pos = {j: np.zeros((len(q), 3)) for j in joints}
    ax = {j: np.zeros((len(q), 3)) for j in axes}
    for f in range(len(q)):
        pin.forwardKinematics(pm, data, q[f])
        for j in joints:
            pos[j][f] = data.oMi[pm.getJointId(j)].translation
        for j, a in axes.items():
            ax[j][f] = data.oMi[pm.getJointId(j)].rotation @ a
    return pos, ax


def test_calibration_finds_a_hand_edited_subject(human, external):
    urdf, pm, q, truth_axes, c3d = external
    trial = read_trial(c3d)
    assert trial.n_frames == FRAMES and set(trial.labels) == set(human.marker_names)
    cal = calibrate(human, trial)
    assert cal.converged, cal.summary.termination
    # The calibrated model and motion, through Pinocchio (the URDF calibrate writes).
    out = cal.write(urdf=urdf.parent / "calibrated.urdf")["urdf"]
    est_model = load_model(out)
    est_pm = pin.buildModelFromUrdf(str(out), pin.JointModelFreeFlyer())
    m = cal.motion
    q_est = np.array([est_model.pin_configuration(m.root_translation[f], m.root_quaternion[f], m.angles[f])
                      for f in range(FRAMES)])
    hinges = list(TILT) + ["knee_l"]
    balls = ["hip_r_flexion", "shoulder_r_flexion", "hip_l_flexion", "shoulder_l_flexion"]
    est_axis = {j: est_model.parameters().axis[est_model.dof_index(j)] for j in hinges}
    est_axis = {j: a / np.linalg.norm(a) for j, a in est_axis.items()}
    true_axis = {**truth_axes, "knee_l": np.array(
        [float(x) for x in re.search(r'<joint name="knee_l".*?<axis xyz="([^"]*)"', urdf.read_text(),
                                     re.S).group(1).split()])}
    tp, ta = _world(pm, q, balls + hinges, true_axis)
    ep, ea = _world(est_pm, q_est, balls + hinges, est_axis)
    # Ball joints (two moved by 20 mm, two not): world centres, median over frames.  Today 0.98 mm
    # (hip_r), 0.62 (shoulder_r), 0.92, 0.67; 2 mm (issue 4's target, 2x today's worst) is a tenth of
    # the edit: a centre left where the base model has it fails by 20 mm.
    for j in balls:
        err = 1000 * np.median(np.linalg.norm(ep[j] - tp[j], axis=1))
        assert err < 2.0, (j, err)
    # Hinges: the centre's distance from the true axis line (along the axis nothing shows it) and
    # the axis direction.  Today 0.59 / 0.63 / 0.67 mm off the axis and 0.18 (knee_r) / 0.53
    # (elbow_l) / 0.21 deg: 2 mm as the balls, 1.5 deg = half the smaller tilt and ~3x today's worst.
    for j in hinges:
        a = ta[j]
        v = ep[j] - tp[j]
        off = 1000 * np.median(np.linalg.norm(v - np.sum(v * a, axis=1)[:, None] * a, axis=1))
        assert off < 2.0, (j, off)
        ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(ea[j] * a, axis=1)), 0, 1)))
        assert np.median(ang) < 1.5, (j, np.median(ang))
    # The marker fit reaches the noise (1 mm per coordinate: 1.73 mm in 3-D, less the fitted share).
    assert 1.2e-3 < cal.marker_rms < 1.8e-3
