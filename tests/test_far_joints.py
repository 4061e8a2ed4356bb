"""A static holding the arms out where the moving trial keeps them low (calibrate.calibration.far_joints): the
static's arm markers are left out, so that a shoulder the static shows elsewhere (its blade turned up, which the
model's shoulder cannot follow) does not bend the arm's geometry.  Simulated: the truth known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibrate.calibration.far_joints import FAR_POSE, far_joints
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.io.trial import Trial
from calibrate.model.blocks import FrameLayout
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_gait

ABDUCTION = math.radians(85.0)
ARM = ("LUPA", "LELB", "LFRM", "LWRA", "LWRB", "LFIN", "RUPA", "RELB", "RFRM", "RWRA", "RWRB", "RFIN")


@pytest.fixture(scope="module")
def model():
    return load_model("models/human.urdf")


@pytest.fixture(scope="module")
def walk(model):
    """A simulated walk: the arms swing at the sides (shoulder flexion 5 +- 15 deg, abduction 10 deg)."""
    return simulate_gait(model, frames=300, seed=3)


def arms_out_static(model, sim, frames: int = 60, lift: float = 0.0, seed: int = 1, abduction: float = ABDUCTION):
    """(Trial, angles, root quaternions) of a static of `sim`'s subject with both arms abducted `abduction`; `lift`
    (m): the arm markers raised by that much, as a shoulder blade turned up carries the arm (what the model cannot
    do)."""
    rng = np.random.default_rng(seed)
    angles = np.zeros((frames, model.n_dofs))
    for side in "lr":
        angles[:, model.dof_index(f"shoulder_{side}_adduction")] = -abduction
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (frames, 1))
    markers, _ = build_kinematics(model).batch(FrameLayout.coordinates(np.zeros((frames, 3)), angles), quat,
                                               sim.truth)
    markers = markers + np.array([0.0, 0.0, 0.95])
    for lab in ARM:
        markers[:, model.marker_index(lab), 2] += lift
    observed = markers + rng.normal(0.0, 0.001, markers.shape)
    return Trial(model.marker_names, observed, 100.0, 0, "static.c3d"), angles, quat


def test_the_shoulders_a_static_holds_out_are_found_and_nothing_else(model, walk):
    static, angles, quat = arms_out_static(model, walk)
    Z = np.concatenate([FrameLayout.coordinates(np.zeros((static.n_frames, 3)), angles),
                        FrameLayout.coordinates(walk.motion.root_translation, walk.motion.angles)])
    Q = np.concatenate([quat, walk.motion.root_quaternion])
    spans = [slice(0, static.n_frames), slice(static.n_frames, Z.shape[0])]
    seen = np.ones((Z.shape[0], len(model.markers)), dtype=bool)
    found = far_joints(model, Z, Q, spans, [True, False], seen)
    assert sorted(f.joint for f in found) == ["shoulder_l", "shoulder_r"]
    for f in found:
        side = f.joint[-1].upper()
        assert f.trial == 0 and set(f.markers) == {lab for lab in ARM if lab[0] == side}
        # The walk's arms: their own abduction's range, measured here from the truth, sets the distance.
        ab = -walk.motion.angles[:, model.dof_index(f"shoulder_{f.joint[-1]}_adduction")]
        assert FAR_POSE < f.angle <= ABDUCTION - ab.max() + math.radians(10)
    # The walk is no still trial; a static in the walk's own poses is near them.
    assert far_joints(model, Z, Q, spans, [False, False], seen) == []
    near = walk.motion.angles[:40]
    Zn = np.concatenate([FrameLayout.coordinates(np.zeros((40, 3)), near), Z[static.n_frames:]])
    Qn = np.concatenate([walk.motion.root_quaternion[:40], Q[static.n_frames:]])
    assert far_joints(model, Zn, Qn, [slice(0, 40), slice(40, Zn.shape[0])], [True, False],
                      np.ones((Zn.shape[0], len(model.markers)), dtype=bool)) == []
    # An "A" pose (arms 30 deg out; the walk swings them about 10 deg out) is near the walk's poses: kept.
    a_pose, a_angles, _ = arms_out_static(model, walk, abduction=math.radians(30.0))
    Za = np.concatenate([FrameLayout.coordinates(np.zeros((a_pose.n_frames, 3)), a_angles), Z[static.n_frames:]])
    assert far_joints(model, Za, Q, spans, [True, False], seen) == []
    # The moving trial must show the markers beyond the joint: the static's are then its only ones, kept.
    blind = seen.copy()
    blind[static.n_frames:, [model.marker_index(lab) for lab in ARM]] = False
    assert far_joints(model, Z, Q, spans, [True, False], blind) == []


def test_a_static_arm_the_model_cannot_follow_no_longer_bends_the_shoulders(model, walk):
    """The static's arm markers 40 mm higher than the model's shoulder puts them (a blade turned up): left out,
    the shoulder centres end about where a static the model can follow puts them; kept (--keep-far-joints),
    the compromise moves them."""
    static, _, _ = arms_out_static(model, walk, lift=0.04)
    consistent, _, _ = arms_out_static(model, walk)
    errors = {}
    for name, trial, far in (("consistent", consistent, False), ("left out", static, True),
                             ("kept", static, False)):
        cal = calibrate(model, [trial, walk.trial], Settings(far_joints=far))
        # Each shoulder centre's world path over the walk against the truth's (median distance, mm).
        mo = cal.motions[1]
        _, C = build_kinematics(cal.model).batch(FrameLayout.coordinates(mo.root_translation, mo.angles),
                                                 mo.root_quaternion, cal.params)
        errors[name] = np.array([1e3 * float(np.median(np.linalg.norm(C[:, k] - walk.clean_centres[:, k], axis=1)))
                                 for k in (model.joint_index("shoulder_l"), model.joint_index("shoulder_r"))])
        if far:
            assert sorted(f.joint for f in cal.far_joints) == ["shoulder_l", "shoulder_r"]
            # The static's positions of the arm markers left out (unseen there), the walk's kept.
            arm = [cal.model.marker_index(lab) for lab in ARM]
            assert np.isnan(cal.residuals[:static.n_frames, arm]).all()
            assert np.isfinite(cal.residuals[static.n_frames:, arm]).mean() > 0.9
            # The static's arm angles fitted to its own markers afterwards (not left at the start's): its
            # abduction, and up to ~8 deg more for the lift (40 mm over a 0.3 m upper arm).
            for side in "lr":
                ab = -cal.motions[0].angles[:, model.dof_index(f"shoulder_{side}_adduction")]
                assert ABDUCTION - math.radians(2) < np.median(ab) < ABDUCTION + math.radians(12)
            report = calibration_report(cal)
            assert [f["joint"] for f in report["far_joints"]] == [f.joint for f in cal.far_joints]
            assert report["far_joints"][0]["trial"] == "static.c3d"
            assert "far pose     static.c3d (still) holds shoulder_" in summary_text(cal)
        else:
            assert cal.far_joints == ()
    # A static the model follows places the shoulders best (sub-millimetre); without the static's arm the walk
    # alone places them less well, yet far better than the compromise with a static it cannot follow.
    assert np.all(errors["consistent"] < 2.0), errors
    assert np.all(errors["left out"] < 0.6 * errors["kept"]) and errors["kept"].min() > 25.0, errors


def test_locked_coordinates_beyond_a_far_joint_stay_locked(model, walk):
    """The static's arm angles fitted afterwards leave the coordinates the run locks at their values: a forearm
    rotation locked beyond a raised shoulder (BTKData's PiG_Calibration-FlatFoot-Hole: its auto-locked radioulnar_r
    carried 14 deg off its lock, the lock's cost 6.6e10 in the summary)."""
    static, _, _ = arms_out_static(model, walk, lift=0.04)
    lock = {"radioulnar_l": 0.2, "radioulnar_r": 0.0}
    cal = calibrate(model, [static, walk.trial], Settings(lock=tuple(lock.items())))
    assert sorted(f.joint for f in cal.far_joints) == ["shoulder_l", "shoulder_r"]
    for mo in cal.motions:
        for name, value in lock.items():
            np.testing.assert_allclose(mo.angles[:, mo.dof_names.index(name)], value, atol=1e-6, err_msg=name)
    # The static's other arm angles are still fitted to its markers (its abduction, as in the test above).
    ab = -cal.motions[0].angles[:, model.dof_index("shoulder_r_adduction")]
    assert ABDUCTION - math.radians(2) < np.median(ab) < ABDUCTION + math.radians(12)
    # The summary's final cost is the fit's: no lock residual of 1e5 per noise SD per radian in it.
    assert cal.summary.final_cost < 2.0 * cal.summary.initial_cost


def test_the_command_line_names_them_and_keep_far_joints_keeps_them(model, walk, tmp_path, capsys):
    """From C3D files: the summary's `far pose` line, the report's far_joints and the HTML name the shoulders;
    --keep-far-joints (and a config's far_joints = false) keep the static's arm markers."""
    import json

    from calibrate.calibration.html import report_html
    from calibrate.cli.main import main
    from calibrate.io.c3d import write_c3d
    from calibrate.io.config import settings_from_dict

    static, _, _ = arms_out_static(model, walk, lift=0.04)
    write_c3d(tmp_path / "static.c3d", static)
    write_c3d(tmp_path / "walk.c3d", walk.trial)
    reports = {}
    for flag in ([], ["--keep-far-joints"]):
        out = tmp_path / ("kept" if flag else "default")
        out.mkdir()
        code = main([str(tmp_path / "static.c3d"), str(tmp_path / "walk.c3d"), str(model.path), "-o",
                     str(out / "s.urdf"), *flag])
        assert code == 0
        summary = capsys.readouterr().out
        assert ("far pose     " in summary) is not bool(flag)
        reports[bool(flag)] = json.loads((out / "static_report.json").read_text())
    far = reports[False]["far_joints"]
    assert sorted(f["joint"] for f in far) == ["shoulder_l", "shoulder_r"]
    assert all(f["trial"].endswith("static.c3d") and f["angle_deg"] > 45.0 for f in far)
    assert reports[False]["settings"]["far_joints"] is True
    assert reports[True]["far_joints"] == [] and reports[True]["settings"]["far_joints"] is False
    assert "far pose: " in report_html(reports[False]) and "far pose: " not in report_html(reports[True])
    assert settings_from_dict({"far_joints": False}).far_joints is False


def test_a_neutral_static_with_its_arms_out_reads_zero_at_its_arms(model, walk):
    """--neutral on the arms-out static: its arm angles are fitted to its markers before the segment frames are
    turned to them, so the static reads zero at the shoulders and elbows as at every other joint."""
    static, _, _ = arms_out_static(model, walk, lift=0.04)
    cal = calibrate(model, [static, walk.trial], neutral=0)
    assert sorted(f.joint for f in cal.far_joints) == ["shoulder_l", "shoulder_r"]
    mo = cal.motions[0]
    # Within 2 deg; the shoulders' flexion within 3: after the turn their angles are fitted afresh to the static's
    # arm markers, whose 40 mm lift no pose of the model meets (1.9-2.7 deg over the last changes to the code).
    for name, tol in (("shoulder_l_adduction", 2.0), ("shoulder_r_adduction", 2.0), ("shoulder_l_flexion", 3.0),
                      ("shoulder_r_flexion", 3.0), ("elbow_l", 2.0), ("elbow_r", 2.0), ("hip_l_flexion", 2.0),
                      ("knee_r", 2.0)):
        assert abs(math.degrees(np.mean(mo.angles[:, mo.dof_names.index(name)]))) < tol, name
    # The walk's arms then hang about the static's abduction below zero (the neutral is the arms-out pose).
    ab = -cal.motions[1].angles[:, model.dof_index("shoulder_l_adduction")]
    assert np.median(ab) < -math.radians(45.0)


def test_frames_whose_markers_do_not_fix_a_coordinate_do_not_call_it_still(model):
    """still_coordinates over a static (the larger part of the frames) whose arm markers far_joints left out: the
    arm's coordinates are judged on the frames that see them.  Counted, those frames' unbounded per-frame SD made
    the median theirs, and every arm coordinate of Rajagopal's walk read "still" (one frame's SD 573 deg)."""
    from calibrate.calibration.identifiability import STILL_RATIO, even_frames, still_coordinates

    F, sigma = 1000, 0.01  # frames; one frame's SD of every coordinate its markers fix (rad)
    nz = FrameLayout.coordinates(np.zeros((1, 3)), np.zeros((1, model.n_dofs))).shape[1]
    rows = even_frames(F, 500)  # the frames whose blocks the pipeline forms (_sampled_blocks)
    A = np.tile(np.eye(nz) / sigma**2, (rows.size, 1, 1))
    unseen = rows < 0.6 * F  # the static: its first 60 % of the frames
    swing, quiet = model.dof_index("shoulder_l_flexion"), model.dof_index("elbow_l")
    for d in (swing, quiet):
        c = FrameLayout.angle(d)
        A[unseen, c, :] = A[unseen, :, c] = 0.0
    rng = np.random.default_rng(0)
    angles = rng.normal(0.0, 0.2, (F, model.n_dofs))  # every other coordinate moves: not still
    walk = np.arange(F) >= 0.6 * F
    angles[walk, quiet] = rng.normal(0.0, 0.5 * sigma, walk.sum())  # still where it is seen ...
    angles[~walk, quiet] = 1.5  # ... and wherever the start left it in the static
    still = {name: (spread, per) for name, spread, per in still_coordinates(model, angles, A, Settings())}
    assert set(still) == {"elbow_l"}, still
    spread, per = still["elbow_l"]
    assert per == pytest.approx(sigma, rel=1e-6)
    assert spread == pytest.approx(np.std(angles[rows[~unseen], quiet]), rel=1e-9) and spread < STILL_RATIO * sigma
    # Every frame seen: the spread over every frame, as before.
    full = np.tile(np.eye(nz) / sigma**2, (F, 1, 1))
    assert {n for n, _, _ in still_coordinates(model, angles, full, Settings())} == set()


def test_the_joints_of_the_pelvis_are_never_far(model, walk):
    """A static crouched (hips flexed 80 deg, trunk 60 deg: where no walk frame goes) with its arms out: only the
    shoulders are far.  The hips and the lumbar joint, the pelvis's own, are not tested (a static stands where a
    crouching trial never goes; without its legs and trunk it would have little left, and a two-keypoint pelvis
    nothing to turn it)."""
    static, angles, quat = arms_out_static(model, walk)
    for d in ("hip_l_flexion", "hip_r_flexion"):
        angles[:, model.dof_index(d)] = math.radians(80.0)
    angles[:, model.dof_index("lumbar_flexion")] = math.radians(60.0)
    Z = np.concatenate([FrameLayout.coordinates(np.zeros((static.n_frames, 3)), angles),
                        FrameLayout.coordinates(walk.motion.root_translation, walk.motion.angles)])
    Q = np.concatenate([quat, walk.motion.root_quaternion])
    spans = [slice(0, static.n_frames), slice(static.n_frames, Z.shape[0])]
    seen = np.ones((Z.shape[0], len(model.markers)), dtype=bool)
    # The hips and the lumbar are that far from every walk frame (the test's own measure, by the truth).
    for d, k in (("hip_l_flexion", 0), ("lumbar_flexion", 0)):
        reach = walk.motion.angles[:, model.dof_index(d)]
        assert angles[k, model.dof_index(d)] - reach.max() > FAR_POSE, d
    assert sorted(f.joint for f in far_joints(model, Z, Q, spans, [True, False], seen)) == ["shoulder_l", "shoulder_r"]
