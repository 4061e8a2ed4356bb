"""`calibrate ik TRIAL ... SUBJECT`: a calibrated subject held fixed, every frame's pose of more trials; checked
against the simulator's true motion, Pinocchio-free of the solver (the truth is the simulator's), and the .osim
subject against the URDF one."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.cli.main import main
from calibrate.io.motion import read_motion_csv
from calibrate.io.osim_export import export_osim
from calibrate.model.model import load_model
from calibrate.simulation.simulate import simulate_squats, write_simulation

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


@pytest.fixture(scope="module")
def squats(tmp_path_factory) -> Path:
    """A noise-free simulated squat trial (60 frames) with its true subject and motion."""
    d = tmp_path_factory.mktemp("ik")
    write_simulation(simulate_squats(load_model(HUMAN), frames=60, noise_mm=0.0, seed=3), d / "sim")
    return d / "sim"


def test_ik_on_the_true_subject_gives_the_true_motion(squats, tmp_path, capsys):
    """The simulator's subject held fixed and its noise-free markers: every frame's joint angles equal the true
    motion's (1e-5 rad) and the root its position (1e-6 m); the same subject as an .osim gives the same motion and
    a .mot beside it; the summary names the trial and its marker RMS (0.00 mm)."""
    out = tmp_path / "urdf"
    out.mkdir()
    assert main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "trial.c3d: 60 frames" in text and "marker RMS 0.00 mm" in text, text
    got, truth = read_motion_csv(out / "trial_motion.csv"), read_motion_csv(squats / "truth_motion.csv")
    assert got.dof_names == truth.dof_names
    assert np.allclose(got.times, truth.times, atol=1e-9)
    assert np.abs(got.angles - truth.angles).max() < 1e-5
    assert np.abs(got.root_translation - truth.root_translation).max() < 1e-6
    osim = export_osim(load_model(squats / "truth.urdf"), tmp_path / "truth.osim")
    out2 = tmp_path / "osim"
    out2.mkdir()
    assert main(["ik", str(squats / "trial.c3d"), str(osim), "-o", str(out2), "-q"]) == 0
    via_osim = read_motion_csv(out2 / "trial_motion.csv")
    assert np.abs(via_osim.angles - got.angles).max() < 1e-8 and (out2 / "trial_motion.mot").is_file()
    # beside it the marker errors as OpenSim's IK tool writes them: the true subject on its noise-free markers, ~0
    sto = (out2 / "trial_ik_marker_errors.sto").read_text().splitlines()
    assert sto[0] == "Model Marker Errors from IK" and sto[2] == "nRows=60"
    errors = np.array([[float(v) for v in line.split("\t")] for line in sto[7:]])
    assert np.allclose(errors[:, 0], truth.times, atol=1e-9) and np.all(errors[:, 3] < 1e-6)


def test_ik_report_holds_the_fit_as_pinocchio_reads_it_back(squats, tmp_path, capsys):
    """<trial>_ik_report.json (subject_ik.trial_report): each marker's RMS, largest error and frames seen equal those of
    the written motion posed by Pinocchio on the subject against the trial's markers (1e-6 mm: the report's rounding);
    the held coordinate in degrees, the markers fitted and the label not fitted, the positions left out (as the
    summary counts them) and the files written as they are on disk."""
    import json

    import pinocchio as pin

    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    subject = load_model(squats / "truth.urdf")
    trial = read_trial(squats / "trial.c3d")
    rng = np.random.default_rng(5)
    markers = trial.markers + rng.normal(0.0, 0.002, trial.markers.shape)  # 2 mm noise
    markers[10:25, 3] = np.nan  # a gap in one marker
    markers[30, 5] += [0.0, 0.0, 0.9]  # a spike, left out before the fit
    extra = np.zeros((trial.n_frames, 1, 3))  # a label the subject has no marker for
    noisy = replace(trial, markers=np.concatenate([markers, extra], axis=1), labels=(*trial.labels, "EXTRA"))
    write_c3d(tmp_path / "noisy.c3d", noisy)
    hinge = next(j.dofs[0] for j in subject.joints if j.kind == "hinge")
    out = tmp_path / "out"
    out.mkdir()
    assert main(["ik", str(tmp_path / "noisy.c3d"), str(squats / "truth.urdf"), "-o", str(out), "--lock",
                 f"{hinge}=10"]) == 0
    text = capsys.readouterr().out
    report = json.loads((out / "noisy_ik_report.json").read_text())
    assert report["outputs"] == [str(out / "noisy_motion.csv"), str(out / "noisy_ik_report.json")]
    assert sorted(p.name for p in out.iterdir()) == ["noisy_ik_report.json", "noisy_motion.csv"]
    assert report["held_deg"] == {hinge: pytest.approx(10.0, abs=1e-9)}
    assert report["markers_fitted"] == [m for m in subject.marker_names if m in trial.labels]
    assert report["labels_not_fitted"] == ["EXTRA"] and report["trial"]["frames"] == trial.n_frames
    left = report["positions_left_out"]
    assert left >= 1 and f"; {left} marker positions left out" in text
    motion = read_motion_csv(out / "noisy_motion.csv")
    kept = read_trial(tmp_path / "noisy.c3d")
    pm = subject.pin
    d = pm.createData()
    err = np.full((trial.n_frames, len(subject.marker_names)), np.nan)
    for f in range(trial.n_frames):
        pin.framesForwardKinematics(pm, d, subject.pin_configuration(motion.root_translation[f],
                                                                      motion.root_quaternion[f], motion.angles[f]))
        for k, m in enumerate(subject.marker_names):
            at = d.oMf[pm.getFrameId(m, pin.FrameType.BODY)].translation
            err[f, k] = np.linalg.norm(at - kept.markers[f, kept.labels.index(m)])
    err[30, subject.marker_names.index(trial.labels[5])] = np.nan  # the spike: not fitted, not counted
    per = report["markers"]["per_marker"]
    assert set(per) == set(report["markers_fitted"])
    for k, m in enumerate(subject.marker_names):
        e = err[np.isfinite(err[:, k]), k]
        assert per[m]["frames"] == e.size, m
        assert per[m]["rms_mm"] == pytest.approx(1e3 * np.sqrt(np.mean(e**2)), abs=2e-6), m
        assert per[m]["max_mm"] == pytest.approx(1e3 * e.max(), abs=2e-6), m
    assert per[trial.labels[3]]["frames"] == trial.n_frames - 15
    assert report["markers"]["rms_mm"] == pytest.approx(1e3 * np.sqrt(np.nanmean(err**2)), abs=2e-6)
    assert report["markers"]["rms_mm"] > 1.0  # the noise and the held hinge: errors the check can see


def test_a_trial_whose_markers_scatter_beyond_the_learnt_noise_is_fitted_with_them_alike(squats, tmp_path, capsys):
    """--report's learnt noise weighs a trial's markers only where it holds for the trial: two markers that drift
    30 mm about their segment (a shoulder marker on the shoulder blade in a squat after a walk's calibration) scatter
    beyond LEARNT_NOISE_HOLDS times the SD learnt for them, so the trial is fitted with its markers weighed alike —
    the motion is fit_trial's with those weights, from Python — and a note and the report (learnt_noise_beyond, its
    weights) say so; the same trial undamaged keeps the learnt weights, no note."""
    import json

    from calibrate.calibration.subject_ik import LEARNT_NOISE_HOLDS, fit_trial, report_holds
    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    subject = load_model(squats / "truth.urdf")
    trial = read_trial(squats / "trial.c3d")
    names = [m for m in subject.marker_names if m in trial.labels]
    a, b = names[names.index("LSHO")], names[len(names) // 2]  # a shoulder marker, RBAK
    sd_mm = {m: (0.5 if m in (a, b) else 3.0 if k % 3 == 0 else 1.0) for k, m in enumerate(names)}
    report = tmp_path / "cal_report.json"  # a calibration's report: nothing held, its learnt noise unequal
    report.write_text(json.dumps({"parameters": {}, "trials": [], "settings": {},
                                  "noise": {"weight_sd_mm": sd_mm}}))
    drift = 0.03 * np.sin(2 * np.pi * trial.times / 1.7)
    markers = trial.markers.copy()
    for m in (a, b):
        markers[:, trial.labels.index(m), 0] += drift
    write_c3d(tmp_path / "drift.c3d", replace(trial, markers=markers))
    out = tmp_path / "out"
    out.mkdir()
    assert main(["ik", str(tmp_path / "drift.c3d"), str(squats / "trial.c3d"), str(squats / "truth.urdf"),
                 "--report", str(report), "-o", str(out)]) == 0
    printed = capsys.readouterr()
    notes = [x for x in printed.err.splitlines() if "noise the calibration learnt" in x]
    assert len(notes) == 1 and notes[0].startswith("note: drift.c3d: ") and "weighed alike" in notes[0], notes
    lines = {x.split(":")[0].strip(): x for x in printed.out.splitlines() if x.startswith("  ") and ".c3d:" in x}
    assert "markers weighed alike" in lines["drift.c3d"] and "weighed alike" not in lines["trial.c3d"], lines
    got = json.loads((out / "drift_ik_report.json").read_text())
    beyond = got["learnt_noise_beyond"]
    assert list(beyond)[:2] in ([a, b], [b, a]) and min(beyond.values()) > LEARNT_NOISE_HOLDS
    assert got["weights"] == {m: 1.0 for m in names}
    h = report_holds(report)
    assert h.noise_sd == pytest.approx({m: 1e-3 * v for m, v in sd_mm.items()})
    alike = fit_trial(subject, read_trial(tmp_path / "drift.c3d"), subject.parameters(), {}, {m: 1.0 for m in names})
    motion = read_motion_csv(out / "drift_motion.csv")
    assert np.abs(motion.angles - alike.fit.motion.angles).max() < 1e-4
    # The undamaged trial: the learnt weights hold (no marker beyond), the report keeps them
    own = json.loads((out / "trial_ik_report.json").read_text())
    assert own["learnt_noise_beyond"] == {}
    ratio = (sd_mm[names[0]] / sd_mm[names[1]]) ** 2
    assert own["weights"][names[1]] / own["weights"][names[0]] == pytest.approx(ratio)
    learnt = fit_trial(subject, trial, subject.parameters(), {}, h.weights, noise_sd=h.noise_sd)
    assert not learnt.weighed_alike and learnt.noise_beyond == {}


def test_ik_notes_a_coordinate_beyond_the_subjects_limits(squats, tmp_path, capsys):
    """The squats' true subject with knee_r's upper limit cut to 25 deg: the fit (under the limits widened by 15 deg,
    as the calibration's) leaves the knee beyond them in the frames where the true knee bends past 30 deg, and
    `calibrate ik` notes it (identifiability.limit_records, as the calibration notes it): the share of frames is the
    truth's, in the note and in the report.  The subject as calibrated: no note."""
    import json
    import re

    truth = read_motion_csv(squats / "truth_motion.csv")
    text = (squats / "truth.urdf").read_text()
    start = text.index('<joint name="knee_r"')
    limit = re.compile(r'upper="[^"]*"')
    cut = text[:start] + limit.sub(f'upper="{float(np.radians(25.0))!r}"', text[start:], count=1)
    (tmp_path / "cut.urdf").write_text(cut)
    assert load_model(tmp_path / "cut.urdf").dofs[truth.dof_names.index("knee_r")].upper == pytest.approx(
        np.radians(25.0))
    knee = np.degrees(truth.angles[:, truth.dof_names.index("knee_r")])
    share = float(np.mean(knee > 30.0))
    assert 0.05 < share < 0.95  # the squats bend it past there, not always
    out = tmp_path / "out"
    out.mkdir()
    assert main(["ik", str(squats / "trial.c3d"), str(tmp_path / "cut.urdf"), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"note: trial.c3d: knee_r beyond cut.urdf's joint limits in {100 * share:.0f} % of its frames" in err, err
    (got,) = json.loads((out / "trial_ik_report.json").read_text())["beyond_limits"]
    assert got["coordinate"] == "knee_r" and got["fraction"] == pytest.approx(share, abs=1.5 / len(knee))
    # held at the widened limit, which the fit's soft limit residual (solve.ik.LIMIT_WEIGHT) lets it pass a little
    assert got["worst_deg"] == pytest.approx(min(knee.max(), 40.0) - 25.0, abs=1.0)
    assert main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "-o", str(out), "--overwrite"]) == 0
    assert "joint limits" not in capsys.readouterr().err
    assert json.loads((out / "trial_ik_report.json").read_text())["beyond_limits"] == []


def _held_at_10_deg(squats: Path, out: Path, dof: str):
    """`calibrate ik` on the squats' true subject with `dof` held at 10 deg (--lock), into the new folder `out`: its
    motion, checked to hold it there in every frame."""
    out.mkdir()
    assert main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "-o", str(out), "--lock",
                 f"{dof}=10", "-q"]) == 0
    m = read_motion_csv(out / "trial_motion.csv")
    assert np.allclose(m.angles[:, m.dof_names.index(dof)], np.radians(10.0), atol=1e-12)
    return m


def test_ik_holds_locked_coordinates_and_refuses_bad_input(squats, tmp_path, capsys):
    """--lock holds a coordinate at its value in every frame (the rest refitted around it); no trial, a trial that
    shares too few markers, a lock the subject lacks, an existing output without --overwrite: one line each,
    exit 2, nothing written."""
    subject = load_model(squats / "truth.urdf")
    hinge = next(j.dofs[0] for j in subject.joints if j.kind == "hinge")
    out = tmp_path / "lock"
    _held_at_10_deg(squats, out, hinge)
    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    trial = read_trial(squats / "trial.c3d")
    write_c3d(tmp_path / "few.c3d", trial.select(trial.labels[:2]))
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "trial_motion.csv").write_text("keep me")
    cases = [(["ik", str(squats / "truth.urdf")], "give one or more trials and then the calibrated subject"),
             (["ik", str(tmp_path / "few.c3d"), str(squats / "truth.urdf"), "-o", str(out)],
              "only 2 of its labels are markers of truth.urdf"),
             (["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "-o", str(out), "--overwrite",
               "--lock", "no_such_dof"], "locked coordinate 'no_such_dof' is not one of truth.urdf's"),
             (["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "-o", str(bad)], "exists")]
    before = sorted(p.name for p in out.iterdir())
    for argv, needle in cases:
        code = main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and needle in err[0], (argv, err)
    assert sorted(p.name for p in out.iterdir()) == before and (bad / "trial_motion.csv").read_text() == "keep me"


def test_ik_leaves_out_damaged_positions(squats, tmp_path, capsys):
    """A ghost 1 m off for three frames on a knee marker and a shank's and a forearm's labels exchanged for six frames:
    `calibrate ik` leaves those positions out, as the calibration does before its start (seeding.jumped_samples),
    and every frame's angles are the true motion's (the other markers, noise-free, still place every segment); the
    summary counts them.  --keep-damaged fits them, as OpenSim's IK would: the pose is then far off (pig_walk's
    walk: a heel's ghost turned the right shoulder 230 deg; scripts/damage_values.py --ik)."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    trial = read_trial(squats / "trial.c3d")
    X = np.array(trial.markers)
    X[20:23, trial.labels.index("LKNE")] += [0.6, -0.5, 0.6]
    a, b = trial.labels.index("RTIB"), trial.labels.index("LWRA")
    X[35:41, [a, b]] = X[35:41, [b, a]]
    write_c3d(tmp_path / "damaged.c3d", replace(trial, markers=X))
    truth = read_motion_csv(squats / "truth_motion.csv")
    fits = {}
    for flag in ((), ("--keep-damaged",)):
        out = tmp_path / ("kept" if flag else "left")
        out.mkdir()
        assert main(["ik", str(tmp_path / "damaged.c3d"), str(squats / "truth.urdf"), "-o", str(out), *flag]) == 0
        fits[bool(flag)] = (read_motion_csv(out / "damaged_motion.csv"), capsys.readouterr().out)
    left, text = fits[False]
    assert "15 marker positions left out" in text, text
    assert np.abs(left.angles - truth.angles).max() < 1e-4
    kept, text = fits[True]
    assert "left out" not in text
    assert np.degrees(np.abs(kept.angles - truth.angles).max()) > 10.0


def test_ik_refuses_another_subjects_trial(squats, tmp_path, capsys):
    """The squats' markers 20 % further apart (a larger subject's trial): its markers on each segment read 20 % from the
    subject's (calibration.subject_ik.size_misfit), and `calibrate ik` refuses it in one line, exit 2, nothing
    written (BTKData's FlatFoot subject had fitted another subject's walk at 82 mm RMS); --other-subject fits it."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    trial = read_trial(squats / "trial.c3d")
    centre = np.nanmean(trial.markers, axis=(0, 1))
    write_c3d(tmp_path / "larger.c3d", replace(trial, markers=centre + 1.2 * (trial.markers - centre)))
    out = tmp_path / "out"
    out.mkdir()
    code = main(["ik", str(tmp_path / "larger.c3d"), str(squats / "truth.urdf"), "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "its markers on each segment are 20 % nearer or further apart than " \
        "truth.urdf's" in err[0], err
    assert not any(out.iterdir())
    assert main(["ik", str(tmp_path / "larger.c3d"), str(squats / "truth.urdf"), "-o", str(out), "-q",
                 "--other-subject"]) == 0
    assert (out / "larger_motion.csv").is_file()


def test_ik_fits_the_later_trials_on_the_other_core_to_the_same_bits(squats, tmp_path, capsys):
    """Trials of 500 frames or more in all: the later ones (about half the frames) are fitted in a forked child on
    the other core (calibrate.solve.ahead.run_ahead) while the first are fitted here.  Each motion equals, to the
    byte, that trial's fit alone; a trial the child refuses (another subject's: size_misfit) fails the command in
    its one line, exit 2, nothing written."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial
    from calibrate.solve.ahead import ahead_split, can_run_ahead

    trial = read_trial(squats / "trial.c3d")  # 60 frames: ten copies, each a little moved, 600 frames
    rng = np.random.default_rng(7)
    names = []
    for k in range(10):
        write_c3d(tmp_path / f"t{k}.c3d", replace(trial, markers=trial.markers + rng.normal(0, 0.001, (1, 1, 3))))
        names.append(str(tmp_path / f"t{k}.c3d"))
    split = ahead_split([60] * 10)
    assert split == (5 if can_run_ahead() else 10)
    together, alone = tmp_path / "together", tmp_path / "alone"
    together.mkdir()
    alone.mkdir()
    assert main(["ik", *names, str(squats / "truth.urdf"), "-o", str(together), "-q"]) == 0
    for name in (names[0], names[-1]):  # one fitted here, one in the child
        assert main(["ik", name, str(squats / "truth.urdf"), "-o", str(alone), "-q"]) == 0
        stem = Path(name).stem
        assert (together / f"{stem}_motion.csv").read_bytes() == (alone / f"{stem}_motion.csv").read_bytes()
    # the last trial another subject's (its markers 20 % further apart): refused where the child fits it
    centre = np.nanmean(trial.markers, axis=(0, 1))
    write_c3d(tmp_path / "t9.c3d", replace(trial, markers=centre + 1.2 * (trial.markers - centre)))
    out = tmp_path / "out"
    out.mkdir()
    capsys.readouterr()
    assert main(["ik", *names, str(squats / "truth.urdf"), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"calibrate: error: {tmp_path / 't9.c3d'}: its markers on each "
                                               "segment are 20 % nearer"), err
    assert not any(out.iterdir())


def test_ahead_split_halves_the_work():
    """ahead_split: the cut that leaves the caller the first jobs, about half the work (the child the rest); none
    for one job or less than AHEAD_LEAST in all."""
    from calibrate.solve.ahead import AHEAD_LEAST, ahead_split, can_run_ahead

    if not can_run_ahead():
        pytest.skip("run_ahead does not fork here")
    assert ahead_split([200, 200, 200, 200]) == 2
    assert ahead_split([1000, 10, 10]) == 1 and ahead_split([10, 10, 1000]) == 2
    assert ahead_split([300, 200, 100, 400]) == 2  # 500 / 500
    assert ahead_split([5000]) == 1 and ahead_split([0.4 * AHEAD_LEAST, 0.4 * AHEAD_LEAST]) == 2


def test_ik_holds_what_a_trials_markers_do_not_place(squats, tmp_path, capsys):
    """A trial without the left hand's only marker (LFIN) cannot place the hand: its wrist's coordinates are held at 0
    and a note names them (model.resolve, as the calibration locks them), and the rest is the true motion."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    trial = read_trial(squats / "trial.c3d")
    write_c3d(tmp_path / "nohand.c3d", trial.select([lab for lab in trial.labels if lab != "LFIN"]))
    assert main(["ik", str(tmp_path / "nohand.c3d"), str(squats / "truth.urdf"), "-o", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "nohand.c3d: 1 segments its markers do not place (hand_l); wrist_l_flexion, wrist_l_deviation held at 0" \
        in err, err
    got, truth = read_motion_csv(tmp_path / "nohand_motion.csv"), read_motion_csv(squats / "truth_motion.csv")
    wrist = [got.dof_names.index(d) for d in ("wrist_l_flexion", "wrist_l_deviation")]
    assert np.all(got.angles[:, wrist] == 0.0)
    rest = [i for i in range(len(got.dof_names)) if i not in wrist]
    assert np.abs(got.angles[:, rest] - truth.angles[:, rest]).max() < 1e-5


def test_ik_fits_under_the_calibrations_limits(squats, tmp_path):
    """The calibration's limits are the model's widened by LIMIT_MARGIN (15 deg), and `calibrate ik` fits under the
    same: the true subject with its knee's upper limit set 10 deg below the squat's deepest knee angle still gives
    back the noise-free true motion (an IK under the model's own limits holds that knee short of the markers)."""
    import math
    import re

    from calibrate.problem.problem import LIMIT_MARGIN

    truth = read_motion_csv(squats / "truth_motion.csv")
    knee = truth.dof_names.index("knee_r")
    deepest = float(truth.angles[:, knee].max())
    assert math.radians(10.0) < LIMIT_MARGIN
    text = (squats / "truth.urdf").read_text()
    joint = re.search(r'<joint name="knee_r".*?</joint>', text, re.S).group(0)
    narrowed = re.sub(r'upper="[^"]+"', f'upper="{deepest - math.radians(10.0)!r}"', joint)
    (tmp_path / "narrow.urdf").write_text(text.replace(joint, narrowed))
    out = tmp_path / "out"
    out.mkdir()
    assert main(["ik", str(squats / "trial.c3d"), str(tmp_path / "narrow.urdf"), "-o", str(out), "-q"]) == 0
    got = read_motion_csv(out / "trial_motion.csv")
    assert np.abs(got.angles[:, knee] - truth.angles[:, knee]).max() < 1e-5


def test_a_static_only_calibrations_auto_locks_hold_on_its_static_alone(squats, tmp_path, capsys):
    """Calibrated on a static alone, calibrate locks the subtalars (the static moves them no more than its markers
    fix them).  `calibrate ik --report` holds them on that static, as the calibration did, and fits them on a trial
    it did not fit (the squats), saying so in one note: held there, they put the wrists of BTKData's FlatFoot walk
    55 mm off."""
    from calibrate.io.c3d import write_c3d
    from calibrate.simulation.simulate import simulate_static

    truth_model = load_model(squats / "truth.urdf")
    static = simulate_static(truth_model, truth_model.parameters(), frames=60, noise_mm=1.0, seed=3)
    write_c3d(tmp_path / "static.c3d", static.trial)
    cal = tmp_path / "cal"
    cal.mkdir()
    assert main([str(tmp_path / "static.c3d"), str(HUMAN), "-o", str(cal / "subject.urdf"), "-q"]) in (0, 1)
    import json

    report = json.loads((cal / "static_report.json").read_text())
    assert report["still_only_mm"] is not None
    auto = {x["coordinate"]: np.radians(x["value_deg"]) for x in report["auto_locked"]}
    assert {"subtalar_l", "subtalar_r"} <= set(auto)
    out = tmp_path / "ik"
    out.mkdir()
    capsys.readouterr()
    assert main(["ik", str(squats / "trial.c3d"), str(tmp_path / "static.c3d"), str(cal / "subject.urdf"),
                 "--report", str(cal / "static_report.json"), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "the calibration held them because its static, its only trial" in err and "fitted in trial.c3d" in err
    moving, still = read_motion_csv(out / "trial_motion.csv"), read_motion_csv(out / "static_motion.csv")
    for name, value in auto.items():
        assert np.allclose(still.angles[:, still.dof_names.index(name)], value, atol=1e-12), name
        assert np.ptp(moving.angles[:, moving.dof_names.index(name)]) > 1e-3, name
    # The same rule from the report (report_locks) and from the Python result (Calibration.locked_elsewhere)
    from calibrate.calibration.pipeline import calibrate
    from calibrate.calibration.report import report_locks
    from calibrate.io.read import read_trial

    assert set(report_locks(report)) - set(report_locks(report, elsewhere=True)) == set(auto)
    result = calibrate(load_model(HUMAN), read_trial(tmp_path / "static.c3d"))
    assert result.still_only is not None and set(result.locked) - set(result.locked_elsewhere) == set(auto)


def test_ik_holds_one_angle_of_a_ball_joint(squats, tmp_path):
    """--lock on one of a ball joint's three angles (Pose2Sim's IK setup holds L5/S1's flexion): the ball is solved on
    its three angles, the held one at its value in every frame and the other two free; the noise-free fit is then
    worse than with nothing held, and no worse than the true motion with that angle set to the value."""
    from calibrate.io.read import read_trial
    from calibrate.model.kinematics import FrameLayout, build_kinematics
    from calibrate.solve.ik import marker_columns

    subject = load_model(squats / "truth.urdf")
    ball = next(j for j in subject.joints if j.kind == "ball" and j.name == "lumbar")
    held, free = ball.dofs[0], ball.dofs[1:]
    m = _held_at_10_deg(squats, tmp_path / "ball", held)
    assert all(np.ptp(m.angles[:, m.dof_names.index(d)]) > 1e-3 for d in free)
    kin = build_kinematics(subject)
    obs = marker_columns(subject, read_trial(squats / "trial.c3d"))

    def sse(motion) -> float:
        pts, _ = kin.batch(FrameLayout.coordinates(motion.root_translation, motion.angles), motion.root_quaternion,
                           subject.parameters())
        return float(np.nansum((np.asarray(pts) - obs) ** 2))

    truth = read_motion_csv(squats / "truth_motion.csv")
    angles = truth.angles.copy()
    angles[:, truth.dof_names.index(held)] = np.radians(10.0)
    moved = type(truth)(truth.times, truth.root_translation, truth.root_quaternion, angles, truth.dof_names)
    assert 1e-6 < sse(m) <= sse(moved)


def test_a_calibrations_locked_coordinates_are_what_its_motion_holds(squats):
    """Calibration.locked: the settings' locks and calibrate's own auto-locks, each at the value the calibrated
    motion holds in every frame (what `calibrate ik` and bench_osim's held-out fit hold)."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.read import read_trial
    from calibrate.problem.settings import Settings

    model = load_model(HUMAN)
    hinge = next(j.dofs[0] for j in model.joints if j.kind == "hinge")
    cal = calibrate(model, read_trial(squats / "trial.c3d"), Settings(lock=((hinge, 0.2),), max_iterations=5))
    assert cal.locked[hinge] == 0.2
    assert {lk.coordinate for lk in cal.auto_locked} <= set(cal.locked)
    motion = cal.motions[0]
    for name, value in cal.locked.items():
        assert np.allclose(motion.angles[:, motion.dof_names.index(name)], value, atol=1e-9), name


def test_ik_with_the_calibrations_report_gives_its_own_motion(squats, tmp_path, capsys):
    """`calibrate ik TRIAL subject.urdf --report subject_report.json` on the calibration's own trial: the markers
    weighed as it weighed them (its learnt noise) and what it held held, the fit is the calibration's motion (outliers
    off: the same positions fitted; to the global solve's convergence).  A report's locks and auto-locks are held at
    their values; a file that is not a report: one line, exit 2."""
    import json

    cal_dir = tmp_path / "cal"
    cal_dir.mkdir()
    assert main([str(squats / "trial.c3d"), str(HUMAN), "-o", str(cal_dir / "subject.urdf"), "--outlier-sigmas", "0",
                 "-q"]) in (0, 1)
    out = tmp_path / "ik"
    out.mkdir()
    # without --report: the subject names its report (its first comment) and the report is beside it, so a note
    # says what --report would do; nothing is taken from it
    capsys.readouterr()
    assert main(["ik", str(squats / "trial.c3d"), str(cal_dir / "subject.urdf"), "-o", str(out)]) == 0
    named = [x for x in capsys.readouterr().err.splitlines() if "names its calibration's report" in x]
    assert named == [f"note: subject.urdf names its calibration's report, trial_report.json, beside it: --report "
                     f"{cal_dir / 'trial_report.json'} holds what the calibration held and weighs the markers as it "
                     "weighed them, as the calibration's own motion was fitted"]
    assert main(["ik", str(squats / "trial.c3d"), str(cal_dir / "subject.urdf"), "--report",
                 str(cal_dir / "trial_report.json"), "-o", str(out), "--overwrite"]) == 0
    assert "names its calibration's report" not in capsys.readouterr().err
    m, calibrated = read_motion_csv(out / "trial_motion.csv"), read_motion_csv(cal_dir / "trial_motion.csv")
    assert np.abs(m.angles - calibrated.angles).max() < 1e-3  # rad, every coordinate of every frame
    assert np.abs(m.root_translation - calibrated.root_translation).max() < 1e-5  # m
    model = load_model(HUMAN)
    hinges = [j.dofs[0] for j in model.joints if j.kind == "hinge"]
    report = tmp_path / "report.json"  # a report's held coordinates: its settings' locks and its auto-locks
    report.write_text(json.dumps({"parameters": {}, "trials": [], "settings": {"lock_deg": {hinges[0]: 5.0}},
                                  "auto_locked": [{"coordinate": hinges[1], "value_deg": -2.0}]}))
    capsys.readouterr()
    assert main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "--report", str(report), "-o", str(out),
                 "--overwrite", "-q"]) == 0
    m = read_motion_csv(out / "trial_motion.csv")
    assert np.allclose(m.angles[:, m.dof_names.index(hinges[0])], np.radians(5.0), atol=1e-12)
    assert np.allclose(m.angles[:, m.dof_names.index(hinges[1])], np.radians(-2.0), atol=1e-12)
    # the same from Python (subject_ik.report_holds): the locks in rad; weights only from a learnt noise, median 1
    from calibrate.calibration.subject_ik import report_holds

    holds = report_holds(report)
    assert holds.locked == pytest.approx({hinges[0]: np.radians(5.0), hinges[1]: np.radians(-2.0)})
    assert holds.weights is None and holds.static_locks == {} and holds.own == frozenset()
    learnt = report_holds(cal_dir / "trial_report.json")
    sd = json.loads((cal_dir / "trial_report.json").read_text())["noise"]["weight_sd_mm"]
    assert set(learnt.weights) == set(sd) and np.median(list(learnt.weights.values())) == pytest.approx(1.0)
    a, b = sorted(sd, key=sd.get)[:2]
    assert learnt.weights[a] / learnt.weights[b] == pytest.approx((sd[b] / sd[a]) ** 2)
    code = main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "--report",
                 str(squats / "truth_motion.csv"), "-o", str(out), "--overwrite", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "truth_motion.csv: not JSON (line 1" in err[0], err
    # a report edited by hand or cut short (found by fuzzing): one line naming it, not a Python error
    for bad, says in (({"lock_deg": {hinges[0]: "5"}}, f"{hinges[0]}'s lock is '5', not an angle in degrees"),
                      ({"lock_deg": {hinges[0]: 1e999}}, "not an angle in degrees"),
                      ({"lock_deg": {}, "auto_locked": ["ankle"]}, "TypeError")):
        report.write_text(json.dumps({"parameters": {}, "trials": [],
                                      "settings": {k: v for k, v in bad.items() if k == "lock_deg"},
                                      "auto_locked": bad.get("auto_locked", [])}))
        code = main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "--report", str(report), "-o",
                     str(out), "--overwrite", "-q"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "report.json: not readable as the report calibrate writes" in err[0]
        assert says in err[0], err


def test_marker_weights_as_an_ik_setup_gives_them(squats, tmp_path):
    """An IK setup's marker tasks weigh the markers: a marker weighed 0 (or its task not applied) is left out, the
    fit then equal to one on the trial without it; a heavier weight pulls the fit to a displaced marker; a marker
    two setups weigh differently: one line."""
    from calibrate.errors import CalibrateError
    from calibrate.io.osim_setup import ik_setup_weights
    from calibrate.io.read import read_trial
    from calibrate.model.kinematics import build_kinematics
    from calibrate.solve.ik import inverse_kinematics

    subject = load_model(squats / "truth.urdf")
    kin, p = build_kinematics(subject), subject.parameters()
    trial = read_trial(squats / "trial.c3d").frames(0, 20)
    names = subject.marker_names
    out, moved = names[5], names[9]
    weights = {n: 1.0 for n in names} | {out: 0.0}
    a = inverse_kinematics(kin, trial, p, weights=weights)
    b = inverse_kinematics(kin, trial.select([n for n in trial.labels if n != out]), p)
    assert np.isnan(a.residuals[:, names.index(out)]).all()
    assert np.abs(a.motion.angles - b.motion.angles).max() < 1e-8
    markers = trial.markers.copy()
    markers[:, trial.labels.index(moved)] += [0.01, 0.0, 0.0]  # one marker displaced 10 mm
    shifted = type(trial)(trial.labels, markers, trial.rate, trial.first_frame, trial.source)
    err = {k: np.linalg.norm(inverse_kinematics(kin, shifted, p, weights={moved: k}).residuals[:, names.index(moved)],
                             axis=1).mean() for k in (1.0, 100.0)}
    assert err[100.0] < 0.5 * err[1.0], err
    task = "<IKMarkerTask name='{}'><apply>{}</apply><weight>{}</weight></IKMarkerTask>"
    for name, tasks in [("a.xml", task.format("A", "true", 10) + task.format("B", "false", 5)),
                        ("b.xml", task.format("A", "true", 2))]:
        (tmp_path / name).write_text("<?xml version='1.0'?><OpenSimDocument Version='40000'><InverseKinematicsTool>"
                                     f"<IKTaskSet><objects>{tasks}</objects></IKTaskSet></InverseKinematicsTool>"
                                     "</OpenSimDocument>")
    assert ik_setup_weights(tmp_path / "a.xml") == {"A": 10.0, "B": 0.0}
    with pytest.raises(CalibrateError, match="weighs marker A 2, and a.xml 10"):
        ik_setup_weights([tmp_path / "a.xml", tmp_path / "b.xml"])


def test_ik_with_a_lower_body_calibrations_report_holds_its_trunk_and_arms(squats, tmp_path, capsys):
    """A lower-body marker set (the pelvis's and legs' markers only) leaves the trunk and arms to no marker:
    calibrate locks their coordinates, ball joints' too, at 0.  `calibrate ik --report` held those (it refused a ball
    joint's lock: "only a hinge's or universal joint's coordinate can be held"), the trunk and arms then at zero in
    every frame and the legs' fit the calibration's; part of a ball held on SO(3) is refused in one line."""
    import json

    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    model = load_model(HUMAN)
    lower = {"pelvis", "femur_l", "tibia_l", "talus_l", "calcn_l", "femur_r", "tibia_r", "talus_r", "calcn_r"}
    trial = read_trial(squats / "trial.c3d")
    legs = [lab for lab in trial.labels if lab in model.marker_names
            and model.markers[model.marker_index(lab)].segment in lower]
    write_c3d(tmp_path / "legs.c3d", trial.select(legs))
    cal = tmp_path / "cal"
    cal.mkdir()
    assert main([str(tmp_path / "legs.c3d"), str(HUMAN), "-o", str(cal / "subject.urdf"), "--outlier-sigmas", "0",
                 "-q"]) in (0, 1)
    locks = json.loads((cal / "legs_report.json").read_text())["settings"]["lock_deg"]
    balls = [d for j in model.joints if j.kind == "ball" and j.child not in lower for d in j.dofs]
    assert set(balls) <= set(locks)  # the trunk's, the neck's and the shoulders' three angles each
    out = tmp_path / "ik"
    out.mkdir()
    assert main(["ik", str(tmp_path / "legs.c3d"), str(cal / "subject.urdf"), "--report",
                 str(cal / "legs_report.json"), "-o", str(out), "-q"]) == 0
    m, calibrated = read_motion_csv(out / "legs_motion.csv"), read_motion_csv(cal / "legs_motion.csv")
    for d in balls:
        assert np.abs(m.angles[:, m.dof_names.index(d)]).max() < 1e-9
    leg_dofs = [m.dof_names.index(d) for j in model.joints if j.child in lower for d in j.dofs]
    assert np.abs(m.angles[:, leg_dofs] - calibrated.angles[:, leg_dofs]).max() < 2e-3  # rad
    # Part of a ball held: the command line solves that ball on its three angles (the test above); kinematics that
    # keep it on SO(3) are refused in one line that names the way to hold it.
    from calibrate.errors import CalibrateError
    from calibrate.model.kinematics import build_kinematics
    from calibrate.solve.ik import inverse_kinematics

    subject = load_model(cal / "subject.urdf")
    with pytest.raises(CalibrateError, match=r"all of its angles can be held, at 0 \(lumbar_.*euler=locked_balls"):
        inverse_kinematics(build_kinematics(subject), read_trial(tmp_path / "legs.c3d"), subject.parameters(),
                           locked={"lumbar_flexion": 0.0})


def test_an_opensim_subjects_urdf_holds_its_locked_coordinates(tmp_path):
    """A subject.urdf written from an OpenSim base carries the .osim's locked coordinates (Rajagopal2016's subtalars,
    mtps, wrists): `calibrate ik` on it holds them at their defaults, as on the subject's .osim (before, only the
    .osim's were held: Pose2Sim's subject.urdf, its mtps free, folded a foot, 48 mm against 15.6)."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.osim_info import osim_info
    from calibrate.model.model import write_model
    from calibrate.simulation.simulate import simulate_static

    osim = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "rajagopal_walk" / \
        "Rajagopal2016.osim"
    base = load_model(osim)
    locked = osim_info(base).locked
    assert {"mtp_angle_r", "subtalar_angle_l"} <= set(locked)
    subject = write_model(base, tmp_path / "subject.urdf", base.parameters())
    assert osim_info(load_model(subject)).locked == locked
    sim = simulate_static(base, base.parameters(), frames=10, noise_mm=0.5, seed=3)
    write_c3d(tmp_path / "static.c3d", sim.trial)
    assert main(["ik", str(tmp_path / "static.c3d"), str(subject), "-o", str(tmp_path), "-q"]) == 0
    m = read_motion_csv(tmp_path / "static_motion.csv")
    for name, value in locked.items():
        assert np.allclose(m.angles[:, m.dof_names.index(name)], value, atol=1e-12), name


def test_a_coordinate_no_seen_marker_moves_is_bridged_across_the_gap():
    """A simulated walk (noise 0.5 mm) with the left hand's one marker hidden for 0.6 s: in those frames only the
    wrist's two coordinates move no seen marker (solve.ik.unseen_coordinates); their angles there run linear between
    the fitted frames either side, within 5 deg of the truth, which the wrist moves 4 deg in.  Left where each frame
    started (the frame before at its last speed), the wrist had flexed 81 deg off."""
    from calibrate.model.kinematics import build_kinematics
    from calibrate.simulation.simulate import simulate_gait
    from calibrate.solve.ik import inverse_kinematics, marker_columns, unseen_coordinates

    human = load_model(HUMAN)
    sim = simulate_gait(human, frames=300, noise_mm=0.5, seed=3)
    X = np.array(sim.trial.markers)
    X[100:160, sim.trial.labels.index("LFIN")] = np.nan
    trial = replace(sim.trial, markers=X)
    wrist = [human.dof_names.index(d) for d in ("wrist_l_flexion", "wrist_l_deviation")]
    unseen = unseen_coordinates(human, np.isfinite(marker_columns(human, trial)[..., 0]))
    assert np.array_equal(np.flatnonzero(unseen.any(axis=0)), wrist)
    assert np.array_equal(np.flatnonzero(unseen[:, wrist[0]]), np.arange(100, 160))
    fit = inverse_kinematics(build_kinematics(sim.model), trial, sim.truth)
    got = fit.motion.angles[:, wrist]
    line = got[99] + (got[160] - got[99]) * (np.arange(100, 160) - 99)[:, None] / 61
    assert np.allclose(got[100:160], line, atol=1e-12)
    assert np.degrees(np.abs(got[100:160] - sim.motion.angles[100:160][:, wrist]).max()) < 5.0


def test_ik_takes_the_calibrations_marker_map(squats, tmp_path, capsys):
    """--markers: the map the calibration renamed the labels by.  A BTS-like file labels the lateral knee marker RKNE1
    and a computed point RKNE (here the ankle marker's path 100 mm up): with `RKNE = ["RKNE1"]` the fit is the
    original trial's to the bit (the displaced RKNE unused); without it the computed point plays RKNE."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    trial = read_trial(squats / "trial.c3d")
    fake = trial.marker("RANK") + np.array([0.0, 0.0, 0.1])
    labels = tuple("RKNE1" if lab == "RKNE" else lab for lab in trial.labels) + ("RKNE",)
    bts = replace(trial, labels=labels, markers=np.concatenate([trial.markers, fake[:, None]], axis=1))
    write_c3d(tmp_path / "bts.c3d", bts)
    (tmp_path / "map.toml").write_text('RKNE = ["RKNE1"]\n')
    outs = {}
    for name, trial_path, extra in (("plain", squats / "trial.c3d", []), ("mapped", tmp_path / "bts.c3d",
                                    ["--markers", str(tmp_path / "map.toml")]), ("unmapped", tmp_path / "bts.c3d", [])):
        out = tmp_path / name
        out.mkdir()
        assert main(["ik", str(trial_path), str(squats / "truth.urdf"), "-o", str(out), "-q", *extra]) == 0
        outs[name] = read_motion_csv(next(out.glob("*_motion.csv")))
    assert np.array_equal(outs["mapped"].angles, outs["plain"].angles)
    assert np.abs(outs["unmapped"].angles - outs["plain"].angles).max() > np.radians(5)
    # A calibration with the map: its report's renaming is the map `calibrate ik --report` applies without --markers.
    cal = tmp_path / "cal"
    cal.mkdir()
    assert main([str(tmp_path / "bts.c3d"), str(HUMAN), "--markers", str(tmp_path / "map.toml"), "-o", str(cal) + "/",
                 "-q"]) == 0
    capsys.readouterr()
    for name, extra in (("by_report", []), ("by_both", ["--markers", str(tmp_path / "map.toml")])):
        out = tmp_path / name
        out.mkdir()
        assert main(["ik", str(tmp_path / "bts.c3d"), str(cal / "bts.urdf"), "--report", str(cal / "bts_report.json"),
                     "-o", str(out), *extra]) == 0
        outs[name] = read_motion_csv(out / "bts_motion.csv")
        err = capsys.readouterr().err
        assert ("labels renamed as its calibration's marker map renamed them: RKNE1 -> RKNE" in err) == (not extra)
    assert np.array_equal(outs["by_report"].angles, outs["by_both"].angles)


def test_frames_that_show_one_or_two_markers_keep_the_pose_beside_them_moved_onto_those():
    """A simulated walk whose first and last 10 frames show one or two markers only (c3d.org's sample10 walk starts
    and ends so): such a frame takes the pose of the fitted frame beside it, its root moved onto the markers it shows.
    One marker is then fitted exactly; the root is within the walk's few centimetres of the truth and the angles are
    the fitted frame's.  Before, the first frames kept the model's default pose at the lab's origin (the trial's
    marker RMS 84 mm where the calibration fitted 3.6) and the last ones the pose of the frame before, standing."""
    from calibrate.model.kinematics import build_kinematics
    from calibrate.simulation.simulate import simulate_gait
    from calibrate.solve.ik import inverse_kinematics

    human = load_model(HUMAN)
    sim = simulate_gait(human, frames=120, noise_mm=0.5, seed=4)
    X = np.array(sim.trial.markers)
    one, two = sim.trial.labels.index("LASI"), sim.trial.labels.index("RHEE")
    for f in (*range(10), *range(110, 120)):
        keep = [one] if f % 2 else [one, two]
        hide = np.setdiff1d(np.arange(X.shape[1]), keep)
        X[f, hide] = np.nan
    fit = inverse_kinematics(build_kinematics(sim.model), replace(sim.trial, markers=X), sim.truth)
    m = fit.motion
    assert np.allclose(m.angles[:10], m.angles[10], atol=1e-12) and np.allclose(m.angles[110:], m.angles[109],
                                                                                   atol=1e-12)
    odd = [f for f in (*range(10), *range(110, 120)) if f % 2]
    assert np.nanmax(fit.marker_rms[odd]) < 1e-6  # one marker: fitted exactly by the shift
    off = np.linalg.norm(m.root_translation - sim.motion.root_translation, axis=1)
    assert off[:10].max() < 0.1 and off[110:].max() < 0.1, (off[:10].max(), off[110:].max())


def test_fit_trial_tells_the_share_of_frames_fitted_every_100_frames(squats):
    """A long trial takes `calibrate ik` a minute (4000 simulated walk frames: 25 s): fit_trial tells the share of
    its frames fitted every 100 frames, which the command line shows with the time left."""
    from calibrate.calibration.subject_ik import fit_trial
    from calibrate.io.read import read_trial
    from calibrate.io.trial import Trial

    subject = load_model(squats / "truth.urdf")
    t = read_trial(squats / "trial.c3d")
    long = Trial(t.labels, np.concatenate([t.markers] * 4), t.rate, 0, None)  # 240 frames
    seen: list[float] = []
    got = fit_trial(subject, long, subject.parameters(), {}, progress=seen.append)
    assert seen == [pytest.approx(100 / 240), pytest.approx(200 / 240)]
    assert got.fit.motion.angles.shape[0] == 240


def test_fit_trial_runs_the_compiled_code_a_calibration_left_to_the_same_bits(squats, monkeypatch):
    """Where a calibration left its subject's compiled per-frame code in the cache, `calibrate ik` evaluates with it
    (about a quarter sooner a frame than CasADi's virtual machine: gait2392's and pig_walk's subjects) and gets the
    virtual machine's motion to 1e-9 rad and m (the compiled code gathers the markers from the segments' poses,
    the virtual machine evaluates the whole kinematics: the same function, its arithmetic in another order); it
    never compiles for one trial (compiled_kinematics(compile=False))."""
    import calibrate.calibration.subject_ik as subject_ik
    from calibrate.calibration.subject_ik import fit_trial
    from calibrate.io.read import read_trial
    from calibrate.model.kinematics import build_kinematics
    from calibrate.problem.codegen import c_compiler, is_compiled
    from calibrate.problem.problem import compiled_kinematics

    if c_compiler() is None:
        pytest.skip("no C compiler: every evaluation runs in CasADi's virtual machine")
    subject = load_model(squats / "truth.urdf")
    trial = read_trial(squats / "trial.c3d")
    kin = build_kinematics(subject)
    assert compiled_kinematics(kin).compiled is not None  # as the calibration of this subject compiles it
    assert is_compiled(subject, kin) and compiled_kinematics(kin, compile=False).compiled is not None
    used: list[bool] = []

    def spy(k, compile=True):
        out = compiled_kinematics(k, compile)
        used.append(out.compiled is not None)
        return out

    monkeypatch.setattr(subject_ik, "compiled_kinematics", spy)
    compiled = fit_trial(subject, trial, subject.parameters(), {})
    monkeypatch.setattr(subject_ik, "compiled_kinematics", lambda k, compile=True: k)  # CasADi's virtual machine
    vm = fit_trial(subject, trial, subject.parameters(), {})
    assert used == [True]
    for a, b in ((compiled.fit.motion.angles, vm.fit.motion.angles),
                 (compiled.fit.motion.root_quaternion, vm.fit.motion.root_quaternion),
                 (compiled.fit.motion.root_translation, vm.fit.motion.root_translation)):
        assert np.abs(a - b).max() < 1e-9
    truth = read_motion_csv(squats / "truth_motion.csv")
    assert np.abs(compiled.fit.motion.angles - truth.angles).max() < 1e-4  # the true motion, noise-free


def test_ik_compiles_the_subjects_code_for_long_trials_only(squats, tmp_path, monkeypatch):
    """Trials of IK_COMPILE_FRAMES frames or more (together) are worth a compile of the subject's per-frame code where
    its calibration did not leave it in the cache; shorter ones run in CasADi's virtual machine, compiling nothing.
    The motion is the same either way (to 1e-9 rad and m: the compiled code's arithmetic runs in another order)."""
    import calibrate.calibration.subject_ik as subject_ik
    from calibrate.problem.codegen import c_compiler

    if c_compiler() is None:
        pytest.skip("no C compiler: every evaluation runs in CasADi's virtual machine")
    cache = tmp_path / "cache"
    monkeypatch.setenv("CALIBRATE_CACHE", str(cache))
    vm, cc = tmp_path / "vm", tmp_path / "cc"
    vm.mkdir()
    cc.mkdir()
    assert main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "-o", str(vm), "-q"]) == 0
    assert not list(cache.glob("frame_*.so"))  # 60 frames: not worth a compile
    monkeypatch.setattr(subject_ik, "IK_COMPILE_FRAMES", 60)  # as if they were a long trial
    assert main(["ik", str(squats / "trial.c3d"), str(squats / "truth.urdf"), "-o", str(cc), "-q"]) == 0
    assert len(list(cache.glob("frame_*.so"))) == 1
    a, b = read_motion_csv(vm / "trial_motion.csv"), read_motion_csv(cc / "trial_motion.csv")
    assert a.dof_names == b.dof_names and np.abs(a.angles - b.angles).max() < 1e-9
    assert np.abs(a.root_translation - b.root_translation).max() < 1e-9


def test_the_python_api_locks_an_opensim_models_locked_coordinates():
    """`calibrate(load_model("m.osim"), trials)` with default settings locks the .osim's locked coordinates
    (Rajagopal2016's subtalars, mtps, wrists) at their values, as the command line does (docs/opensim.md): each
    in Calibration.locked and at its value in every frame of the motion, to the bit (the solve's stiff penalty
    left the subtalars 8e-9 rad off)."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.osim_info import osim_info
    from calibrate.problem.settings import Settings
    from calibrate.simulation.simulate import simulate_static

    osim = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "rajagopal_walk" / \
        "Rajagopal2016.osim"
    base = load_model(osim)
    locked = osim_info(base).locked
    assert {"mtp_angle_r", "subtalar_angle_l", "wrist_flex_r"} <= set(locked)
    sim = simulate_static(base, base.parameters(), frames=10, noise_mm=0.5, seed=4)
    cal = calibrate(base, sim.trial, Settings(max_iterations=3))
    motion = cal.motions[0]
    for name, value in locked.items():
        assert cal.locked[name] == value, name
        assert np.all(motion.angles[:, motion.dof_names.index(name)] == value), name


_OPENSIM_IK = r"""
import sys
import opensim as osim
osim.Logger.removeFileSink()  # no opensim.log in the working directory
osim.Logger.setLevelString("warn")
setup, model, trc, out = sys.argv[1:5]
ik = osim.InverseKinematicsTool(setup)
ik.set_model_file(model)
ik.setMarkerDataFileName(trc)
ik.setResultsDir(out)
ik.setOutputMotionFileName(out + "/opensim.mot")
ik.set_report_errors(True)
assert ik.run()
print(ik.getName())
"""


def test_ik_marker_errors_are_opensims_on_the_same_model(tmp_path):
    """gait2392 with its marker set, exported as calibrate writes a subject (exact in OpenSim), and the walk fitted by
    OpenSim's IK tool (a child process: opensim and calibrate's casadi cannot share one) and by `calibrate ik` with the
    same IK setup: the two _ik_marker_errors.sto files agree, every frame's RMS marker error to 0.02 mm and its largest
    to 0.5 mm (measured 0.004 and 0.12 mm: the two optima, OpenSim's accuracy 1e-5), so the file says what OpenSim's
    says."""
    import importlib.util
    import subprocess
    import sys

    real = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "gait2392"
    if importlib.util.find_spec("opensim") is None or not real.exists():
        pytest.skip("needs the opensim package (pip install -e '.[opensim]') and ../shared/data/real/gait2392")
    model = load_model(real / "gait2392.osim", real / "gait2392_Scale_MarkerSet.xml")
    base = export_osim(model, tmp_path / "base.osim")
    setup, trc = real / "subject01_Setup_IK.xml", real / "subject01_walk1.trc"
    (tmp_path / "opensim").mkdir()
    child = subprocess.run([sys.executable, "-c", _OPENSIM_IK, str(setup), str(base), str(trc),
                            str(tmp_path / "opensim")], capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert child.returncode == 0, child.stderr[-2000:]
    theirs = tmp_path / "opensim" / f"{child.stdout.split()[-1]}_ik_marker_errors.sto"
    (tmp_path / "ours").mkdir()
    # the generic model is not this subject (its markers 12 % apart): --other-subject fits it all the same
    assert main(["ik", str(trc), str(base), "--ik-setup", str(setup), "-o", str(tmp_path / "ours"), "--other-subject",
                 "-q"]) == 0
    ours = tmp_path / "ours" / "subject01_walk1_ik_marker_errors.sto"

    def table(path: Path) -> np.ndarray:
        lines = path.read_text().splitlines()
        assert lines[lines.index("endheader") + 1].split("\t") == ["time", "total_squared_error", "marker_error_RMS",
                                                                   "marker_error_max"]
        return np.array([[float(v) for v in line.split("\t")] for line in lines[lines.index("endheader") + 2:]])

    a, b = table(ours), table(theirs)
    assert a.shape == b.shape == (121, 4)
    assert np.abs(a[:, 0] - b[:, 0]).max() < 0.5 / 60  # the same frames (OpenSim's times read from the file's)
    assert np.abs(a[:, 2] - b[:, 2]).max() < 2e-5 and 0.03 < b[:, 2].mean() < 0.06  # m: 45 mm RMS, the generic size
    assert np.abs(a[:, 3] - b[:, 3]).max() < 5e-4 and np.abs(a[:, 1] / b[:, 1] - 1).max() < 1e-3


def test_ik_setups_alone_must_name_their_trial_and_one_model(tmp_path, capsys):
    """`calibrate ik --ik-setup A.xml --ik-setup B.xml` with no trial or subject: each setup must name its trial and
    the one model they share; otherwise one line each, exit 2, nothing written."""
    def setup(name: str, model: str | None, trial: str | None) -> Path:
        path = tmp_path / name
        path.write_text("<?xml version='1.0'?><OpenSimDocument Version='40000'><InverseKinematicsTool name='x'>"
                        + (f"<model_file>{model}</model_file>" if model else "<model_file>Unassigned</model_file>")
                        + (f"<marker_file>{trial}</marker_file>" if trial else "")
                        + "</InverseKinematicsTool></OpenSimDocument>")
        return path

    a, b = setup("a.xml", "s1.osim", "walk1.trc"), setup("b.xml", "s2.osim", "walk2.trc")
    cases = [(["ik", "--ik-setup", str(a), "--ik-setup", str(b)], "their model_file names s1.osim and s2.osim"),
             (["ik", "--ik-setup", str(setup("c.xml", None, "walk.trc"))], "its model_file is Unassigned"),
             (["ik", "--ik-setup", str(setup("d.xml", "s1.osim", None))], "its marker_file is Unassigned"),
             (["ik"], "or --ik-setup files whose model_file and marker_file name them")]
    for argv, needle in cases:
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.xml", "b.xml", "c.xml", "d.xml"]


def test_ik_bridges_the_frames_whose_markers_do_not_place_the_pelvis(squats, tmp_path, capsys):
    """The squats' last 10 frames showing the right leg's markers alone (the subject leaving the volume): the command
    line's note names them, the motion holds frame 49's pose there, and the report's notes carry the line."""
    import json

    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    trial = read_trial(squats / "trial.c3d")
    X = trial.markers.copy()
    X[50:, [k for k, lab in enumerate(trial.labels) if lab not in ("RKNE", "RTIB", "RANK", "RHEE", "RTOE")]] = np.nan
    write_c3d(tmp_path / "leaving.c3d", replace(trial, markers=X))
    assert main(["ik", str(tmp_path / "leaving.c3d"), str(squats / "truth.urdf"), "-o", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    line = "leaving.c3d: frames 50-59 (10 of 60, from 0) show too few markers to place pelvis: their poses are bridged"
    assert line in err, err
    got = read_motion_csv(tmp_path / "leaving_motion.csv")
    np.testing.assert_array_equal(got.angles[50:], np.broadcast_to(got.angles[49], got.angles[50:].shape))
    report = json.loads(next(tmp_path.glob("leaving*report*.json")).read_text())
    assert any(line in n for n in report["notes"]), report["notes"]
