"""Unresolved segments (calibrate.model.resolve): the markers' Jacobian null space, and calibration with
the coordinates the markers do not see locked."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest
from conftest import HUMAN, ROOT

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.errors import CalibrateError
from calibrate.io.c3d import write_c3d
from calibrate.model.resolve import resolve, unresolved
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats

PELVIS = ("LASI", "RASI", "LPSI", "RPSI")


def test_full_marker_set_resolves_every_segment_talus_included(human):
    res = resolve(human, human.marker_names)
    assert res.root_resolved and res.segments == () and res.lock == ()
    assert not human.segments[human.segment_index("talus_l")].markers  # no marker of its own, resolved via calcn


def test_forearm_without_its_two_wrist_markers(human):
    """LWRA and LWRB removed: the radius (and the hand below it) cannot be placed; the rest can."""
    labels = [m for m in human.marker_names if m not in ("LWRA", "LWRB")]
    found = unresolved(human, labels)
    assert [u.segment for u in found] == ["radius_l", "hand_l"]
    assert "radioulnar_l" in found[0].coordinates
    assert all("LFIN" in u.reason for u in found)


def test_foot_without_markers_and_an_independent_rank_check(human):
    """Heel and toe removed: talus and calcaneus unresolved.  Checked independently: with Pinocchio,
    turning the ankle and subtalar joints moves no remaining marker but moves the calcaneus."""
    labels = [m for m in human.marker_names if m not in ("LHEE", "LTOE")]
    res = resolve(human, labels)
    assert res.names == ("talus_l", "calcn_l") and set(res.lock) == {"ankle_l", "subtalar_l"}
    pm, data = human.pin, human.pin.createData()
    angles = np.zeros(human.n_dofs)
    q0 = human.pin_configuration(np.zeros(3), [0, 0, 0, 1], angles)
    angles[human.dof_index("ankle_l")] = 0.3
    q1 = human.pin_configuration(np.zeros(3), [0, 0, 0, 1], angles)
    where = []
    for q in (q0, q1):
        pin.framesForwardKinematics(pm, data, q)
        where.append({f.name: data.oMf[i].translation.copy() for i, f in enumerate(pm.frames)})
    assert max(np.linalg.norm(where[0][m] - where[1][m]) for m in labels) < 1e-12
    assert np.linalg.norm(where[0]["LHEE"] - where[1]["LHEE"]) > 0.01  # the calcaneus moves


def test_five_shared_labels_calibrate_with_the_unseen_coordinates_locked(human):
    """A trial sharing only the four pelvis markers and LKNE with the model: calibration locks the
    coordinates the markers do not see, lists the unresolved segments, and those coordinates stay put."""
    sim = simulate_squats(human, frames=40, noise_mm=0.5, seed=4)
    trial = sim.trial.select([*PELVIS, "LKNE"])
    cal = calibrate(human, trial, Settings(max_iterations=15))
    names = [u.segment for u in cal.unresolved]
    assert "pelvis" not in names and "femur_l" in names and "hand_r" in names and len(names) == 18
    locked = dict(cal.settings.lock)
    assert "hip_l_rotation" in locked and "knee_l" in locked and "hip_l_flexion" not in locked
    for dof, value in locked.items():
        k = human.dof_index(dof)
        assert np.abs(cal.motion.angles[:, k] - value).max() < 1e-3, dof
    assert np.isfinite(cal.marker_rms)
    # No marker on or below a segment: the joint centres it carries and its scale stay the base model's.
    base, below = human.parameters(), {"LKNE": "femur_l"}
    for k, j in enumerate(human.joints):
        if j.parent in names and j.parent not in below.values():
            assert np.allclose(cal.params.centre[k], base.centre[k], atol=1e-9), j.name
            assert cal.params.scale[human.segment_index(j.parent)] == pytest.approx(1.0, abs=1e-9), j.parent
    report = calibration_report(cal)
    assert [u["segment"] for u in report["unresolved"]] == names
    assert "hip_l_rotation" in report["unresolved"][0]["coordinates"]
    text = summary_text(cal)
    assert "18 segments the markers cannot place" in text and "femur_l: " in text
    # A centre nothing estimates (no marker on or below its segment) has no posterior SD: the summary's row says why
    # it is held, not '+- nan'; the report's std is null.
    unseen = [c for c in cal.changes if c.group == "centre" and not np.isfinite(c.std).any()]
    assert {c.item for c in unseen} >= {"knee_r", "elbow_r"}, [c.item for c in unseen]
    rows = {line.split()[0]: line for line in text.splitlines() if line.startswith("    ") and len(line.split()) > 2}
    for c in unseen:
        assert "nan" not in rows[c.item] and rows[c.item].endswith(f"(held: {c.note.split(':')[0]})"), rows[c.item]
        assert "no marker seen on or below" in rows[c.item], rows[c.item]
        assert report["parameters"][[q["name"] for q in report["parameters"]].index(c.name)]["std"] == [None] * 3
    assert "nan" not in text
    # No label the model does not know: the markers line counts no new ones ("0 new" said nothing).
    assert not cal.new_markers and "model markers seen, " in text and " new, placed" not in text


def test_no_pelvis_markers_is_refused_naming_the_segments(human, tmp_path):
    sim = simulate_squats(human, frames=20, noise_mm=0.5, seed=5)
    trial = sim.trial.select(["LKNE", "RKNE", "LANK", "RANK", "C7"])
    with pytest.raises(CalibrateError, match="cannot place the pelvis.*unresolved: pelvis, femur_l.*more than one "
                                              "branch of the model and none on the root"):
        calibrate(human, trial)
    path = tmp_path / "five.c3d"
    write_c3d(path, trial)
    out = subprocess.run([sys.executable, "-m", "calibrate.cli", str(path), str(HUMAN)], capture_output=True,
                         text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 2
    assert out.stderr.startswith("calibrate: error: ") and "pelvis" in out.stderr and "--markers" in out.stderr


def test_left_out_markers_share_the_unmarked_segments_clause_once(human):
    """Two trial markers that ride on no segment (each a random walk of its own) are left out by the rigidity
    association, each reason naming the segments that carry no markers (the talus); the summary says that shared
    clause once, after the markers, and keeps each marker's own figure on its line."""
    from calibrate.calibration.report import left_out_lines
    from calibrate.io.trial import Trial
    from calibrate.seed.association import associate_to_model

    sim = simulate_squats(human, frames=200, noise_mm=1.0, seed=3)
    rng = np.random.default_rng(0)
    loose = np.cumsum(rng.normal(0, 0.01, (200, 2, 3)), axis=0) + np.array([0.0, 0.0, 1.0])
    trial = Trial(sim.trial.labels + ("LOOSE1", "LOOSE2"), np.concatenate([sim.trial.markers, loose], axis=1),
                  sim.trial.rate)
    left = [(m.label, m.reason) for m in associate_to_model(human, trial).markers if m.segment is None]
    assert [label for label, _ in left] == ["LOOSE1", "LOOSE2"]
    clause = "segments without markers (talus_l, talus_r) cannot receive markers"
    assert all(reason.endswith("; " + clause) for _, reason in left)
    lines = left_out_lines(left)
    assert lines[-1] == f"  left out, all 2: {clause}"
    assert [line.count("cannot receive") for line in lines] == [0, 0, 1]
    for (label, reason), line in zip(left, lines, strict=False):
        assert line == f"  left out {label}: {reason.removesuffix('; ' + clause)}"
    # One marker, or reasons without a shared last clause: every line as it was.
    assert left_out_lines(left[:1]) == [f"  left out LOOSE1: {left[0][1]}"]
    other = [("A", "x; " + clause.replace("talus_l, ", "")), ("B", "x; " + clause)]
    assert left_out_lines(other) == [f"  left out {a}: {r}" for a, r in other]


def test_a_pelvis_with_two_markers_on_a_line_turns_with_the_trunk(human):
    """LASI and RASI alone on the pelvis (a markerless pelvis's two hip keypoints): its tilt about their line trades
    against the lumbar's flexion and the hips', so the lumbar's DoF about that line is held (as Pose2Sim's IK setup
    holds L5_S1_Flex_Ext).  The DoF is the one whose axis, by Pinocchio at the neutral pose, runs along LASI-RASI."""
    from calibrate.model.resolve import line_root_holds

    two = [n for n in human.marker_names if n not in ("LPSI", "RPSI")]
    held = line_root_holds(human, two)
    assert [(u.segment, u.coordinates) for u in held] == [("pelvis", ("lumbar_flexion",))]
    data = human.pin.createData()
    pin.framesForwardKinematics(human.pin, data, pin.neutral(human.pin))
    line = (data.oMf[human.pin.getFrameId("LASI")].translation - data.oMf[human.pin.getFrameId("RASI")].translation)
    for d in ("lumbar_flexion", "lumbar_bending", "lumbar_rotation"):
        axis = data.oMi[human.pin.getJointId(d)].rotation @ human.dofs[human.dof_index(d)].axis
        assert (abs(axis @ line) / np.linalg.norm(line) > 0.9) == (d == "lumbar_flexion"), d
    assert line_root_holds(human, human.marker_names) == ()  # four pelvis markers turn it themselves
    assert line_root_holds(human, two, locked=["lumbar_flexion"]) == ()

    sim = simulate_squats(human, frames=60, noise_mm=0.5, seed=6)
    cal = calibrate(human, sim.trial.select(two), Settings(max_iterations=15))
    assert dict(cal.settings.lock).get("lumbar_flexion") == 0.0
    k = human.dof_index("lumbar_flexion")
    assert np.abs(cal.motion.angles[:, k]).max() < 1e-3
    assert [u.segment for u in cal.unresolved] == ["pelvis"]
    # The trunk and the thighs are where the simulator put them: every marker fitted to the noise's order.
    assert cal.marker_rms < 0.002
    assert "pelvis: lumbar_flexion: its markers (LASI, RASI) lie on one line" in summary_text(cal)
    off = calibrate(human, sim.trial.select(two), Settings(max_iterations=15, auto_hold=False))
    assert "lumbar_flexion" not in dict(off.settings.lock)


UPPER = ("torso", "head", "humerus_l", "ulna_l", "radius_l", "hand_l", "humerus_r", "ulna_r", "radius_r", "hand_r")


def test_a_markerless_root_rides_with_the_one_branch_the_markers_place(human):
    """No marker on the pelvis and every one on the trunk and above (an upper-body trial), or on one leg: the pelvis
    rides with that branch's top, the DoFs between them held; markers on two branches and none on the root: None."""
    from calibrate.model.resolve import carried_root

    upper = [m for s in UPPER for m in human.segments[human.segment_index(s)].markers]
    lumbar = ("lumbar_flexion", "lumbar_bending", "lumbar_rotation")
    got = carried_root(human, upper)
    assert got is not None and got.segment == "pelvis" and got.coordinates == lumbar
    assert not resolve(human, upper).root_resolved and resolve(human, upper, locked=lumbar).root_resolved
    leg = [m for s in ("femur_l", "tibia_l", "calcn_l") for m in human.segments[human.segment_index(s)].markers]
    assert carried_root(human, leg).coordinates == ("hip_l_flexion", "hip_l_adduction", "hip_l_rotation")
    assert carried_root(human, ["LKNE", "RKNE", "LANK", "RANK", "C7"]) is None  # two branches
    assert carried_root(human, [*upper, "LASI"]) is None  # a marker on the root: not this rule's
    assert carried_root(human, ["C7", *human.segments[human.segment_index("head")].markers]) is None  # torso: 1 marker
    assert carried_root(human, upper, locked=lumbar) is None  # nothing left to hold
    # The shoulders and elbows alone place the trunk by the rank test, through the arms' turns, but loosely (the
    # root's columns, the other coordinates' share taken out, by Pinocchio's frame Jacobians): not carried.
    from calibrate.model.resolve import CARRY_FIRM, root_firmness

    loose = ["LSHO", "RSHO", "LELB", "RELB"]
    assert resolve(human, loose, locked=lumbar).root_resolved
    assert root_firmness(human, loose, locked=lumbar) < CARRY_FIRM <= root_firmness(human, ["C7", "CLAV", "STRN"],
                                                                                     locked=lumbar)
    assert carried_root(human, loose) is None and carried_root(human, ["C7", "CLAV", "STRN"]) is not None
    assert root_firmness(human, upper, locked=lumbar) > 0.2 and root_firmness(human, human.marker_names) > 0.15
    # The refusal says why: the branch too loose (with its figure), or markers on two branches.
    from calibrate.model.resolve import carry_refusal

    why = carry_refusal(human, loose)
    assert f"({root_firmness(human, loose, locked=lumbar):.3f} m of marker motion per rad" in why and "torso" in why
    assert "more than one branch" in carry_refusal(human, ["LKNE", "RKNE", "LANK", "RANK", "C7"])


def test_an_upper_body_trial_calibrates_its_arms_as_the_whole_marker_set_does(human):
    """The simulator's overhead arm arcs with only the trunk's, head's and arms' markers: calibrated with the pelvis
    riding on the trunk (lumbar held at 0, the pelvis's and legs' geometry the base model's at the subject's size),
    every shoulder, elbow, wrist and neck centre as near the simulator's truth, frame by frame, as the calibration from
    every marker puts it; and `calibrate ik` fits the trial to a subject the same way."""
    from calibrate.calibration.subject_ik import fit_trial
    from calibrate.model.kinematics import build_kinematics
    from calibrate.simulation.simulate import simulate_overhead

    sim = simulate_overhead(human, frames=200, seed=3, measured=True)  # (the knee, ankle and elbow widths written)
    upper = [m for s in UPPER for m in human.segments[human.segment_index(s)].markers]
    kin = build_kinematics(human)
    joints = ("neck", "shoulder_l", "shoulder_r", "elbow_l", "elbow_r", "wrist_l", "wrist_r")
    err, rms = {}, {}
    for name, trial in (("all", sim.trial), ("upper", sim.trial.select(upper))):
        cal = calibrate(human, trial, Settings())
        rms[name] = cal.marker_rms
        mo = cal.motion
        Z = np.column_stack([mo.root_translation, np.zeros((mo.n_frames, 3)), mo.angles])
        _, C = kin.batch(Z, mo.root_quaternion, cal.params)
        err[name] = {j: float(np.linalg.norm(C[:, human.joint_index(j)] - sim.clean_centres[:, human.joint_index(j)],
                                             axis=1).mean()) for j in joints}
    for j in joints:
        assert err["upper"][j] <= err["all"][j] + 1e-3, (j, err)
    assert max(err["upper"][j] for j in ("neck", "shoulder_l", "shoulder_r")) < 0.003, err
    assert cal.unresolved[0].segment == "pelvis" and "rides with torso" in cal.unresolved[0].reason
    lumbar = [human.dof_index(d) for d in ("lumbar_flexion", "lumbar_bending", "lumbar_rotation")]
    assert np.abs(cal.motion.angles[:, lumbar]).max() < 1e-6
    # The pelvis sized with the legs after the fit, every frame's root moved so the trunk stays: the fit unchanged.
    assert rms["upper"] < rms["all"] + 2e-5, rms
    # The pelvis's geometry: the base model's, at the size of the legs (no data reach either).
    base, pelvis = human.parameters(), human.segment_index("pelvis")
    assert cal.params.scale[pelvis] == pytest.approx(cal.params.scale[human.segment_index("femur_l")], abs=1e-12)
    for j in ("hip_l", "hip_r", "lumbar"):
        k = human.joint_index(j)
        assert np.allclose(cal.params.centre[k], base.centre[k], atol=1e-9), j
    text = summary_text(cal)
    assert "pelvis rides with torso" in text and "no marker seen on pelvis, which rides with torso" in text
    assert "  hips " not in text  # no motion of a locked hip to judge
    # The joints into or out of the unplaced segments have no seed: one line names them all (the report keeps each).
    seeds = [line for line in text.splitlines() if line.startswith("  seed: ") and "no joint-centre seed" in line]
    assert len(seeds) == 1 and all(j in seeds[0] for j in ("hip_l", "knee_r", "subtalar_l", "lumbar")), seeds
    assert sum(n.startswith("knee_l: no joint-centre seed") for n in cal.seed.notes) == 1
    # The measured widths: only the elbows' lateral markers are shown, so only they are compared (not LKNE, unseen).
    from calibrate.calibration.report import measurements_table

    assert set(measurements_table(cal)["lateral_mm"]) == {"elbow_l", "elbow_r"}
    fit = fit_trial(human, sim.trial.select(upper), cal.params, {}, source="upper")
    assert fit.unplaced[0] == "pelvis" and set(fit.unplaced_held) >= {"lumbar_flexion", "hip_l_flexion"}
    assert fit.fit.rms < 0.0016


def test_a_one_leg_trial_sizes_the_leg_it_shows_not_its_unseen_partner(human):
    """Only the left leg marked, a 1.5 m subject: the pelvis rides with the left thigh (its hip held), and the left
    leg's scales and knee are the subject's.  The left/right symmetry prior leaves a pair alone where one side is a
    segment no data reach (held at the base model's while the fit runs): before, it pulled femur_l to 0.99 against
    the truth's 0.82, the knee 55 mm from the truth."""
    sim = simulate_squats(human, frames=300, seed=7, height=1.5)
    leg = [m for s in ("femur_l", "tibia_l", "calcn_l") for m in human.segments[human.segment_index(s)].markers]
    cal = calibrate(human, sim.trial.select(leg), Settings())
    assert cal.unresolved[0].coordinates == ("hip_l_flexion", "hip_l_adduction", "hip_l_rotation")
    for s in ("femur_l", "tibia_l"):
        i = human.segment_index(s)
        assert cal.params.scale[i] == pytest.approx(sim.truth.scale[i], rel=0.04), s
    k = human.joint_index("knee_l")
    femur = human.segment_index("femur_l")
    knee = cal.params.scale[femur] * cal.params.centre[k] - sim.truth.scale[femur] * sim.truth.centre[k]
    assert np.linalg.norm(knee) < 0.025  # 22.6 mm, 16 of it along the axis, which no motion shows


def test_a_trial_that_does_not_place_what_the_others_place_is_named(human):
    """A static with every marker and an arm trial with the trunk's, head's and arms' only: the calibration places
    every segment (the static's markers), but the arm trial's frames do not place the pelvis and the legs, which the
    summary, the report and the HTML report name with the coordinates that rest on the priors there (resolve on that
    trial's markers alone: its root carried by the trunk, the lumbar's three DoFs among them)."""
    from calibrate.calibration.html import report_html
    from calibrate.simulation.simulate import simulate_overhead, simulate_static

    sim = simulate_overhead(human, frames=150, seed=3)
    static = simulate_static(human, sim.truth, frames=50)
    upper = [m for s in UPPER for m in human.segments[human.segment_index(s)].markers]
    cal = calibrate(human, [static.trial, sim.trial.select(upper)], Settings(max_iterations=20))
    assert cal.unresolved == ()
    assert [i for i, _ in cal.unplaced_in_trial] == [1]
    segments = [u.segment for u in cal.unplaced_in_trial[0][1]]
    assert segments[0] == "pelvis" and {"femur_l", "calcn_r"} <= set(segments) and "torso" not in segments
    assert set(cal.unplaced_in_trial[0][1][0].coordinates) >= {"lumbar_flexion", "lumbar_bending", "lumbar_rotation"}
    text = summary_text(cal)
    assert any(line.startswith("  unplaced     trial 2: its markers do not place pelvis, femur_l")
               and "are held at 0 and its pelvis rides with" in line for line in text.splitlines()), text
    report = calibration_report(cal)
    assert report["unplaced_in_trial"][0]["trial"] == 1 and report["unplaced_in_trial"][0]["held"]
    assert "its markers do not place pelvis" in report_html(report)
    # In the arm trial's motion those coordinates are held at 0, the pelvis carried so that every marker the trial
    # shows stays where the solve put it: the motion's markers (the kinematics at the calibrated geometry) against
    # the trial's positions plus the calibration's residuals, to a micrometre.
    assert cal.unplaced_held == (1,)
    mo = cal.motions[1]
    held = [human.dof_index(d) for d in ("lumbar_flexion", "lumbar_bending", "lumbar_rotation", "hip_l_flexion")]
    assert np.abs(mo.angles[:, held]).max() == 0.0
    assert (np.sum(mo.root_quaternion[1:] * mo.root_quaternion[:-1], axis=1) > 0).all()  # no sign flips
    from calibrate.model.kinematics import build_kinematics

    Z = np.column_stack([mo.root_translation, np.zeros((mo.n_frames, 3)), mo.angles])
    M = build_kinematics(human).batch(Z, mo.root_quaternion, cal.params)[0]
    ks = [human.marker_index(m) for m in upper]
    shown = cal.trials[1].markers[:, [cal.trials[1].labels.index(m) for m in upper]]
    fitted = shown + cal.residuals[static.trial.n_frames:][:, ks]
    assert np.nanmax(np.abs(M[:, ks] - fitted)) < 1e-6
    alone = calibrate(human, static.trial, Settings(max_iterations=5))
    assert alone.unplaced_in_trial == () and "  unplaced " not in summary_text(alone)


def test_the_trials_say_whether_the_roots_markers_lie_on_a_line():
    """pipeline._off_line: a sacral marker 0.15 m behind the ASIS line is off it, a keypoint between two hip
    keypoints is on it (Pose2Sim's Hip between RHip and LHip), in the trials' own frames (a new label without a
    place sits at the root's origin, which an OpenSim pelvis has on its ASIS line)."""
    from calibrate.calibration.pipeline import _off_line
    from calibrate.io.trial import Trial

    rng = np.random.default_rng(0)
    F = 100
    turn = rng.normal(0.0, 0.3, (F, 3))
    asis = np.array([[0.0, 0.12, 0.0], [0.0, -0.12, 0.0]])
    sacral = np.array([[-0.15, 0.0, 0.02]])
    middle = np.array([[0.0, 0.0, 0.0]])

    def trial(points: np.ndarray, labels: tuple[str, ...]) -> Trial:
        from scipy.spatial.transform import Rotation

        R = Rotation.from_rotvec(turn).as_matrix()  # (F, 3, 3): the pelvis turning about
        X = np.einsum("fij,pj->fpi", R, points) + rng.normal(0.0, 0.001, (F, len(points), 3))
        return Trial(labels, X, 100.0)

    assert _off_line([trial(np.vstack([asis, sacral]), ("LASI", "RASI", "V.Sacral"))], ["LASI", "RASI", "V.Sacral"])
    assert not _off_line([trial(np.vstack([asis, middle]), ("LHip", "RHip", "Hip"))], ["LHip", "RHip", "Hip"])
    assert not _off_line([trial(asis, ("LASI", "RASI"))], ["LASI", "RASI"])  # two always make a line
