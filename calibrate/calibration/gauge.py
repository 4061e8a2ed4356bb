"""Gauge: segment frames turned to where the priors, the markers or a neutral trial's zero angles want
them, the data fit unchanged."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from calibrate.calibration.start import absolute, frames_of

from ..model.blocks import FrameLayout
from ..model.rotations import matrix_quats, quat_matrices, quat_multiply, quat_rotvecs
from ..problem.gauge import MARKER_FRAMES
from ..problem.options import SolverOptions
from ..problem.problem import Problem
from ..problem.state import State
from ..solve.lm import levenberg_marquardt


def align_gauge(problem: Problem, state: State, options: SolverOptions | None = None,
                centre_weight: float = 1.0) -> State:
    """Turn every free segment frame to the orientation the priors prefer (turn_frames;
    `centre_weight`: the joint centres' weight relative to their priors') and re-solve the frame
    coordinates for it (the solver's `options`, default SolverOptions()): the turn keeps the data fit,
    the re-solve answers the joint limits (a hinge's angle shifts by its child's turn) and the ball
    joints kept on their three angles."""
    aligned, _ = levenberg_marquardt(problem, turn_frames(problem, state, centre_weight), options, pose_only=True,
                                     max_iterations=20)
    return aligned


def turn_frames(problem: Problem, state: State, centre_weight: float = 1.0) -> State:
    """`state` with every free segment frame turned as Problem.align_frames turns it (`centre_weight`
    as there) and the frame coordinates carried along: the root's pose, a hinge's angle (its child
    turned about its axis), the SO(3) ball joints' reference rotations (_balls_carried); every
    marker stays where it was, but below a ball kept on its three angles (re-solved by align_gauge)."""
    model = problem.model
    net: dict[int, np.ndarray] = {}
    p, moves = problem.align_frames(state.p, centre_weight, net)
    # The root's and the balls' increments folded into their references first: the turns act on whole rotations.
    Z, Q, B = problem.kin.retract(state.Z, state.Q, state.B)
    for si, kind, G, t in moves:
        if kind == "rigid":
            R = quat_matrices(Q)
            Z[:, FrameLayout.translation] += np.einsum("fij,j->fi", R, t)
            Q = matrix_quats(R @ G)
        elif kind == "axis":
            j = next(j for j in model.joints if j.child == model.segments[si].name)
            d = model.dof_index(j.dofs[-1])
            # G turns about the hinge axis as align_frames found it: with every turn above carried into it (p's)
            a = problem.axis_direction(p, d)
            Z[:, FrameLayout.angle(d)] += float(quat_rotvecs(matrix_quats(G)) @ a)
    Q = np.where(Q[:, 3:4] < 0, -Q, Q)
    return State(Z, Q, p, _balls_carried(problem, B, net))


def _balls_carried(problem: Problem, B: np.ndarray, net: dict[int, np.ndarray]) -> np.ndarray:
    """The SO(3) ball joints' reference rotations B (F, n_balls, 4; their increments folded in) carried
    through the segment frames' turns `net` (segment -> N: its frame R turned to R N): a ball with origin
    rotation O between segments P and C turns from B to Oᵀ N_Pᵀ O B N_C, so that every segment and
    marker stays where it was.  Left to align_gauge's re-solve, each turn broke the fit (pig_walk: the
    cost 8.7e4 -> 4.6e7, 5 iterations to repair it; now 3.1e5, from the joint limits, and 3)."""
    kin, model = problem.kin, problem.model
    joint = {j.name: j for j in model.joints}
    urdf = {u.name: u for u in model.urdf_joints}
    left, right = [], []
    for ball in kin.balls:
        j = joint[ball.name]
        O = urdf[j.urdf_joints[0]].rotation
        NP, NC = net.get(model.segment_index(j.parent)), net.get(model.segment_index(j.child))
        left.append(np.eye(3) if NP is None else O.T @ NP.T @ O)
        right.append(np.eye(3) if NC is None else NC)
    if all(np.array_equal(m, np.eye(3)) for m in left + right):
        return B
    B = quat_multiply(quat_multiply(matrix_quats(np.array(left)), B), matrix_quats(np.array(right)))
    return np.where(B[..., 3:4] < 0, -B, B)


def align_markers(problem: Problem, state: State, options: SolverOptions | None = None) -> State:
    """Turn every free segment frame to where its markers put it against the base model's (the joint
    centres only breaking ties, MARKER_FRAMES) and re-solve the frame coordinates for it: the
    frames in which the lab's model defines its joint angles.  A change of gauge for the report (the
    data fit stays; the priors' cost rises), made once the solve is done: the solve itself runs in
    the gauge the priors prefer, where they hold the geometry least against the data (in the markers'
    gauge pig_walk's marker RMS ended 0.5 mm higher).  Under the priors' gauge a joint centre the data
    moved far turns its segment's frame against the markers: gait2392's lumbar centre, 73 mm from the
    base model's, turned the pelvis 14°, and every hip flexion angle read 18-19° below OpenSim's IK."""
    return align_gauge(problem, state, options, centre_weight=MARKER_FRAMES)


NEUTRAL_MAX = math.radians(45.0)  # a hinge held further from zero in the neutral trial may be no neutral pose
POSE_LIMIT_SLACK = math.radians(0.1)  # a lab's pose turn may carry no frame further than this past a limit


def align_neutral(problem: Problem, state: State, neutral: np.ndarray, options: SolverOptions | None = None,
                  pose: Mapping[str, float] | None = None
                  ) -> tuple[State, list[tuple[str, float]], list[str]]:
    """Turn every free segment frame but the root's (Problem.neutral_gauges) so that the frames
    marked `neutral` have zero joint angles on average, a tree level at a time, every frame's coordinates
    carried through the turns (as turn_frames carries them) and then re-solved against the joint limits
    with the solver's `options`; the data fit is unchanged.  A hinge (or universal joint) held more than
    NEUTRAL_MAX from zero in the neutral trial whose turn would carry the trials' angles beyond its limits (by more
    than LIMIT_NOTE_DEG in LIMIT_NOTE_FRACTION more of the frames than before the turn) is held there where the
    model has no neutral pose, and is not turned: pig_walk's static holds its elbows at 101 / 114 deg, and turned
    to zero there, the walk's elbows went 70-90 deg past their limits, whose re-solve dragged the walk's fit from
    8.7 to 62 mm.  (A ball joint has no limits in the solve: an arms-out static's shoulders are turned, the neutral
    being the arms-out pose.)  `pose` (coordinate -> rad): a lab's static pose (its Scale setup's coordinate
    tasks, calibrate.io.osim_setup.StaticPose): only the joints of the coordinates it names are turned, each
    named angle to its value on average (a ball joint's others kept at their means).  Returns the state,
    (joint, its mean angle in the neutral trial, rad) per joint not turned, and the coordinates of `pose` no turn
    can set (the root's, a frame its markers or a held axis fix, a universal joint's first angle)."""
    from .identifiability import LIMIT_NOTE_DEG, LIMIT_NOTE_FRACTION

    model = problem.model
    depth = {model.segments[0].name: 0}
    for j in model.joints:  # parents come first
        depth[j.child] = depth[j.parent] + 1
    segs = [(si, kind) for si, kind in problem.neutral_gauges() if kind != "rigid"]
    into = {j.child: j for j in model.joints}
    unset: list[str] = []
    targets: dict[int, float] | None = None
    if pose is not None:
        turnable = {model.segments[si].name: kind for si, kind in segs}
        targets = {}
        for name, value in pose.items():
            j = next((j for j in model.joints if name in j.dofs), None)
            kind = None if j is None else turnable.get(j.child)
            if kind is None or (kind == "axis" and name != j.dofs[-1]):
                unset.append(name)
            else:
                targets[model.dof_index(name)] = float(value)
        named = {model.dofs[d].name for d in targets}
        segs = [(si, kind) for si, kind in segs if any(d in named for d in into[model.segments[si].name].dofs)]
    skipped: list[tuple[str, float]] = []
    tol = math.radians(LIMIT_NOTE_DEG)
    for level in sorted({depth[model.segments[si].name] for si, _ in segs}):
        here = [(si, kind) for si, kind in segs if depth[model.segments[si].name] == level]
        Zn = absolute(problem.kin, frames_of(state, neutral))[0]
        every = FrameLayout.angles(absolute(problem.kin, state)[0])
        keep = []
        for si, kind in here:
            if kind == "axis":
                dof = model.dofs[model.dof_index(into[model.segments[si].name].dofs[-1])]
                k = model.dof_index(dof.name)
                mean = float(np.mean(FrameLayout.angles(Zn)[:, k])) - (targets or {}).get(k, 0.0)  # the turn

                def beyond(th: np.ndarray, d=dof) -> float:
                    return float(np.mean((th < d.lower - tol) | (th > d.upper + tol)))

                def past(th: np.ndarray, d=dof) -> np.ndarray:  # how far each frame lies beyond the range
                    return np.maximum(np.maximum(d.lower - th, th - d.upper), 0.0)

                # A large turn (a joint held bent) that carries a share of the frames past the limits: a few
                # degrees near a limit (squats' ankles at human.urdf's 30 deg) the re-solve absorbs.
                if abs(mean) > NEUTRAL_MAX and beyond(every[:, k] - mean) > beyond(every[:, k]) + LIMIT_NOTE_FRACTION:
                    skipped.append((into[model.segments[si].name].name, mean))
                    continue
                # A lab's pose is met only by a pure change of gauge: a turn that carries any frame further past the
                # joint's limits (which the re-solve would pull back, moving the fit) is left and said (Hamner2010's
                # static elbows, 39 deg there, turned to the setup's 5 deg put the walk's past full extension).
                if targets is not None and np.any(past(every[:, k] - mean) > past(every[:, k]) + POSE_LIMIT_SLACK):
                    skipped.append((into[model.segments[si].name].name, mean))
                    continue
            keep.append((si, kind))
        if not keep:
            continue
        net: dict[int, np.ndarray] = {}
        p, moves = problem.neutral_frames(state.p, Zn, keep, net, targets)
        # Every frame's coordinates carried through the turns: a hinge's angle by its child's turn, the balls'
        # reference rotations through every segment's (_balls_carried); the re-solve then answers the limits.
        Z, Q, B = problem.kin.retract(state.Z, state.Q, state.B)
        for si, kind, G, _ in moves:
            if kind == "axis":  # G turns about the hinge's (last) axis: its angle follows
                d = model.dof_index(into[model.segments[si].name].dofs[-1])
                Z[:, FrameLayout.angle(d)] += float(quat_rotvecs(matrix_quats(G))
                                                    @ problem.axis_direction(state.p, d))
        state, _ = levenberg_marquardt(problem, State(Z, Q, p, _balls_carried(problem, B, net)), options,
                                       pose_only=True, max_iterations=20)
    return state, skipped, unset
