"""The typed records and single helpers of issue 19: Kabsch, marker RMS, summaries merged, progress
records, all-or-nothing output writing (values computed independently here)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.calibration.pipeline import merge_summaries
from calibrate.calibration.records import Identified, LimitNote, ParameterChange, Progress, StillNote
from calibrate.errors import CalibrateError
from calibrate.io.outputs import check_targets, write_all
from calibrate.seed.geometry import kabsch, kabsch_batch, marker_rms, similarity_fit
from calibrate.solve.lm import SolverSummary


def test_kabsch_recovers_a_rigid_motion():
    rng = np.random.default_rng(4)
    a = rng.normal(size=(7, 3))
    R = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    t = np.array([0.1, -0.4, 2.0])
    R1, t1 = kabsch(a, a @ R.T + t)
    np.testing.assert_allclose(R1, R, atol=1e-12)
    np.testing.assert_allclose(t1, t, atol=1e-12)
    # a mirrored set: still a proper rotation
    assert np.linalg.det(kabsch(a, a * [1, 1, -1])[0]) == pytest.approx(1.0)
    # the batched, weighted form agrees, and so does Umeyama's rotation with a scale
    Rb, tb = kabsch_batch(a, (a @ R.T + t)[None], np.ones((1, 7)))
    np.testing.assert_allclose(Rb[0], R, atol=1e-12)
    np.testing.assert_allclose(tb[0], t, atol=1e-12)
    s, Rs, ts = similarity_fit(a, 1.3 * a @ R.T + t)
    assert s == pytest.approx(1.3)
    np.testing.assert_allclose(Rs, R, atol=1e-12)


def test_marker_rms_over_the_seen_markers():
    res = np.full((2, 3, 3), np.nan)
    res[0, 0] = [0.003, 0.0, 0.004]  # 5 mm
    res[1, 2] = [0.0, 0.012, 0.0]  # 12 mm
    assert marker_rms(res) == pytest.approx(math.sqrt((0.005**2 + 0.012**2) / 2))
    assert math.isnan(marker_rms(np.full((2, 3, 3), np.nan)))


def test_merge_summaries_adds_counts_and_joins_histories():
    coarse = SolverSummary(iterations=3)
    a = SolverSummary(iterations=5, accepted=4, initial_cost=10.0, final_cost=4.0, cost_history=[10.0, 6.0, 4.0],
                      termination="a", converged=False, seconds=1.0, linearize_seconds=0.5,
                      linear_solver_seconds=0.25, evaluate_seconds=0.125, coarse=coarse, coarse_frames=60, rounds=2)
    b = SolverSummary(iterations=2, accepted=1, initial_cost=4.0, final_cost=3.5, cost_history=[4.0, 3.5],
                      termination="b", converged=True, seconds=2.0, linearize_seconds=1.0,
                      linear_solver_seconds=0.5, evaluate_seconds=0.25)
    m = merge_summaries(a, b)
    assert (m.iterations, m.accepted) == (7, 5)
    assert (m.initial_cost, m.final_cost, m.cost_history) == (10.0, 3.5, [10.0, 6.0, 4.0, 3.5])
    assert (m.termination, m.converged) == ("b", True)
    assert (m.seconds, m.linearize_seconds, m.linear_solver_seconds, m.evaluate_seconds) == (3.0, 1.5, 0.75, 0.375)
    assert m.coarse is coarse and m.coarse_frames == 60 and m.rounds == 1


def test_records_render_the_words_the_user_reads():
    c = ParameterChange("centre", "knee_r", np.zeros(3), np.zeros(3), 0.0, np.zeros(3), Identified.ACROSS_AXIS)
    assert c.name == "centre[knee_r]" and not c.identified
    assert ParameterChange("scale", "femur_r", np.ones(1), np.ones(1), 0.0, np.zeros(1), Identified.FIXED).identified
    note = LimitNote("subtalar_r", 0.1, math.radians(12))
    assert note.text().startswith("subtalar_r: beyond the base model's joint limits in 10 % of frames "
                                  "(by up to 12 deg)")
    # One rotation of a ball joint (a walk's hip adduction, 1.5 deg SD): what the trials show, no axis to hold and
    # no advice to lock what a walk moves.
    hip = StillNote("hip_l_adduction", math.radians(1.5), math.radians(1.4), axis_held=False, ball="hip_l")
    assert hip.text() == ("hip_l_adduction: turned 1.5 deg SD over the frames, under 3 times what one frame's markers "
                          "fix (1.4 deg): the trials show little of this rotation of hip_l, so its centre rests on its "
                          "other rotations and the segment frame's zero about it on the priors (--lock hip_l_adduction "
                          "holds it, if the subject kept it still)")
    still = StillNote("knee_l", math.radians(0.5), math.radians(0.4), axis_held=True)
    assert still.text().startswith("knee_l: moved no more than the markers fix it in a frame (SD over frames 0.5 deg")
    assert "its axis was held" in still.text()
    ankle = StillNote("ankle_l", math.radians(15.3), math.radians(5.9), axis_held=True, bare="talus_l",
                      neighbours=("subtalar_l",))
    assert ankle.text().startswith("ankle_l: one frame's markers fix it only to 5.9 deg (its joint and the next trade "
                                   "off across talus_l, which carries no markers the trials show), and it moved no "
                                   "more than that allows (SD over frames 15.3 deg)")
    assert "does not show this joint moving" not in ankle.text()
    assert ankle.text().endswith("its axis was held at the base model's; if one of ankle_l or subtalar_l hardly moved "
                                 "(a subtalar joint in a walk), lock that one (--lock NAME, or [lock_deg] in the "
                                 "config), as OpenSim's gait pipelines do: the other is then found")
    for msg in ("solve: iteration   3  cost 1.0e+00  lambda 1.0e-03", "build: compiling the model's C code",
                "solve: all frames, iteration   2  cost 1.0e+00  lambda 1.0e-03", "no stage here"):
        assert str(Progress.of(msg)) == msg
    assert Progress.of("solve: iteration   3  cost 1").iteration == 3
    assert Progress.of("solve: all frames, iteration   3  cost 1").iteration is None
    assert Progress.of("build: compiling the model's C code").long


def test_write_all_writes_every_file_or_none(tmp_path: Path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    write_all({a: lambda p: p.write_text(f"new {p.name}"), b: lambda p: p.write_text(f"new {p.name}")},
              keep_names=True)
    assert (a.read_text(), b.read_text()) == ("new a.txt", "new b.txt")  # each writer saw its own file name
    write_all({a: lambda p: p.write_text("staged " + str(p.name.startswith(".a.txt.")))})
    assert a.read_text() == "staged True"
    a.write_text("new a.txt")

    def fail(p: Path) -> None:
        p.write_text("half")
        raise OSError("disk full")

    with pytest.raises(CalibrateError, match=r"an output could not be written \(disk full\); nothing was written or "
                                             "changed") as e:
        write_all({a: lambda p: p.write_text("newer"), b: fail})
    assert "\n" not in str(e.value)
    assert (a.read_text(), b.read_text()) == ("new a.txt", "new b.txt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]  # no temporary left behind


def test_write_all_gives_new_files_the_users_permissions_and_keeps_replaced_ones(tmp_path: Path):
    """A new output is created as any new file is (0666 less the umask), not with a temporary file's
    0600 that would hide a lab's results from its group; a replaced output keeps its permissions."""
    import os
    import stat

    old = os.umask(0o027)
    try:
        a, b, c = tmp_path / "a.urdf", tmp_path / "b.csv", tmp_path / "c.json"
        c.write_text("old")
        os.chmod(c, 0o604)
        write_all({a: lambda p: p.write_text("a"), b: lambda p: p.write_text("b"), c: lambda p: p.write_text("c")})
        write_all({tmp_path / "d.trc": lambda p: p.write_text("d")}, keep_names=True)
    finally:
        os.umask(old)
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in tmp_path.iterdir()}
    assert modes == {"a.urdf": 0o640, "b.csv": 0o640, "c.json": 0o604, "d.trc": 0o640}
    assert c.read_text() == "c"


def test_check_targets_refuses_before_any_work(tmp_path: Path):
    a = tmp_path / "a.txt"
    a.write_text("x")
    with pytest.raises(CalibrateError, match="a.txt: exists; pass --overwrite"):
        check_targets([a], overwrite=False)
    check_targets([a], overwrite=True)
    with pytest.raises(CalibrateError, match="same file"):
        check_targets([a, tmp_path / "." / "a.txt"], overwrite=True, same="same file")
    with pytest.raises(CalibrateError, match="that is the base model"):
        check_targets([a], overwrite=True, inputs={a: "that is the base model"})
    with pytest.raises(CalibrateError, match="does not exist; create it first"):
        check_targets([tmp_path / "no" / "b.txt"], overwrite=False)


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc")
def test_check_targets_tries_the_folder_before_any_work():
    """A folder os.access calls writable that takes no new file (/proc here; a read-only file system, or any folder
    for root, alike): refused before the work in one line, not a FileNotFoundError after it."""
    with pytest.raises(CalibrateError, match=r"/proc/subject.urdf: directory '/proc' takes no new file \(.+\); "
                                             "choose another place"):
        check_targets([Path("/proc/subject.urdf")], overwrite=False)


def test_a_hinge_centre_names_the_direction_across_its_axis_the_trial_left_open(human):
    """A hinge centre the trial fixes in one direction across its axis and not in the other: its note names that
    other direction (in the parent's frame), the one the posterior leaves near its prior (built so here)."""
    from calibrate.calibration.identifiability import _judge_centre

    P = human.parameters()
    j = next(j for j in human.joints if j.name == "knee_r")
    d = human.dof_index(j.dofs[0])
    u = next(u for u in human.urdf_joints if u.name == j.urdf_joints[0])
    a = u.rotation @ (P.axis[d] / np.linalg.norm(P.axis[d]))
    rng = np.random.default_rng(3)
    w = np.cross(a, rng.normal(size=3))
    w /= np.linalg.norm(w)  # the open direction, across the axis
    fixed = np.cross(a, w)  # the one the trial fixes
    C0 = 0.02 ** 2 * np.eye(3)
    C = 0.02 ** 2 * (np.outer(a, a) + 0.9 ** 2 * np.outer(w, w) + 0.1 ** 2 * np.outer(fixed, fixed))
    status, note, ratio, _ = _judge_centre(human, P, j, None, C, C0)
    assert status is Identified.NO and ratio == pytest.approx(0.9, rel=1e-9)
    named = np.array([float(x) for x in note.split("across the axis not identified along (")[1].split(")")[0]
                      .split(",")])
    assert abs(abs(named @ w) - 1.0) < 1e-2  # printed to two decimals
    # Fixed in both directions across the axis: identified there, no direction named.
    C = 0.02 ** 2 * (np.outer(a, a) + 0.1 ** 2 * (np.eye(3) - np.outer(a, a)))
    status, note, _, _ = _judge_centre(human, P, j, None, C, C0)
    assert status is Identified.ACROSS_AXIS and note.endswith("across the axis identified")
