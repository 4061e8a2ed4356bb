"""The time ranges of a lab's OpenSim setups: a TRC's Time column, the Scale setup's static span and the IK setup's
span cut from the trials they name (calibrate.io.osim_setup.apply_time_ranges; --whole-trials keeps every frame)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calibrate.cli.main import main
from calibrate.errors import TrialError
from calibrate.io.osim_setup import TimeRange, apply_time_ranges, ik_setup_range, scale_setup
from calibrate.io.read import read_trial
from calibrate.io.trc import read_trc
from calibrate.model.model import load_model
from tests.test_osim_import import _muscled_trial, muscle_osim

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


def _trc_columns(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The Time column and the first marker's x (file units) of a TRC, read with numpy alone."""
    rows = [line.split("\t") for line in path.read_text().splitlines()[5:] if line.strip()]
    return np.array([float(r[1]) for r in rows]), np.array([float(r[2]) for r in rows])


def test_a_trc_time_column_gives_the_trial_its_times(tmp_path, capsys):
    """A TRC whose Time column is not (Frame# - 1) / rate (OpenSim's running trial: frame 23 at 0.23 s, 100 Hz): the
    trial's times are the file's, ``frames`` keeps them, and ``time_range`` takes the frames nearest a range's ends
    (both kept); `calibrate inspect` shows those times; a reversed range or one outside the trial: one line."""
    lines = ["PathFileType\t4\t(X/Y/Z)\trun.trc",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             "100\t100\t40\t1\tmm\t100\t23\t40", "Frame#\tTime\tA\t\t", "\t\tX1\tY1\tZ1", ""]
    lines += [f"{23 + i}\t{0.23 + i / 100:.6f}\t{i + 1.0}\t2\t3" for i in range(40)]
    path = tmp_path / "run.trc"
    path.write_text("\n".join(lines) + "\n")
    times, x = _trc_columns(path)
    trial = read_trc(path)
    assert trial.first_frame == 22 and trial.times == pytest.approx(times, abs=1e-9)  # not (22 + i) / 100
    assert trial.frames(5, 9).times == pytest.approx(times[5:9], abs=1e-9)
    cut = trial.time_range(0.25, 0.30)
    keep = (times > 0.25 - 0.005) & (times < 0.30 + 0.005)
    assert cut.n_frames == keep.sum() == 6
    assert cut.times == pytest.approx(times[keep], abs=1e-9)
    assert cut.markers[:, 0, 0] == pytest.approx(x[keep] / 1000)
    assert trial.time_range(0.0, 9.0).n_frames == 40  # beyond the ends: to the ends
    assert main(["inspect", str(path)]) == 0
    assert "first frame 22 (0-based), times 0.23 to 0.62 s" in capsys.readouterr().out
    for start, stop, needle in [(0.3, 0.25, "is not a range"), (1.0, 2.0, "lies outside the trial (0.23 to 0.62 s)")]:
        with pytest.raises(TrialError) as e:
            trial.time_range(start, stop)
        assert needle in str(e.value) and str(path) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.skipif(not (REAL / "gait2392").is_dir(), reason="the real trials (../shared/data/real) are not here")
def test_the_gait2392_pipelines_setups_cut_its_static_and_walk():
    """OpenSim's gait2392 example: its Scale setup's scaler and marker placer both use 1 to 2 s of
    subject01_static.trc, its IK setup 0.5 to 2.5 s of subject01_walk1.trc; cut, the trials keep exactly the rows
    of those times (61 and 121: the frames OpenSim's tools fit), marker for marker.  A range naming a trial not
    given is reported, not applied; a .c3d of the setup's .trc (same stem) is cut as the .trc would be."""
    d = REAL / "gait2392"
    setup = scale_setup(d / "subject01_Setup_Scale.xml")
    assert [(r.step, r.file, r.start, r.stop) for r in setup.ranges] == [
        ("ModelScaler", "subject01_static.trc", 1.0, 2.0), ("MarkerPlacer", "subject01_static.trc", 1.0, 2.0)]
    ik = ik_setup_range(d / "subject01_Setup_IK.xml")
    assert (ik.file, ik.start, ik.stop) == ("subject01_walk1.trc", 0.5, 2.5)
    static, walk = read_trial(d / "subject01_static.trc"), read_trial(d / "subject01_walk1.trc")
    absent = TimeRange(d / "other_Setup.xml", "MarkerPlacer", "static_2.trc", 0.0, 0.1)
    (cs, cw), lines = apply_time_ranges([static, walk], [*setup.ranges, ik, absent])
    for trial, cut, (lo, hi) in [(static, cs, (1.0, 2.0)), (walk, cw, (0.5, 2.5))]:
        times, x = _trc_columns(Path(trial.source))
        keep = (times > lo - 1e-6) & (times < hi + 1e-6)  # the file's own times, rounded to 3 decimals
        assert cut.n_frames == keep.sum()
        assert np.allclose(cut.markers[:, 0, 0] * 1000, x[keep], rtol=0, atol=1e-9)
    assert (cs.n_frames, cw.n_frames) == (61, 121)
    assert lines == [
        "other_Setup.xml: its MarkerPlacer names static_2.trc, not among the trials; its time range 0 to 0.1 s "
        "not applied",
        "subject01_Setup_Scale.xml: subject01_static.trc cut to 1 to 2 s, 61 of its 300 frames (the ModelScaler and "
        "MarkerPlacer's time range; --whole-trials to use every frame)",
        "subject01_Setup_IK.xml: subject01_walk1.trc cut to 0.5 to 2.5 s, 121 of its 151 frames (the "
        "InverseKinematicsTool's time range; --whole-trials to use every frame)"]
    (c3d_cut,), _ = apply_time_ranges([static], setup.ranges, names=["lab/subject01_static.c3d"])
    assert c3d_cut.n_frames == 61


def _ik_setup_with_range(trial: str, start: float, stop: float) -> str:
    return ("<?xml version='1.0'?><OpenSimDocument Version='40000'><InverseKinematicsTool name='ik'><IKTaskSet>"
            "<objects/></IKTaskSet>"
            f"<marker_file>{trial}</marker_file><time_range> {start} {stop}</time_range></InverseKinematicsTool>"
            "</OpenSimDocument>")


def test_the_command_line_fits_the_ik_setups_frames(tmp_path, capsys):
    """`calibrate TRIAL MODEL.osim --ik-setup FILE.xml` whose setup names the trial and 0.1 to 0.3 s of it: the motion
    (CSV and .mot) holds those 13 frames at their times, a note says so, the summary and the report give the span;
    --whole-trials: all 30; --frames beside
    the range, or a range beyond the trial: one line, exit 2, nothing written.  `calibrate inspect` says what the setup
    cuts."""
    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    trc = _muscled_trial(tmp_path, load_model(src))  # 30 frames at 60 Hz
    setup = tmp_path / "Setup_IK.xml"
    setup.write_text(_ik_setup_with_range("trial.trc", 0.1, 0.3))
    for k, extra, frames in [(0, [], 13), (1, ["--whole-trials"], 30)]:
        out = tmp_path / f"run{k}"
        out.mkdir()
        code = main([str(trc), str(src), "--ik-setup", str(setup), "-o", str(out / "s.urdf"), "--no-new-markers",
                     *extra])
        captured = capsys.readouterr()
        err = captured.err
        assert code == 0, err
        rows = (out / "trial_motion.csv").read_text().splitlines()[1:]
        times = np.array([float(r.split(",")[0]) for r in rows])
        assert times == pytest.approx((np.arange(frames) + (6 if k == 0 else 0)) / 60, abs=1e-9)
        report = json.loads((out / "trial_report.json").read_text())
        assert report["trials"][0]["frames"] == frames
        span = [0.1, 0.3] if k == 0 else [0.0, 29 / 60]
        assert report["trials"][0]["times_s"] == pytest.approx(span, abs=1e-6)
        assert f"trial.trc: {frames} frames at 60 Hz ({span[0]:.4g} to {span[1]:.4g} s)" in captured.out
        note = "note: Setup_IK.xml: trial.trc cut to 0.1 to 0.3 s, 13 of its 30 frames"
        assert (note in err) == (k == 0), err
    out = tmp_path / "run2"
    out.mkdir()
    code = main([str(trc), str(src), "--ik-setup", str(setup), "--frames", "0:20", "-o", str(out / "s.urdf"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--frames and the setup's time range both select frames" in err[0], err
    assert not any(out.iterdir())
    assert main(["inspect", str(setup)]) == 0
    assert "cuts trial.trc to 0.1 to 0.3 s (--whole-trials: every frame)" in capsys.readouterr().out
    far = tmp_path / "Setup_IK_far.xml"  # a range beyond the trial's 0.48 s: one line naming the setup, exit 2
    far.write_text(_ik_setup_with_range("trial.trc", 10, 12))
    code = main([str(trc), str(src), "--ik-setup", str(far), "-o", str(out / "s.urdf"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("calibrate: error: Setup_IK_far.xml: ") and (
        "time range 10 to 12 s lies outside the trial" in err[0] and "--whole-trials" in err[0]), err
    assert not any(out.iterdir())


def test_one_ik_setup_per_trial(tmp_path, capsys):
    """A lab keeps one IK setup per trial: `--ik-setup A.xml --ik-setup B.xml` cuts each trial to its own setup's span
    and locks what either holds; two setups holding one coordinate at different values: one line naming both, exit
    2, nothing written.  A batch manifest lists them (TOML) or separates them by ';' (CSV)."""
    import shutil

    from calibrate.calibration.batch import read_manifest
    from tests.test_osim_import import _task

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    trc = _muscled_trial(tmp_path, load_model(src))  # 30 frames at 60 Hz
    shutil.copy(trc, tmp_path / "trial2.trc")

    def setup(name: str, trial: str, start: float, stop: float, task: str) -> Path:
        path = tmp_path / name
        path.write_text(_ik_setup_with_range(trial, start, stop).replace("<objects/>", f"<objects>{task}</objects>"))
        return path

    a = setup("A.xml", "trial.trc", 0.1, 0.3, _task("knee_q", "manual_value", -0.25))
    b = setup("B.xml", "trial2.trc", 0.2, 0.4, _task("knee_q", "manual_value", -0.25))
    out = tmp_path / "run"
    out.mkdir()
    code = main([str(trc), str(tmp_path / "trial2.trc"), str(src), "--ik-setup", str(a), "--ik-setup", str(b),
                 "-o", str(out / "s.urdf"), "--no-new-markers", "-q"])
    assert code == 0, capsys.readouterr().err
    for name, first in [("trial", 6), ("trial2", 12)]:
        rows = (out / f"{name}_motion.csv").read_text().splitlines()
        head = rows[0].split(",")
        values = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
        assert values[:, 0] == pytest.approx((first + np.arange(13)) / 60, abs=1e-9)
        assert np.allclose(values[:, head.index("knee_q")], -0.25, atol=1e-6)
    c = setup("C.xml", "trial2.trc", 0.2, 0.4, _task("knee_q", "manual_value", 0.1))
    bad = tmp_path / "bad"
    bad.mkdir()
    code = main([str(trc), str(tmp_path / "trial2.trc"), str(src), "--ik-setup", str(a), "--ik-setup", str(c),
                 "-o", str(bad / "s.urdf"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and str(c) in err[0] and "A.xml's at -0.25" in err[0], err
    assert not any(bad.iterdir())
    (tmp_path / "m.toml").write_text('[[subject]]\nid = "S"\ntrials = ["trial.trc", "trial2.trc"]\n'
                                     'model = "muscled.osim"\nik_setup = ["A.xml", "B.xml"]\n')
    (tmp_path / "m.csv").write_text("subject,trials,model,ik_setup\nS,trial.trc;trial2.trc,muscled.osim,A.xml;B.xml\n"
                                    "T,trial.trc,muscled.osim,A.xml\n")
    assert read_manifest(tmp_path / "m.toml")[0].ik_setup == (a, b)
    assert [s.ik_setup for s in read_manifest(tmp_path / "m.csv")] == [(a, b), (a,)]


def test_a_scale_setup_that_does_not_preserve_the_mass_distribution_is_named(tmp_path, capsys):
    """A Scale setup whose ModelScaler says preserve_mass_distribution false (OpenSim would scale each segment's mass
    by its size first): calibrate still scales every mass alike, and says so in the run's note and in `inspect`;
    its ModelScaler's static span cuts the trial (0 to 0.2 s: 13 of 30 frames at 60 Hz)."""
    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    trc = _muscled_trial(tmp_path, load_model(src))
    setup = tmp_path / "Setup_Scale.xml"
    setup.write_text("<?xml version='1.0'?><OpenSimDocument Version='40000'><ScaleTool name='s'><mass>61.5</mass>"
                     "<ModelScaler><apply>true</apply><marker_file>trial.trc</marker_file><time_range>0 0.2"
                     "</time_range><preserve_mass_distribution>false</preserve_mass_distribution></ModelScaler>"
                     "</ScaleTool></OpenSimDocument>")
    got = scale_setup(setup)
    assert not got.preserve_mass and got.mass == 61.5 and [(r.step, r.start, r.stop) for r in got.ranges] == [
        ("ModelScaler", 0.0, 0.2)]
    out = tmp_path / "run"
    out.mkdir()
    code = main([str(trc), str(src), "--scale-setup", str(setup), "-o", str(out / "s.urdf"), "--no-new-markers"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert ("note: Setup_Scale.xml: mass 61.5 kg taken; its preserve_mass_distribution is false, yet calibrate "
            "scales every segment's mass alike") in captured.err
    assert "trial.trc cut to 0 to 0.2 s, 13 of its 30 frames (the ModelScaler's time range" in captured.err
    assert json.loads((out / "trial_report.json").read_text())["trials"][0]["frames"] == 13
    assert main(["inspect", str(setup)]) == 0
    assert "preserve_mass_distribution false (calibrate scales every segment's mass alike)" in capsys.readouterr().out


def _scale_setup_with_pose(trial: str, tasks: str) -> str:
    return ("<?xml version='1.0'?><OpenSimDocument Version='40000'><ScaleTool name='s'><MarkerPlacer><apply>true"
            f"</apply><IKTaskSet><objects>{tasks}</objects></IKTaskSet><marker_file>{trial}</marker_file>"
            "<time_range>-1 -1</time_range></MarkerPlacer></ScaleTool></OpenSimDocument>")


def _motion(path: Path) -> tuple[list[str], np.ndarray]:
    rows = path.read_text().splitlines()
    return rows[0].split(","), np.array([[float(v) for v in r.split(",")] for r in rows[1:]])


def test_the_scale_setups_coordinate_tasks_set_the_static_pose(tmp_path, capsys):
    """`--scale-setup` whose MarkerPlacer holds knee_q at -0.8 rad (manual_value) and hip_q at the model's default
    (0.2 rad) in trial.trc: the trial's mean knee_q and hip_q are those values (the segment frames turned at the end,
    as OpenSim places its markers on the model so posed), the marker fit is that of the run without the setup, the
    summary and the report say so, the note names the root's p_tx as not set; `--neutral` beside it takes over (a note;
    it then refuses this moving trial); a setup posing a trial not given: a note, nothing turned; a value whose turn
    would carry the trial past the joint's range: not turned, said with where the angle ends; a task of weight 5 (a
    preference OpenSim weighs against the markers): not applied, said.  `inspect` lists the pose; the HTML report
    names it."""
    from tests.test_osim_import import _task

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    trc = _muscled_trial(tmp_path, load_model(src))  # 30 frames at 60 Hz, the hip and knee moving
    setup = tmp_path / "Setup_Scale.xml"
    setup.write_text(_scale_setup_with_pose("trial.trc", _task("knee_q", "manual_value", -0.8) + _task("hip_q")
                                            + _task("p_tx") + _task("knee_q_x", apply="false")))
    far = tmp_path / "Setup_Scale_far.xml"  # 0.15 rad: the turn would carry the trial's knees past 0.2 rad, its limit
    far.write_text(_scale_setup_with_pose("trial.trc", _task("knee_q", "manual_value", 0.15)))
    soft = tmp_path / "Setup_Scale_soft.xml"  # weight 5: a preference OpenSim weighs against the markers
    soft.write_text(_scale_setup_with_pose("trial.trc", _task("knee_q", "manual_value", -0.8).replace(
        "<weight>1000</weight>", "<weight>5</weight>")))
    other = tmp_path / "Setup_Scale_other.xml"
    other.write_text(_scale_setup_with_pose("static.trc", _task("knee_q", "manual_value", -0.8)))
    runs = {}
    for key, extra in [("none", []), ("pose", ["--scale-setup", str(setup), "--html", str(tmp_path / "pose.html")]),
                       ("neutral", ["--scale-setup", str(setup), "--neutral", "1"]),
                       ("other", ["--scale-setup", str(other)]), ("far", ["--scale-setup", str(far)]),
                       ("soft", ["--scale-setup", str(soft)])]:
        out = tmp_path / key
        out.mkdir()
        code = main([str(trc), str(src), "-o", str(out / "s.urdf"), "--no-new-markers", "--mass", "70", *extra])
        captured = capsys.readouterr()
        if key == "neutral":  # the setup's pose yields to --neutral, which refuses this moving trial
            assert code == 2 and "--neutral turns every joint to zero instead" in captured.err, captured.err
            assert "neutral: trial 1" in captured.err and "moves" in captured.err
            continue
        assert code == 0, captured.err
        head, values = _motion(out / "trial_motion.csv")
        runs[key] = (head, values, json.loads((out / "trial_report.json").read_text()), captured)
    head, values, report, captured = runs["pose"]
    assert values[:, head.index("knee_q")].mean() == pytest.approx(-0.8, abs=1e-6)
    assert values[:, head.index("hip_q")].mean() == pytest.approx(0.2, abs=1e-6)  # the model's default
    h0, v0, r0, _ = runs["none"]
    assert abs(v0[:, h0.index("knee_q")].mean() + 0.8) > 0.05  # not so without the setup
    # The same fit: the turn is a change of gauge.
    assert report["trials"][0]["rms_mm"] == pytest.approx(r0["trials"][0]["rms_mm"], abs=1e-4)
    assert report["neutral_pose_deg"] == pytest.approx({"knee_q": np.degrees(-0.8), "hip_q": np.degrees(0.2)})
    assert report["neutral_pose_not_set"] == []
    assert ("note: Setup_Scale.xml: in trial.trc its MarkerPlacer holds knee_q -45.8 deg, hip_q 11.5 deg: the segment "
            "frames are turned so at the end") in captured.err and "; not p_tx (the ground joint's" in captured.err
    assert "knee_q is -45.8 deg, hip_q is 11.5 deg on average (the lab's static pose)" in captured.out
    assert ("static pose: segment frames turned so that the neutral trial holds knee_q -45.8 deg, hip_q 11.5 deg on "
            "average") in (tmp_path / "pose.html").read_text()
    head, values, report, captured = runs["other"]
    assert "its MarkerPlacer poses static.trc, not among the trials; its coordinate tasks (knee_q -45.8 deg) not " \
        "applied" in captured.err
    assert report["neutral_pose_deg"] is None
    assert values[:, head.index("knee_q")].mean() == pytest.approx(v0[:, h0.index("knee_q")].mean(), abs=1e-6)
    head, values, report, captured = runs["far"]  # not turned, and said with where the angle ends
    knee = v0[:, h0.index("knee_q")].mean()
    assert values[:, head.index("knee_q")].mean() == pytest.approx(knee, abs=1e-6)
    assert report["neutral_pose_not_set"] == [f"knee_q ({np.degrees(knee):.1f} deg)"]
    assert report["trials"][0]["rms_mm"] == pytest.approx(r0["trials"][0]["rms_mm"], abs=1e-4)
    assert f"not met: knee_q ({np.degrees(knee):.1f} deg)" in captured.out
    head, values, report, captured = runs["soft"]
    assert ("no coordinate held in trial.trc; its lighter tasks (knee_q weight 5) are preferences OpenSim weighs "
            "against the markers, not applied") in captured.err, captured.err
    assert report["neutral_pose_deg"] is None
    assert values[:, head.index("knee_q")].mean() == pytest.approx(v0[:, h0.index("knee_q")].mean(), abs=1e-6)
    assert main(["inspect", str(soft)]) == 0
    assert "knee_q (-0.8, weight 5: not applied)" in capsys.readouterr().out
    assert main(["inspect", str(setup)]) == 0
    assert ("the static pose its MarkerPlacer holds in trial.trc: knee_q (-0.8), hip_q (the model's default), p_tx "
            "(the model's default) (segment frames turned so)") in capsys.readouterr().out


@pytest.mark.skipif(not (REAL / "gait2392").is_dir(), reason="the real trials (../shared/data/real) are not here")
def test_the_gait2392_scale_setup_poses_its_static(capsys):
    """OpenSim's gait2392 Scale setup: its MarkerPlacer holds both subtalar and mtp angles and lumbar_extension at
    the model's defaults (0) in subject01_static.trc; the static trial is found by its file name."""
    from calibrate.io.osim_setup import setup_pose, static_pose

    d = REAL / "gait2392"
    model = load_model(d / "gait2392.osim", d / "gait2392_Scale_MarkerSet.xml")
    pose = static_pose(d / "subject01_Setup_Scale.xml", model)
    assert pose.file == "subject01_static.trc"
    assert dict(pose.values) == {"subtalar_angle_r": 0.0, "mtp_angle_r": 0.0, "subtalar_angle_l": 0.0,
                                 "mtp_angle_l": 0.0, "lumbar_extension": 0.0}
    assert pose.soft == () and pose.root == ()  # every task of weight 1000: held
    static, walk = read_trial(d / "subject01_static.trc"), read_trial(d / "subject01_walk1.trc")
    k, held, lines = setup_pose(d / "subject01_Setup_Scale.xml", model, [walk, static])
    assert k == 1 and held == dict(pose.values) and len(lines) == 1
    assert main(["inspect", str(d / "subject01_Setup_Scale.xml")]) == 0  # what it does not take, said
    out = capsys.readouterr().out
    assert "its manual scale factors (femur_r 1.14724, femur_l 1.14724, tibia_r 0.988523, tibia_l 0.988523)" in out
    # and where --setup-names writes what it names: its MarkerPlacer's model, its ModelScaler's scale factors and the
    # static motion, beside the setup; and what it leaves out: the ModelScaler's model
    assert (f"--setup-names writes the subject {d / 'subject01_simbody.osim'}, its scale factors "
            f"{d / 'subject01_scaleSet_applied.xml'}, subject01_static.trc's motion "
            f"{d / 'subject01_static_output.mot'}") in out
    assert f"--setup-names leaves out the ModelScaler's {d / 'subject01_scaledOnly.osim'}" in out
    # and what it does run alone: the generic model and the static it names
    assert (f"alone: 'calibrate --scale-setup subject01_Setup_Scale.xml [--ik-setup ...]' calibrates "
            f"{d / 'gait2392_simbody.osim'} to {d / 'subject01_static.trc'}") in out


def test_a_markerless_held_segment_does_not_stop_the_pose_above_it(tmp_path, capsys):
    """The trial without the shank's markers: the shank is held at the base model's (no data reach it) and its knee
    locked; the thigh's frame above it is still turned to the pose (hip_q 0.5 rad on average), the fit unchanged.
    An OpenSim setup whose root is the tool itself (Hamner's Setup_Scale.xml has no <OpenSimDocument>): inspect reads
    it."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.trial import Trial

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    model = load_model(src)
    full = read_trial(_muscled_trial(tmp_path, model))
    keep = [k for k, name in enumerate(full.labels) if model.markers[model.marker_index(name)].segment != "shank"]
    assert len(keep) == len(full.labels) - 2
    trial = Trial([full.labels[k] for k in keep], full.markers[:, keep], full.rate, 0, full.source)
    plain = calibrate(model, [trial])
    posed = calibrate(model, [trial], neutral=0, pose={"hip_q": 0.5})
    assert "shank" in posed.settings.hold_segments
    assert posed.pose == (("hip_q", 0.5),) and posed.pose_unset == ()
    hip = posed.motions[0].dof_names.index("hip_q")
    assert posed.motions[0].angles[:, hip].mean() == pytest.approx(0.5, abs=1e-6)
    assert abs(plain.motions[0].angles[:, hip].mean() - 0.5) > 0.05
    assert posed.marker_rms == pytest.approx(plain.marker_rms, abs=1e-7)
    bare = tmp_path / "Setup_Scale_bare.xml"  # the tool as the file's root
    bare.write_text("<?xml version='1.0'?><ScaleTool name='s'><mass>61</mass></ScaleTool>")
    assert main(["inspect", str(bare)]) == 0
    assert "an OpenSim Scale setup" in capsys.readouterr().out


def test_a_setups_task_set_file_is_read(tmp_path, capsys):
    """A setup whose IKTaskSet names a file (`<IKTaskSet file="Tasks.xml"/>`, as OpenSim's GUI writes a Scale setup's
    tasks): its coordinate tasks lock (IK setup) or pose the static (Scale setup's MarkerPlacer) as written inline;
    the file not there: one line naming it, exit 2, nothing written."""
    from calibrate.io.osim_setup import ik_setup_locks, static_pose
    from tests.test_osim_import import _task

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    model = load_model(src)
    trc = _muscled_trial(tmp_path, model)
    (tmp_path / "Tasks.xml").write_text("<?xml version='1.0'?><OpenSimDocument Version='40000'><IKTaskSet name='t'>"
                                        f"<objects>{_task('knee_q', 'manual_value', -0.25)}</objects></IKTaskSet>"
                                        "</OpenSimDocument>")
    ik = tmp_path / "Setup_IK.xml"
    ik.write_text("<?xml version='1.0'?><OpenSimDocument Version='40000'><InverseKinematicsTool name='ik'>"
                  "<IKTaskSet file='Tasks.xml'/></InverseKinematicsTool></OpenSimDocument>")
    assert ik_setup_locks(ik, model) == (("knee_q", -0.25),)
    scale = tmp_path / "Setup_Scale.xml"
    scale.write_text("<?xml version='1.0'?><OpenSimDocument Version='40000'><ScaleTool name='s'><MarkerPlacer>"
                     "<apply>true</apply><IKTaskSet file='Tasks.xml'/><marker_file>trial.trc</marker_file>"
                     "</MarkerPlacer></ScaleTool></OpenSimDocument>")
    assert static_pose(scale, model).values == (("knee_q", -0.25),)
    assert main(["inspect", str(ik)]) == 0
    assert "knee_q (-0.25)" in capsys.readouterr().out
    (tmp_path / "Tasks.xml").unlink()
    out = tmp_path / "out"
    out.mkdir()
    code = main([str(trc), str(src), "--ik-setup", str(ik), "-o", str(out / "s.urdf"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "its task set file 'Tasks.xml' is not at" in err[0], err
    assert not any(out.iterdir())


def test_a_pose_on_one_angle_of_a_ball_joint():
    """A pose naming one angle of a ball joint (human.urdf's hip_r_flexion at 0.1 rad, lumbar_flexion at -0.05 in a
    simulated static): the static's mean of each named angle is its value, the joint's other angles keep the means
    they have without the pose, every joint the pose does not name keeps its angles, and the fit is unchanged."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.simulation.simulate import simulate_gait
    from tests.test_far_joints import arms_out_static

    model = load_model(Path(__file__).resolve().parents[1] / "models" / "human.urdf")
    walk = simulate_gait(model, frames=200, seed=3)
    static, _, _ = arms_out_static(model, walk, abduction=0.0)  # standing, arms down
    pose = {"hip_r_flexion": 0.1, "lumbar_flexion": -0.05}
    plain = calibrate(model, [static, walk.trial])  # the segment frames where the priors put them
    posed = calibrate(model, [static, walk.trial], neutral=0, pose=pose)
    assert dict(posed.pose) == pose and posed.pose_unset == ()
    a0, a1 = plain.motions[0].angles.mean(axis=0), posed.motions[0].angles.mean(axis=0)
    names = plain.motions[0].dof_names
    for name, value in pose.items():
        assert a1[names.index(name)] == pytest.approx(value, abs=1e-4), name
    for name in ("hip_r_adduction", "hip_r_rotation", "lumbar_bending", "lumbar_rotation"):
        # A ball's other angles stay (to second order in the named turn: the chain's angles are not independent).
        assert a1[names.index(name)] == pytest.approx(a0[names.index(name)], abs=np.radians(0.5)), name
    # The balls below the turned torso (neck, shoulders) absorb its turn; the hinges below the turned thigh (knee,
    # ankle) turn with it, their angles unchanged; every joint elsewhere keeps its angles (to the re-solve's 0.06 deg).
    others = [i for i, n in enumerate(names) if not n.startswith(("hip_r", "lumbar", "neck", "shoulder"))]
    assert np.abs(a1[others] - a0[others]).max() < 1e-3, [names[i] for i in others]
    assert posed.marker_rms == pytest.approx(plain.marker_rms, abs=1e-7)
