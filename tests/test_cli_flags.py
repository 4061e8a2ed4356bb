"""The calibrate command's flags, each checked by its effect on the files it writes (read back by
Pinocchio, yourdfpy and the CSV/JSON readers), on short simulated trials; the report's figures
against the written URDF; a lower-body marker set; a TRC file end to end; all-or-nothing writing."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy

from calibrate.calibration.evaluate import compare_to_truth
from calibrate.calibration.pipeline import calibrate
from calibrate.cli import main
from calibrate.errors import CalibrateError
from calibrate.io.c3d import write_c3d
from calibrate.io.labels import map_labels
from calibrate.io.motion import read_motion_csv
from calibrate.io.read import read_trial
from calibrate.io.trial import Trial
from calibrate.model.model import load_model
from calibrate.seed.joints import estimate_model_joints
from calibrate.simulation.simulate import simulate_squats, simulate_static, write_simulation

FRAMES = 150
# Hips from 150 frames: 0.9 and 3.2 mm today with every default (world centres, medians over frames).
# 5 mm (the worst-ball target of issue 4): a flag that breaks the fit (spikes followed, a unit slip)
# puts them a centimetre or more off.
HIP_MM = 5.0


# ---------------------------------------------------------------------- helpers
def run(capsys, *args) -> tuple[int, str, str]:
    """`calibrate ARGS -q` in this process: (exit status, stdout, stderr)."""
    code = main([str(a) for a in args] + ["-q"])
    out, err = capsys.readouterr()
    return code, out, err


def outputs(d: Path, name: str) -> list:
    """-o/--motion/--report for outputs NAME.* in d."""
    return ["-o", d / f"{name}.urdf", "--motion", d / f"{name}.csv", "--report", d / f"{name}.json"]


def world_joints(urdf: Path, motion_csv: Path, joints: list[str]) -> dict[str, np.ndarray]:
    """(F, 3) world position of each named URDF joint, by Pinocchio's forward kinematics of `urdf`
    driven by `motion_csv`."""
    model = load_model(urdf)
    m = read_motion_csv(motion_csv)
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    data = pm.createData()
    ids = {j: pm.getJointId(j) for j in joints}
    out = {j: np.zeros((len(m.times), 3)) for j in joints}
    for f in range(len(m.times)):
        pin.forwardKinematics(pm, data, model.pin_configuration(m.root_translation[f], m.root_quaternion[f],
                                                                m.angles[f]))
        for j, i in ids.items():
            out[j][f] = data.oMi[i].translation
    return out


def ball_errors_mm(urdf: Path, motion_csv: Path, sim_dir: Path, joints=("hip_l", "hip_r")) -> dict[str, float]:
    """Median distance (mm) between the calibrated and the true world centre of each ball joint
    (its first URDF joint), calibrated from `urdf` + `motion_csv`, truth from the simulation."""
    urdf_names = [f"{j}_flexion" for j in joints]
    est = world_joints(urdf, motion_csv, urdf_names)
    true = world_joints(sim_dir / "truth.urdf", sim_dir / "truth_motion.csv", urdf_names)
    return {j: 1000 * float(np.median(np.linalg.norm(est[u] - true[u], axis=1)))
            for j, u in zip(joints, urdf_names, strict=True)}


@pytest.fixture(scope="module")
def squat(human, tmp_path_factory):
    """A 150-frame squat written as the simulator writes it: trial.c3d, truth.urdf, truth_motion.csv."""
    d = tmp_path_factory.mktemp("squat")
    sim = simulate_squats(human, frames=FRAMES, noise_mm=1.0, seed=3)
    write_simulation(sim, d)
    return sim, d


@pytest.fixture(scope="module")
def spiky(human, squat, tmp_path_factory):
    """The same squat with 1 % of marker positions thrown 20-50 mm (spikes); their (frame, marker)."""
    sim, sim_dir = squat
    d = tmp_path_factory.mktemp("spiky")
    rng = np.random.default_rng(1)
    mk = np.array(sim.trial.markers)
    F, N = mk.shape[:2]
    hits = sorted({(int(f), int(k)) for f, k in zip(rng.integers(0, F, 60), rng.integers(0, N, 60), strict=True)})
    for f, k in hits:
        v = rng.normal(size=3)
        mk[f, k] += rng.uniform(0.02, 0.05) * v / np.linalg.norm(v)
    write_c3d(d / "spiky.c3d", Trial(sim.trial.labels, mk, sim.trial.rate))
    return d, hits


@pytest.fixture(scope="module")
def default_run(human, squat, tmp_path_factory):
    """`calibrate trial.c3d human.urdf` with every default; its outputs' directory."""
    _, sim_dir = squat
    d = tmp_path_factory.mktemp("default")
    code = main([str(sim_dir / "trial.c3d"), str(human.path), *map(str, outputs(d, "s")), "-q"])
    assert code == 0
    return d


# ---------------------------------------------------------------------- the report against the URDF
def test_report_values_are_the_written_urdfs(human, squat, default_run):
    """parameters[].value and .base (mm, unit axes with changes in degrees, scales) are what the
    subject and base URDFs hold (read by yourdfpy), `unidentified` lists exactly the parameters
    flagged, per-marker figures are Pinocchio's, and `outputs` names the files written."""
    sim, sim_dir = squat
    d = default_run
    rep = json.loads((d / "s.json").read_text())
    subj = yourdfpy.URDF.load(str(d / "s.urdf"), build_scene_graph=False, load_meshes=False)
    base = yourdfpy.URDF.load(str(human.path), build_scene_graph=False, load_meshes=False)
    first_urdf_joint = {j.name: j.urdf_joints[0] for j in human.joints}
    seen = set()
    for p in rep["parameters"]:
        group, name = p["group"], p["name"][len(p["group"]) + 1:-1]
        seen.add(group)
        if group in ("centre", "marker"):
            assert p["unit"] == "mm"
            uj = first_urdf_joint[name] if group == "centre" else f"{name}_marker"
            # Values are rounded to 1e-6 mm in the report.
            np.testing.assert_allclose(p["value"], 1000 * subj.joint_map[uj].origin[:3, 3], rtol=0, atol=2e-6)
            np.testing.assert_allclose(p["base"], 1000 * base.joint_map[uj].origin[:3, 3], rtol=0, atol=2e-6)
            assert p["change"] == pytest.approx(np.linalg.norm(np.subtract(p["value"], p["base"])), abs=1e-5)
        elif group == "axis":
            assert p["unit"] == "deg"
            a = subj.joint_map[name].axis / np.linalg.norm(subj.joint_map[name].axis)
            a0 = base.joint_map[name].axis / np.linalg.norm(base.joint_map[name].axis)
            np.testing.assert_allclose(p["value"], a, atol=2e-9)
            np.testing.assert_allclose(p["base"], a0, atol=2e-9)
            assert p["change"] == pytest.approx(math.degrees(math.acos(min(1.0, abs(a @ a0)))), abs=1e-5)
        elif group == "scale":
            # The URDF keeps no scale, but a segment's inertia scales with s² (mass kept).
            s = p["value"][0]
            link, link0 = subj.link_map[name], base.link_map[name]
            if link0.inertial is not None and link0.inertial.mass > 0:
                np.testing.assert_allclose(link.inertial.inertia, s**2 * link0.inertial.inertia, rtol=1e-6,
                                           atol=1e-12)
                assert link.inertial.mass == pytest.approx(link0.inertial.mass, rel=1e-12)
    assert seen == {"centre", "axis", "marker", "scale"}
    assert rep["unidentified"] == [p["name"] for p in rep["parameters"] if not p["identified"]]
    # A hinge's centre is a gauge along its axis: never identified (docs/calibration.md).
    assert {"centre[knee_r]", "centre[elbow_l]"} <= set(rep["unidentified"])
    assert {"centre[hip_r]", "axis[knee_r]"}.isdisjoint(rep["unidentified"])
    assert rep["outputs"] == {"urdf": str(d / "s.urdf"), "report": str(d / "s.json"), "motion": [str(d / "s.csv")]}
    # Per marker: frames seen (from the trial file) and RMS / max error by Pinocchio.
    subject = load_model(d / "s.urdf")
    motion = read_motion_csv(d / "s.csv")
    trial = read_trial(sim_dir / "trial.c3d")
    pm, data = subject.pin, subject.pin.createData()
    fids = [pm.getFrameId(n) for n in subject.marker_names]
    idx = [trial.labels.index(n) for n in subject.marker_names]
    err = np.zeros((trial.n_frames, len(idx)))
    for f in range(trial.n_frames):
        pin.framesForwardKinematics(pm, data, subject.pin_configuration(motion.root_translation[f],
                                                                        motion.root_quaternion[f], motion.angles[f]))
        err[f] = np.linalg.norm(np.array([data.oMf[i].translation for i in fids]) - trial.markers[f, idx], axis=1)
    for k, n in enumerate(subject.marker_names):
        per = rep["markers"]["per_marker"][n]
        assert per["frames"] == trial.n_frames
        assert per["rms_mm"] == pytest.approx(1000 * np.sqrt(np.mean(err[:, k] ** 2)), rel=1e-6, abs=2e-6), n
        assert per["max_mm"] == pytest.approx(1000 * err[:, k].max(), rel=1e-6, abs=2e-6), n
    # The default run finds the hips (the yardstick the flag tests below compare with): 0.9 / 3.2 mm
    # on these 150 frames, as compare_to_truth has it (this is Pinocchio's count of the same).
    assert max(ball_errors_mm(d / "s.urdf", d / "s.csv", sim_dir).values()) < HIP_MM


# ---------------------------------------------------------------------- flags
def test_free_no_seed_and_lock_in_degrees(human, squat, tmp_path, capsys):
    """--free centre,marker: scales and axes stay the base model's (URDF inertias and axes), centres
    move.  --no-seed: started from the base model (report).  --lock subtalar_r=5,subtalar_l: those
    coordinates are 5 deg (0.0873 rad in the motion CSV) and 0 in every frame."""
    _, sim_dir = squat
    code, _, err = run(capsys, sim_dir / "trial.c3d", human.path, *outputs(tmp_path, "f"),
                       "--free", "centre,marker", "--no-seed", "--lock", "subtalar_r=5,subtalar_l")
    assert code == 0, err
    rep = json.loads((tmp_path / "f.json").read_text())
    assert rep["settings"]["free"] == ["centre", "marker"]
    assert rep["settings"]["segment_frames"] == "priors"  # a URDF's default: where the priors hold the geometry least
    assert {p["group"] for p in rep["parameters"] if "not free" not in p.get("note", "")} == {"centre", "marker"}
    subject = load_model(tmp_path / "f.urdf")
    P, B = subject.parameters(), human.parameters()
    np.testing.assert_allclose(P.axis, B.axis, atol=1e-12)
    subj = yourdfpy.URDF.load(str(tmp_path / "f.urdf"), build_scene_graph=False, load_meshes=False)
    base = yourdfpy.URDF.load(str(human.path), build_scene_graph=False, load_meshes=False)
    np.testing.assert_allclose(subj.link_map["femur_r"].inertial.inertia, base.link_map["femur_r"].inertial.inertia,
                               rtol=1e-12)  # scale 1: inertia unchanged
    assert np.linalg.norm(P.centre - B.centre, axis=1).max() > 0.005  # the hips etc. moved
    # --no-seed
    assert rep["settings"]["seed"] is False and rep["seed"]["joints"] == {}
    assert rep["seed"]["notes"] == ["seed switched off; starting from the base model"]
    # --lock: degrees on the command line, radians in the motion CSV.
    m = read_motion_csv(tmp_path / "f.csv")
    assert rep["settings"]["lock_deg"] == {"subtalar_l": 0.0, "subtalar_r": 5.0}
    r, left = m.angles[:, human.dof_index("subtalar_r")], m.angles[:, human.dof_index("subtalar_l")]
    # LOCK_WEIGHT holds them against the data's pull to a few micro-radians.
    assert np.abs(r - math.radians(5)).max() < 1e-4 and np.abs(left).max() < 1e-4
    assert np.ptp(m.angles[:, human.dof_index("ankle_r")]) > 0.1  # the others still move


def test_robust_loss_without_outlier_rejection(human, squat, spiky, tmp_path, capsys):
    """--loss cauchy --outlier-sigmas 0: nothing rejected, and the loss alone takes the worst hip
    centre error under 0.8x plain least squares' on the same spiky trial (measured: 7.8 mm against
    11.1 mm with the learnt noise; the default, rejection, gives 5.1 mm) and under 2 HIP_MM."""
    _, sim_dir = squat
    d, hits = spiky
    worst = {}
    for loss in ("cauchy", "linear"):
        code, _, err = run(capsys, d / "spiky.c3d", human.path, *outputs(tmp_path, loss), "--loss", loss,
                           "--outlier-sigmas", "0")
        assert code == 0, err
        rep = json.loads((tmp_path / f"{loss}.json").read_text())
        assert rep["settings"]["loss"] == loss and rep["settings"]["outlier_sigmas"] == 0
        assert rep["outliers"]["count"] == 0
        worst[loss] = max(ball_errors_mm(tmp_path / f"{loss}.urdf", tmp_path / f"{loss}.csv", sim_dir).values())
    assert worst["cauchy"] < 0.8 * worst["linear"] and worst["cauchy"] < 2 * HIP_MM, worst


def test_outlier_sigmas_threshold(human, spiky, tmp_path, capsys):
    """--outlier-sigmas 3: every spike is rejected, and more (3 noise SDs cuts into the noise's own
    tail: a 3-D error beyond 3 SDs has probability 3 % at one SD per coordinate), each beyond 3 SDs of
    its marker's learnt noise (the report's noise.per_marker_mm; measured: 3.10 at the least)."""
    d, hits = spiky
    code, _, err = run(capsys, d / "spiky.c3d", human.path, *outputs(tmp_path, "o"), "--outlier-sigmas", "3")
    assert code == 0, err
    rep = json.loads((tmp_path / "o.json").read_text())
    assert rep["settings"]["outlier_sigmas"] == 3 and rep["outliers"]["threshold_noise_sd"] == 3
    names = read_trial(d / "spiky.c3d").labels
    got = {(o["frame"], names.index(o["marker"])) for o in rep["outliers"]["rejected"]}
    assert len(set(hits) & got) >= 0.95 * len(hits)
    assert rep["outliers"]["count"] > len(hits)
    noise = rep["noise"]["per_marker_mm"]
    assert min(o["error_mm"] / noise[o["marker"]] for o in rep["outliers"]["rejected"]) > 3.0


def test_neutral_static_trial(human, squat, tmp_path, capsys):
    """--neutral 2 with the static trial second: that trial's hinge angles (its motion CSV) are zero
    on average."""
    sim, sim_dir = squat
    static = simulate_static(human, sim.truth, frames=60, seed=7)
    write_c3d(tmp_path / "static.c3d", static.trial)
    code, _, err = run(capsys, sim_dir / "trial.c3d", tmp_path / "static.c3d", human.path, "-o",
                       tmp_path / "n.urdf", "--report", tmp_path / "n.json", "--neutral", "2")
    assert code == 0, err
    rep = json.loads((tmp_path / "n.json").read_text())
    assert rep["neutral_trial"] == str(tmp_path / "static.c3d")
    m = read_motion_csv(tmp_path / "static_motion.csv")
    hinges = [human.dof_index(j.dofs[0]) for j in human.joints if j.kind == "hinge"]
    # Without --neutral the segment frames sit where the priors put them: offsets of degrees
    # (test_real_trials.test_neutral_static_trial_sets_the_zero_of_the_joint_angles).
    assert np.abs(np.degrees(m.angles[:, hinges].mean(axis=0))).max() < 0.05
    code, _, err = run(capsys, tmp_path / "static.c3d", human.path, *outputs(tmp_path, "x"), "--neutral", "2")
    assert code == 2 and "--neutral 2: there are only 1 trials" in err


def test_a_subject_osim_needs_an_opensim_base_model(human, tmp_path, capsys):
    """-o NAME.osim from a URDF base model: one line, exit 2, nothing written (the .osim path with an OpenSim base:
    test_osim_import.test_cli_calibrates_from_osim)."""
    write_c3d(tmp_path / "s.c3d", simulate_squats(human, frames=5, seed=1).trial)
    code, _, err = run(capsys, tmp_path / "s.c3d", human.path, "-o", tmp_path / "subject.osim")
    assert code == 2 and "a subject .osim is written from an OpenSim base model" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.c3d"]


def test_neutral_first_trial_is_accepted(human, tmp_path, capsys):
    """--neutral 1 names the first trial (the help: '1 = the first'); here the only one."""
    from calibrate.cli import build_calibrate_parser

    args = build_calibrate_parser().parse_args([str(tmp_path / "static.c3d"), str(human.path), "--neutral", "1"])
    assert args.neutral == 1


def test_no_aliases_and_no_new_markers(human, squat, tmp_path, capsys):
    """A trial spelling RASI as 'R.ASIS' and carrying an extra shank marker RSHIN.  With --no-aliases
    'R.ASIS' is not renamed (the model's RASI goes unused), with --no-new-markers neither unknown
    label is placed: both ignored, the URDF has neither."""
    sim, _ = squat
    i, k = human.marker_index("RTIB"), human.marker_index("RANK")
    shin = sim.clean_markers[:, i] + 0.4 * (sim.clean_markers[:, k] - sim.clean_markers[:, i])
    stray = shin + np.cumsum(np.random.default_rng(3).normal(0, 0.002, shin.shape), axis=0)
    labels = tuple("R.ASIS" if lab == "RASI" else lab for lab in sim.trial.labels) + ("RSHIN", "*7", "LKNEin")
    trial = Trial(labels, np.concatenate([sim.trial.markers, shin[:, None], stray[:, None],
                                          np.full_like(shin[:, None], np.nan)], axis=1), sim.trial.rate)
    write_c3d(tmp_path / "t.c3d", trial)
    # With the aliases on, R.ASIS is RASI (no calibration needed to see that).
    _, mapping = map_labels(trial, human.marker_names)
    assert any(mp.trial_label == "R.ASIS" and mp.label == "RASI" for mp in mapping)
    code, _, err = run(capsys, tmp_path / "t.c3d", human.path, *outputs(tmp_path, "a"), "--no-aliases",
                       "--no-new-markers")
    assert code == 0, err
    rep = json.loads((tmp_path / "a.json").read_text())
    ms = rep["marker_set"]
    assert sorted(ms["ignored_labels"]) == ["*7", "LKNEin", "R.ASIS", "RSHIN"] and ms["new"] == []
    assert ms["unused_model_markers"] == ["RASI"]
    # Warned about: the two named labels as not the model's, the unlabelled trajectory (Vicon's '*7') as such; the
    # label with no position in any frame is not a warning (-q: not even a note).
    named = next(line for line in err.splitlines() if "trial labels are not markers of" in line)
    assert "R.ASIS" in named and "RSHIN" in named and "*7" not in named and "LKNEin" not in named
    assert "warning: 1 unlabelled trajectory ignored (*7); label them" in err
    assert "LKNEin" not in err
    subject = load_model(tmp_path / "a.urdf")
    assert "RSHIN" not in subject.marker_names and "R.ASIS" not in subject.marker_names
    assert rep["settings"]["new_markers"] is False
    # Without -q the empty label is a note of its own.
    assert main([str(tmp_path / "t.c3d"), str(human.path), *map(str, outputs(tmp_path, "b")), "--no-aliases",
                 "--no-new-markers"]) == 0
    assert "note: 1 trial label with no position in any frame, ignored: LKNEin" in capsys.readouterr().err


def test_no_auto_hold(human, human_kin, squat, tmp_path, capsys):
    """Forearms and wrists held still in every frame: by default their axes are held at the base
    model's (test_calibration.test_axes_of_still_coordinates_are_held_at_the_base_models);
    --no-auto-hold calibrates them all the same."""
    sim, _ = squat
    dofs = [d for d in human.dof_names if d.startswith(("radioulnar", "wrist"))]
    m = sim.motion
    ang = m.angles.copy()
    ang[:, [human.dof_index(d) for d in dofs]] = 0.0
    M, _ = human_kin.batch(np.column_stack([m.root_translation, np.zeros((FRAMES, 3)), ang]), m.root_quaternion,
                           sim.truth)
    noisy = M + np.random.default_rng(6).normal(scale=0.001, size=M.shape)
    write_c3d(tmp_path / "still.c3d", Trial(human.marker_names, noisy, sim.trial.rate))
    code, _, err = run(capsys, tmp_path / "still.c3d", human.path, *outputs(tmp_path, "h"), "--no-auto-hold")
    assert code == 0, err
    rep = json.loads((tmp_path / "h.json").read_text())
    assert rep["held_axes"] == [] and rep["settings"]["auto_hold"] is False
    names = {p["name"] for p in rep["parameters"]}
    assert {f"axis[{d}]" for d in dofs} <= names
    subject = load_model(tmp_path / "h.urdf")
    moved = [np.degrees(np.arccos(min(1.0, abs(subject.parameters().axis[human.dof_index(d)]
                                               @ human.parameters().axis[human.dof_index(d)])))) for d in dofs]
    assert max(moved) > 0.01  # not held at the base model's


def test_joints_cutoff_and_no_filter(human, squat, tmp_path, capsys):
    """calibrate joints --cutoff-hz 3 / --no-filter write what estimate_model_joints gives with that
    low-pass (3 Hz) or none, and the two differ."""
    _, sim_dir = squat
    trial = read_trial(sim_dir / "trial.c3d")
    cols = {}
    for flag, cutoff in ((["--cutoff-hz", "3"], 3.0), (["--no-filter"], None)):
        out = tmp_path / f"{cutoff}.csv"
        assert main(["joints", str(sim_dir / "trial.c3d"), str(human.path), "--out", str(out), *flag]) == 0
        text = capsys.readouterr().out
        assert ("low-passed at 3 Hz" if cutoff else "unfiltered") in text
        header = out.read_text().splitlines()[0].split(",")
        body = np.loadtxt(out, delimiter=",", skiprows=1)
        c = header.index("hip_r_x")
        est = estimate_model_joints(human, trial, cutoff_hz=cutoff)
        np.testing.assert_allclose(body[:, c:c + 3], est["hip_r"].centre, atol=2e-6)  # 1 µm resolution
        cols[cutoff] = body[:, c:c + 3]
    assert np.abs(cols[3.0] - cols[None]).max() > 1e-4


# ---------------------------------------------------------------------- marker sets and file formats
def test_lower_body_marker_set(human, squat):
    """Pelvis and leg markers only: the legs are calibrated (hips within HIP_MM, knee axes within 2 deg
    of the truth), the upper body's markers are listed as unused and its parameters flagged."""
    sim, _ = squat
    legs = {"pelvis", "femur_l", "femur_r", "tibia_l", "tibia_r", "calcn_l", "calcn_r", "talus_l", "talus_r"}
    keep = [m.name for m in human.markers if m.segment in legs]
    assert 12 <= len(keep) < len(human.markers)
    cal = calibrate(human, sim.trial.select(keep))
    assert cal.converged
    assert set(cal.unused_markers) == set(human.marker_names) - set(keep)
    cmp = compare_to_truth(cal, sim)
    # Hips 3.4 / 0.9 mm today (3.2 / 0.9 with the full marker set on these frames); knee axes
    # 0.6 / 1.0 deg with the full set: the legs keep their markers, so the same bounds.
    assert max(cmp.centre_error["hip_l"], cmp.centre_error["hip_r"]) < HIP_MM / 1000, cmp.centre_error
    assert max(cmp.axis_error_deg["knee_l"], cmp.axis_error_deg["knee_r"]) < 2.0, cmp.axis_error_deg
    by = {c.name: c for c in cal.changes}
    for name in ("centre[neck]", "centre[shoulder_r]", "centre[elbow_l]", "marker[RFIN]", "marker[C7]"):
        assert not by[name].identified, name
    assert by["centre[hip_r]"].identified
    assert 1000 * cal.marker_rms < 1.9


def _write_trc_by_hand(path: Path, trial: Trial) -> None:
    """An OpenSim-style TRC (tab-separated, mm), written here without calibrate's writers."""
    n, F = trial.n_markers, trial.n_frames
    lines = [f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
             "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
             f"{trial.rate:g}\t{trial.rate:g}\t{F}\t{n}\tmm\t{trial.rate:g}\t1\t{F}",
             "Frame#\tTime\t" + "\t\t\t".join(trial.labels) + "\t\t",
             "\t\t" + "\t".join(f"X{k + 1}\tY{k + 1}\tZ{k + 1}" for k in range(n)),
             ""]
    for f in range(F):
        xyz = "\t".join(f"{1000 * v:.5f}" for v in trial.markers[f].ravel())
        lines.append(f"{f + 1}\t{f / trial.rate:.5f}\t{xyz}")
    path.write_text("\n".join(lines) + "\n")


def test_trc_end_to_end(human, squat, tmp_path, capsys):
    """A TRC file (written by hand here) through the command line: the trial as the C3D's, and the
    hips within HIP_MM of the truth."""
    sim, sim_dir = squat
    _write_trc_by_hand(tmp_path / "walk.trc", sim.trial)
    back = read_trial(tmp_path / "walk.trc")
    assert back.labels == sim.trial.labels and back.rate == sim.trial.rate
    np.testing.assert_allclose(back.markers, sim.trial.markers, atol=1e-8)  # 1e-5 mm written
    code, out, err = run(capsys, tmp_path / "walk.trc", human.path)
    assert code == 0, err
    for name in ("walk.urdf", "walk_motion.csv", "walk_report.json"):
        assert (tmp_path / name).is_file()
    rep = json.loads((tmp_path / "walk_report.json").read_text())
    assert rep["trials"][0]["source"].endswith("walk.trc") and rep["trials"][0]["frames"] == FRAMES
    errs = ball_errors_mm(tmp_path / "walk.urdf", tmp_path / "walk_motion.csv", sim_dir)
    assert max(errs.values()) < HIP_MM, errs


def test_outputs_go_beside_the_output_urdf(human, squat, tmp_path, capsys):
    """With only -o given, the motion CSV and the report go beside the URDF it names (named by the
    trial), and nothing is written beside the trial (a lab's data folder may be shared or read-only)."""
    _, sim_dir = squat
    before = sorted(p.name for p in sim_dir.iterdir())
    code, out, err = run(capsys, sim_dir / "trial.c3d", human.path, "-o", tmp_path / "sub.urdf", "--frames", "0:60")
    assert code in (0, 1), err
    assert sorted(p.name for p in sim_dir.iterdir()) == before
    assert read_motion_csv(tmp_path / "trial_motion.csv").n_frames == 60
    assert json.loads((tmp_path / "trial_report.json").read_text())["trials"][0]["frames"] == 60
    assert load_model(tmp_path / "sub.urdf").nz == human.nz


def test_an_output_name_without_suffix_is_the_subject_urdf(human, squat, tmp_path, capsys):
    """-o out/subject02 names the subject: written subject02.urdf (not a file without a suffix), the motion and the
    report beside it."""
    _, sim_dir = squat
    code, out, err = run(capsys, sim_dir / "trial.c3d", human.path, "-o", tmp_path / "subject02", "--frames", "0:60")
    assert code in (0, 1), err
    assert not (tmp_path / "subject02").exists()
    assert load_model(tmp_path / "subject02.urdf").nz == human.nz
    assert (tmp_path / "trial_motion.csv").exists() and (tmp_path / "trial_report.json").exists()


def test_an_output_folder_takes_every_output(human, squat, tmp_path, capsys):
    """-o results/ (or an existing folder without the slash): the subject under the trial's name in it, the motion
    and the report beside it (it had written results.urdf beside the folder); a folder that is not there: one line,
    exit 2, nothing written."""
    _, sim_dir = squat
    folder = tmp_path / "results"
    folder.mkdir()
    for given in (f"{folder}/", folder):
        code, out, err = run(capsys, sim_dir / "trial.c3d", human.path, "-o", given, "--frames", "0:60", "--overwrite")
        assert code in (0, 1), err
        assert sorted(p.name for p in folder.iterdir()) == ["trial.urdf", "trial_motion.csv", "trial_report.json"]
        assert load_model(folder / "trial.urdf").nz == human.nz
        assert not (tmp_path / "results.urdf").exists()
    code, out, err = run(capsys, sim_dir / "trial.c3d", human.path, "-o", f"{tmp_path / 'missing'}/")
    assert code == 2 and err.count("\n") == 1 and "missing/: no such folder; create it first" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]


# ---------------------------------------------------------------------- all or nothing
@pytest.fixture(scope="module")
def small_cal(human, squat):
    sim, _ = squat
    return calibrate(human, sim.trial.frames(0, 100))


def test_failure_while_staging_leaves_nothing(small_cal, tmp_path, monkeypatch):
    """The disk fills while the report is staged (writing its staging file fails): the URDF and
    motion already staged are removed, no output exists, an old output is kept."""
    (tmp_path / "s.csv").write_text("old motion")
    real = Path.write_text

    def full_disk(self, *args, **kwargs):
        if self.name.startswith(".s.json."):  # the report's staging file
            raise OSError(28, "No space left on device")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full_disk)
    with pytest.raises(CalibrateError, match=r"could not be written \(No space left on device\); nothing was"):
        small_cal.write(urdf=tmp_path / "s.urdf", motion=tmp_path / "s.csv", report=tmp_path / "s.json",
                        overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv"]
    assert (tmp_path / "s.csv").read_text() == "old motion"


def test_failure_between_renames_leaves_nothing_half_renamed(small_cal, tmp_path, monkeypatch):
    """The rename of the second output fails: the staged files are removed, and either every output
    is in place or none (here none: the URDF must not be left renamed while the report is missing)."""
    real = os.replace

    def fail_second(src, dst):
        if Path(dst) == tmp_path / "s.json":
            raise OSError(28, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(os, "replace", fail_second)
    with pytest.raises(CalibrateError, match=r"could not be written \(No space left on device\); nothing was"):
        small_cal.write(urdf=tmp_path / "s.urdf", motion=tmp_path / "s.csv", report=tmp_path / "s.json")
    left = sorted(p.name for p in tmp_path.iterdir())
    assert not any(n.endswith(".part") for n in left), left  # staged files cleaned
    assert left == [], left


def test_failure_reports_a_calibrate_error_for_an_unwritable_target(small_cal, tmp_path):
    """A target directory that cannot take files (here: a path through a regular file) fails before
    anything is written, in one CalibrateError line."""
    (tmp_path / "file").write_text("x")
    with pytest.raises(CalibrateError, match="does not exist"):
        small_cal.write(urdf=tmp_path / "s.urdf", motion=tmp_path / "file" / "s.csv", report=tmp_path / "s.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_the_program_ends_at_once_after_a_calibration_with_its_exit_handlers_run(tmp_path):
    """`calibrate` (calibrate.cli.main.run) skips Python's teardown after a calibration: its summary is
    on stdout in full, the files are written, exit handlers registered before it still run, and the
    status is main's (0; 2 for bad input).  Under a profiler it ends as usual: the profile is written."""
    import subprocess
    import sys

    human_path = Path(__file__).resolve().parents[1] / "models" / "human.urdf"
    write_c3d(tmp_path / "t.c3d", simulate_squats(load_model(human_path), frames=40, noise_mm=1.0, seed=3).trial)
    prog = ("import atexit, sys; atexit.register(lambda: print('exit handler ran', flush=True)); "
            "from calibrate.cli.main import run; run()")

    def calibrate_cli(*args, before=()):
        return subprocess.run([sys.executable, *before, "-c", prog, *map(str, args)], capture_output=True,
                              text=True, cwd=tmp_path, timeout=300)

    r = calibrate_cli(tmp_path / "t.c3d", human_path, "-o", tmp_path / "s.urdf", "-q")
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and r.stdout.rstrip().endswith("exit handler ran")
    assert yourdfpy.URDF.load(str(tmp_path / "s.urdf"), load_meshes=False).robot.name
    assert len(read_motion_csv(tmp_path / "t_motion.csv").times) == 40
    bad = calibrate_cli(tmp_path / "missing.c3d", human_path, "-o", tmp_path / "x.urdf", "-q")
    assert bad.returncode == 2 and bad.stderr.startswith("calibrate: error:") and "exit handler ran" in bad.stdout
    # cProfile's own report comes after main() returns: under it the program must end as usual.
    prof = tmp_path / "p.prof"
    r = subprocess.run([sys.executable, "-m", "cProfile", "-o", str(prof), "-m", "calibrate.cli", tmp_path / "t.c3d",
                        human_path, "-o", tmp_path / "s2.urdf", "--overwrite", "-q"], capture_output=True, text=True,
                       cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    assert prof.stat().st_size > 0 and (tmp_path / "s2.urdf").exists()


def test_output_piped_into_a_reader_that_stops_ends_quietly(tmp_path):
    """`calibrate inspect MODEL | head`: the reader gone before calibrate writes, the program ends with 141 (128 +
    SIGPIPE, as Unix tools do) and no traceback on stderr."""
    import subprocess
    import sys

    model = Path(__file__).resolve().parents[1] / "models" / "human.urdf"
    proc = subprocess.Popen([sys.executable, "-c", "from calibrate.cli.main import run; run()", "inspect",
                             str(model)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # before the interpreter has even imported calibrate: every write finds no reader
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141 and "Traceback" not in err and "BrokenPipe" not in err, err


def test_the_calibration_help_names_every_command_and_both_model_formats(capsys):
    """`calibrate TRIAL MODEL --help` lists every command the program's parser registers (read from that parser's
    subcommands, not from a list kept beside it) and says MODEL may be an OpenSim .osim."""
    import argparse

    from calibrate.cli.main import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    with pytest.raises(SystemExit) as ended:
        main(["trial.c3d", "model.urdf", "--help"])
    assert ended.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    usage = text.split("Calibrate MODEL")[0]
    listed = usage[usage.index("{") + 1:usage.index("}")].split(",")
    others = text.split("Other commands:")[1].split("(see")[0].replace(",", " ").split()
    assert len(sub.choices) >= 11
    assert sorted(listed) == sorted(sub.choices) == sorted(others)
    assert ".osim" in text.split("positional arguments:")[1].split("options:")[0]


def test_the_readme_describes_every_option_of_the_calibration():
    """Every option `calibrate TRIAL MODEL` accepts (read from its parser) is named in the README's section on
    calibrating a subject, where a user looks them up."""
    from calibrate.cli.main import build_calibrate_parser

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    section = readme.split("## Calibrating a subject", 1)[1].split("\n## ", 1)[0]
    options = [s for a in build_calibrate_parser()._actions for s in a.option_strings
               if s.startswith("--") and s != "--help"]
    assert len(options) >= 30
    missing = [s for s in options if f"`{s}" not in section and f"{s} " not in section]
    assert missing == [], missing


def test_version_prints_the_versions_a_result_depends_on(capsys):
    """`calibrate --version`: one line, exit 0, calibrate's version and those of Python and the libraries, each as the
    library itself reports it (what a lab records beside a result; the report JSON's "software" holds the same)."""
    import sys

    import casadi
    import ezc3d
    import scipy

    import calibrate

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code in (0, None)
    out = capsys.readouterr().out
    assert out == (f"calibrate {calibrate.__version__} (Python {sys.version.split()[0]}; casadi {casadi.__version__}, "
                   f"pinocchio {pin.__version__}, ezc3d {ezc3d.__version__}, yourdfpy {yourdfpy.__version__}, "
                   f"numpy {np.__version__}, scipy {scipy.__version__})\n")
