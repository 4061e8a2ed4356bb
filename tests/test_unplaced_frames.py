"""Frames whose markers do not place the pelvis (the subject walking out of the capture volume, or a stretch where
only a leg is seen): their fit is any pose that puts those few markers in place, so the motion bridges them from the
frames either side that place it, held at the trial's edges (calibrate.model.resolve.unplaced_frames,
calibrate.solve.ik.bridge_unplaced), and the summary and the report list them."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.calibration.html import report_html
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.calibration.subject_ik import fit_trial
from calibrate.io.trial import Trial
from calibrate.model.resolve import CARRY_FIRM, resolve, root_firmness, unplaced_frames
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_gait

RIGHT_LEG = ("RKNE", "RTIB", "RANK", "RHEE", "RTOE")


def _only_right_leg(trial: Trial, frames: np.ndarray) -> Trial:
    X = trial.markers.copy()
    others = [k for k, label in enumerate(trial.labels) if label not in RIGHT_LEG]
    X[np.ix_(frames, others)] = np.nan
    return Trial(trial.labels, X, trial.rate, trial.first_frame, trial.source)


def test_unplaced_frames_by_the_markers_each_frame_shows(human):
    """resolve on each frame's seen markers: the right leg's five alone leave the root unplaced, every marker places
    it and every coordinate; the left leg's markers hidden leave its coordinates to blame, not the right's."""
    seen = np.ones((4, len(human.markers)), dtype=bool)
    seen[1] = np.isin(human.marker_names, RIGHT_LEG)
    seen[2, [human.marker_index(m) for m in ("LTHI", "LKNE", "LTIB", "LANK", "LHEE", "LTOE")]] = False
    seen[3] = False
    root, dofs = unplaced_frames(human, seen)
    assert root.tolist() == [False, True, False, True]
    assert not dofs[0].any() and dofs[1].all() and dofs[3].all()
    assert {human.dof_index(d) for d in ("hip_l_flexion", "hip_l_rotation", "knee_l")} <= set(np.flatnonzero(dofs[2]))
    assert not dofs[2, [human.dof_index(d) for d in ("hip_r_flexion", "knee_r", "lumbar_flexion")]].any()


def test_a_frame_that_places_the_root_weakly_counts_as_unplaced_where_the_others_place_it_firmly(human):
    """PlugInC3D's first frames on human.urdf (RASI, the right leg's markers and LKNE): the rank test places the root,
    but at 0.024 m/rad (root_firmness; every marker: 0.20), and the fit rotated the left hip 88-123 deg there.  Such a
    frame counts as unplaced beside frames that place it firmly, not in a trial of such frames alone."""
    weak = ["RASI", "RKNE", "RTHI", "RTOE", "RHEE", "LKNE", "RTIB"]
    assert resolve(human, weak).root_resolved and root_firmness(human, weak) < CARRY_FIRM
    seen = np.ones((3, len(human.markers)), dtype=bool)
    seen[0] = np.isin(human.marker_names, weak)
    root, dofs = unplaced_frames(human, seen)
    assert root.tolist() == [True, False, False] and dofs[0].all()
    root, _ = unplaced_frames(human, seen[[0, 0, 1]])
    assert root.tolist() == [False, False, False]


def test_frames_that_show_a_leg_alone_are_bridged_not_fitted(human):
    """A simulated walk whose frames 50-59 and 100-119 show the right leg's markers only: those frames are listed,
    their poses run linear between frames 49 and 60 (to the last bit of the interpolation) and hold frame 99's at the
    end; the bridged hips stay within 8 deg of the truth over the 0.1 s gap; the summary, the report and the HTML
    report say so."""
    sim = simulate_gait(human, frames=120, seed=4)
    gap, end = np.arange(50, 60), np.arange(100, 120)
    trial = _only_right_leg(sim.trial, np.concatenate([gap, end]))
    cal = calibrate(human, trial, Settings(max_iterations=30))
    assert cal.unplaced_frames == (tuple(range(50, 60)) + tuple(range(100, 120)),)
    mo = cal.motions[0]
    for a in (mo.angles, mo.root_translation):
        np.testing.assert_array_equal(a[end], np.broadcast_to(a[99], a[end].shape))
        w = (gap - 49) / 11.0
        np.testing.assert_allclose(a[gap], (1 - w)[:, None] * a[49] + w[:, None] * a[60], rtol=0, atol=1e-12)
    q = mo.root_quaternion
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0) and (np.abs(np.sum(q[1:] * q[:-1], axis=1)) > 0.99).all()
    hips = [human.dof_index(d) for d in ("hip_l_flexion", "hip_l_adduction", "hip_r_flexion", "hip_r_adduction")]
    off = np.degrees(np.abs(mo.angles[np.ix_(gap, hips)] - sim.motion.angles[np.ix_(gap, hips)]))
    assert off.max() < 8.0, off.max()
    text = summary_text(cal)
    assert "frames 50-59, 100-119 (30 of 120, from 0) show too few markers to place pelvis" in text, text
    report = calibration_report(cal)
    assert report["unplaced_frames"] == [{"trial": 0, "frames": list(range(50, 60)) + list(range(100, 120)),
                                          "runs": [[50, 59], [100, 119]]}]
    assert "frames 50-59, 100-119 (30 frames) show too few markers" in report_html(report)
    # the same walk with every marker: nothing listed, nothing bridged
    whole = calibrate(human, sim.trial, Settings(max_iterations=30))
    assert whole.unplaced_frames == ((),) and "frames" not in "".join(
        line for line in summary_text(whole).splitlines() if line.startswith("  unplaced"))
    # `calibrate ik` on the damaged walk with that subject: the same frames listed, bridged and held the same way
    fit = fit_trial(whole.model, trial, whole.params, {}).fit
    assert fit.unplaced_frames == cal.unplaced_frames[0]
    ik = fit.motion
    np.testing.assert_array_equal(ik.angles[end], np.broadcast_to(ik.angles[99], ik.angles[end].shape))
    off = np.degrees(np.abs(ik.angles[np.ix_(gap, hips)] - sim.motion.angles[np.ix_(gap, hips)]))
    assert off.max() < 8.0, off.max()


def test_a_trial_whose_markers_place_the_root_in_few_frames_is_refused(human):
    """The same walk showing the right leg's markers alone from frame 8 on: the pelvis placed in 8 of the 120 frames
    that show markers (under ROOT_PLACED_MIN), every other pose and the geometry would rest on interpolation; refused
    in one line that names the count (kineticstoolkit's racing_full on human.urdf: 12 of 700, a humerus scaled 0.20
    before).  The same walk showing nothing from frame 8 on (the subject gone from the volume) calibrates: those
    frames fit nothing, and its 8 frames that show markers place the pelvis."""
    from calibrate.calibration.pipeline import ROOT_PLACED_MIN
    from calibrate.errors import CalibrateError

    sim = simulate_gait(human, frames=120, seed=4)
    assert 8 < ROOT_PLACED_MIN * 120 <= 30  # (30 of 120 unplaced calibrate: the test above)
    trial = _only_right_leg(sim.trial, np.arange(8, 120))
    with pytest.raises(CalibrateError, match=r"place the pelvis in only 8 of the 120 frames that show 3 or more") \
            as err:
        calibrate(human, trial, Settings(max_iterations=10))
    assert "\n" not in str(err.value)
    X = sim.trial.markers.copy()
    X[8:] = np.nan
    gone = Trial(sim.trial.labels, X, sim.trial.rate, sim.trial.first_frame, sim.trial.source)
    cal = calibrate(human, gone, Settings(max_iterations=10))
    assert cal.unplaced_frames == (tuple(range(8, 120)),)  # listed, their poses held at frame 7's
    angles = cal.motions[0].angles
    np.testing.assert_array_equal(angles[8:], np.broadcast_to(angles[7], angles[8:].shape))


def test_a_bridge_of_part_of_a_chain_keeps_the_markers_the_frame_shows(human, tmp_path):
    """Simulated squats without LUPA and LFRM, whose LELB and LFIN are hidden in frames 100-105: there the left
    humerus shows no marker, resolve leaves hand_l unplaced and blames shoulder_l_flexion, shoulder_l_rotation,
    radioulnar_l and the wrist's angles, which the motion bridges; the shoulder's adduction and the elbow, fitted
    beside them, are fitted again with them held (solve.ik.refit_bridged), so the written subject posed by Pinocchio
    puts the wrist markers the frames show where they are (bridged alone, 3-67 mm off; PiG_Motion-FlatFoot-Full's
    walk: 72-79 mm), in `calibrate` and in `calibrate ik` alike."""
    from conftest import markers_in_world

    from calibrate.simulation.simulate import simulate_squats

    sim = simulate_squats(human, frames=200, noise_mm=1.0, seed=0)
    trial = sim.trial.select([n for n in sim.trial.labels if n not in ("LUPA", "LFRM")])
    X, col = trial.markers.copy(), {n: i for i, n in enumerate(trial.labels)}
    gap = np.arange(100, 106)
    X[np.ix_(gap, [col["LELB"], col["LFIN"]])] = np.nan
    trial = Trial(trial.labels, X, trial.rate)
    shown = [n for n in trial.labels if n not in ("LELB", "LFIN")]
    (u,) = resolve(human, shown).segments
    blamed = {"shoulder_l_flexion", "shoulder_l_rotation", "radioulnar_l", "wrist_l_flexion", "wrist_l_deviation"}
    assert u.segment == "hand_l" and set(u.coordinates) == blamed
    cal = calibrate(human, trial, Settings(max_iterations=30))
    wrist = [human.marker_index(n) for n in ("LWRA", "LWRB")]
    for name, motion in (("calibrate", cal.motions[0]),
                         ("ik", fit_trial(cal.model, trial, cal.params, {}).fit.motion)):
        P = markers_in_world(human, cal.params, motion, tmp_path, f"{name}.urdf")
        off = np.linalg.norm(P[np.ix_(gap, wrist)] - X[np.ix_(gap, [col["LWRA"], col["LWRB"]])], axis=-1)
        assert off.max() < 0.005, (name, 1000 * off)  # 1 mm noise
        # the blamed coordinates still bridged: linear between frames 99 and 106
        d = [human.dof_index(n) for n in sorted(blamed)]
        w = (gap - 99) / 7.0
        np.testing.assert_allclose(motion.angles[np.ix_(gap, d)], (1 - w)[:, None] * motion.angles[99, d]
                                   + w[:, None] * motion.angles[106, d], rtol=0, atol=1e-9)
