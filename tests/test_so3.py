"""Ball joints on SO(3) in the solver (the solver's form h_ref of calibrate.model.kinematics): against
Pinocchio and finite differences, and through 180 degrees of shoulder abduction, where the
URDF's flexion-adduction-rotation angles meet their gimbal lock at 90 degrees."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from calibrate.model.kinematics import IDENTITY
from calibrate.problem.options import SolverOptions
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.problem.state import State
from calibrate.solve.lm import levenberg_marquardt


def _pin_markers(model, t, quat, th):
    d = model.pin.createData()
    pin.framesForwardKinematics(model.pin, d, model.pin_configuration(t, quat, th))
    return np.array([d.oMf[model.pin.getFrameId(m.name, pin.FrameType.BODY)].translation for m in model.markers])


def _random_refs(kin, rng, F):
    """Random root quaternions and ball references (F, n_balls, 4)."""
    Q = Rotation.random(F, random_state=rng).as_quat()
    B = Rotation.random(F * len(kin.balls), random_state=rng).as_quat().reshape(F, len(kin.balls), 4)
    return Q, B


def test_solver_form_equals_pinocchio_at_its_absolute_angles(human, human_kin):
    """Markers of h_ref at random references and increments equal Pinocchio's at the URDF
    coordinates Kinematics.absolute gives for them (1e-12 m): the reference form, its retraction
    and the angle recovery describe one and the same pose."""
    kin, p = human_kin, human.parameters().vector()
    assert {b.name for b in kin.balls} == {"hip_l", "hip_r", "lumbar", "neck", "shoulder_l", "shoulder_r"}
    rng = np.random.default_rng(0)
    F = 30
    Q, B = _random_refs(kin, rng, F)
    Z = np.column_stack([rng.normal(size=(F, 3)), rng.normal(0, 0.3, (F, 3)), rng.uniform(-2, 2, (F, human.n_dofs))])
    refs = kin.refs(Q, B)
    Za, Qa = kin.absolute(Z, Q, B)
    Zr, Qr, Br = kin.retract(Z, Q, B)
    refs_r = kin.refs(Qr, Br)
    for f in range(F):
        want = _pin_markers(human, Za[f, :3], Qa[f], Za[f, 6:])
        got = np.asarray(kin.h_ref(Z[f], refs[f], p)[0]).T
        assert np.abs(got - want).max() < 1e-12
        # retracted: increments of the balls and the root zero, the same markers
        assert np.abs(np.asarray(kin.h_ref(Zr[f], refs_r[f], p)[0]).T - want).max() < 1e-12
    ball_cols = [6 + d for b in kin.balls for d in b.dofs]
    assert np.all(Zr[:, ball_cols] == 0) and np.all(Zr[:, 3:6] == 0)
    # with every reference the identity the solver's form is the URDF's (absolute) form
    M_abs, _ = kin.batch(Za, Qa, p)
    ident = kin.refs(Qa, None)
    for f in range(0, F, 7):
        assert np.abs(np.asarray(kin.h_ref(Za[f], ident[f], p)[0]).T - M_abs[f]).max() < 1e-12


def test_solver_form_jacobian_matches_finite_differences(human, human_kin):
    """d markers / dz of h_ref (what the solver uses), at a pose with the left shoulder abducted
    90 degrees (the URDF angles' gimbal lock), against central differences; its ball columns are
    the (orthonormal) joint axes' cross products, of full rank there."""
    kin, p = human_kin, human.parameters().vector()
    rng = np.random.default_rng(1)
    Q, B = _random_refs(kin, rng, 1)
    th = np.zeros(human.n_dofs)
    th[human.dof_index("shoulder_l_adduction")] = -np.pi / 2
    _, _, B = kin.retract(np.concatenate([np.zeros(6), th])[None], Q, None)
    z = np.concatenate([rng.normal(size=3), np.zeros(3), rng.uniform(-0.3, 0.3, human.n_dofs)])
    ball = next(b for b in kin.balls if b.name == "shoulder_l")
    z[6 + np.array(ball.dofs)] = 0.0
    refs = kin.refs(Q, B)[0]
    _, J = kin.h_ref_jz(z, refs, p)
    J = np.asarray(J)
    h = 1e-6
    fd = np.empty_like(J)
    for c in range(z.size):
        e = np.zeros_like(z)
        e[c] = h
        plus, minus = (np.asarray(kin.h_ref_jz(z + s * e, refs, p)[0]).ravel() for s in (1, -1))
        fd[:, c] = (plus - minus) / (2 * h)
    assert np.abs(J - fd).max() < 1e-7
    # The absolute angles' Jacobian is singular there (flexion and rotation turn about one line);
    # the increments' is not: the three columns of the humerus markers have rank 3.
    rows = np.concatenate([3 * human.marker_index(m) + np.arange(3) for m in ("LELB", "LUPA", "LWRA")])
    cols = 6 + np.array(ball.dofs)
    assert np.linalg.matrix_rank(J[np.ix_(rows, cols)], tol=1e-6) == 3
    za, qa = kin.absolute(z[None], Q, B)
    _, Ja = kin.h_jz(za[0], qa[0], p)
    assert np.linalg.matrix_rank(np.asarray(Ja)[np.ix_(rows, cols)], tol=1e-6) == 2


def _abduction_sweep(human, F=181):
    """Coordinates (F, nz) of a pose sweeping the left arm from the side to overhead: 0 to 180
    degrees of abduction (through 90, the gimbal lock), with some flexion and rotation."""
    s = np.linspace(0.0, 1.0, F)
    Z = np.zeros((F, human.nz))
    Z[:, 2] = 1.0
    Z[:, 6 + human.dof_index("shoulder_l_adduction")] = -np.pi * s
    Z[:, 6 + human.dof_index("shoulder_l_flexion")] = 0.3 * np.sin(2 * np.pi * s)
    Z[:, 6 + human.dof_index("shoulder_l_rotation")] = 0.4 * s
    Z[:, 6 + human.dof_index("elbow_l")] = 0.5
    return Z


def test_absolute_angles_are_continuous_through_the_gimbal_lock(human, human_kin):
    """Through 180 degrees of abduction the output angles reproduce the pose (markers 1e-12 m)
    and stay continuous: no frame-to-frame jump larger than the motion's own (no 2 pi jumps, one
    branch), in the URDF's angles, although they pass through the flexion-adduction-rotation
    sequence's singularity."""
    kin, p = human_kin, human.parameters().vector()
    Z = _abduction_sweep(human)
    Q = np.tile(IDENTITY, (Z.shape[0], 1))
    M, _ = kin.batch(Z, Q, p)
    Zr, Qr, Br = kin.retract(Z, Q, None)
    Za, Qa = kin.absolute(Zr, Qr, Br)
    Ma, _ = kin.batch(Za, Qa, p)
    assert np.abs(Ma - M).max() < 1e-12
    step = np.abs(np.diff(Za[:, 6:], axis=0)).max()
    assert step < 2 * np.abs(np.diff(Z[:, 6:], axis=0)).max() + 1e-9


def test_absolute_angles_stay_within_half_a_turn_of_the_range_near_the_gimbal_lock(human, human_kin):
    """An arm circling 10 degrees from the gimbal lock (adduction -80 deg) three times: its flexion, the angle about
    the lock's axis, turns three whole turns (what kineticstoolkit's tennis serve did to 1100 deg).  The output angles
    reproduce every pose (markers 1e-12 m) and each stays within half a turn of the middle of its limits; unwrapped,
    flexion ran from -360 to 720 deg."""
    kin, p = human_kin, human.parameters().vector()
    F = 241
    Z = np.zeros((F, human.nz))
    Z[:, 2] = 1.0
    dofs = [human.dof_index(f"shoulder_l_{a}") for a in ("flexion", "adduction", "rotation")]
    Z[:, 6 + dofs[1]] = np.radians(-80.0)
    Z[:, 6 + dofs[0]] = np.linspace(0.0, 6 * np.pi, F)
    Q = np.tile(IDENTITY, (F, 1))
    M, _ = kin.batch(Z, Q, p)
    Za, Qa = kin.absolute(*kin.retract(Z, Q, None))
    Ma, _ = kin.batch(Za, Qa, p)
    assert np.abs(Ma - M).max() < 1e-12
    lo, hi = (np.array([getattr(human.dofs[d], b) for d in dofs]) for b in ("lower", "upper"))
    out = Za[:, 6 + np.array(dofs)]
    assert np.all(np.abs(out - 0.5 * (lo + hi)) <= np.pi + 1e-12), np.degrees([out.min(0), out.max(0)])


def test_pose_solve_through_overhead_abduction(human, human_kin):
    """The global solver's pose-only fit (Problem + levenberg_marquardt on the solver's form)
    recovers every frame of the overhead sweep from a start 10 degrees off in every ball joint,
    markers to 1e-9 m, and the output angles give the true poses."""
    kin, p = human_kin, human.parameters().vector()
    Z = _abduction_sweep(human, F=61)
    F = Z.shape[0]
    Q = np.tile(IDENTITY, (F, 1))
    M, _ = kin.batch(Z, Q, p)
    problem = Problem(human, M, Settings(free=()), kin)
    rng = np.random.default_rng(2)
    off = [rng.normal(0, 0.01, (F, 3)), np.zeros((F, 3)), rng.normal(0, np.radians(10), (F, human.n_dofs))]
    start = Z + np.concatenate(off, axis=1)
    # Noise-free markers: asked to go on to exactness, not to stop once the cost falls by less than a χ² unit
    # (the default atol, met here at 7e-8 m after 6 steps).
    state, summary = levenberg_marquardt(problem, State(start, Q.copy(), p.copy()), SolverOptions(atol=1e-12),
                                         pose_only=True, max_iterations=50)
    res = problem.marker_residuals(state)
    assert np.nanmax(np.abs(res)) < 1e-9
    Za, Qa = kin.absolute(state.Z, state.Q, state.B, previous=Z[0, 6:])
    Ma, _ = kin.batch(Za, Qa, p)
    assert np.abs(Ma - M).max() < 1e-9


def test_overhead_trial_calibrates_as_squats_do(human, human_kin):
    """A trial whose shoulders go through 180 degrees of elevation (simulate_overhead: serve and
    throw arcs, abduction through the gimbal lock): the calibration finds the shoulder centres
    as it does on squats (0.57-0.62 mm measured; limit 1.5 mm, 2.5x), fits the markers to the
    noise floor, and the output shoulder angles follow the truth's branch (5-8 degrees RMS
    measured, from t1/t3 near the lock where only their sum is well defined; limit 15 degrees,
    where a wrong branch costs 100-180)."""
    from calibrate import calibrate
    from calibrate.calibration.evaluate import compare_to_truth
    from calibrate.simulation.simulate import simulate_overhead

    sim = simulate_overhead(human, frames=300, noise_mm=1.0, seed=1)
    cal = calibrate(human, sim.trial, kinematics=human_kin)
    assert cal.converged
    cmp = compare_to_truth(cal, sim)
    assert cmp.centre_error["shoulder_l"] < 1.5e-3 and cmp.centre_error["shoulder_r"] < 1.5e-3
    assert cmp.marker_rms < 1.05 * cmp.floor_rms
    for side in ("l", "r"):
        for dof in ("flexion", "adduction", "rotation"):
            assert cmp.angle_rms_per_dof_deg[f"shoulder_{side}_{dof}"] < 15.0


def test_a_ball_whose_limits_do_not_decide_takes_the_branch_nearer_its_ranges_middle():
    """Each rotation has two angle triplets, (t1, t2, t3) and (t1 + pi, pi - t2, t3 + pi).  A shoulder of +-180 deg
    (Expert1's generic.osim) keeps both inside its limits, and the two branches' smoothness costs are equal but for
    rounding, which had chosen between them: `calibrate ik` reported one walk's arm at -160, -175, -170 deg and
    another's same poses at -13, -17, 11.  Now the branch nearer the range's middle is taken, on every one of 200
    random short motions within 1.1 rad of it (the angles given back to 1e-9 rad; before, 90 came back on the other
    branch)."""
    from calibrate.model.kinematics import BallJoint
    from calibrate.model.rotations import quat_matrices

    joint = BallJoint("shoulder", (0, 1, 2), np.eye(3), np.full(3, -np.pi), np.full(3, np.pi))
    rng = np.random.default_rng(7)
    for _ in range(200):
        centre = rng.uniform(-1.1, 1.1, 3)  # the branch nearer the middle: the other lies >= 1.9 rad off in each angle
        angles = centre + np.cumsum(rng.normal(0.0, 0.01, (40, 3)), axis=0)
        out = joint.angles(quat_matrices(joint.quaternion(angles)))
        assert np.abs(out - angles).max() < 1e-9, (angles[0], out[0])
