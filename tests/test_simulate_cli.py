"""Synthetic squats and gait (files, truth, noise, gaps, ranges of motion) and the command line."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

from calibrate.cli import main
from calibrate.io.c3d import read_c3d
from calibrate.io.motion import read_motion_csv
from calibrate.model.model import load_model
from calibrate.simulation.simulate import simulate_gait, simulate_squats


def test_simulate_writes_consistent_files(tmp_path, human):
    assert main(["simulate", "--out", str(tmp_path / "sim"), "--frames", "40", "--noise-mm", "0", "--seed", "4"]) == 0
    trial = read_c3d(tmp_path / "sim" / "trial.c3d")
    truth = load_model(tmp_path / "sim" / "truth.urdf")
    motion = read_motion_csv(tmp_path / "sim" / "truth_motion.csv")
    assert trial.n_frames == motion.n_frames == 40 and trial.rate == 100.0
    assert motion.dof_names == truth.dof_names == human.dof_names
    np.testing.assert_allclose(motion.times, np.arange(40) / 100.0)
    # Independent check: Pinocchio on truth.urdf, driven by the motion CSV, gives the C3D's markers.
    d = truth.pin.createData()
    index = {lab: i for i, lab in enumerate(trial.labels)}
    worst = 0.0
    for f in range(0, 40, 3):
        q = truth.pin_configuration(motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        pin.forwardKinematics(truth.pin, d, q)
        pin.updateFramePlacements(truth.pin, d)
        for m in truth.markers:
            x = d.oMf[truth.pin.getFrameId(m.name, pin.FrameType.BODY)].translation
            worst = max(worst, np.abs(x - trial.markers[f, index[m.name]]).max())
    assert worst < 1e-4  # C3D stores mm as float32: ~1e-4 mm quantisation at 2 m, far below this


def test_subject_changes_are_within_documented_ranges(human):
    sim = simulate_squats(human, frames=10, seed=9)
    p0, p1 = human.parameters(), sim.truth
    assert np.all(np.abs(p1.scale - 1) <= 0.10) and np.abs(p1.scale - 1).max() > 0.05
    assert np.abs(p1.centre - p0.centre).max() <= 0.015
    knees = [human.marker_index(k) for k in ("LKNE", "RKNE")]  # by the knee's axis (hinges_by_their_landmarks)
    others = np.ones(len(human.markers), dtype=bool)
    others[knees] = False
    assert np.abs(p1.marker - p0.marker)[others].max() <= 0.010
    assert np.abs(p1.marker - p0.marker)[knees].max() <= 0.010 + 0.015 * 2
    cosines = np.sum(p1.axis * p0.axis, axis=1)
    tilt = np.degrees(np.arccos(np.clip(cosines, -1, 1)))
    hinges = [human.dof_index(j.dofs[0]) for j in human.joints if j.kind == "hinge"]
    assert tilt[hinges].max() <= 5.0 + 1e-9 and tilt[hinges].min() > 1.0
    others = np.setdiff1d(np.arange(human.n_dofs), hinges)
    assert tilt[others].max() < 1e-6


def test_noise_and_gaps(human):
    sim = simulate_squats(human, frames=400, noise_mm=2.0, gaps=True, seed=1)
    noise = (sim.trial.markers - sim.clean_markers)
    sd = np.nanstd(noise)
    assert sd == pytest.approx(0.002, rel=0.05)
    gap = np.isnan(sim.trial.markers[..., 0])
    assert 0 < gap.mean() and gap.mean(axis=0).max() <= 0.2 + 1e-9
    clean = simulate_squats(human, frames=50, seed=1)
    assert not np.isnan(clean.trial.markers).any()


def test_every_joint_moves_through_a_useful_range(human):
    sim = simulate_squats(human, frames=1000, seed=0)
    rom = np.degrees(np.ptp(sim.motion.angles, axis=0))
    need = {"hip_r_flexion": 80, "knee_r": 90, "ankle_r": 20, "hip_r_adduction": 20, "hip_r_rotation": 30,
            "shoulder_l_flexion": 90, "shoulder_l_adduction": 45, "elbow_l": 80, "radioulnar_r": 60,
            "lumbar_flexion": 20, "neck_rotation": 40}
    for name, deg in need.items():
        assert rom[human.dof_index(name)] >= deg, (name, rom[human.dof_index(name)])
    assert rom.min() > 10  # every DoF moves
    # squats: the pelvis drops by more than 30 cm while the ankles stay put (up to 1 cm sway)
    z = sim.motion.root_translation[:, 2]
    assert z.max() - z.min() > 0.3
    ankles = sim.clean_centres[:, [human.joint_index("ankle_r"), human.joint_index("ankle_l")]].mean(axis=1)
    assert np.ptp(ankles[:, :2], axis=0).max() < 0.021 and np.ptp(ankles[:, 2]) < 1e-12


def test_gait_walks_with_normal_ranges_and_nearly_still_joints(human, tmp_path):
    """Treadmill gait: the subject simulate_squats draws for the seed; hips, knees and ankles through
    a normal gait cycle's arcs, the two sides half a stride apart; forearms, wrists and subtalar
    joints within a few degrees; the pelvis in place on the treadmill."""
    sim = simulate_gait(human, frames=600, seed=3)
    squats = simulate_squats(human, frames=10, seed=3)
    np.testing.assert_array_equal(sim.truth.vector(), squats.truth.vector())
    rom = np.degrees(np.ptp(sim.motion.angles, axis=0))
    for name, (lo, hi) in {"hip_r_flexion": (40, 55), "knee_r": (45, 80), "ankle_r": (20, 40),
                           "shoulder_l_flexion": (25, 40), "elbow_l": (15, 30)}.items():
        assert lo <= rom[human.dof_index(name)] <= hi, (name, rom[human.dof_index(name)])
    for name in ("radioulnar_r", "wrist_l_flexion", "wrist_r_deviation", "subtalar_l", "neck_bending"):
        assert rom[human.dof_index(name)] <= 10, (name, rom[human.dof_index(name)])
    a = sim.motion.angles
    r, left = a[:, human.dof_index("hip_r_flexion")], a[:, human.dof_index("hip_l_flexion")]
    assert np.corrcoef(r, left)[0, 1] < -0.8  # half a stride apart
    assert np.ptp(sim.motion.root_translation, axis=0).max() < 0.1  # a treadmill: the pelvis stays within 10 cm
    assert main(["simulate", "--out", str(tmp_path / "g"), "--frames", "30", "--motion", "gait", "--seed", "3"]) == 0
    motion = read_motion_csv(tmp_path / "g" / "truth_motion.csv")
    np.testing.assert_allclose(motion.angles, simulate_gait(human, frames=30, seed=3).motion.angles, atol=1e-9)


def test_demo_runs_and_reports(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--frames", "60"]) == 0
    out = capsys.readouterr().out
    assert "39 markers" in out and "38 DoF" in out and "truth vs estimate" in out
    assert "hip_r" in out and "noise floor" in out and "CONVERGED" in out
    for name in ("trial.c3d", "subject.urdf", "subject_motion.csv", "subject_report.json"):
        assert (tmp_path / "calibrate-demo" / name).exists()


@pytest.mark.parametrize("argv, needle", [
    (["simulate", "--out", "x", "--frames", "abc"], "whole number"),
    (["simulate", "--out", "x", "--rate", "-5"], "positive"),
    (["simulate", "--out", "x", "--model", "missing.urdf"], "missing.urdf"),
    (["inspect", "nope.c3d"], "nope.c3d"),
])
def test_cli_bad_input_one_line_nonzero(tmp_path, monkeypatch, argv, needle):
    monkeypatch.chdir(tmp_path)
    r = subprocess.run([sys.executable, "-m", "calibrate.cli", *argv], capture_output=True, text=True)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("calibrate")]
    assert needle in r.stderr and "Traceback" not in r.stderr and len(lines) == 1, r.stderr
    assert not (tmp_path / "x").exists()  # nothing written


def test_cli_truncated_c3d_one_line(tmp_path, capsys):
    """A C3D file cut short: one line naming it, exit 2 (in this process: the program's own exit is
    test_cli_bad_input_one_line_nonzero's)."""
    assert main(["simulate", "--out", str(tmp_path), "--frames", "30"]) == 0
    data = (tmp_path / "trial.c3d").read_bytes()
    for cut in (len(data) // 2, 700, 100):
        bad = tmp_path / f"cut{cut}.c3d"
        bad.write_bytes(data[:cut])
        capsys.readouterr()
        assert main(["inspect", str(bad)]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and f"cut{cut}.c3d" in err, err


def test_python_m_calibrate_is_the_command_line(tmp_path):
    """`python -m calibrate` runs the `calibrate` program: the output and exit codes of `python -m calibrate.cli`."""
    assert main(["simulate", "--out", str(tmp_path), "--frames", "10"]) == 0
    for argv, code in ((["inspect", str(tmp_path / "trial.c3d")], 0), (["inspect", str(tmp_path / "none.c3d")], 2)):
        a, b = (subprocess.run([sys.executable, "-m", m, *argv], capture_output=True, text=True)
                for m in ("calibrate", "calibrate.cli"))
        assert a.returncode == b.returncode == code
        assert a.stdout == b.stdout and a.stderr == b.stderr
        assert (a.stdout if code == 0 else a.stderr).strip()


def test_simulate_does_not_overwrite_unless_asked(tmp_path):
    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--frames", "5", "--seed", "1"]) == 0
    before = (out / "trial.c3d").read_bytes()
    r = subprocess.run([sys.executable, "-m", "calibrate.cli", "simulate", "--out", str(out), "--frames", "5",
                        "--seed", "2"], capture_output=True, text=True)
    assert r.returncode == 2 and "--overwrite" in r.stderr
    assert (out / "trial.c3d").read_bytes() == before
    assert main(["simulate", "--out", str(out), "--frames", "5", "--seed", "2", "--overwrite"]) == 0
    assert (out / "trial.c3d").read_bytes() != before


def test_simulate_refuses_a_file_as_output_dir(tmp_path):
    f = tmp_path / "afile"
    f.write_text("keep")
    r = subprocess.run([sys.executable, "-m", "calibrate.cli", "simulate", "--out", str(f), "--frames", "5"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "not a directory" in r.stderr and f.read_text() == "keep"


def test_default_model_without_source_tree(tmp_path, monkeypatch):
    """An installed package has no models/ folder: the same model is generated instead."""
    from conftest import HUMAN, assert_same_text_and_numbers

    import calibrate.cli.commands as cli

    monkeypatch.setattr(cli, "DEFAULT_MODEL", tmp_path / "absent" / "human.urdf")
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    path = cli.default_model()
    assert path.parent == tmp_path
    assert_same_text_and_numbers(path.read_text(), HUMAN.read_text())


def test_motion_csv_errors(tmp_path):
    from calibrate.errors import CalibrateError

    bad = tmp_path / "m.csv"
    bad.write_text("t,x\n0,1\n")
    with pytest.raises(CalibrateError, match="header must start with time"):
        read_motion_csv(bad)
    with pytest.raises(CalibrateError, match="cannot read"):
        read_motion_csv(tmp_path / "missing.csv")


def test_inspect_model_and_trial(tmp_path, capsys):
    from conftest import HUMAN

    assert main(["inspect", str(HUMAN)]) == 0
    assert "knee_r" in capsys.readouterr().out
    assert main(["simulate", "--out", str(tmp_path), "--frames", "5"]) == 0
    capsys.readouterr()
    assert main(["inspect", str(tmp_path / "trial.c3d")]) == 0
    assert "5 frames at 100 Hz" in capsys.readouterr().out


def test_inspect_says_whether_a_trial_keeps_still(tmp_path, capsys):
    """`calibrate inspect TRIAL` measures how much its markers move relative to each other (the median over pairs of
    their distance's SD, computed here with numpy alone): a static keeps still, squats move."""
    import re

    from conftest import HUMAN

    from calibrate.io.c3d import write_c3d
    from calibrate.simulation.simulate import simulate_static

    human = load_model(HUMAN)
    squats = simulate_squats(human, frames=60, noise_mm=1.0, seed=2)
    static = simulate_static(human, squats.truth, frames=60, noise_mm=1.0, seed=2)
    for name, sim, word in (("static", static, "still, a static trial"), ("squats", squats, "a movement trial")):
        write_c3d(tmp_path / f"{name}.c3d", sim.trial)
        assert main(["inspect", str(tmp_path / f"{name}.c3d")]) == 0
        line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("  motion: "))
        X = read_c3d(tmp_path / f"{name}.c3d").markers
        d = np.linalg.norm(X[:, :, None] - X[:, None, :], axis=3)
        sd = np.std(d, axis=0, ddof=1)[np.triu_indices(X.shape[1], 1)]
        assert float(re.search(r"to ([0-9.]+) mm SD", line).group(1)) == pytest.approx(1000 * np.median(sd), abs=0.06)
        assert word in line, line


def test_an_opensim_models_coordinates_take_the_motions_by_their_names():
    """An imported OpenSim model's coordinates take the squats' and the walk's motions by OpenSim's names
    (motions.OPENSIM_MOTIONS): Rajagopal2016's knees flex through a squat (they had a generic +-20 deg sinusoid while
    its hips flexed 100 deg), gait2392's knee_angle, negative in flexion (range -120 to 10 deg), flexes negative, and
    lumbar_extension (the trunk's extension) leans the trunk forward, negative; the coordinates the model locks
    (Rajagopal's subtalars and mtps) stay at their locked values."""
    from pathlib import Path

    real = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
    raj = real / "rajagopal_walk" / "Rajagopal2016.osim"
    g2392 = real / "gait2392" / "gait2392.osim"
    if not raj.is_file() or not g2392.is_file():
        pytest.skip("../shared/data/real is not here")
    for path, marker_set in ((raj, None), (g2392, g2392.with_name("gait2392_Scale_MarkerSet.xml"))):
        model = load_model(path, marker_set)
        squats = simulate_squats(model, frames=400, seed=1).motion.angles
        walk = simulate_gait(model, frames=240, seed=1).motion.angles
        knee, trunk = model.dof_index("knee_angle_r"), model.dof_index("lumbar_extension")
        flex = -1.0 if path == g2392 else 1.0  # the knee's flexion, as the model's range puts it
        assert np.degrees(np.max(flex * squats[:, knee])) > 90 and np.degrees(np.min(flex * squats[:, knee])) < 20
        assert np.degrees(np.ptp(walk[:, knee])) > 45
        assert np.degrees(np.max(squats[:, trunk])) < 1 and np.degrees(np.min(squats[:, trunk])) < -20
        assert np.degrees(np.ptp(squats[:, model.dof_index("ankle_angle_r")])) > 25
        if path == raj:  # its subtalar and mtp joints locked in the model: held there, not driven
            from calibrate.io.osim_info import osim_info

            locked = osim_info(model).locked
            assert {"subtalar_angle_r", "mtp_angle_l"} <= set(locked)
            for name, value in locked.items():
                for a in (squats, walk):
                    np.testing.assert_array_equal(a[:, model.dof_index(name)], value)


def test_simulate_an_osim_with_its_marker_set(tmp_path, capsys):
    """`calibrate simulate --model MODEL.osim --marker-set XML` simulates the OpenSim model with the marker set's
    markers (gait2392.osim has none of its own); --marker-set without an .osim is one line, exit 2, nothing written."""
    from pathlib import Path

    g = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "gait2392"
    if not (g / "gait2392.osim").is_file():
        pytest.skip("../shared/data/real is not here")
    out = tmp_path / "s"
    assert main(["simulate", "--out", str(out), "--model", str(g / "gait2392.osim"), "--marker-set",
                 str(g / "gait2392_Scale_MarkerSet.xml"), "--frames", "30", "--seed", "1"]) == 0
    trial = read_c3d(out / "trial.c3d")
    assert {"R.ASIS", "R.Heel", "R.Knee.Lat"} <= set(trial.labels)
    assert {"hip_flexion_r", "knee_angle_r", "lumbar_extension"} <= set(read_motion_csv(out / "truth_motion.csv")
                                                                        .dof_names)
    capsys.readouterr()
    bad = tmp_path / "b"
    assert main(["simulate", "--out", str(bad), "--marker-set", str(g / "gait2392_Scale_MarkerSet.xml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--marker-set adds markers to an OpenSim model" in err[0] and not bad.exists()


def test_a_stature_for_a_model_without_a_neck_by_its_legs(human, tmp_path):
    """A model that is not calibrate.model.human-style (an OpenSim model: no neck joint, no head segment, y up) takes
    a stature by its legs: the hips' height above the ankles over Drillis and Contini's 0.491 of the stature.  On
    models/human.urdf the rule gives its generator's 1.75 m within 5 mm; Rajagopal2016 simulated at --height 1.6 has
    that stature; a model without legs is refused in one line."""
    from pathlib import Path

    from calibrate.errors import ModelError
    from calibrate.simulation.subject import _leg_stature, stature

    assert abs(_leg_stature(human, human.parameters()) - 1.75) < 0.005
    assert abs(stature(human, human.parameters()) - 1.75) < 1e-6
    raj = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "rajagopal_walk" / "Rajagopal2016.osim"
    if not raj.is_file():
        pytest.skip("../shared/data/real is not here")
    model = load_model(raj)
    sim = simulate_squats(model, frames=20, seed=1, height=1.6)
    assert abs(stature(model, sim.truth) - 1.6) < 1e-9
    from tests.test_osim_fold import shoulder_osim

    path = tmp_path / "arm.osim"
    path.write_text(shoulder_osim())
    arm = load_model(path)
    with pytest.raises(ModelError, match="two hips and two ankles"):
        stature(arm, arm.parameters())
    assert main(["simulate", "--out", str(tmp_path / "a"), "--model", str(path), "--height", "1.7"]) == 2
    assert not (tmp_path / "a").exists()
