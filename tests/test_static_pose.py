"""Calibration.static_asymmetry: in a static trial a subject holds each left hinge within a few degrees of its
right partner; a pair further apart than STATIC_ASYMMETRY_DEG is flagged in the report and the summary."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.result import STATIC_ASYMMETRY_DEG, static_hinges, static_trials
from calibrate.io.trial import Trial
from calibrate.model.blocks import FrameLayout
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model
from calibrate.simulation.simulate import simulate_squats


@pytest.fixture(scope="module")
def human():
    return load_model(Path(__file__).resolve().parents[1] / "models" / "human.urdf")


def _static(model, kin, sim, degrees: dict[str, float], frames: int = 80, seed: int = 0) -> Trial:
    """The simulated subject standing still in one pose (coordinates in degrees, the rest zero), 1 mm noise."""
    angles = np.zeros((frames, model.n_dofs))
    for name, value in degrees.items():
        angles[:, model.dof_index(name)] = math.radians(value)
    Z = FrameLayout.coordinates(np.zeros((frames, 3)), angles)
    quat = np.tile(sim.motion.root_quaternion[0], (frames, 1))
    markers, _ = kin.batch(Z, quat, sim.truth)
    markers = markers + sim.motion.root_translation[0]
    markers = markers + np.random.default_rng(seed).normal(0.0, 0.001, markers.shape)
    return Trial(model.marker_names, markers, 100.0, 0, f"static{seed}")


def test_a_static_trial_whose_left_ankle_is_turned_is_flagged(human):
    kin = build_kinematics(human)
    sim = simulate_squats(human, frames=150, noise_mm=1.0, seed=31)
    pose = {"hip_l_flexion": 10.0, "hip_r_flexion": 10.0, "knee_l": 20.0, "knee_r": 20.0,
            "elbow_l": 30.0, "elbow_r": 30.0}
    even = _static(human, kin, sim, pose, seed=1)
    turned = _static(human, kin, sim, {**pose, "ankle_l": -35.0}, seed=2)  # the left foot turned 35 deg
    cal = calibrate(human, [sim.trial, even, turned], kinematics=kin)
    assert static_trials(cal.model, cal.motions) == [1, 2]  # the squats move: not static
    hinges = {(h.trial, h.joint): h for h in static_hinges(cal.model, cal.motions)}
    assert {"knee", "ankle", "subtalar", "elbow", "radioulnar"} <= {j for _, j in hinges}
    # signed alike on both sides: the symmetric pose's knees and elbows (20 and 30 deg) agree, and are those angles
    for j, value in (("knee", 20.0), ("elbow", 30.0)):
        h = hinges[(1, j)]
        assert math.degrees(h.difference) < 3.0
        assert math.degrees(h.left_angle) == pytest.approx(value, abs=4.0)
    # the turn shows, to the few degrees a foot on two markers is known to (the even trial's ankles: 4 apart)
    assert math.degrees(hinges[(2, "ankle")].difference) == pytest.approx(35.0, abs=6.0)
    assert math.degrees(hinges[(1, "ankle")].difference) < 10.0
    assert max(math.degrees(h.difference) for (t, _), h in hinges.items() if t == 1) < STATIC_ASYMMETRY_DEG
    flagged = cal.static_asymmetry
    assert [(h.trial, h.joint) for h in flagged] == [(2, "ankle")]
    report = cal.report()["static_pose"]
    assert report["trials"] == ["static1", "static2"]
    assert [(f["trial"], f["joint"]) for f in report["flagged"]] == [("static2", "ankle")]
    assert "implausible  static2 (static): ankle_l" in cal.text()
    # the feet carry HEE and TOE only: the line says how to hold the subtalars; locked, it does not
    assert "--lock subtalar_l,subtalar_r holds them at 0" in cal.text()
    assert cal.report()["static_pose"]["advice"].startswith("the feet carry two markers each")
    held = replace(cal, settings=replace(cal.settings, lock=(("subtalar_l", 0.0), ("subtalar_r", 0.0))))
    assert "implausible  static2 (static): ankle_l" in held.text() and "--lock subtalar" not in held.text()


def test_a_pair_held_on_one_side_only_names_both_for_hold_axes(human):
    """A flagged static pair whose axis is held on one side only (Expert1's forearms: radioulnar_l held for its narrow
    turn, radioulnar_r free, 113 deg apart) gets the line's hint to hold both; held alike, no hint."""
    from calibrate.problem.settings import Settings

    kin = build_kinematics(human)
    sim = simulate_squats(human, frames=150, noise_mm=1.0, seed=31)
    pose = {"elbow_l": 30.0, "elbow_r": 30.0}
    static = _static(human, kin, sim, {**pose, "radioulnar_l": 60.0}, seed=3)  # the left forearm turned 60 deg
    cal = calibrate(human, [sim.trial, static], Settings(hold_axes=("radioulnar_l",)), kinematics=kin)
    flagged = {h.joint: h for h in cal.static_asymmetry}
    # (the forearm's frames are placed by their markers' priors: the turn reads some 10 deg short of the truth's 60)
    assert "radioulnar" in flagged and math.degrees(flagged["radioulnar"].difference) == pytest.approx(60.0, abs=15.0)
    hint = "radioulnar_l's axis held, radioulnar_r's free: held on one side only"
    assert hint in cal.text() and "--hold-axes radioulnar_l,radioulnar_r holds both" in cal.text()
    assert hint in cal.report()["static_pose"]["advice"]
    from calibrate.calibration.html import report_html

    page = report_html(cal.report())  # the advice once, after the flagged pairs
    assert page.count("held on one side only") == 1 and "implausible static poses: radioulnar_l" in page
    both = replace(cal, settings=replace(cal.settings, hold_axes=("radioulnar_l", "radioulnar_r")))
    assert "implausible  static3 (static): radioulnar_l" in both.text() and "held on one side only" not in both.text()
    locked = replace(cal, settings=replace(cal.settings, hold_axes=(), lock=(("radioulnar_r", 0.0),)))
    assert "radioulnar_r locked, radioulnar_l's axis free" in locked.text()


def test_a_walk_with_its_trunk_and_arms_locked_is_no_static(human):
    """A lower-body marker set locks the trunk and arms (20 of human.urdf's 32 coordinates held at 0 in every frame):
    its walk, whose legs turn through tens of degrees, is no static trial (c3d.org's sample09 Plug-in Gait walk had
    been called one, its knees "37 deg apart" flagged); a still trial with the same coordinates locked still is."""
    from calibrate.io.motion import Motion

    rng = np.random.default_rng(5)
    frames = 200
    legs = [d for d in human.dof_names if any(k in d for k in ("hip", "knee", "ankle", "subtalar"))]
    held = [d for d in human.dof_names if d not in legs]
    assert len(held) >= len(legs)  # the locked coordinates are the majority: their SD of 0 was the median
    phase = np.linspace(0.0, 4 * np.pi, frames)
    walk = np.zeros((frames, human.n_dofs))
    still = np.zeros((frames, human.n_dofs))
    for d in legs:
        k = human.dof_index(d)
        walk[:, k] = math.radians(20.0) * np.sin(phase + k)
        still[:, k] = math.radians(0.5) * rng.standard_normal(frames)
    root = np.zeros((frames, 3))
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (frames, 1))
    times = np.arange(frames) / 100.0
    motions = [Motion(times, root, quat, a, human.dof_names) for a in (walk, still)]
    assert static_trials(human, motions) == [1]
