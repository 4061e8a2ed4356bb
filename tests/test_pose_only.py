"""A pose-only fit (`free = []`, `--free ""`): inverse kinematics with the base model held fixed.

The global solver's poses are checked against the frame-wise inverse kinematics of calibrate.solve.ik
(a separate solver) and, through the written files, against Pinocchio's forward kinematics."""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

from calibrate.calibration.pipeline import calibrate
from calibrate.cli import main
from calibrate.io.c3d import write_c3d
from calibrate.io.config import load_settings
from calibrate.io.motion import read_motion_csv
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model, write_model
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import inverse_kinematics, marker_columns


@pytest.fixture(scope="module")
def truth_case(human, tmp_path_factory):
    """A 150-frame squat and its true subject written as a URDF (the base model of the fit)."""
    sim = simulate_squats(human, frames=150, noise_mm=1.0, seed=4)
    d = tmp_path_factory.mktemp("pose_only")
    write_model(human, d / "truth.urdf", sim.truth)
    write_c3d(d / "trial.c3d", sim.trial)
    return sim, load_model(d / "truth.urdf"), d


def test_free_nothing_gives_the_frame_wise_inverse_kinematics(truth_case, tmp_path):
    """free = [] (read from a config file, as a user would write it): the geometry stays the base
    model's to the bit and every frame's pose is the one calibrate.solve.ik finds frame by frame."""
    sim, truth, _ = truth_case
    (tmp_path / "c.toml").write_text("free = []\n")
    settings = load_settings(tmp_path / "c.toml")
    assert settings.free == ()
    cal = calibrate(truth, sim.trial, settings)
    assert cal.converged
    assert np.array_equal(cal.params.vector(), truth.parameters().vector())
    assert all(c.note == "held (not free)" for c in cal.changes)
    ik = inverse_kinematics(build_kinematics(truth), sim.trial, truth.parameters())
    # Both minimise the same per-frame sum of squares (the truth's motion stays inside the joint
    # limits, so neither limit penalty is active); they stop at their own tolerances, 1e-8 relative
    # cost (ik) and ftol on the whole trial: 1e-3 deg and 1e-3 mm are ~1000x what separates the
    # two today (1.5e-5 deg) and ~100x below a wrong pose (a frame one LM step short of converging
    # moves angles by 0.1 deg or more).
    assert np.abs(np.degrees(cal.motion.angles - ik.motion.angles)).max() < 1e-3
    assert np.abs(cal.motion.root_translation - ik.motion.root_translation).max() < 1e-6
    dots = np.abs(np.sum(cal.motion.root_quaternion * ik.motion.root_quaternion, axis=1))
    assert np.degrees(2 * np.arccos(np.clip(dots, -1, 1))).max() < 1e-3
    frame_rms = np.sqrt(np.nanmean(np.sum(cal.residuals**2, axis=2), axis=1))
    assert np.allclose(frame_rms, ik.marker_rms, rtol=1e-6, atol=0)
    # The truth model refitted: the marker RMS is the simulated noise (1 mm per coordinate, so
    # sqrt(3) mm in 3-D, minus the 6 + 32 coordinates' share of the 39 x 3 observations).
    assert 1.2e-3 < cal.marker_rms < 1.7e-3


def test_cli_free_empty_with_the_base_model(truth_case, tmp_path, human, capsys):
    """`--free ""` on the base model (not the subject's): exit 0, the written URDF is the base model's
    geometry, and the written motion drives Pinocchio's forward kinematics of that URDF to markers
    whose RMS error is the report's."""
    _, _, d = truth_case
    out = tmp_path / "s.urdf"
    code = main([str(d / "trial.c3d"), str(human.path), "-o", str(out), "--motion", str(tmp_path / "s.csv"),
                 "--report", str(tmp_path / "s.json"), "--free", "", "-q"])
    assert code == 0, capsys.readouterr().err
    subject = load_model(out)
    assert np.allclose(subject.parameters().vector(), human.parameters().vector(), rtol=0, atol=1e-12)
    rep = json.loads((tmp_path / "s.json").read_text())
    assert rep["settings"]["free"] == [] and rep["solver"]["converged"] is True
    assert all(p["value"] == p["base"] for p in rep["parameters"])
    motion = read_motion_csv(tmp_path / "s.csv")
    pm, data = subject.pin, subject.pin.createData()
    fids = [pm.getFrameId(n) for n in subject.marker_names]
    from calibrate.io.read import read_trial

    obs = marker_columns(subject, read_trial(d / "trial.c3d"))
    sq = []
    for f in range(len(motion.times)):
        q = subject.pin_configuration(motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        pin.framesForwardKinematics(pm, data, q)
        pos = np.array([data.oMf[i].translation for i in fids])
        sq.append(np.sum((pos - obs[f]) ** 2, axis=1))
    rms = float(np.sqrt(np.nanmean(sq)))
    # The base model is not the subject (segments up to 10 % off): the fit is tens of mm off,
    # and Pinocchio must agree with the report to the CSV's and report's rounding (1e-4 relative).
    assert rms > 0.01
    assert rms == pytest.approx(rep["markers"]["rms_mm"] / 1000, rel=1e-4)
