"""Plug-in Gait's knee axes checked against the motion its own bones record (calibrate.calibration.plugin_gait):
bones built from a simulated subject's true hip, knee and ankle, the femur's lateral axis turned about the thigh by a
known angle, as a thigh wand turned on the thigh does."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.plugin_gait import MISALIGNED, bone_frames, knee_axis_checks
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.io.trial import Trial
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import hinge_lines_world, simulate_squats


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _turned(y: np.ndarray, z: np.ndarray, angle: float) -> np.ndarray:
    """y (normal to the unit z) turned about z by `angle`."""
    return y * math.cos(angle) + np.cross(z, y) * math.sin(angle)


def pig_bones(sim, femur_turn: float, tibia_turn: float = 0.0) -> dict[str, np.ndarray]:  # noqa: ANN001
    """Plug-in Gait's femur and tibia bones (O, A, L, P) of both legs from the simulation's truth: femur at the
    true knee centre, proximal towards the true hip, lateral along the true knee axis turned about the thigh by
    `femur_turn`; tibia at the true ankle centre, proximal towards the knee, lateral along the true ankle axis turned
    by `tibia_turn`."""
    lines = hinge_lines_world(sim.model, sim.truth, sim.motion)
    names = [j.name for j in sim.model.joints]
    out = {}
    for side, s in (("l", "L"), ("r", "R")):
        hip = sim.clean_centres[:, names.index(f"hip_{side}")]
        knee, knee_axis = lines[f"knee_{side}"]
        ankle, ankle_axis = lines[f"ankle_{side}"]
        for bone, origin, top, axis, turn in (("FE", knee, hip, knee_axis, femur_turn),
                                              ("TI", ankle, knee, ankle_axis, tibia_turn)):
            z = _unit(top - origin)
            y = _unit(axis - np.sum(axis * z, axis=1, keepdims=True) * z)
            y = _turned(y, z, turn)
            x = np.cross(y, z)
            out[s + bone + "O"], out[s + bone + "A"] = origin, origin + 0.1 * x
            out[s + bone + "L"], out[s + bone + "P"] = origin + 0.1 * y, top
    return out


def with_outputs(trial: Trial, outputs: dict[str, np.ndarray]) -> Trial:
    return Trial(trial.labels, trial.markers, trial.rate, model_outputs=outputs,
                 output_kinds={k: "point" for k in outputs}, output_units={k: "m" for k in outputs})


@pytest.fixture(scope="module")
def squats(human):  # noqa: ANN001
    return simulate_squats(human, frames=150, noise_mm=0.5, seed=3)


@pytest.mark.parametrize("turn_deg", [0.0, 30.0])
def test_the_femur_frames_turn_is_found_from_the_bones_alone(squats, turn_deg: float) -> None:
    """On the true subject and motion: Plug-in Gait's knee axis is the femur turn from the axis the tibia turns about
    (to the 2 deg the true knee axis leans out of the plane normal to the thigh), whatever the tibia frame's own
    twist; the true knee axis is that axis, and Plug-in Gait's knee centre (the true one) lies on its line."""
    sim = squats
    turn = math.radians(turn_deg)
    checks = knee_axis_checks(sim.model, sim.truth, [with_outputs(sim.trial, pig_bones(sim, turn))], [sim.motion])
    twisted = knee_axis_checks(sim.model, sim.truth, [with_outputs(sim.trial, pig_bones(sim, turn, math.radians(25)))],
                               [sim.motion])
    assert [c.joint for c in checks] == ["knee_l", "knee_r"]
    for c, t in zip(checks, twisted, strict=True):
        assert c.frames == sim.trial.n_frames and c.turn > math.radians(30)
        assert abs(math.degrees(c.pig) - turn_deg) < 2.5, (c.joint, math.degrees(c.pig))
        assert abs(t.pig - c.pig) < math.radians(0.1)
        assert math.degrees(c.ours) < 0.1 and c.centre < 1e-9
        assert c.misaligned == (turn > MISALIGNED) and c.varus is None


def test_too_few_frames_or_a_missing_bone_point_give_no_check(squats) -> None:
    sim = squats
    bones = pig_bones(sim, math.radians(30))
    short = sim.trial.frames(0, 8)
    few = with_outputs(short, {k: v[:8] for k, v in bones.items()})
    assert knee_axis_checks(sim.model, sim.truth, [few], [sim.motion]) == ()
    partial = with_outputs(sim.trial, {k: v for k, v in bones.items() if k != "LFEL"})
    assert bone_frames(partial, "LFE") is None
    assert [c.joint for c in knee_axis_checks(sim.model, sim.truth, [partial], [sim.motion])] == ["knee_r"]


def test_a_calibration_reports_a_turned_femur_frame_and_finds_the_knee_axis(squats) -> None:
    """calibrate on the squats with Plug-in Gait's femur frames turned 30 deg: the report and the summary name both
    knees, the calibrated axes within 1.5 deg of the axis the tibia turns about and Plug-in Gait's (true) knee centres
    within 2 mm of their lines; the file's knee varus-valgus angle range read from its KneeAngles output."""
    sim = squats
    bones = pig_bones(sim, math.radians(30))
    flexion = sim.motion.angles[:, sim.model.dof_names.index("knee_l")]
    angles = np.stack([flexion, 0.5 * flexion, np.zeros_like(flexion)], axis=1)
    t = sim.trial
    trial = Trial(t.labels, t.markers, t.rate, model_outputs={**bones, "LKneeAngles": angles},
                  output_kinds={**{k: "point" for k in bones}, "LKneeAngles": "angle"},
                  output_units={**{k: "m" for k in bones}, "LKneeAngles": "rad"})
    cal = calibrate(sim.model, trial, Settings(max_iterations=30))
    assert [c.joint for c in cal.knee_axes] == ["knee_l", "knee_r"]
    for c in cal.knee_axes:
        assert c.misaligned and abs(math.degrees(c.pig) - 30) < 2.5
        assert math.degrees(c.ours) < 1.5 and c.centre < 2e-3, (c.joint, math.degrees(c.ours), c.centre)
    half = 0.5 * (np.percentile(flexion, 95) - np.percentile(flexion, 5))
    assert cal.knee_axes[0].varus == pytest.approx(half) and cal.knee_axes[1].varus is None
    text = summary_text(cal)
    assert "plug-in gait" in text and "its knee_l axis is 30 deg from the axis its tibia turns about" in text
    report = calibration_report(cal)["plugin_gait_knees"]
    assert [r["joint"] for r in report] == ["knee_l", "knee_r"]
    assert report[0]["plugin_gait_axis_deg"] == pytest.approx(math.degrees(cal.knee_axes[0].pig))
    assert report[0]["varus_valgus_range_deg"] == pytest.approx(math.degrees(half)) and report[0]["misaligned"]


def test_inspect_checks_a_c3d_files_own_knee_axes(squats, tmp_path, capsys) -> None:
    """`calibrate inspect TRIAL.c3d` runs the check on the file alone (written as Nexus writes its bones, in mm):
    the femur frame turned 30 deg is named misaligned, one turned 5 deg is not."""
    from test_vicon_outputs import write_vicon_file

    from calibrate.cli import main

    sim = squats
    markers = {lab: 1000 * sim.trial.markers[:, k] for k, lab in enumerate(sim.trial.labels)}
    for turn, misaligned in ((30.0, True), (5.0, False)):
        bones = {k: 1000 * v for k, v in pig_bones(sim, math.radians(turn)).items()}
        path = tmp_path / f"turned{turn:g}.c3d"
        write_vicon_file(path, markers, bones, {}, {})
        assert main(["inspect", str(path)]) == 0
        out = capsys.readouterr().out
        for side in "lr":
            line = next(x for x in out.splitlines() if f"plug-in gait: its knee_{side} axis is" in x)
            got = float(line.split("axis is ")[1].split(" deg")[0])
            assert abs(got - turn) <= 2.5 and ("misaligned" in line) == misaligned, line


def test_turn_axis_is_scipys_rotation_mean_and_principal_direction() -> None:
    """turn_axis in numpy (scipy's import kept off a calibration's way) against the same steps in scipy's Rotation:
    the relative rotations, their mean, each one's rotation vector from it, their principal direction and span."""
    from scipy.spatial.transform import Rotation

    from calibrate.calibration.plugin_gait import turn_axis

    rng = np.random.default_rng(3)
    parent = Rotation.random(150, random_state=4).as_matrix()
    axis = np.array([0.2, 0.95, -0.25]) / np.linalg.norm([0.2, 0.95, -0.25])
    turn = Rotation.from_rotvec(np.radians(55.0) * np.sin(np.linspace(0.0, 9.0, 150))[:, None] * axis)
    child = np.einsum("fij,fjk->fik", parent, (turn * Rotation.from_rotvec(rng.normal(0, 0.03, (150, 3)))).as_matrix())
    got, span = turn_axis(parent, child)
    rel = Rotation.from_matrix(np.einsum("fji,fjk->fik", parent, child))
    v = (rel * rel.mean().inv()).as_rotvec()
    want = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)[2][0]
    s = v @ want
    assert abs(abs(got @ want) - 1.0) < 1e-12
    assert span == pytest.approx(np.percentile(s, 95) - np.percentile(s, 5), abs=1e-9)
    assert np.degrees(np.arccos(abs(got @ axis))) < 2.0  # and it is the hinge the child turns about
