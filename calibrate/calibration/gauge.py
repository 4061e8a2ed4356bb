"""Gauge: segment frames turned to where the priors (or a neutral trial's zero angles) want them, the
data fit unchanged."""

from __future__ import annotations

import numpy as np

from calibrate.calibration.start import absolute, frames_of

from ..model.blocks import FrameLayout
from ..model.kinematics import matrix_quats, quat_matrices, quat_rotvecs
from ..problem.options import SolverOptions
from ..problem.problem import Problem
from ..problem.state import State
from ..solve.lm import levenberg_marquardt


def align_gauge(problem: Problem, state: State, options: SolverOptions | None = None) -> State:
    """Turn every free segment frame to the orientation the priors prefer (Problem.align_frames)
    and re-solve the frame coordinates for it (the data fit is unchanged by construction; the
    solver's `options`, default SolverOptions())."""
    model = problem.model
    p, moves = problem.align_frames(state.p)
    Z, Q = state.Z.copy(), state.Q.copy()
    for si, kind, G, t in moves:
        if kind == "rigid":
            R = quat_matrices(Q)
            Z[:, FrameLayout.translation] += np.einsum("fij,j->fi", R, t)
            Q = matrix_quats(R @ G)
        elif kind == "axis":
            j = next(j for j in model.joints if j.child == model.segments[si].name)
            d = model.dof_index(j.dofs[-1])
            a = problem.axis_direction(state.p, d)
            Z[:, FrameLayout.angle(d)] += float(quat_rotvecs(matrix_quats(G)) @ a)  # G turns about the hinge axis
    Q = np.where(Q[:, 3:4] < 0, -Q, Q)
    aligned = State(Z, Q, p, state.B)
    aligned, _ = levenberg_marquardt(problem, aligned, options, pose_only=True, max_iterations=20)
    return aligned


def align_neutral(problem: Problem, state: State, neutral: np.ndarray, options: SolverOptions | None = None) -> State:
    """Turn every free segment frame but the root's (Problem.neutral_frames) so that the frames
    marked `neutral` have zero joint angles on average, a tree level at a time (a turn changes the
    ball angles below it, which are re-solved before the next level, with the solver's `options`); the
    data fit is unchanged."""
    model = problem.model
    depth = {model.segments[0].name: 0}
    for j in model.joints:  # parents come first
        depth[j.child] = depth[j.parent] + 1
    segs = [(si, kind) for si, kind in problem.neutral_gauges() if kind != "rigid"]
    into = {j.child: j for j in model.joints}
    for level in sorted({depth[model.segments[si].name] for si, _ in segs}):
        here = [(si, kind) for si, kind in segs if depth[model.segments[si].name] == level]
        p, moves = problem.neutral_frames(state.p, absolute(problem.kin, frames_of(state, neutral))[0], here)
        Z = state.Z.copy()
        for si, kind, G, _ in moves:
            if kind == "axis":  # G turns about the hinge's (last) axis: its angle follows
                d = model.dof_index(into[model.segments[si].name].dofs[-1])
                Z[:, FrameLayout.angle(d)] += float(quat_rotvecs(matrix_quats(G))
                                                    @ problem.axis_direction(state.p, d))
        state, _ = levenberg_marquardt(problem, State(Z, state.Q, p, state.B), options,
                                       pose_only=True, max_iterations=20)
    return state
