"""Joints a still trial holds where the moving trials never go: its markers beyond them left out.

A lab's static often holds the arms out (Plug-in Gait's and many OpenSim protocols' "T" or "A" pose) while
the walk after it swings them at the sides.  A model without a shoulder blade fixes the shoulder's centre on
the thorax, but raising the arm turns the blade up and carries the shoulder's centre (and the skin over the
acromion) a few centimetres with it.  Fitted with one geometry, the static's arm then pulls the arm's
geometry towards a compromise between two shoulders: on Rajagopal2016's recording (arms out, elbows bent
78 deg in the static) the left elbow ended folded to 164 deg with its axis turned 48 deg and two forearm
markers moved 74-88 mm; without the static's arm markers it ends at 45-64 deg in the walk, every arm
parameter within its prior.  The cost: the static's elbow bend no longer helps place the elbow's axis (a walk
that bends the elbows little leaves it at the base model's, Settings.auto_hold).

Test (on the start's poses, before the solve): for each joint of two or three degrees of freedom, its
rotation (child segment in parent segment) in each frame of a still trial against every frame of the
moving trials; the still trial is *far* at that joint when its median frame lies more than FAR_POSE from
the nearest moving frame.  The still trial's positions of the markers on the segments beyond that joint
are then left out (the moving trials place them, and must show at least MIN_MARKERS of them); after the
solve, the still trial's coordinates beyond the joint are fitted to those markers at the calibrated
geometry, the rest of each pose held (refit_beyond): its angles there as its markers show them.  The skin
over the acromion rides on the thorax in the models and is left to Settings.moved_markers."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..model.blocks import FrameLayout
from ..model.kinematics import Kinematics
from ..model.model import Model
from ..model.resolve import root_group
from ..problem.problem import LIMIT_MARGIN
from ..problem.state import State
from ..solve.ik import FrameSolver

FAR_POSE = math.radians(45.0)  # a still pose this far from every moving frame (standing in a walk: < 10 deg)
MIN_MARKERS = 3  # markers beyond the joint the moving trials must show for the still trial's to be left out
STILL_SAMPLE = 15  # frames of a still trial compared (its pose barely changes)
MOVING_SAMPLE = 400  # frames of the moving trials compared against, evenly spread


@dataclass(frozen=True)
class FarJoint:
    """A joint that still trial `trial` holds `angle` (rad) from every pose the moving trials reach."""

    trial: int  # index of the still trial among the calibration's trials
    joint: str
    angle: float  # rad: median over the still trial's frames of the rotation to the nearest moving frame
    markers: tuple[str, ...]  # the still trial's markers beyond the joint, left out of the fit

    def text(self, source: str) -> str:
        shown = ", ".join(self.markers[:6]) + (f" and {len(self.markers) - 6} more" if len(self.markers) > 6 else "")
        return (f"{source} (still) holds {self.joint} {math.degrees(self.angle):.0f} deg from every pose the moving "
                f"trials reach; its {shown} beyond it left out there")

    def to_json(self) -> dict:
        return {"trial": self.trial, "joint": self.joint, "angle_deg": math.degrees(self.angle),
                "markers": list(self.markers)}


def _beyond(model: Model, segment: str) -> list[str]:
    """`segment` and every segment below it in the tree."""
    children: dict[str, list[str]] = {}
    for j in model.joints:
        children.setdefault(j.parent, []).append(j.child)
    out, todo = [], [segment]
    while todo:
        s = todo.pop()
        out.append(s)
        todo.extend(children.get(s, []))
    return out


def _relative_rotations(model: Model, Z: np.ndarray, Q: np.ndarray, frames: np.ndarray,
                        joints: Sequence) -> np.ndarray:
    """(len(joints), len(frames), 3, 3) each joint's child segment frame in its parent's, by Pinocchio's
    forward kinematics of the base model (a rotation does not depend on the segments' scale)."""
    import pinocchio as pin

    pm = model.pin
    data = pm.createData()
    angles = FrameLayout.angles(Z)
    ids = [(pm.getFrameId(j.parent), pm.getFrameId(j.child)) for j in joints]
    out = np.empty((len(joints), len(frames), 3, 3))
    for i, f in enumerate(frames):
        pin.framesForwardKinematics(pm, data, model.pin_configuration(Z[f, FrameLayout.translation], Q[f], angles[f]))
        for k, (a, b) in enumerate(ids):
            out[k, i] = data.oMf[a].rotation.T @ data.oMf[b].rotation
    return out


def far_joints(model: Model, Z: np.ndarray, Q: np.ndarray, spans: Sequence[slice], still: Sequence[bool],
               seen: np.ndarray) -> list[FarJoint]:
    """The joints each still trial holds more than FAR_POSE from every frame of the moving trials, at poses
    (Z absolute coordinates, Q root quaternions: calibrate.calibration.start.absolute) of every frame of the
    trials in `spans`; `seen` (frames, model markers).  A joint beyond one already far is not tested again, nor are
    the joints of the root and the segments welded to it (the hips, the lumbar): the rule is for a limb's joint the
    model cannot follow (a shoulder without its blade), while a static stands where a crouching trial never goes
    and the models' hips and trunk follow any pose; leaving out the static's legs or trunk would leave it little
    to fit (Pose2Sim's crouching child: hips 69-79 deg, L5/S1 115 deg away, the tibia then scaled 0.52) or nothing
    to turn a two-keypoint pelvis (Pose2Sim's demo: its static's pelvis turned 150 deg).  Nothing when no trial is
    still or none moves."""
    moving = [sl for sl, s in zip(spans, still, strict=True) if not s]
    if not moving or not any(still):
        return []
    # Model.joints lists parents first: a far joint's own descendants come after it and are not tested again.
    root = root_group(model)
    joints = [j for j in model.joints if len(j.dofs) >= 2 and j.parent not in root
              and model.pin.existFrame(j.parent) and model.pin.existFrame(j.child)]
    if not joints:
        return []
    moving_frames = np.concatenate([np.arange(sl.start, sl.stop) for sl in moving])
    moving_frames = moving_frames[np.linspace(0, moving_frames.size - 1, min(MOVING_SAMPLE, moving_frames.size))
                                  .round().astype(int)]
    seen_moving = seen[moving_frames].any(axis=0)
    R_moving = _relative_rotations(model, Z, Q, moving_frames, joints)
    segment_markers: dict[str, list[int]] = {}
    for k, m in enumerate(model.markers):
        segment_markers.setdefault(m.segment, []).append(k)
    out: list[FarJoint] = []
    for t, (sl, s) in enumerate(zip(spans, still, strict=True)):
        if not s:
            continue
        frames = np.arange(sl.start, sl.stop)
        frames = frames[np.linspace(0, frames.size - 1, min(STILL_SAMPLE, frames.size)).round().astype(int)]
        R_still = _relative_rotations(model, Z, Q, frames, joints)
        done: set[str] = set()  # segments already beyond a far joint of this trial
        for k, j in enumerate(joints):
            if j.child in done:
                continue
            # angle between rotations A and B: arccos((trace(A'B) - 1) / 2), for every still x moving pair
            tr = np.einsum("sij,mij->sm", R_still[k], R_moving[k])
            nearest = np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)).min(axis=1)
            angle = float(np.median(nearest))
            if angle <= FAR_POSE:
                continue
            segments = _beyond(model, j.child)
            idx = [i for seg in segments for i in segment_markers.get(seg, [])]
            mine = [i for i in idx if seen[sl, i].any()]
            if not mine or sum(bool(seen_moving[i]) for i in idx) < MIN_MARKERS:
                continue
            done.update(segments)
            out.append(FarJoint(t, j.name, angle, tuple(model.markers[i].name for i in mine)))
    return out


def refit_beyond(kin: Kinematics, state: State, observed: np.ndarray, far: Sequence[FarJoint],
                 spans: Sequence[slice], locked: np.ndarray | None = None, evaluator=None) -> State:
    """`state` with each far joint's still-trial frames' coordinates of that joint and every joint below it
    fitted to the markers beyond it (`observed`: the positions left out of the fit, (F, n_markers, 3)) at
    the geometry state.p, the rest of each frame's pose held: the still trial's arm angles as its markers
    show them, though those markers did not shape the geometry.  A still trial holds one pose: REFIT_FRAMES
    of its frames, evenly spread, are fitted (each from the last one's fit) and every other frame takes the
    nearest one's angles beyond the joint.  `locked` (n_dofs,): coordinates the run holds (Settings.lock,
    auto-locks), kept at their values (a ball joint with one of its angles locked is kept whole).  `evaluator`: the
    per-frame evaluator at state.p (the problem's compiled one, Problem.frame_evaluator), else kin's."""
    solver = FrameSolver(kin, state.p, evaluator, margin=LIMIT_MARGIN)  # the limits as the solve's
    Z, Q = state.Z.copy(), state.Q.copy()
    B = None if state.B is None else state.B.copy()
    names = [j.name for j in kin.model.joints]
    nb = 0 if B is None else B.shape[1]
    for fj in far:
        _, sub_dofs, sub_mk, *_ = solver.plan[names.index(fj.joint)]
        free = np.asarray(sub_dofs)
        if locked is not None and locked.any():
            # A locked forearm rotation beyond a raised shoulder stays locked (PiG_Calibration-FlatFoot-Hole's
            # auto-locked radioulnar_r was carried 14 deg off its lock, the lock's cost 6.6e10).
            held = set(np.flatnonzero(locked).tolist())
            for ball in kin.balls:
                if held & set(ball.dofs):
                    held |= set(ball.dofs)
            free = np.array([c for c in free if FrameLayout.dof(c) not in held], dtype=int)
            if not free.size:
                continue
        # the balls among the joints beyond: their reference quaternions travel with the angles
        balls = [b for b, ball in enumerate(kin.balls) if np.isin(FrameLayout.angle(np.asarray(ball.dofs)), free).any()]
        frames = np.arange(spans[fj.trial].start, spans[fj.trial].stop)
        frames = frames[[len([k for k in sub_mk if np.isfinite(observed[f, k, 0])]) >= 2 for f in frames]]
        if not frames.size:
            continue
        fitted = frames[np.unique(np.linspace(0, frames.size - 1, min(REFIT_FRAMES, frames.size)).round().astype(int))]
        last = None
        for f in fitted:
            seen = [k for k in sub_mk if np.isfinite(observed[f, k, 0])]
            z = Z[f].copy()
            q = Q[f] if B is None else np.concatenate([Q[f], B[f].ravel()])
            if last is not None:  # the last fitted frame's angles beyond the joint, and its balls' references
                z[free] = Z[last, free]
                for b in balls:
                    q[4 + 4 * b:8 + 4 * b] = B[last, b]
            z, q, _, _ = solver.solve(z, q, observed[f], seen, free, 20 if last is None else 6)
            Z[f] = z
            if nb:
                B[f] = q[4:].reshape(nb, 4)
            last = f
        nearest = fitted[np.abs(frames[:, None] - fitted[None, :]).argmin(axis=1)]
        Z[frames[:, None], free[None, :]] = Z[nearest[:, None], free[None, :]]
        if balls:
            B[frames[:, None], np.array(balls)[None, :]] = B[nearest[:, None], np.array(balls)[None, :]]
    return State(Z, Q, state.p, B)


REFIT_FRAMES = 40  # frames of a still trial whose angles beyond a far joint are fitted (the rest: the nearest's)
