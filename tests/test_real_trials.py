"""Real-trial situations (issue: real trials): markers the model does not know, several trials
of one subject (a static trial among them), gaps, bad frames and spikes.  Every trial is made by
the simulator; truths are the simulator's."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

from calibrate.calibration.evaluate import compare_to_truth
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.records import ZeroNote
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.errors import CalibrateError
from calibrate.io.c3d import write_c3d
from calibrate.io.motion import read_motion_csv
from calibrate.io.read import read_trial
from calibrate.io.trial import Trial
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import add_markers, load_model
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats, simulate_static

# A thigh plate (three markers), a shank pair and a hand marker, in segment frames (m): markers a
# lab adds to the model's set.
CLUSTER = {"RTH1": ("femur_r", (0.06, -0.09, -0.18)), "RTH2": ("femur_r", (0.07, -0.06, -0.24)),
           "RTH3": ("femur_r", (0.05, -0.10, -0.28)), "LSH1": ("tibia_l", (0.05, 0.08, -0.15)),
           "LSH2": ("tibia_l", (0.06, 0.06, -0.22)), "RHND": ("hand_r", (0.0, -0.03, -0.06))}
BALL_MEDIAN_MM = 2.0


@pytest.fixture(scope="module")
def subject(human):
    """The human model with the cluster markers: what the simulated subject wears."""
    return add_markers(human, {k: (seg, np.array(xyz)) for k, (seg, xyz) in CLUSTER.items()})


def _world(model, params, motion) -> np.ndarray:
    """Marker positions (frames, markers, 3) of `model` with `params` through `motion`."""
    kin = build_kinematics(model)
    Z = np.column_stack([motion.root_translation, np.zeros((motion.n_frames, 3)), motion.angles])
    return kin.batch(Z, motion.root_quaternion, params)[0]


def _ball_median_mm(cmp) -> float:
    return 1000 * float(np.median(list(cmp.ball().values())))


def _with_loose_marker(sim, rng) -> Trial:
    """The trial plus 'LOOSE', halfway between the two knees: it rides on no segment."""
    i, j = sim.trial.labels.index("RKNE"), sim.trial.labels.index("LKNE")
    loose = 0.5 * (sim.clean_markers[:, i] + sim.clean_markers[:, j]) + rng.normal(0, 1e-3, (sim.trial.n_frames, 3))
    return Trial(sim.trial.labels + ("LOOSE",), np.concatenate([sim.trial.markers, loose[:, None]], axis=1),
                 sim.trial.rate)


# ---------------------------------------------------------------------- unknown markers
def test_unknown_markers_are_placed_fitted_and_written(human, subject, tmp_path):
    sim = simulate_squats(subject, frames=300, noise_mm=1.0, seed=4)
    trial = _with_loose_marker(sim, np.random.default_rng(0))
    cal = calibrate(human, trial)
    placed = {m.label: m for m in cal.new_markers}
    for label, (segment, _) in CLUSTER.items():
        assert placed[label].segment == segment, placed[label]
    assert placed["LOOSE"].segment is None and "LOOSE" in cal.ignored_labels
    assert "varies" in placed["LOOSE"].reason
    # Three new markers on femur_r start at one place, as the base model's placeholders do, but the base model puts
    # none of them anywhere: each has its 'new marker' line, none is listed among the placeholders.
    assert not set(CLUSTER) & set(calibration_report(cal)["placeholder_markers"])
    text = summary_text(cal)
    assert "  placeholders " not in text
    n_new = sum(m.segment is not None for m in cal.new_markers)
    assert f"model markers seen ({n_new} new, placed on segments" in text, text
    # Each new marker is fitted: where the calibrated model puts it, frame by frame, against the
    # noise-free truth (segment frames are a gauge, so positions are compared in the lab).
    est = _world(cal.model, cal.params, cal.motion)
    for label in CLUSTER:
        err = np.linalg.norm(est[:, cal.model.marker_index(label)] - sim.clean_markers[:, subject.marker_index(label)],
                             axis=1)
        assert 1000 * np.median(err) < 1.5, label
    assert _ball_median_mm(compare_to_truth(cal, _known_only(sim, human))) < BALL_MEDIAN_MM
    # The written subject model carries them: Pinocchio puts them where the calibration did.
    out = tmp_path / "s.urdf"
    cal.write(urdf=out)
    written = load_model(out)
    assert set(CLUSTER) <= set(written.marker_names) and "LOOSE" not in written.marker_names
    pm = written.pin
    data = pm.createData()
    f = 150
    mo = cal.motion
    pin.framesForwardKinematics(pm, data, written.pin_configuration(mo.root_translation[f], mo.root_quaternion[f],
                                                                     mo.angles[f]))
    for label, (segment, _) in CLUSTER.items():
        assert written.markers[written.marker_index(label)].segment == segment
        np.testing.assert_allclose(data.oMf[pm.getFrameId(label)].translation, est[f, cal.model.marker_index(label)],
                                   atol=1e-9)
    # The subject's next trial runs with them as model markers.
    again = calibrate(written, trial.frames(0, 120))
    assert {m.label for m in again.new_markers} == {"LOOSE"} and set(CLUSTER) <= set(again.model.marker_names)
    # Switched off: the same labels are ignored, and the model keeps its own markers only.
    off = calibrate(human, trial.frames(0, 120), Settings(new_markers=False))
    assert off.new_markers == () and set(CLUSTER) | {"LOOSE"} <= set(off.ignored_labels)
    assert off.model.marker_names == human.marker_names


def test_new_markers_placed_by_the_moving_trial_not_the_static(human, subject):
    """Rigidity is judged on the trials that move: the cluster markers, seen in a long static trial and a short
    squat, go on their segments; a marker the static trial alone carries (a lab's calibration-only marker the
    model does not know, named as no medial marker: tests/test_axis_pairs.py places those) is left out and says why:
    in a static trial every marker keeps its distance to every other, so it would pass as rigid with any segment."""
    sim = simulate_squats(subject, frames=240, noise_mm=1.0, seed=8)
    static = simulate_static(subject, sim.truth, frames=600, seed=9)
    rng = np.random.default_rng(1)
    i = static.trial.labels.index("LKNE")
    extra = static.clean_markers[:, i] + np.array([0.0, 0.1, 0.0]) + rng.normal(0, 1e-3, (600, 3))
    markers = np.concatenate([static.trial.markers, extra[:, None]], axis=1)
    static_trial = Trial(static.trial.labels + ("LPTR",), markers, static.trial.rate, source="static.c3d")
    cal = calibrate(human, [static_trial, sim.trial])
    placed = {m.label: m for m in cal.new_markers}
    for label, (segment, _) in CLUSTER.items():
        assert placed[label].segment == segment, placed[label]
    assert placed["LPTR"].segment is None and "LPTR" in cal.ignored_labels
    assert placed["LPTR"].reason.startswith("seen only in still trials (static.c3d)"), placed["LPTR"].reason


def _known_only(sim, human):
    """`sim` as seen by the base model's joints (the cluster adds markers, not joints)."""
    from dataclasses import replace

    keep = [sim.model.marker_index(n) for n in human.marker_names]
    truth = replace(sim.truth, marker=sim.truth.marker[keep])
    return replace(sim, model=human, truth=truth, clean_markers=sim.clean_markers[:, keep],
                   trial=sim.trial.select(human.marker_names))


# ---------------------------------------------------------------------- several trials
def test_static_and_movement_trials_share_the_subject(human):
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=6)
    static = simulate_static(human, sim.truth, frames=120, seed=7)
    both = calibrate(human, [static.trial, sim.trial])
    assert [m.n_frames for m in both.motions] == [120, 300]
    assert "seeded from trial 2" in both.seed.notes[0]
    np.testing.assert_allclose(both.motions[0].times, static.trial.times)
    # Each trial's own residuals, and both fitted to the noise.
    for i, t in enumerate(both.trials):
        res = both.residuals[both.trial_frames(i)]
        assert res.shape[0] == t.n_frames
        assert 1000 * np.sqrt(np.nanmean(np.sum(res**2, axis=2))) < 1.9
    assert both.converged
    # The movement trial's motion and geometry, judged against the truth.
    movement = type(both)(**{**both.__dict__, "trials": (sim.trial,), "motions": (both.motions[1],),
                             "residuals": both.residuals[both.trial_frames(1)]})
    assert _ball_median_mm(compare_to_truth(movement, sim)) < BALL_MEDIAN_MM
    # The static pose, through the shared geometry: every marker where the truth puts it.
    est = _world(human, both.params, both.motions[0])
    assert 1000 * np.median(np.linalg.norm(est - static.clean_markers, axis=2)) < 1.5


def test_neutral_static_trial_sets_the_zero_of_the_joint_angles(human):
    """With the static trial named neutral, the segment frames are turned so that its joint angles
    are zero on average (as the simulator's truth has them), without changing the fit: every hinge
    angle of the movement trial then carries no constant offset against the truth."""
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=3)
    static = simulate_static(human, sim.truth, frames=100, seed=4)
    held = Settings(hold_axes=("radioulnar_r",))  # a held axis does not stop the turns: it is re-expressed
    free = calibrate(human, [static.trial, sim.trial], held)
    cal = calibrate(human, [static.trial, sim.trial], held, neutral=0)
    assert cal.neutral == 0 and free.neutral is None
    # a change of gauge: the fit stays (to the ball angles' re-solve below each turned frame: 2e-6 measured)
    assert cal.marker_rms == pytest.approx(free.marker_rms, rel=1e-5)
    hinges = [human.dof_index(j.dofs[0]) for j in human.joints if j.kind == "hinge"]
    mean_static = np.degrees(cal.motions[0].angles.mean(axis=0))
    assert np.abs(mean_static[hinges]).max() < 0.05, mean_static[hinges]
    err = np.degrees(cal.motions[1].angles - sim.motion.angles)[:, hinges]
    raw, offset_free = np.sqrt((err**2).mean(0)), err.std(0)
    assert np.all(raw <= offset_free + 0.6), (raw, offset_free)  # the truth's static angles drift by 0.5 deg
    err0 = np.degrees(free.motions[1].angles - sim.motion.angles)[:, hinges]
    assert np.sqrt((err0**2).mean()) > 2 * np.sqrt((err**2).mean())  # the priors' frames: offsets of degrees
    # Without the neutral trial the note names each pair of free hinges across a markerless segment (ankle and
    # subtalar across the talus) and the still trial to take their zero from; with it, none.  The truth bears it out:
    # the ankles' constant offsets are larger without.
    zero = [n for n in free.coordinate_notes if isinstance(n, ZeroNote)]
    assert {(n.coordinate, n.bare, n.neighbours, n.beyond, n.still) for n in zero} == {
        (f"ankle_{s}", f"talus_{s}", (f"subtalar_{s}",), f"calcn_{s}", 1) for s in "lr"}
    assert "--neutral 1 takes it from trial 1" in zero[0].text() and zero[0].text() in free.text()
    assert not any(isinstance(n, ZeroNote) for n in cal.coordinate_notes)
    ankles = [human.dof_index(f"ankle_{s}") for s in "lr"]
    off_free = np.abs(np.degrees(free.motions[1].angles - sim.motion.angles)[:, ankles].mean(axis=0))
    off_neutral = np.abs(np.degrees(cal.motions[1].angles - sim.motion.angles)[:, ankles].mean(axis=0))
    assert off_free.max() > 2 * off_neutral.max(), (off_free, off_neutral)
    assert "neutral      segment frames turned" in cal.text() and cal.report()["neutral_trial"] == 0
    with pytest.raises(CalibrateError, match="neutral: 2 is not the index"):
        calibrate(human, [static.trial, sim.trial], neutral=2)
    # The moving trial as the neutral one (every segment frame would turn by its mean pose): refused, the static named.
    with pytest.raises(CalibrateError, match=r"neutral: trial 2 \(.*\) moves .* give trial 1"):
        calibrate(human, [static.trial, sim.trial], neutral=1)


def test_a_neutral_static_that_bends_its_elbows_keeps_their_zero_and_the_fit(human):
    """A "neutral" static with the elbows bent to 90 deg (pig_walk's: 101 / 114 deg) is not the model's neutral pose
    there: turned to zero, the squats' elbows went 90 deg past their limits, and the re-solve against the limits
    dragged the other trial's fit (19.7 mm against 1.4; pig_walk's walk: 8.7 -> 62 mm).  A hinge whose zero there
    would carry the trials beyond its limits is not turned and is named; the rest are, and the fit is unchanged.
    Under locked subtalars (auto_hold's lock on two-marker feet) the legs are still turned: a turn is carried
    through a joint locked at its value."""
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=3)
    base = simulate_static(human, sim.truth, frames=100, seed=4)
    ang = base.motion.angles.copy()
    bent = [human.dof_index(d) for d in ("elbow_l", "elbow_r")]
    ang[:, bent] = np.radians(90.0)
    kin = build_kinematics(human)
    F = ang.shape[0]
    M, _ = kin.batch(np.column_stack([np.zeros((F, 3)), np.zeros((F, 3)), ang]), base.motion.root_quaternion, sim.truth)
    M = M + base.motion.root_translation[:, None, :] + np.random.default_rng(5).normal(0.0, 0.001, M.shape)
    static = Trial(human.marker_names, M, base.trial.rate)
    for settings in (Settings(), Settings(lock=("subtalar_l", "subtalar_r"))):
        free = calibrate(human, [static, sim.trial], settings)
        cal = calibrate(human, [static, sim.trial], settings, neutral=0)
        assert cal.marker_rms == pytest.approx(free.marker_rms, rel=1e-4)
        assert {j for j, _ in cal.not_neutral} == {"elbow_l", "elbow_r"}
        assert all(abs(np.degrees(a) - 90.0) < 10.0 for _, a in cal.not_neutral)
        mean_static = np.degrees(cal.motions[0].angles.mean(axis=0))
        legs = [human.dof_index(d) for d in ("knee_l", "knee_r", "ankle_l", "ankle_r")]
        assert np.abs(mean_static[legs]).max() < 0.1, mean_static[legs]
        assert np.all(np.abs(mean_static[bent] - 90.0) < 10.0), mean_static[bent]  # the model's zero kept
        assert "not turned: elbow_l (" in cal.text()
        assert {n["joint"] for n in cal.report()["not_neutral"]} == {"elbow_l", "elbow_r"}
        from calibrate.calibration import report_html
        assert "<li>neutral trial: not turned to zero there, elbow_l (" in report_html(cal.report())


def test_static_trial_alone_scales_and_flags_what_it_cannot_identify(human):
    sim = simulate_squats(human, frames=10, noise_mm=1.0, seed=8)  # only for a subject's truth
    static = simulate_static(human, sim.truth, frames=150, seed=9)
    cal = calibrate(human, static.trial)
    assert cal.converged
    flagged = {c.name for c in cal.changes if not c.identified}
    for joint in ("hip_l", "hip_r", "knee_l", "knee_r", "shoulder_l", "elbow_r"):
        assert f"centre[{joint}]" in flagged
    # No joint moves, so no hinge axis can be placed: each is held at the base model's, and said so.
    for dof in ("knee_l", "elbow_r"):
        assert dof in cal.held_axes and f"axis[{dof}]" not in {c.name for c in cal.changes}
    assert "axes held" in cal.text()
    # It sizes the subject as far as a static pose can.  Without motion, marker offsets and segment
    # scales trade off (the scales come out 0.2-17 % from the truth, some further than the base
    # model's), so they are not judged here (their SDs are, over many subjects, by
    # scripts/bench_uncertainty.py).  What one pose shows is the marker constellation: the distances
    # between markers of one segment, against the truth's (independent of the SDs and of the
    # segment-frame gauge).  Base model: 8.1 mm median, 26 mm max over the 43 pairs; calibrated
    # 0.10 mm median, 0.27 mm max today.  Every pair improves (1 mm or more off in the base model); 0.3 / 0.6 mm:
    # 2-3x today's, far below the base model's (a marker left where the base model had it fails).
    scales = [c for c in cal.changes if c.name.startswith("scale[")]
    assert any(not c.identified for c in scales)  # e.g. the markerless tali
    seg = np.array([human.segment_index(m.segment) for m in human.markers])
    pairs = [(i, j) for i in range(len(seg)) for j in range(i + 1, len(seg)) if seg[i] == seg[j]]

    def pair_errors(P) -> np.ndarray:
        x, t = P.scale[seg, None] * P.marker, sim.truth.scale[seg, None] * sim.truth.marker
        return np.array([abs(np.linalg.norm(x[i] - x[j]) - np.linalg.norm(t[i] - t[j])) for i, j in pairs])

    before, after = pair_errors(human.parameters()), pair_errors(cal.params)
    # (every pair the base model has 1 mm or more wrong: the simulator's RKNE, kept by the knee's axis, happens to sit
    # 0.15 mm from the base model's distance to RTHI, calibrated 0.27)
    assert np.all(after[before > 0.001] < before[before > 0.001])
    assert np.median(after) < 0.0003 and after.max() < 0.0006
    # ... and places its markers: the model fits the static pose to the noise.
    assert 1000 * cal.marker_rms < 1.9


# ---------------------------------------------------------------------- gaps, bad frames, spikes
def _through_c3d(trial: Trial, path) -> Trial:
    """`trial` written as a C3D file and read back, as a lab's file reaches calibrate."""
    write_c3d(path, trial)
    return read_trial(path)


def test_spikes_are_rejected_and_reported(human, tmp_path):
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=11)
    rng = np.random.default_rng(1)
    mk = np.array(sim.trial.markers)
    F, N = mk.shape[:2]
    hits = {(int(f), int(k)) for f, k in zip(rng.integers(0, F, 60), rng.integers(0, N, 60), strict=True)}
    for f, k in hits:
        d = rng.normal(size=3)
        mk[f, k] += rng.uniform(0.03, 0.15) * d / np.linalg.norm(d)
    cal = calibrate(human, _through_c3d(Trial(sim.trial.labels, mk, sim.trial.rate), tmp_path / "spikes.c3d"))
    found = {(o.frame, human.marker_names.index(o.marker)) for o in cal.outliers}
    assert len(hits & found) >= 0.95 * len(hits)
    assert len(found - hits) <= 0.001 * F * N
    cmp = compare_to_truth(cal, sim)
    assert _ball_median_mm(cmp) < BALL_MEDIAN_MM
    assert cal.marker_rms < 1.05 * cmp.floor_rms
    rep = cal.report()
    assert rep["outliers"]["count"] == len(cal.outliers) and rep["trials"][0]["outliers"] == len(cal.outliers)


def test_gaps_late_markers_and_empty_frames(human, tmp_path):
    # Seed 13 since 2026-12-07: seed 12's subject draws a poorly placed left elbow axis (1.73 deg over 300 gap-free
    # frames), here 0.68 deg, 1.06 with the base model's elbow marker moved out to 48 mm (docs/benchmarks.md).
    sim = simulate_squats(human, frames=400, noise_mm=1.0, gaps=True, seed=13)
    mk = np.array(sim.trial.markers)
    col = {n: i for i, n in enumerate(sim.trial.labels)}
    mk[:10] = np.nan  # the recording starts before the markers are tracked
    mk[50:250, col["RKNE"]] = np.nan  # a two-second gap
    mk[:200, col["LFIN"]] = np.nan  # a marker that appears mid-trial
    mk[300:330, col["RKNE"]] = np.nan  # no marker at all on the right thigh for 0.3 s
    mk[300:330, col["RTHI"]] = np.nan
    mk[340:345, [col["LELB"], col["LUPA"]]] = np.nan
    cal = calibrate(human, _through_c3d(Trial(sim.trial.labels, mk, sim.trial.rate), tmp_path / "gaps.c3d"))
    assert cal.converged
    assert np.all(np.isfinite(cal.motion.angles)) and np.all(np.isfinite(cal.motion.root_translation))
    cmp = compare_to_truth(cal, sim)
    assert _ball_median_mm(cmp) < BALL_MEDIAN_MM
    assert max(cmp.axis_error_deg[j] for j in ("knee_l", "knee_r", "elbow_l", "elbow_r")) < 1.0
    assert np.isnan(cal.residuals[:10]).all()  # no data, no residual


# ---------------------------------------------------------------------- command line
def test_cli_several_trials_with_a_marker_map(human, subject, tmp_path):
    sim = simulate_squats(subject, frames=200, noise_mm=1.0, seed=13)
    static = simulate_static(subject, sim.truth, frames=80, seed=14)
    rename = {"RASI": "R.ASIS", "LASI": "L.ASIS", "RTH1": "R_thigh_plate_1"}
    for name, sm in (("static", static), ("squat", sim)):
        labels = tuple(rename.get(n, n) for n in sm.trial.labels)
        write_c3d(tmp_path / f"{name}.c3d", Trial(labels, sm.trial.markers, sm.trial.rate))
    (tmp_path / "map.toml").write_text('RASI = ["R.ASIS"]\n')
    r = subprocess.run([sys.executable, "-m", "calibrate.cli", tmp_path / "static.c3d", tmp_path / "squat.c3d",
                        human.path, "--markers", tmp_path / "map.toml", "-q"], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr
    for name in ("static.urdf", "static_report.json", "static_motion.csv", "squat_motion.csv"):
        assert (tmp_path / name).is_file(), name
    assert read_motion_csv(tmp_path / "static_motion.csv").n_frames == 80
    assert read_motion_csv(tmp_path / "squat_motion.csv").n_frames == 200
    rep = json.loads((tmp_path / "static_report.json").read_text())
    assert [t["frames"] for t in rep["trials"]] == [80, 200]
    became = {e["trial_label"]: e for e in rep["trials"][1]["labels"]}
    assert became["R.ASIS"]["label"] == "RASI" and became["R.ASIS"]["how"] == "map"
    assert became["L.ASIS"]["label"] == "LASI" and became["L.ASIS"]["how"] == "alias"
    assert became["R_thigh_plate_1"]["how"] == "unknown" and became["RKNE"]["how"] == "exact"
    new = {m["label"]: m["segment"] for m in rep["marker_set"]["new"]}
    assert new["R_thigh_plate_1"] == "femur_r" and new["LSH1"] == "tibia_l"
    written = load_model(tmp_path / "static.urdf")
    assert "R_thigh_plate_1" in written.marker_names and "RASI" in written.marker_names
    # Bad input: one line, exit 2, nothing written or replaced.
    (tmp_path / "bad.toml").write_text('NOPE = ["X"]\n')
    before = (tmp_path / "squat_motion.csv").read_text()
    r = subprocess.run([sys.executable, "-m", "calibrate.cli", tmp_path / "squat.c3d", human.path, "--markers",
                        tmp_path / "bad.toml", "-o", tmp_path / "x.urdf", "--overwrite", "-q"], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "NOPE" in r.stderr
    assert not (tmp_path / "x.urdf").exists() and (tmp_path / "squat_motion.csv").read_text() == before
