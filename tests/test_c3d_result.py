"""A calibrated trial written as C3D (calibrate.calibration.c3d_result, write_c3d's model outputs): the file read
back by ezc3d (calibrate.io.c3d.read_c3d) against the trial, against Pinocchio's forward kinematics of the subject
URDF driven by the motion CSV the same run wrote, and against that CSV's angles."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from calibrate.cli import main
from calibrate.errors import TrialError
from calibrate.io.c3d import read_c3d, write_c3d
from calibrate.io.motion import read_motion_csv
from calibrate.io.trial import Trial
from calibrate.model.model import load_model
from calibrate.simulation.simulate import simulate_squats

FLOAT32_M = 2e-7  # m: float32 C3D storage in mm of positions within 3 m


def test_model_outputs_of_every_kind_read_back(tmp_path: Path) -> None:
    """write_c3d lists each model output in its kind's POINT parameter, in Vicon's units: read_c3d gives back the
    kinds, SI values and gaps; the markers' descriptions come back too; an output with a marker's label is refused."""
    rng = np.random.default_rng(4)
    frames = 25
    markers = rng.uniform(-1.5, 1.5, size=(frames, 3, 3))
    markers[3, 1] = np.nan
    outputs = {"hip_r_JC": rng.uniform(-1, 1, (frames, 3)), "knee_r_angles": rng.uniform(-3, 3, (frames, 3)),
               "LKneeForce": rng.uniform(-900, 900, (frames, 3)), "LKneeMoment": rng.uniform(-80, 80, (frames, 3)),
               "LKneePower": rng.uniform(-200, 200, (frames, 3))}
    outputs["hip_r_JC"][7] = np.nan
    outputs["knee_r_angles"][9] = np.nan
    kinds = {"hip_r_JC": "point", "knee_r_angles": "angle", "LKneeForce": "force", "LKneeMoment": "moment",
             "LKneePower": "power"}
    trial = Trial(("RASI", "LASI", "SACR"), markers, 120.0, first_frame=3, model_outputs=outputs, output_kinds=kinds,
                  descriptions={"RASI": "right anterior superior iliac spine"})
    write_c3d(tmp_path / "t.c3d", trial)
    back = read_c3d(tmp_path / "t.c3d")
    assert back.labels == trial.labels and back.first_frame == 3 and back.descriptions == trial.descriptions
    np.testing.assert_allclose(back.markers, markers, atol=FLOAT32_M, equal_nan=True)
    assert back.output_kinds == kinds
    assert back.output_units == {"hip_r_JC": "m", "knee_r_angles": "rad", "LKneeForce": "N", "LKneeMoment": "N m",
                                 "LKneePower": "W"}
    for label, values in outputs.items():
        np.testing.assert_array_equal(np.isnan(back.model_outputs[label]), np.isnan(values))
        np.testing.assert_allclose(back.model_outputs[label], values, rtol=1e-6, atol=FLOAT32_M, equal_nan=True)
    clash = Trial(trial.labels, markers, 120.0, model_outputs={"RASI": outputs["hip_r_JC"]})
    with pytest.raises(TrialError, match="model output 'RASI' has a marker's label"):
        write_c3d(tmp_path / "u.c3d", clash)


def assert_as_pinocchio_puts_them(c3d: Path, urdf: Path, motion_csv: Path, trial: Trial) -> None:
    """The C3D holds `trial`'s markers as recorded, every joint centre and model marker where Pinocchio puts them
    for `urdf` driven by `motion_csv` (to float32 storage), each joint's angles as the CSV's coordinates."""
    out = read_c3d(c3d)
    assert out.labels == trial.labels
    np.testing.assert_allclose(out.markers, trial.markers, atol=FLOAT32_M, equal_nan=True)
    subject = load_model(urdf)
    motion = read_motion_csv(motion_csv)
    assert motion.n_frames == out.n_frames
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    data = pm.createData()
    centres = {j.name: pm.getFrameId(j.urdf_joints[0]) for j in subject.joints}
    marks = {m: pm.getFrameId(m) for m in subject.marker_names}
    assert set(out.model_outputs) == ({f"{j}_JC" for j in centres} | {f"{m}_model" for m in marks}
                                      | {f"{j.name}_angles" for j in subject.joints if j.dofs})
    for f in range(0, motion.n_frames, 9):
        pin.framesForwardKinematics(pm, data, subject.pin_configuration(motion.root_translation[f],
                                                                       motion.root_quaternion[f], motion.angles[f]))
        for j, fid in centres.items():
            np.testing.assert_allclose(out.model_outputs[f"{j}_JC"][f], data.oMf[fid].translation, atol=FLOAT32_M)
        for m, fid in marks.items():
            np.testing.assert_allclose(out.model_outputs[f"{m}_model"][f], data.oMf[fid].translation, atol=FLOAT32_M)
    for j in subject.joints:
        if j.dofs:
            got = out.model_outputs[f"{j.name}_angles"][:, :len(j.dofs)]
            want = np.column_stack([motion.angles[:, subject.dof_index(d)] for d in j.dofs])
            np.testing.assert_allclose(got, want, atol=1e-6)
            assert out.output_kinds[f"{j.name}_angles"] == "angle"


def test_calibrated_c3d_against_pinocchio(human, tmp_path: Path, capsys) -> None:  # noqa: ANN001
    """`calibrate TRIAL MODEL --c3d` writes TRIAL_calibrated.c3d (named in the report), and `calibrate ik TRIAL
    SUBJECT --c3d` likewise: each as Pinocchio and the run's own motion CSV put the subject."""
    sim = simulate_squats(human, frames=100, noise_mm=1.0, seed=5)
    write_c3d(tmp_path / "squat.c3d", sim.trial)
    assert main([str(tmp_path / "squat.c3d"), str(human.path), "--c3d", "-q"]) == 0, capsys.readouterr().err
    report = json.loads((tmp_path / "squat_report.json").read_text())
    assert report["outputs"]["c3d"] == [str(tmp_path / "squat_calibrated.c3d")]
    assert_as_pinocchio_puts_them(tmp_path / "squat_calibrated.c3d", tmp_path / "squat.urdf",
                                  tmp_path / "squat_motion.csv", sim.trial)
    (tmp_path / "ik").mkdir()
    assert main(["ik", str(tmp_path / "squat.c3d"), str(tmp_path / "squat.urdf"), "--out", str(tmp_path / "ik"),
                 "--c3d", "-q"]) == 0, capsys.readouterr().err
    assert_as_pinocchio_puts_them(tmp_path / "ik" / "squat_calibrated.c3d", tmp_path / "squat.urdf",
                                  tmp_path / "ik" / "squat_motion.csv", sim.trial)


def test_calibrated_c3d_refused_before_the_work_for_a_trial_past_its_frames(human, tmp_path: Path,
                                                                            capsys) -> None:  # noqa: ANN001
    """A C3D holds 65 535 frames: --c3d with a longer trial is refused in one line before calibrating."""
    rng = np.random.default_rng(0)
    base = rng.uniform(-1, 1, size=(1, 3, 3))
    trial = Trial(human.marker_names[:3], np.repeat(base, 65536, axis=0), 100.0)
    from calibrate.io.trc import write_trc

    write_trc(tmp_path / "long.trc", trial)
    assert main([str(tmp_path / "long.trc"), str(human.path), "--c3d", "-q"]) == 2
    err = capsys.readouterr().err
    assert "long.trc: more frames than a C3D file holds (65535); leave out --c3d" in err and err.count("\n") == 1
    assert not (tmp_path / "long.urdf").exists()
