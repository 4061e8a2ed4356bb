"""Symbolic kinematics h(z, p) against Pinocchio and finite differences; frame-wise IK."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calibrate.errors import CalibrateError
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model, write_model
from calibrate.model.rotations import cayley_np, retract_root
from calibrate.simulation.simulate import simulate_squats
from calibrate.simulation.subject import perturb_parameters
from calibrate.solve.ik import inverse_kinematics


def _pin_points(model, q):
    d = model.pin.createData()
    pin.forwardKinematics(model.pin, d, q)
    pin.updateFramePlacements(model.pin, d)
    mk = np.array([d.oMf[model.pin.getFrameId(m.name, pin.FrameType.BODY)].translation for m in model.markers])
    jc = np.array([d.oMf[model.pin.getFrameId(j.urdf_joints[0])].translation for j in model.joints])
    return mk, jc


def _random_configs(model, rng, n):
    for _ in range(n):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        t = rng.normal(size=3)
        th = rng.uniform(-np.pi, np.pi, model.n_dofs)
        yield t, quat, th


def _max_fk_error(model, kin, params, pin_model_of, rng, n=100):
    err = 0.0
    for t, quat, th in _random_configs(model, rng, n):
        z = np.concatenate([t, np.zeros(3), th])
        mk, jc = _pin_points(pin_model_of, pin_model_of.pin_configuration(t, quat, th))
        err = max(err, np.abs(kin.markers(z, quat, params) - mk).max(), np.abs(kin.centres(z, quat, params) - jc).max())
    return err


def test_fk_equals_pinocchio_on_human(human, human_kin):
    err = _max_fk_error(human, human_kin, human.parameters(), human, np.random.default_rng(0))
    assert err < 1e-10, err


def test_fk_equals_pinocchio_on_perturbed_copy(human, human_kin, tmp_path):
    rng = np.random.default_rng(7)
    truth = perturb_parameters(human, rng)
    path = write_model(human, tmp_path / "perturbed.urdf", truth)
    other = load_model(path)
    # (a) the base model's h with the perturbed p reproduces Pinocchio on the written URDF
    err_a = _max_fk_error(human, human_kin, truth, other, rng)
    # (b) the perturbed copy's own symbolic kinematics agree with Pinocchio too
    err_b = _max_fk_error(other, build_kinematics(other), other.parameters(), other, rng)
    assert err_a < 1e-10 and err_b < 1e-10, (err_a, err_b)
    assert np.abs(truth.scale - 1).max() > 0.02  # the copy really differs


def test_jacobians_match_central_differences(human, human_kin):
    rng = np.random.default_rng(3)
    p = perturb_parameters(human, rng).vector()
    for t, quat, th in _random_configs(human, rng, 3):
        z = np.concatenate([t, 0.1 * rng.normal(size=3), th])
        Jz, Jp = (np.asarray(x) for x in human_kin.jac(z, quat, p))

        def f(zz, pp, quat=quat):
            return np.asarray(human_kin.h(zz, quat, pp)[0]).ravel(order="F")

        h = 1e-6
        Fz = np.column_stack([(f(z + h * e, p) - f(z - h * e, p)) / (2 * h) for e in np.eye(z.size)])
        Fp = np.column_stack([(f(z, p + h * e) - f(z, p - h * e)) / (2 * h) for e in np.eye(p.size)])
        assert np.abs(Jz - Fz).max() < 1e-7, np.abs(Jz - Fz).max()
        assert np.abs(Jp - Fp).max() < 1e-7, np.abs(Jp - Fp).max()
    # the p-Jacobian is sparse: a marker depends only on its chain's parameters
    assert human_kin.jac.sparsity_out(1).nnz() < 0.15 * Jp.size


def test_joint_jacobian_equals_pinocchio(human, human_kin):
    rng = np.random.default_rng(5)
    t, quat, th = next(_random_configs(human, rng, 1))
    q = human.pin_configuration(t, quat, th)
    d = human.pin.createData()
    pin.computeJointJacobians(human.pin, d, q)
    pin.updateFramePlacements(human.pin, d)
    Jz = np.asarray(human_kin.jac(np.concatenate([t, np.zeros(3), th]), quat, human.parameters().vector())[0])
    for k, m in enumerate(human.markers):
        fid = human.pin.getFrameId(m.name, pin.FrameType.BODY)
        Jpin = pin.getFrameJacobian(human.pin, d, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
        np.testing.assert_allclose(Jz[3 * k:3 * k + 3, 6:], Jpin[:, 6:], atol=1e-12)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("angle_deg", [90.0, -90.0, 180.0])
def test_root_rotation_has_no_gimbal_lock(human, human_kin, axis, angle_deg):
    """At ±90° (and 180°) about each axis the rotation increment keeps full rank and the
    retraction q_ref ⊗ Cay(delta) reproduces Pinocchio at the rotated pose."""
    half = np.radians(angle_deg) / 2
    quat = np.zeros(4)
    quat[axis], quat[3] = np.sin(half), np.cos(half)
    rng = np.random.default_rng(axis)
    th = rng.uniform(-1, 1, human.n_dofs)
    p = human.parameters()
    z = np.concatenate([[0.1, 0.2, 0.9], np.zeros(3), th])
    Jz = np.asarray(human_kin.jac(z, quat, p.vector())[0])
    s = np.linalg.svd(Jz[:, 3:6], compute_uv=False)
    s0 = np.linalg.svd(np.asarray(human_kin.jac(z, [0, 0, 0, 1.0], p.vector())[0])[:, 3:6], compute_uv=False)
    np.testing.assert_allclose(s, s0, rtol=1e-9)  # conditioning independent of the orientation
    assert s.min() > 0.1
    delta = np.array([0.3, -0.2, 0.25])
    z2 = z.copy()
    z2[3:6] = delta
    q_new = retract_root(quat, delta)
    mk, _ = _pin_points(human, human.pin_configuration(z[:3], q_new, th))
    np.testing.assert_allclose(human_kin.markers(z2, quat, p), mk, atol=1e-12)
    R = pin.Quaternion(quat[3], *quat[:3]).toRotationMatrix() @ cayley_np(delta)
    np.testing.assert_allclose(pin.Quaternion(q_new[3], *q_new[:3]).toRotationMatrix(), R, atol=1e-12)


def test_batch_equals_single_frames(human, human_kin):
    sim = simulate_squats(human, frames=20, noise_mm=0.0, seed=2)
    M, C = human_kin.batch(sim.motion.z(), sim.motion.root_quaternion, sim.truth)
    for f in (0, 7, 19):
        z, q = sim.motion.z()[f], sim.motion.root_quaternion[f]
        np.testing.assert_allclose(M[f], human_kin.markers(z, q, sim.truth), atol=1e-14)
        np.testing.assert_allclose(C[f], human_kin.centres(z, q, sim.truth), atol=1e-14)


def test_ik_recovers_true_motion_noise_free(human, human_kin):
    sim = simulate_squats(human, frames=60, noise_mm=0.0, seed=11)
    res = inverse_kinematics(human_kin, sim.trial, sim.truth)
    assert res.rms < 1e-9
    err = np.angle(np.exp(1j * (res.motion.angles - sim.motion.angles)))
    assert np.abs(err).max() < 1e-6
    np.testing.assert_allclose(res.motion.root_translation, sim.motion.root_translation, atol=1e-8)


def test_ik_started_from_a_motion(human, human_kin):
    """`start`: every frame from the given motion's pose.  From the true motion turned by up to 0.1 rad per
    coordinate the noise-free fit is the truth again; from a fit of the same frames it stops at once; a motion of
    other frames is refused."""
    sim = simulate_squats(human, frames=40, noise_mm=0.0, seed=13)
    rng = np.random.default_rng(0)
    off = sim.motion
    moved = type(off)(off.times, off.root_translation + rng.uniform(-0.02, 0.02, off.root_translation.shape),
                      off.root_quaternion, off.angles + rng.uniform(-0.1, 0.1, off.angles.shape), off.dof_names)
    res = inverse_kinematics(human_kin, sim.trial, sim.truth, start=moved)
    assert res.rms < 1e-9
    assert np.abs(np.angle(np.exp(1j * (res.motion.angles - sim.motion.angles)))).max() < 1e-6
    again = inverse_kinematics(human_kin, sim.trial, sim.truth, start=res.motion)
    assert again.iterations.max() <= 1
    np.testing.assert_allclose(again.motion.angles, res.motion.angles, atol=1e-9)
    short = type(off)(off.times[:10], off.root_translation[:10], off.root_quaternion[:10], off.angles[:10],
                      off.dof_names)
    with pytest.raises(CalibrateError, match="start motion has 10 frames"):
        inverse_kinematics(human_kin, sim.trial, sim.truth, start=short)


def _straight_then_bent_arm(human, human_kin, rotation_deg: float, bend_deg: float):
    """Noise-free squats whose right arm is held out (flexion 90, adduction -80 deg, turned `rotation_deg` about its
    length), its elbow straight for the first quarter and then bent to `bend_deg`; the arm's only markers an elbow and
    a wrist on the bones' line (video keypoints).  Returns (trial, true geometry, true angles)."""
    from calibrate.io.trial import Trial
    from calibrate.model.kinematics import FrameLayout

    sim = simulate_squats(human, frames=80, noise_mm=0.0, seed=11)
    truth = sim.truth.copy()
    truth.marker[human.marker_index("RELB")] = truth.centre[human.joint_index("elbow_r")]
    truth.marker[human.marker_index("RWRA")] = truth.centre[human.joint_index("wrist_r")]
    names = list(human.dof_names)
    angles = sim.motion.angles.copy()
    angles[:, names.index("shoulder_r_flexion")] = np.radians(90.0)
    angles[:, names.index("shoulder_r_adduction")] = np.radians(-80.0)
    angles[:, names.index("shoulder_r_rotation")] = np.radians(rotation_deg)
    angles[:, names.index("elbow_r")] = np.radians(bend_deg) * np.clip((np.linspace(0.0, 1.0, 80) - 0.25) / 0.75,
                                                                       0.0, 1.0)
    markers, _ = human_kin.batch(FrameLayout.coordinates(sim.motion.root_translation, angles),
                                 sim.motion.root_quaternion, truth)
    markers = markers.copy()
    for name in ("RUPA", "RFRM", "RWRB", "RFIN"):  # the arm's other markers: none on the bones' line
        markers[:, human.marker_index(name)] = np.nan
    motion = type(sim.motion)(sim.motion.times, sim.motion.root_translation, sim.motion.root_quaternion, angles,
                              sim.motion.dof_names)
    return Trial(labels=human.marker_names, markers=markers, rate=100.0), truth, motion


@pytest.mark.parametrize("rotation_deg", [-80.0, 0.0])
def test_ik_finds_a_straight_arm_turned_by_its_later_bend(human, human_kin, rotation_deg):
    """While the elbow is straight the arm's turn about its length is free, and a track warm-started frame to frame
    can hold a wrong turn as the elbow bends, the elbow straight at its limit and the fit drifting (Pose2Sim's right
    arm: 13 -> 55 mm).  The drifting frames are fitted again from scratch, the elbow started off its limit, and the
    frames before refitted backwards: every frame fits the noise-free markers exactly."""
    trial, truth, _ = _straight_then_bent_arm(human, human_kin, rotation_deg, 130.0)
    res = inverse_kinematics(human_kin, trial, truth)
    assert np.max(res.marker_rms) < 1e-6


def test_ik_restarts_a_frame_whose_one_limb_is_in_another_basin(human, human_kin):
    """Every frame started with the arm half a turn about its length and the elbow straight (`start`): the wrist then
    misses by up to some 100 mm while the frame's RMS over its 33 markers stays under 20 mm (BTKData's walk: an arm
    turned at 12 mm where the calibration's own motion fits 4).  Such a frame, 1.5x worse than those before it and
    over 5 mm, is fitted again from scratch: every frame fits the noise-free markers."""
    trial, truth, motion = _straight_then_bent_arm(human, human_kin, 0.0, 60.0)
    names = list(human.dof_names)
    wrong = motion.angles.copy()
    wrong[:, names.index("shoulder_r_rotation")] = np.pi
    wrong[:, names.index("elbow_r")] = 0.0
    start = type(motion)(motion.times, motion.root_translation, motion.root_quaternion, wrong, motion.dof_names)
    res = inverse_kinematics(human_kin, trial, truth, start=start)
    assert np.max(res.marker_rms) < 1e-4


def test_ik_with_gaps_and_noise_reaches_the_noise_floor(human, human_kin):
    sim = simulate_squats(human, frames=60, noise_mm=1.0, gaps=True, seed=12)
    res = inverse_kinematics(human_kin, sim.trial, sim.truth)
    # 3-D RMS of pure noise is sqrt(3) mm; a fit absorbs part of it (38 DoF of 117 coordinates)
    assert 1.0e-3 < res.rms < np.sqrt(3) * 1e-3
    assert np.isnan(res.residuals).any()  # gaps stay gaps


GENERIC_URDF = """<robot name="generic">
  <link name="base"><inertial><mass value="2"/>UNIT_INERTIA</inertial></link>
  <link name="arm"><inertial><mass value="1"/>UNIT_INERTIA</inertial></link>
  <link name="plate"><inertial><mass value="0.3"/>UNIT_INERTIA</inertial>
  </link>
  <link name="wheel"><inertial><mass value="0.5"/>UNIT_INERTIA</inertial>
  </link>
  <link name="hand_a"/>
  <link name="hand"><inertial><mass value="0.4"/>UNIT_INERTIA</inertial>
  </link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="arm"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.3 -0.5 1.1"/><axis xyz="0.2 0.9 -0.3"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="weld" type="fixed"><parent link="arm"/><child link="plate"/>
    <origin xyz="0.05 0.02 -0.3" rpy="0.7 0 -0.4"/>
  </joint>
  <joint name="spin" type="continuous"><parent link="plate"/><child link="wheel"/><origin xyz="0 0.1 0" rpy="0 1.2 0"/>
    <axis xyz="1 0 0"/></joint>
  <joint name="wrist_a" type="revolute"><parent link="arm"/><child link="hand_a"/><origin xyz="0 0 -0.4" rpy="0 0 0.2"/>
    <axis xyz="1 0 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="wrist_b" type="revolute"><parent link="hand_a"/><child link="hand"/><origin xyz="0 0 0" rpy="0.1 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <link name="M1"/><joint name="M1_j" type="fixed"><parent link="base"/><child link="M1"/>
    <origin xyz="0.1 0 0"/></joint>
  <link name="M2"/><joint name="M2_j" type="fixed"><parent link="plate"/><child link="M2"/>
    <origin xyz="0.02 0.03 0.04" rpy="0.5 0.5 0.5"/></joint>
  <link name="M3"/><joint name="M3_j" type="fixed"><parent link="wheel"/><child link="M3"/>
    <origin xyz="0 0.07 0.01"/></joint>
  <link name="M4"/><joint name="M4_j" type="fixed"><parent link="hand"/><child link="M4"/>
    <origin xyz="0.01 0 -0.08"/></joint>
</robot>
""".replace("UNIT_INERTIA", '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/>')


def test_generic_tree_rpy_continuous_and_welded_segments(tmp_path):
    """Origins with rpy, a continuous joint, a welded (fixed) segment and a connector chain."""
    src = tmp_path / "generic.urdf"
    src.write_text(GENERIC_URDF)
    model = load_model(src)
    kinds = {j.name: j.kind for j in model.joints}
    assert kinds == {"shoulder": "hinge", "weld": "fixed", "spin": "hinge", "wrist": "universal"}
    assert model.dofs[model.dof_index("spin")].continuous
    kin = build_kinematics(model)
    rng = np.random.default_rng(21)
    assert _max_fk_error(model, kin, model.parameters(), model, rng, n=30) < 1e-12
    p = model.parameters()
    p.scale[:] = rng.uniform(0.8, 1.2, p.scale.size)
    p.centre[:] += rng.normal(0, 0.02, p.centre.shape)
    p.marker[:] += rng.normal(0, 0.02, p.marker.shape)
    p.axis[:] += rng.normal(0, 0.1, p.axis.shape)
    other = load_model(write_model(model, tmp_path / "perturbed.urdf", p))
    assert _max_fk_error(model, kin, p, other, rng, n=30) < 1e-12



def test_kinematics_are_built_once_per_structure_and_are_each_models_own(tmp_path):
    """build_kinematics makes the graphs once per model structure: a model differing only in what p holds (a
    joint centre, a marker, a limit) shares them, and each Kinematics is its model's (its limits); one whose fixed
    rotation inside a joint differs gets graphs of its own.  Each, built after the others in one process, agrees
    with Pinocchio on its own URDF."""
    def model_of(name: str, text: str):
        (tmp_path / name).write_text(text)
        return load_model(tmp_path / name)

    base = model_of("base.urdf", GENERIC_URDF)
    moved = model_of("moved.urdf", GENERIC_URDF.replace('xyz="0.05 0.02 -0.3" rpy="0.7 0 -0.4"',
                                                        'xyz="0.09 -0.01 -0.25" rpy="0.7 0 -0.4"')
                     .replace('<origin xyz="0.01 0 -0.08"/>', '<origin xyz="0.03 0.02 -0.06"/>')
                     .replace('lower="-1" upper="1"', 'lower="-0.8" upper="0.9"'))
    turned = model_of("turned.urdf", GENERIC_URDF.replace('rpy="0.1 0 0"/>', 'rpy="0.35 0 0"/>'))
    kb, km, kt = (build_kinematics(m) for m in (base, moved, turned))
    assert km.h is kb.h and km.h_ref_jz is kb.h_ref_jz  # the same structure: one set of graphs
    assert kt.h is not kb.h  # the universal joint's fixed turn is part of the structure
    assert km.model is moved and kb.model is base and kt.model is turned
    assert moved.dofs[moved.dof_index("wrist_a")].upper == 0.9 and base.dofs[base.dof_index("wrist_a")].upper == 1
    rng = np.random.default_rng(5)
    for model, kin in ((turned, kt), (moved, km), (base, kb)):
        assert _max_fk_error(model, kin, model.parameters(), model, rng, n=20) < 1e-12
    # the turn moves the hand's marker: the shared graphs would have put it where the base model has it
    z, quat = np.concatenate([np.zeros(6), [0.4, 0.3, 0.5, -0.6]]), np.array([0.0, 0.0, 0.0, 1.0])
    assert np.abs(kt.markers(z, quat, turned.parameters()) - kb.markers(z, quat, base.parameters())).max() > 1e-3

# ------------------------------------------------------------------ rotations in numpy, against scipy's Rotation
def test_rotation_helpers_equal_scipy_rotation():
    # Written out so that no command imports scipy on its way (0.25 s); scipy's Rotation is the reference.
    from scipy.spatial.transform import Rotation, Slerp

    from calibrate.model.rotations import (
        matrix_quats,
        quat_inverse,
        quat_multiply,
        quat_rotvecs,
        rotvec_quats,
        slerp_quats,
    )

    rng = np.random.default_rng(3)
    q = rng.normal(size=(2000, 4))
    q[:5] = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [0, 0, 0, -1]]  # half turns, no turn
    q[5:10] = np.array([0, 0, 0, 1.0]) + 1e-9 * rng.normal(size=(5, 4))  # below the series' switch
    R = Rotation.from_quat(q)
    M = R.as_matrix()
    np.testing.assert_allclose(matrix_quats(M), Rotation.from_matrix(M).as_quat(), rtol=0, atol=1e-15)
    np.testing.assert_allclose(quat_rotvecs(q), R.as_rotvec(), rtol=0, atol=1e-14)
    v = rng.normal(size=(2000, 3)) * np.r_[1e-7, 1e-4, 1.0, 3.0][rng.integers(0, 4, 2000)][:, None]
    np.testing.assert_allclose(rotvec_quats(v), Rotation.from_rotvec(v).as_quat(), rtol=0, atol=1e-15)
    a, b = q[:1000], q[1000:]
    ours = quat_multiply(a, quat_inverse(b / np.linalg.norm(b, axis=1, keepdims=True)))
    theirs = (Rotation.from_quat(a) * Rotation.from_quat(b).inv()).as_matrix()
    np.testing.assert_allclose(Rotation.from_quat(ours).as_matrix(), theirs, rtol=0, atol=1e-14)
    keys = np.sort(rng.choice(400, 30, replace=False)).astype(float)
    at = np.r_[keys[0], rng.uniform(keys[0], keys[-1], 500), keys, keys[-1]]
    k = q[10:40]  # random keys (between two half turns the shortest arc has no one direction)
    ours = Rotation.from_quat(slerp_quats(keys, k, at)).as_matrix()  # the same rotation (q or -q)
    np.testing.assert_allclose(ours, Slerp(keys, Rotation.from_quat(k))(at).as_matrix(), rtol=0, atol=1e-14)
    with pytest.raises(ValueError, match="within the key times"):
        slerp_quats(keys, k, keys[-1:] + 1)


def test_euler_and_rotation_vector_helpers_equal_scipy_rotation():
    # The OpenSim import and exports read and write Euler angles (OpenSim's body-fixed X-Y-Z, URDF's rpy, the
    # ground joint's Z-Y-X) without scipy; its Rotation is the reference, at every sequence and at gimbal lock.
    import warnings

    from scipy.spatial.transform import Rotation

    from calibrate.model.rotations import (
        euler_matrices,
        euler_quats,
        matrix_eulers,
        matrix_rotvecs,
        quat_eulers,
        rotvec_matrices,
    )

    rng = np.random.default_rng(11)
    turns = lambda a, b: np.abs(np.angle(np.exp(1j * (a - b)))).max()  # noqa: E731 - angles apart, mod 2 pi
    sequences = [a + b + c for a in "xyz" for b in "xyz" for c in "xyz" if a != b != c]
    assert len(sequences) == 12
    for seq in sequences + [s.upper() for s in sequences]:
        angles = rng.uniform(-np.pi, np.pi, (600, 3))
        angles[:50, 1] = 0.0  # gimbal lock: the middle angle at an end of its range
        angles[50:100, 1] = np.pi / 2 * rng.choice([-1.0, 1.0], 50) if seq[0] != seq[2] else np.pi
        R = Rotation.from_euler(seq, angles)
        np.testing.assert_allclose(euler_matrices(seq, angles), R.as_matrix(), rtol=0, atol=2e-15)
        assert np.abs(np.abs(euler_quats(seq, angles) @ R.as_quat().T).diagonal() - 1).max() < 1e-15
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # scipy warns at gimbal lock; the helpers give its angles silently
            want_q, want_m = R.as_euler(seq), Rotation.from_matrix(R.as_matrix()).as_euler(seq)
        assert turns(quat_eulers(R.as_quat(), seq), want_q) < 1e-14, seq
        assert turns(matrix_eulers(R.as_matrix(), seq), want_m) < 1e-14, seq
        np.testing.assert_allclose(euler_matrices(seq, matrix_eulers(R.as_matrix(), seq)), R.as_matrix(), atol=1e-14)
    for seq in ("x", "Y", "xy", "ZX"):
        angles = rng.uniform(-3, 3, len(seq))
        np.testing.assert_allclose(euler_matrices(seq, angles), Rotation.from_euler(seq, angles).as_matrix(),
                                   rtol=0, atol=1e-15)
    np.testing.assert_allclose(euler_matrices("x", 0.7), Rotation.from_euler("x", 0.7).as_matrix(), atol=1e-15)
    v = rng.normal(size=(1000, 3)) * np.r_[1e-7, 1e-4, 1.0, 1.7][rng.integers(0, 4, 1000)][:, None]
    np.testing.assert_allclose(rotvec_matrices(v), Rotation.from_rotvec(v).as_matrix(), rtol=0, atol=1e-15)
    M = Rotation.from_rotvec(v).as_matrix()
    np.testing.assert_allclose(matrix_rotvecs(M), Rotation.from_matrix(M).as_rotvec(), rtol=0, atol=1e-14)
    for bad in ("xx", "xyzx", "xYz", "abc", ""):
        with pytest.raises(ValueError, match="Euler sequence"):
            euler_matrices(bad, np.zeros(len(bad)))
    with pytest.raises(ValueError, match="takes 3 angles"):
        euler_matrices("xyz", np.zeros(2))
    with pytest.raises(ValueError, match="Euler sequence"):
        matrix_eulers(np.eye(3), "xy")


def test_importing_calibrate_imports_no_scipy():
    # scipy stays a dependency (labelling, the simulator, tests) but no command pays for it on its way in (an
    # OpenSim model's commands neither: tests/test_osim_import.py; nor the demo's simulator).
    import subprocess
    import sys

    code = ("import sys, calibrate, calibrate.cli.main, calibrate.simulation.simulate; "  # the demo's simulator
            "print(sorted(m for m in sys.modules if m.startswith('scipy')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_one_quaternion_retracts_to_the_same_bits_as_many():
    """retract_root of one quaternion (its float path, used at every step of frame-wise inverse kinematics)
    gives the bits of the vectorised path, over increments from 1e-8 to 1 rad."""
    rng = np.random.default_rng(11)
    Q = rng.normal(size=(5000, 4))
    Q /= np.linalg.norm(Q, axis=1, keepdims=True)
    D = rng.normal(size=(5000, 3)) * 10 ** rng.uniform(-8, 0, size=(5000, 1))
    many = retract_root(Q, D)
    one = np.array([retract_root(q, d) for q, d in zip(Q, D, strict=True)])
    assert np.array_equal(one, many)
    assert np.all(one[:, 3] >= 0)


def test_one_frame_retracts_its_balls_to_the_same_bits_as_many(human_kin):
    """Kinematics.retract_one (floats, once per frame's solve in frame-wise inverse kinematics) gives the bits of
    retract_refs (numpy over frames) for the root and every SO(3) ball, over increments of 1e-8 to 3 rad in size."""
    assert human_kin.balls  # the bundled model's balls (hips, shoulders, ...) are solved on SO(3)
    rng = np.random.default_rng(12)
    Z = rng.normal(size=(3000, human_kin.model.nz)) * 10 ** rng.uniform(-8, 0.5, size=(3000, 1))
    refs = rng.normal(size=(3000, human_kin.n_refs // 4, 4))
    refs = (refs / np.linalg.norm(refs, axis=2, keepdims=True)).reshape(3000, -1)
    many_z, many_refs = human_kin.retract_refs(Z, refs)
    one = [human_kin.retract_one(z, r) for z, r in zip(Z, refs, strict=True)]
    assert np.array_equal(np.array([z for z, _ in one]), many_z)
    assert np.array_equal(np.array([r for _, r in one]), many_refs)
    assert np.all(many_refs.reshape(3000, -1, 4)[:, :, 3] >= 0)


def test_compiled_kinematics_fit_as_the_virtual_machine_does(human, human_kin):
    """compiled_kinematics' per-frame evaluator (the model's compiled C code) gives CasADi's markers and
    Jacobian to rounding, and frame-wise inverse kinematics through it the same poses."""
    from calibrate.problem.problem import compiled_kinematics

    kin = compiled_kinematics(human_kin)
    if kin.compiled is None:
        pytest.skip("no C compiler: nothing compiled")
    assert compiled_kinematics(kin) is kin
    sim = simulate_squats(human, frames=15, noise_mm=1.0, seed=8)
    p = sim.truth.vector()
    vm, cc = human_kin.frame_evaluator(p, reference=True), kin.frame_evaluator(p, reference=True)
    rng = np.random.default_rng(3)
    refs = human_kin.refs(np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9]), None)[0]
    for _ in range(5):
        z = 0.3 * rng.normal(size=human.nz)
        m0, j0 = (a.copy() for a in vm(z, refs))
        m1, j1 = cc(z, refs)
        assert np.allclose(m1, m0, rtol=0, atol=1e-12) and np.allclose(j1, j0, rtol=0, atol=1e-12)
    a = inverse_kinematics(human_kin, sim.trial, sim.truth)
    b = inverse_kinematics(kin, sim.trial, sim.truth)
    assert np.allclose(b.motion.angles, a.motion.angles, atol=1e-7)
    assert abs(b.rms - a.rms) < 1e-9


def test_a_two_marker_pelvis_is_started_whatever_the_labs_heading(human):
    """A sparse set (LASI and RASI alone on the pelvis, as a markerless pelvis's two keypoints) walking in any
    direction of the lab: the first frame's root is placed by every marker as one rigid body (and, as before, unturned
    at their mean; the better fit kept), so the fit reaches the noise's level whatever the heading.  Before, the root
    started unturned only, and two of these walks ended in another basin at two headings of four (0.72-0.82 mm);
    Pose2Sim's subject folded a foot (48 mm against 15)."""
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from calibrate.problem.problem import LIMIT_MARGIN
    from calibrate.simulation.simulate import simulate_gait
    from calibrate.solve.ik import inverse_kinematics

    keep = ["LASI", "RASI", "LKNE", "RKNE", "LANK", "RANK", "LHEE", "RHEE", "LTOE", "RTOE", "LSHO", "RSHO", "C7",
            "LELB", "RELB", "LWRA", "RWRA", "LFHD", "RFHD"]
    kin = build_kinematics(human)
    for seed in (1, 2):
        sim = simulate_gait(human, frames=30, noise_mm=0.5, seed=seed)
        for yaw in (0.0, 90.0, 180.0, -120.0):
            turned = Rotation.from_euler("z", yaw, degrees=True).apply(np.array(sim.trial.markers).reshape(-1, 3))
            trial = replace(sim.trial, markers=turned.reshape(sim.trial.markers.shape)).select(keep)
            fit = inverse_kinematics(kin, trial, sim.truth, margin=LIMIT_MARGIN)
            assert fit.rms < 0.0006, (seed, yaw, fit.rms)
