"""calibrate batch (issue 21 item 4): a manifest of generated subjects calibrated on a 2-worker Dask
LocalCluster; a broken trial reported without stopping the others; resume and --overwrite; bad manifests."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="calibrate batch needs dask.distributed (the [batch] extra)")

from calibrate.calibration.batch import read_manifest, run_batch  # noqa: E402
from calibrate.errors import CalibrateError  # noqa: E402
from calibrate.io.read import read_trial  # noqa: E402
from calibrate.model.model import load_model  # noqa: E402
from calibrate.simulation.simulate import simulate_squats, write_simulation  # noqa: E402

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """Three generated subjects (80 squat frames each) and a manifest; S3's trial file is broken."""
    root = tmp_path_factory.mktemp("lab")
    model = load_model(HUMAN)
    for k, sid in enumerate(("S1", "S2", "S3")):
        write_simulation(simulate_squats(model, frames=80, noise_mm=1.0, seed=10 + k), root / sid)
    (root / "S3" / "trial.c3d").write_bytes(b"not a c3d file at all")
    lines = [f'[[subject]]\nid = "{sid}"\ntrials = ["{sid}/trial.c3d"]\nmodel = "{HUMAN}"\n'
             for sid in ("S1", "S2", "S3")]
    (root / "lab.toml").write_text("\n".join(lines) + 'mass = 70.0\n')
    return root


def test_batch_on_a_local_cluster_isolates_a_broken_subject_and_resumes(lab):
    out = lab / "out"
    seen = []
    rows = run_batch(read_manifest(lab / "lab.toml"), out, workers=2, progress=lambda r, k, n: seen.append((k, n)))
    status = {r["subject"]: r["status"] for r in rows}
    assert status["S1"] in ("ok", "not converged") and status["S2"] in ("ok", "not converged")
    assert status["S3"] == "failed" and "trial.c3d" in rows[2]["error"]
    assert sorted(seen) == [(1, 3), (2, 3), (3, 3)]
    for sid in ("S1", "S2"):
        folder = out / sid
        assert {p.name for p in folder.iterdir()} >= {"subject.urdf", "trial_motion.csv", "report.json", "report.html"}
        # The summary's RMS is the one in the subject's report, read back.
        rep = json.loads((folder / "report.json").read_text())
        row = next(r for r in rows if r["subject"] == sid)
        assert row["marker_rms_mm"] == pytest.approx(rep["markers"]["rms_mm"], abs=1e-5) and row["marker_rms_mm"] < 5
        # Its warnings: what the report asks to look at (notes, unreliable parameters, labels to check, no
        # convergence), not the parameters the trial leaves to the priors.
        assert row["warnings"] == (len(rep["notes"]) + len(rep["unreliable"]) + len(rep["suspect_labels"])
                                   + len(rep["exchanged_labels"]) + (0 if rep["solver"]["converged"] else 1))
        assert read_trial(lab / sid / "trial.c3d").n_frames == 80
        # Its implausible results: the report's, named (the summary's implausible lines)
        assert row["implausible"] == rep["implausible_flags"]
    with open(out / "summary.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["subject"] for r in table] == ["S1", "S2", "S3"] and table[2]["status"] == "failed"
    for r, got in zip(rows, table, strict=True):
        assert got["implausible"] == " | ".join(r["implausible"])
    index = (out / "index.html").read_text()
    assert 'href="S1/report.html"' in index and 'href="S2/report.json"' in index and "S3" in index
    # Resume: the done subjects are skipped (their outputs untouched), the failed one tried again.
    mtime = (out / "S1" / "report.json").stat().st_mtime_ns
    again = run_batch(read_manifest(lab / "lab.toml"), out, workers=2)
    assert [r["status"] for r in again] == ["skipped", "skipped", "failed"]
    # ... their figures read back from their reports: the resumed batch's summary keeps them
    for first, later in zip(rows[:2], again[:2], strict=True):
        assert later["marker_rms_mm"] == pytest.approx(first["marker_rms_mm"], abs=1e-5)
        assert [later[k] for k in ("iterations", "converged", "warnings", "implausible")] == \
            [first[k] for k in ("iterations", "converged", "warnings", "implausible")]
    with open(out / "summary.csv") as f:
        kept = list(csv.DictReader(f))
    assert [r["marker_rms_mm"] for r in kept[:2]] == [r["marker_rms_mm"] for r in table[:2]]
    assert (out / "S1" / "report.json").stat().st_mtime_ns == mtime
    # --overwrite (the command line): calibrated again.
    run = subprocess.run([sys.executable, "-m", "calibrate.cli", "batch", str(lab / "lab.toml"), "--out", str(out),
                          "--workers", "2", "--overwrite"], capture_output=True, text=True, timeout=600)
    assert run.returncode == 1, run.stderr  # S3 still fails
    assert (out / "S1" / "report.json").stat().st_mtime_ns != mtime
    assert "[3/3]" in run.stderr and "3 subjects: 2 ok, 1 failed" in run.stdout.replace("not converged", "ok")


def test_csv_manifest_and_bad_manifests(tmp_path):
    (tmp_path / "m.csv").write_text(f"subject,trials,model,markers,mass\nA,a.c3d;b.c3d,{HUMAN},,61.5\n")
    (s,) = read_manifest(tmp_path / "m.csv")
    assert s.id == "A" and [t.name for t in s.trials] == ["a.c3d", "b.c3d"] and s.mass == 61.5 and s.markers is None
    bad = {"x.toml": "[[subject]]\nid = \"A\"\nmodel = \"m.urdf\"\n",  # no trials
           "y.toml": "[[subject]]\nid = \"A\"\ntrials = [\"a.c3d\"]\nmodel = \"m.urdf\"\n[[subject]]\nid = \"A\"\n"
                     "trials = [\"b.c3d\"]\nmodel = \"m.urdf\"\n",  # the same id twice
           "z.csv": "name,trials\nA,a.c3d\n",  # no subject/model columns
           "w.txt": "anything",
           # an ik trial that is a calibration trial too, two of one name, one that is not a file name
           "v.toml": "[[subject]]\nid = \"A\"\ntrials = [\"a.c3d\"]\nmodel = \"m.urdf\"\nik_trials = [\"a.c3d\"]\n",
           "u.toml": "[[subject]]\nid = \"A\"\ntrials = [\"a.c3d\"]\nmodel = \"m.urdf\"\n"
                     "ik_trials = [\"S1/w.c3d\", \"S2/w.trc\"]\n",
           "t.toml": "[[subject]]\nid = \"A\"\ntrials = [\"a.c3d\"]\nmodel = \"m.urdf\"\nik_trials = [3]\n"}
    for name, text in bad.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(CalibrateError) as e:
            read_manifest(tmp_path / name)
        assert str(e.value).startswith(str(tmp_path / name)) and "\n" not in str(e.value)
    run = subprocess.run([sys.executable, "-m", "calibrate.cli", "batch", str(tmp_path / "x.toml"), "--out",
                          str(tmp_path / "o")], capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and "trials" in run.stderr and not (tmp_path / "o").exists()
    assert np.isfinite(s.mass)
    (tmp_path / "i.csv").write_text(f"subject,trials,model,ik_trials\nA,a.c3d,{HUMAN},w1.c3d;w2.trc\n")
    assert [t.name for t in read_manifest(tmp_path / "i.csv")[0].ik_trials] == ["w1.c3d", "w2.trc"]
    # a pattern: every file it matches but the calibration trials, in name order (named and matched: once)
    (tmp_path / "S").mkdir()
    for name in ("static.c3d", "walk.c3d", "run2.c3d", "jump.c3d", "notes.txt"):
        (tmp_path / "S" / name).write_text("x")
    (tmp_path / "g.toml").write_text('[[subject]]\nid = "A"\ntrials = ["S/static.c3d", "S/walk.c3d"]\n'
                                     f'model = "{HUMAN}"\nik_trials = ["S/*.c3d", "S/jump.c3d"]\n')
    assert [t.name for t in read_manifest(tmp_path / "g.toml")[0].ik_trials] == ["jump.c3d", "run2.c3d"]
    (tmp_path / "n.toml").write_text('[[subject]]\nid = "A"\ntrials = ["S/static.c3d"]\n'
                                     f'model = "{HUMAN}"\nik_trials = ["S/*.trc"]\n')
    with pytest.raises(CalibrateError, match=r"ik_trials' pattern S/\*\.trc matches no file"):
        read_manifest(tmp_path / "n.toml")


def test_a_subjects_ik_trials_are_fitted_to_it_as_calibrate_ik_fits_them(tmp_path):
    """A manifest's ik_trials: each fitted to the subject the batch calibrated, held fixed, to the byte as `calibrate
    ik TRIAL subject.urdf --report report.json` fits it, near the simulator's true walk; the summary counts them and
    takes their worst marker RMS from their reports; a broken one is its own line in the error column (the others
    written, exit 1); resumed, the done ones are kept and the one mended is fitted."""
    from calibrate.io.motion import read_motion_csv
    from calibrate.simulation.simulate import simulate_gait

    model = load_model(HUMAN)
    write_simulation(simulate_squats(model, frames=80, noise_mm=1.0, seed=10), tmp_path / "S1")
    write_simulation(simulate_gait(model, frames=60, noise_mm=1.0, seed=10), tmp_path / "walk")  # the same subject
    (tmp_path / "S1" / "walk.c3d").write_bytes((tmp_path / "walk" / "trial.c3d").read_bytes())
    (tmp_path / "S1" / "late.c3d").write_bytes(b"not a c3d file")
    (tmp_path / "lab.toml").write_text(f'[[subject]]\nid = "S1"\ntrials = ["S1/trial.c3d"]\nmodel = "{HUMAN}"\n'
                                       'ik_trials = ["S1/walk.c3d", "S1/late.c3d"]\n')
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "calibrate.cli", "batch", str(tmp_path / "lab.toml"), "--out",
                          str(out)], capture_output=True, text=True, timeout=600)
    assert run.returncode == 1, run.stderr  # the calibration is done, one ik trial failed
    assert "1 ik trials, worst marker RMS" in run.stderr and "late.c3d: not a readable C3D file" in run.stderr
    with open(out / "summary.csv") as f:
        (row,) = list(csv.DictReader(f))
    assert row["status"] in ("ok", "not converged") and row["ik_trials"] == "1"
    assert row["error"].startswith(str(tmp_path / "S1" / "late.c3d")) and "not a readable C3D" in row["error"]
    folder = out / "S1"
    rep = json.loads((folder / "walk_ik_report.json").read_text())
    assert float(row["ik_marker_rms_mm"]) == pytest.approx(rep["markers"]["rms_mm"], abs=1e-3)
    assert rep["outputs"] == [str(folder / "walk_motion.csv"), str(folder / "walk_ik_report.json")]
    assert not (folder / "late_motion.csv").exists() and not (folder / "late_ik_report.json").exists()
    ik = tmp_path / "ik"
    ik.mkdir()
    cli = subprocess.run([sys.executable, "-m", "calibrate.cli", "ik", str(tmp_path / "S1" / "walk.c3d"),
                          str(folder / "subject.urdf"), "--report", str(folder / "report.json"), "-o", str(ik), "-q"],
                         capture_output=True, text=True, timeout=300)
    assert cli.returncode == 0, cli.stderr
    assert (ik / "walk_motion.csv").read_bytes() == (folder / "walk_motion.csv").read_bytes()
    got, truth = read_motion_csv(folder / "walk_motion.csv"), read_motion_csv(tmp_path / "walk" / "truth_motion.csv")
    for dof in ("knee_l", "knee_r", "hip_l_flexion", "hip_r_flexion"):
        k = got.dof_names.index(dof)
        assert np.degrees(np.sqrt(np.mean((got.angles[:, k] - truth.angles[:, k]) ** 2))) < 3.0, dof
    # Resumed once late.c3d is mended: the subject and walk.c3d kept as they were, late.c3d fitted.
    (tmp_path / "S1" / "late.c3d").write_bytes((tmp_path / "walk" / "trial.c3d").read_bytes())
    kept = {p: (folder / p).stat().st_mtime_ns for p in ("report.json", "walk_motion.csv", "walk_ik_report.json")}
    (again,) = run_batch(read_manifest(tmp_path / "lab.toml"), out, workers=2)
    assert again["status"] == "skipped" and again["ik_trials"] == 2 and again["error"] == ""
    assert {p: (folder / p).stat().st_mtime_ns for p in kept} == kept
    assert (folder / "late_motion.csv").read_bytes() == (folder / "walk_motion.csv").read_bytes()
    assert again["ik_marker_rms_mm"] == pytest.approx(rep["markers"]["rms_mm"], abs=1e-6)
    assert "<th>ik trials (marker RMS)</th>" in (out / "index.html").read_text()


def test_a_manifest_asks_for_the_hips_by_regression(tmp_path):
    """hip_regression per subject (TOML true / false / "auto", a CSV column): read, passed to the calibration (a
    trial without the PSIS markers fails that subject with the regression's one line, before any solve), and anything
    else refused in one line naming the subject."""
    from calibrate.calibration.batch import calibrate_subject
    from calibrate.io.c3d import write_c3d
    from calibrate.simulation.simulate import simulate_static

    model = load_model(HUMAN)
    static = simulate_static(model, model.parameters(), frames=5, noise_mm=0.0, seed=1).trial
    write_c3d(tmp_path / "s.c3d", static.select([lab for lab in static.labels if lab not in ("RPSI", "LPSI")]))
    (tmp_path / "m.toml").write_text("".join(f'[[subject]]\nid = "{sid}"\ntrials = ["s.c3d"]\nmodel = "{HUMAN}"\n'
                                             + (f"hip_regression = {value}\n" if value else "")
                                             for sid, value in (("A", '"auto"'), ("B", "true"), ("C", ""))))
    a, b, c = read_manifest(tmp_path / "m.toml")
    assert (a.hip_regression, b.hip_regression, c.hip_regression) == ("auto", True, None)
    (tmp_path / "m.csv").write_text(f"subject,trials,model,hip_regression\nA,s.c3d,{HUMAN},auto\nB,s.c3d,{HUMAN},"
                                    f"true\nC,s.c3d,{HUMAN},\n")
    assert [x.hip_regression for x in read_manifest(tmp_path / "m.csv")] == ["auto", True, None]
    row = calibrate_subject(b, tmp_path / "out")
    assert row["status"] == "failed" and row["error"].startswith("hip_regression: ") and "RPSI and LPSI" in row["error"]
    for name, text in (("x.toml", f'[[subject]]\nid = "A"\ntrials = ["s.c3d"]\nmodel = "{HUMAN}"\n'
                                  'hip_regression = "sometimes"\n'),
                       ("x.csv", f"subject,trials,model,hip_regression\nA,s.c3d,{HUMAN},sometimes\n")):
        (tmp_path / name).write_text(text)
        with pytest.raises(CalibrateError, match="hip_regression") as e:
            read_manifest(tmp_path / name)
        assert str(e.value).startswith(str(tmp_path / name)) and "\n" not in str(e.value) and "auto" in str(e.value)


def test_a_manifest_gives_each_subject_a_settings_file(tmp_path, monkeypatch, capsys):
    """config: the manifest's (before the first [[subject]]) for every subject naming none, a subject's own over it,
    a CSV column; the settings reach the calibration (the report's settings, read back), the manifest's
    hip_regression over the file's, nothing run ahead whatever the file says; a bad settings file refused in one
    line naming the subject, before any work."""
    import calibrate.calibration.pipeline as pipeline
    from calibrate.calibration.batch import calibrate_subject
    from calibrate.io.c3d import write_c3d
    from calibrate.simulation.simulate import simulate_static

    model = load_model(HUMAN)
    static = simulate_static(model, model.parameters(), frames=5, noise_mm=0.0, seed=1).trial
    write_c3d(tmp_path / "s.c3d", static.select([lab for lab in static.labels if lab not in ("RPSI", "LPSI")]))
    given = []  # the settings each calibration was given (the real calibration runs)
    real = pipeline.calibrate
    monkeypatch.setattr(pipeline, "calibrate", lambda *a, **k: given.append(a[2]) or real(*a, **k))
    (tmp_path / "lab.toml").write_text("hip_regression = true\nahead = true\nmax_iterations = 7\n")
    (tmp_path / "S2").mkdir()
    (tmp_path / "S2" / "own.toml").write_text("noise_mm = 2.5\n[lock_deg]\nsubtalar_r = 3.0\n")
    subject = f'[[subject]]\ntrials = ["s.c3d"]\nmodel = "{HUMAN}"\n'
    (tmp_path / "m.toml").write_text('config = "lab.toml"\n' + subject + 'id = "A"\n' + subject
                                     + 'id = "B"\nhip_regression = false\n' + subject
                                     + 'id = "C"\nconfig = "S2/own.toml"\n')
    a, b, c = read_manifest(tmp_path / "m.toml")
    lab = tmp_path / "lab.toml"
    assert (a.config, b.config, c.config) == (lab, lab, tmp_path / "S2" / "own.toml")
    # A: the file's hip_regression, and this static has no PSIS: the regression's one line, before any solve.
    row = calibrate_subject(a, tmp_path / "out")
    assert row["status"] == "failed" and row["error"].startswith("hip_regression: ") and "RPSI and LPSI" in row["error"]
    for sub, want in ((b, {"max_iterations": 7, "noise_mm": 1.0, "subtalar_r": 0.0, "hip_regression": False}),
                      (c, {"max_iterations": 100, "noise_mm": 2.5, "subtalar_r": 3.0, "hip_regression": "outside"})):
        row = calibrate_subject(sub, tmp_path / "out")
        assert row["status"] in ("ok", "not converged"), row["error"]
        got = json.loads((tmp_path / "out" / sub.id / "report.json").read_text())["settings"]
        assert got["max_iterations"] == want["max_iterations"] and got["noise_mm"] == pytest.approx(want["noise_mm"])
        assert got["lock_deg"].get("subtalar_r", 0.0) == pytest.approx(want["subtalar_r"])  # a still trial locks some
        # B: the manifest's false over the file's true; C: its own file's, which says nothing (the default)
        assert got["hip_regression"] == want["hip_regression"] and given[-1].ahead is False
    (tmp_path / "m.csv").write_text(f"subject,trials,model,config\nA,s.c3d,{HUMAN},S2/own.toml\nB,s.c3d,{HUMAN},\n")
    assert [x.config for x in read_manifest(tmp_path / "m.csv")] == [tmp_path / "S2" / "own.toml", None]
    # The command line's (--config): every subject naming none of its own, in place of the manifest's.
    assert [x.config for x in read_manifest(tmp_path / "m.csv", lab)] == [tmp_path / "S2" / "own.toml", lab]
    own = tmp_path / "S2" / "own.toml"
    assert [x.config for x in read_manifest(tmp_path / "m.toml", own)] == [own, own, own]
    (tmp_path / "bad.toml").write_text("noise = 2\n")  # not a key of a settings file
    for name, text, what in (("x.toml", 'config = "bad.toml"\n' + subject + 'id = "A"\n', "noise"),
                             ("y.toml", subject + 'id = "A"\nconfig = "none.toml"\n', "no such config file"),
                             ("z.toml", 'config = 3\n' + subject + 'id = "A"\n', "'config' must name"),
                             ("w.csv", f"subject,trials,model,config\nA,s.c3d,{HUMAN},bad.toml\n", "noise")):
        (tmp_path / name).write_text(text)
        with pytest.raises(CalibrateError, match=what) as e:
            read_manifest(tmp_path / name)
        assert str(e.value).startswith(str(tmp_path / name)) and "\n" not in str(e.value)
        assert name == "z.toml" or "subject 1 (A)" in str(e.value)
    with pytest.raises(CalibrateError, match="noise") as e:  # the command line's, refused in its own line
        read_manifest(tmp_path / "m.csv", tmp_path / "bad.toml")
    assert str(e.value).startswith(str(tmp_path / "bad.toml"))
    from calibrate.cli.main import main  # the command line in this process (its program-level refusal: above)

    capsys.readouterr()
    code = main(["batch", str(tmp_path / "m.csv"), "--out", str(tmp_path / "o"), "--config",
                 str(tmp_path / "bad.toml")])
    err = capsys.readouterr().err
    assert code == 2 and "bad.toml" in err and "noise" in err and not (tmp_path / "o").exists()


def test_an_opensim_lab_batch_takes_its_setups_and_writes_osim(tmp_path):
    """A subject on an OpenSim base model (models/human.urdf exported as .osim) with the lab's marker set, IK setup
    and Scale setup in the manifest: the Scale setup's mass and marker set are taken (the report names the file),
    the IK setup's coordinate task holds its coordinate in every frame and its time range cuts the trial it names
    (by the stem: the lab's .trc, the .c3d here; ``whole_trials`` keeps every frame), the marker set's extra marker
    is in the subject, and the subject is written as subject.osim and a .mot per trial beside the URDF and CSVs.
    The setups with a URDF model: one line."""
    from calibrate.calibration.batch import calibrate_subject
    from calibrate.io.osim_export import export_osim

    human = load_model(HUMAN)
    export_osim(human, tmp_path / "human.osim")
    write_simulation(simulate_squats(human, frames=80, noise_mm=1.0, seed=12), tmp_path / "S1")
    (tmp_path / "ms.xml").write_text(
        "<?xml version='1.0'?><OpenSimDocument Version='40000'><MarkerSet><objects><Marker name='EXTRA'>"
        "<socket_parent_frame>/bodyset/femur_r</socket_parent_frame><location>0.05 -0.2 0.04</location></Marker>"
        "</objects></MarkerSet></OpenSimDocument>")
    (tmp_path / "Setup_Scale.xml").write_text(
        "<?xml version='1.0'?><OpenSimDocument Version='40000'><ScaleTool name='S1'><mass>61.5</mass>"
        "<GenericModelMaker><marker_set_file>ms.xml</marker_set_file></GenericModelMaker></ScaleTool>"
        "</OpenSimDocument>")
    (tmp_path / "Setup_IK.xml").write_text(
        "<?xml version='1.0'?><OpenSimDocument Version='40000'><InverseKinematicsTool name='ik'><IKTaskSet><objects>"
        "<IKCoordinateTask name='subtalar_r'><apply>true</apply><weight>1000</weight><value_type>manual_value"
        "</value_type><value>0.1</value></IKCoordinateTask></objects></IKTaskSet>"
        "<marker_file>trial.trc</marker_file><time_range>0.1 0.6</time_range></InverseKinematicsTool>"
        "</OpenSimDocument>")  # the lab's IK on the .trc export of this trial, from 0.1 to 0.6 s
    (tmp_path / "lab.toml").write_text('[[subject]]\nid = "S1"\ntrials = ["S1/trial.c3d"]\nmodel = "human.osim"\n'
                                       'ik_setup = "Setup_IK.xml"\nscale_setup = "Setup_Scale.xml"\n')
    (subject,) = read_manifest(tmp_path / "lab.toml")
    row = calibrate_subject(subject, tmp_path / "out", c3d=True, mjcf=True)
    assert row["status"] in ("ok", "not converged"), row
    folder = tmp_path / "out" / "S1"
    assert {p.name for p in folder.iterdir()} >= {"subject.urdf", "subject.osim", "trial_motion.csv",
                                                  "trial_motion.mot", "trial_ik_marker_errors.sto",
                                                  "trial_calibrated.c3d", "report.json",
                                                  "subject_mujoco.xml", "trial_motion_qpos.csv"}
    # human.osim came from a z-up URDF: its subject keeps the source's gravity, in OpenSim and in MuJoCo
    for name in ("subject.osim", "subject_mujoco.xml"):
        assert "0 0 -9.80665" in (folder / name).read_text(), name
    from calibrate.io.c3d import read_c3d
    from calibrate.io.motion import read_motion_csv

    calibrated = read_c3d(folder / "trial_calibrated.c3d")  # the frames the IK setup's range cut, as the motion's
    assert calibrated.n_frames == read_motion_csv(folder / "trial_motion.csv").n_frames < 80
    assert {"hip_r_JC", "knee_r_angles", "RASI_model"} <= set(calibrated.model_outputs)
    rep = json.loads((folder / "report.json").read_text())
    assert rep["outputs"]["osim"] == str(folder / "subject.osim")  # every output listed in the report
    assert rep["outputs"]["mot"] == [str(folder / "trial_motion.mot")]
    assert rep["outputs"]["errors"] == [str(folder / "trial_ik_marker_errors.sto")]
    assert rep["outputs"]["mjcf"] == str(folder / "subject_mujoco.xml")
    assert rep["mass"]["subject_kg"] == pytest.approx(61.5) and rep["mass"]["from"] == str(tmp_path / "Setup_Scale.xml")
    assert rep["settings"]["lock_deg"]["subtalar_r"] == pytest.approx(np.degrees(0.1))
    assert "EXTRA" in load_model(folder / "subject.osim").marker_names
    lines = (folder / "trial_motion.mot").read_text().splitlines()
    head = lines.index("endheader") + 1
    cols = lines[head].split("\t")
    rows = np.array([[float(v) for v in line.split("\t")] for line in lines[head + 1:]])
    assert np.allclose(rows[:, cols.index("subtalar_r")], np.degrees(0.1), atol=1e-3)  # degrees
    # the IK setup's frames only, as the command line cuts them: 0.1 to 0.6 s of the 80 frames at 100 Hz
    assert len(rows) == 51 and np.allclose(rows[:, 0], np.arange(10, 61) / 100, atol=1e-9)
    (tmp_path / "whole.toml").write_text((tmp_path / "lab.toml").read_text() + "whole_trials = true\n")
    (tmp_path / "whole.csv").write_text("subject,trials,model,ik_setup,whole_trials\nS1,S1/trial.c3d,human.osim,"
                                        "Setup_IK.xml,yes\nS2,S1/trial.c3d,human.osim,Setup_IK.xml,\n")
    assert read_manifest(tmp_path / "whole.toml")[0].whole_trials and not subject.whole_trials
    assert [s.whole_trials for s in read_manifest(tmp_path / "whole.csv")] == [True, False]
    (tmp_path / "bad.csv").write_text("subject,trials,model,whole_trials\nS1,S1/trial.c3d,human.osim,maybe\n")
    with pytest.raises(CalibrateError, match="whole_trials 'maybe' must be true or false"):
        read_manifest(tmp_path / "bad.csv")
    (tmp_path / "bad.toml").write_text(f'[[subject]]\nid = "S1"\ntrials = ["S1/trial.c3d"]\nmodel = "{HUMAN}"\n'
                                       'marker_set = "ms.xml"\n')
    with pytest.raises(CalibrateError, match="'marker_set' applies to an OpenSim base model"):
        read_manifest(tmp_path / "bad.toml")


def test_a_manifest_subject_with_setup_names_writes_where_its_setups_say(tmp_path):
    """``setup_names = true``: the subject .osim, its marker set, its motion and its marker errors go where the
    subject's Scale and IK setups have OpenSim write them (the lab's later setups read them there), the rest into
    out/<id>/; run again, the lab's files are refused (one line: the subject fails) unless overwritten; without a
    setup to take the names from, the manifest is refused."""
    from calibrate.calibration.batch import calibrate_subject
    from calibrate.io.osim_export import export_osim

    human = load_model(HUMAN)
    export_osim(human, tmp_path / "human.osim")
    write_simulation(simulate_squats(human, frames=60, noise_mm=1.0, seed=13), tmp_path / "S1")
    lab = tmp_path / "S1" / "opensim"
    (lab / "ik").mkdir(parents=True)
    (lab / "Setup_Scale.xml").write_text(
        "<?xml version='1.0'?><OpenSimDocument Version='40000'><ScaleTool name='S1'><mass>61.5</mass><ModelScaler>"
        "<apply>true</apply><output_scale_file>S1_scales.xml</output_scale_file></ModelScaler><MarkerPlacer>"
        "<apply>true</apply><output_model_file>S1_scaled.osim</output_model_file><output_marker_file>"
        "S1_markers.xml</output_marker_file></MarkerPlacer></ScaleTool></OpenSimDocument>")
    (lab / "Setup_IK.xml").write_text(
        "<?xml version='1.0'?><OpenSimDocument Version='40000'><InverseKinematicsTool name='squat'>"
        "<results_directory>ik</results_directory><marker_file>../trial.trc</marker_file>"
        "<report_marker_locations>true</report_marker_locations>"
        "<output_motion_file>ik/squat_ik.mot</output_motion_file></InverseKinematicsTool></OpenSimDocument>")
    (tmp_path / "lab.toml").write_text(
        '[[subject]]\nid = "S1"\ntrials = ["S1/trial.c3d"]\nmodel = "human.osim"\n'
        'ik_setup = "S1/opensim/Setup_IK.xml"\nscale_setup = "S1/opensim/Setup_Scale.xml"\nsetup_names = true\n')
    (subject,) = read_manifest(tmp_path / "lab.toml")
    assert subject.setup_names
    row = calibrate_subject(subject, tmp_path / "out")
    assert row["status"] in ("ok", "not converged"), row
    named = {"S1_scaled.osim", "S1_markers.xml", "S1_scales.xml", "ik/squat_ik.mot", "ik/squat_ik_marker_errors.sto",
             "ik/squat_ik_model_marker_locations.sto"}
    assert {str(p.relative_to(lab)) for p in lab.rglob("*") if p.is_file() and not p.name.startswith("Setup")} == named
    folder = tmp_path / "out" / "S1"
    assert {"subject.urdf", "trial_motion.csv", "report.json"} <= {p.name for p in folder.iterdir()}
    assert not any(p.suffix in (".osim", ".mot", ".sto") for p in folder.iterdir())
    rep = json.loads((folder / "report.json").read_text())
    assert rep["outputs"]["mot"] == [str(lab / "ik" / "squat_ik.mot")]
    assert rep["outputs"]["marker_set"] == str(lab / "S1_markers.xml")
    # the scale set: each body of the subject .osim at the segment scale the report gives it
    scales = {p["name"][6:-1]: p["value"][0] for p in rep["parameters"] if p["group"] == "scale"}
    written = {sc.findtext("segment"): [float(x) for x in sc.findtext("scales").split()]
               for sc in ET.parse(lab / "S1_scales.xml").getroot().iter("Scale")}
    assert scales and all(np.allclose(written[seg], s, atol=1e-8) for seg, s in scales.items())
    # the model marker locations: the subject's markers posed by its motion, as Pinocchio puts them
    import pinocchio as pin

    from calibrate.io.motion import read_motion_csv

    lines = (lab / "ik" / "squat_ik_model_marker_locations.sto").read_text().splitlines()
    at = lines.index("endheader")
    names = [c[:-3] for c in lines[at + 1].split("\t")[1::3]]
    values = np.array([[float(v) for v in line.split("\t")] for line in lines[at + 2:]])
    urdf, motion = load_model(folder / "subject.urdf"), read_motion_csv(folder / "trial_motion.csv")
    assert len(names) == len(urdf.marker_names) and values.shape == (motion.n_frames, 1 + 3 * len(names))
    data = urdf.pin.createData()
    for f in (0, motion.n_frames // 2, motion.n_frames - 1):
        pin.framesForwardKinematics(urdf.pin, data, urdf.pin_configuration(
            motion.root_translation[f], motion.root_quaternion[f], motion.angles[f]))
        got = [data.oMf[urdf.pin.getFrameId(n, pin.FrameType.BODY)].translation for n in names]
        assert np.abs(np.ravel(got) - values[f, 1:]).max() < 1e-9
    # the subject's markers, read back from the marker set onto its .osim, are the subject's
    subject_osim = load_model(lab / "S1_scaled.osim")
    again = load_model(lab / "S1_scaled.osim", lab / "S1_markers.xml")
    assert np.array_equal(again.parameters().marker, subject_osim.parameters().marker)
    (folder / "report.json").unlink()  # the subject to do again: the lab's files are there now
    row = calibrate_subject(subject, tmp_path / "out")
    assert row["status"] == "failed" and "exists; the lab's setup names it" in row["error"] and "\n" not in row["error"]
    assert calibrate_subject(subject, tmp_path / "out", overwrite=True)["status"] in ("ok", "not converged")
    (tmp_path / "bad.toml").write_text('[[subject]]\nid = "S1"\ntrials = ["S1/trial.c3d"]\nmodel = "human.osim"\n'
                                       'setup_names = true\n')
    with pytest.raises(CalibrateError, match="'setup_names' takes the names the lab's setups give"):
        read_manifest(tmp_path / "bad.toml")
    (tmp_path / "lab.csv").write_text("subject,trials,model,ik_setup,setup_names\n"
                                      "S1,S1/trial.c3d,human.osim,S1/opensim/Setup_IK.xml,yes\n")
    assert read_manifest(tmp_path / "lab.csv")[0].setup_names
    # the setups alone, as OpenSim's tools take them: no trials, no model; those the setups name, setup_names true
    scale = (lab / "Setup_Scale.xml").read_text()
    (lab / "Setup_Scale.xml").write_text(scale.replace(
        "<MarkerPlacer>", "<GenericModelMaker><model_file>../../human.osim</model_file></GenericModelMaker>"
        "<MarkerPlacer><marker_file>../trial.trc</marker_file>"))
    (tmp_path / "alone.toml").write_text('[[subject]]\nid = "S1"\nik_setup = "S1/opensim/Setup_IK.xml"\n'
                                         'scale_setup = "S1/opensim/Setup_Scale.xml"\n')
    (alone,) = read_manifest(tmp_path / "alone.toml")
    assert alone.model == tmp_path / "human.osim" and alone.trials == (tmp_path / "S1" / "trial.trc",)
    assert alone.setup_names and alone.ik_setup == subject.ik_setup and alone.scale_setup == subject.scale_setup
    (lab / "Setup_Scale.xml").write_text(scale)  # no model_file: refused, one line naming what to give
    with pytest.raises(CalibrateError, match="model_file is Unassigned; name it in the setup, or give the subject's"):
        read_manifest(tmp_path / "alone.toml")
