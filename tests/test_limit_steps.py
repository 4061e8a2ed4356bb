"""A step's model with the joint limits it crosses (Problem.limit_crossings, calibrate.solve.lm._HeldLimits) and the
frames whose blocks changed factored again alone (calibrate.solve.schur.refactor_frames), against the limits'
residuals and a whole elimination."""

from __future__ import annotations

import math

import numpy as np

from calibrate.model.blocks import FrameLayout
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns
from calibrate.solve.lm import State, _HeldLimits
from calibrate.solve.schur import eliminate, marquardt_diagonal, refactor_frames


def _problem_and_state(human, human_kin):
    sim = simulate_squats(human, frames=5, noise_mm=1.0, seed=0)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(), human_kin)
    m = sim.motion
    return problem, State(FrameLayout.coordinates(m.root_translation, m.angles), m.root_quaternion.copy(),
                          sim.truth.vector())


def test_limit_crossings_name_the_limits_a_step_carries_an_angle_across(human, human_kin):
    problem, state = _problem_and_state(human, human_kin)
    d = human.dof_index("knee_l")
    c = FrameLayout.angle(d)
    th = state.Z[:, c]
    assert np.all((th > problem.lower[d]) & (th < problem.upper[d]))
    dz = np.zeros_like(state.Z)
    dz[1, c] = problem.upper[d] - th[1] + 0.1  # 0.1 rad past the upper limit
    dz[2, c] = problem.upper[d] - th[2] + 1e-7  # grazes it: less than one noise SD's worth of residual
    dz[3, c] = problem.lower[d] - th[3] - 0.2  # 0.2 rad past the lower limit
    f, dof, w, r = problem.limit_crossings(state.Z, dz)
    assert sorted(zip(f.tolist(), dof.tolist(), strict=True)) == [(1, d), (3, d)]
    after = problem.limits(state.Z + dz)[:, d]  # the limit's residual beyond: w·(θ + δ − bound)
    for frame, weight, res in zip(f, w, r, strict=True):
        assert math.isclose(res + weight * dz[frame, c], after[frame], rel_tol=1e-12)  # linear in the step
    assert r[list(f).index(1)] < 0 < r[list(f).index(3)]  # inside the range: short of the bound
    assert problem.limit_crossings(state.Z, np.zeros_like(dz)) is None
    # An angle already beyond its limit has its row in the linearization: not a crossing.
    beyond = state.Z.copy()
    beyond[1, c] = problem.upper[d] + 0.05
    f, dof, _, _ = problem.limit_crossings(beyond, dz)
    crossed = set(zip(f.tolist(), dof.tolist(), strict=True))
    assert (1, d) not in crossed and (3, d) in crossed


def test_refactor_frames_equals_a_whole_elimination_and_the_rows_go_back(human, human_kin):
    problem, state = _problem_and_state(human, human_kin)
    lin = problem.linearize(state)
    damping = 1e-2 * marquardt_diagonal(np.diagonal(lin.A, axis1=1, axis2=2), float(lin.A.max()))
    A0, g0 = lin.A.copy(), lin.gz.copy()
    el = eliminate(lin, damping)
    held = _HeldLimits(lin, problem.layout.frame)
    d = [human.dof_index("knee_l"), human.dof_index("ankle_r")]
    assert held.take(np.array([1, 3]), np.array(d), np.array([1e3, 2e3]), np.array([-30.0, 12.0]))
    assert not held.take(np.array([1]), np.array(d[:1]), np.array([1e3]), np.array([-30.0]))  # taken already
    assert held.offset == 0.5 * (30.0**2 + 12.0**2)
    assert refactor_frames(lin, damping, el, np.array([3, 1]))
    whole = eliminate(lin, damping)
    for a, b in ((el.L, whole.L), (el.Y.dense(), whole.Y.dense()), (el.yz, whole.yz)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(el.S, whole.S, rtol=0, atol=1e-12 * np.abs(whole.S).max())
    c = problem.layout.frame.angle(d[0])
    assert lin.A[1, c, c] == A0[1, c, c] + 1e6 and lin.gz[1, c] == g0[1, c] + 1e3 * -30.0
    held.release()
    np.testing.assert_array_equal(lin.A, A0)
    np.testing.assert_array_equal(lin.gz, g0)
