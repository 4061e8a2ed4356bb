"""Seed 002's 3-D tracker: the Lagrangian relaxation against exhaustive search, triangulation against known
points, the camera and detection files read back (and refused when bad), and a short tracking run against
the simulator's truth."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from calibrate.io.cameras import CameraError, Detections, cameras_toml, read_cameras, read_detections
from calibrate.model.model import load_model
from calibrate.simulation.cameras import ring_cameras, simulate_cameras, write_camera_simulation
from calibrate.simulation.simulate import simulate_squats
from calibrate.track.assignment import exhaustive_assignment, is_feasible, solve_assignment
from calibrate.track.geometry import ray_compromise, triangulate
from calibrate.track.tracker import Tracker, TrackSettings

MODEL = "models/human.urdf"


def _instance(rng: np.random.Generator):
    D = int(rng.integers(3, 5))
    sizes = rng.integers(2, 4, D)
    every = [e for e in itertools.product(*[range(-1, s) for s in sizes]) if sum(x >= 0 for x in e) >= 2]
    pick = rng.choice(len(every), size=min(len(every), 25), replace=False)
    edges = np.array([every[i] for i in pick])
    return edges, rng.normal(-1.0, 1.0, len(edges)), sizes


def test_lagrangian_relaxation_against_exhaustive_search():
    rng = np.random.default_rng(3)
    optimal = proved = 0
    for _ in range(120):
        edges, cost, sizes = _instance(rng)
        a = solve_assignment(edges, cost, sizes, max_iterations=50)
        chosen, best = exhaustive_assignment(edges, cost)
        assert is_feasible(edges, a.chosen) and is_feasible(edges, chosen)
        assert cost[a.chosen].sum() == pytest.approx(a.primal)
        # the bound is honest: dual <= optimum <= primal, so the gap covers the distance from the optimum
        assert a.dual <= best + 1e-9
        assert a.primal >= best - 1e-9
        assert a.primal - best <= a.gap + 1e-9
        optimal += abs(a.primal - best) < 1e-9
        proved += a.gap < 1e-6
        if a.gap < 1e-6:
            assert a.primal == pytest.approx(best)
    assert optimal >= 0.6 * 120  # random dense instances are the hard case; tracking frames are easy
    assert proved <= optimal


def test_two_dimensional_problem_is_solved_exactly():
    rng = np.random.default_rng(0)
    for _ in range(30):
        sizes = (4, 5)
        every = np.array([e for e in itertools.product(range(-1, 4), range(-1, 5)) if e != (-1, -1)])
        cost = rng.normal(-0.5, 1.0, len(every))
        a = solve_assignment(every, cost, sizes)
        _, best = exhaustive_assignment(every, cost)
        assert a.primal == pytest.approx(best) and a.gap == pytest.approx(0.0, abs=1e-9)


def test_triangulation_of_a_known_point_and_the_one_ray_compromise():
    cams = ring_cameras(6, seed=2)
    X = np.array([0.3, -0.2, 1.1])
    centres = np.array([c.centre for c in cams])
    dirs = np.array([c.rays(c.project(X[None])[0])[0] for c in cams])
    Y, r = triangulate(centres, dirs)
    np.testing.assert_allclose(Y, X, atol=1e-9)
    assert r < 1e-12  # m²: rounding of s − bᵀX
    # noisy pixels: the error is about what 0.3 px at ~4.5 m gives
    rng = np.random.default_rng(1)
    errs = []
    for _ in range(200):
        d = np.array([c.rays(c.project(X[None])[0] + rng.normal(0, 0.3, (1, 2)))[0] for c in cams])
        errs.append(np.linalg.norm(triangulate(centres, d)[0] - X))
    assert 0.1e-3 < np.sqrt(np.mean(np.square(errs))) < 1.0e-3
    # one ray and a prediction: the point on the ray nearest the prediction when the ray is trusted
    pred = X + np.array([0.01, 0.0, 0.0])
    Z = ray_compromise(pred, centres[0], dirs[0], 1e-3, 1e3)
    t = (pred - centres[0]) @ dirs[0]
    np.testing.assert_allclose(Z, centres[0] + t * dirs[0], atol=1e-6)
    np.testing.assert_allclose(ray_compromise(pred, centres[0], dirs[0], 1e3, 1e-3), pred, atol=1e-6)


def test_camera_files_round_trip_and_bad_files(tmp_path):
    cams = ring_cameras(4, seed=5)
    p = tmp_path / "cameras.toml"
    p.write_text(cameras_toml(cams))
    back = read_cameras(p)
    X = np.random.default_rng(0).uniform(-1, 1, (50, 3)) + [0, 0, 1]
    for a, b in zip(cams, back, strict=True):
        assert a.name == b.name and a.size == b.size
        np.testing.assert_allclose(a.project(X)[0], b.project(X)[0], atol=1e-9)
    # JSON with a Rodrigues vector instead of R
    j = tmp_path / "cameras.json"
    from scipy.spatial.transform import Rotation
    c = cams[0]
    rvec = Rotation.from_matrix(c.R).as_rotvec().tolist()
    j.write_text(json.dumps({"camera": [{"name": "a", "K": c.K.tolist(), "rvec": rvec, "t": c.t.tolist(),
                                         "size": list(c.size), "dist": c.dist.tolist()}]}))
    np.testing.assert_allclose(read_cameras(j)[0].project(X)[0], c.project(X)[0], atol=1e-9)
    bad = tmp_path / "bad.toml"
    for text, what in [("[[camera]]\nK = [[1, 0, 0], [0, 1, 0]]\nt = [0, 0, 0]\nsize = [10, 10]\nR = "
                        "[[1,0,0],[0,1,0],[0,0,1]]\n", "'K' must be 3x3"),
                       ("[[camera]]\nK = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nsize = [10, 10]\n", "has no 't'"),
                       ("[[camera]]\nK = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\nt = [0, 0, 0]\nsize = [10, 10]\nR = "
                        "[[2,0,0],[0,1,0],[0,0,1]]\n", "not a rotation"),
                       ("camera = 3\n", "no cameras"), ("[[camera\n", "not valid TOML")]:
        bad.write_text(text)
        with pytest.raises(CameraError, match=what) as e:
            read_cameras(bad)
        assert "\n" not in str(e.value) and str(bad) in str(e.value)
    with pytest.raises(CameraError, match="no such file"):
        read_cameras(tmp_path / "none.toml")
    d = tmp_path / "det.npz"
    np.savez(d, frame=np.array([0, 1]), camera=np.array([0, 3]), uv=np.zeros((2, 2)), rate=np.array(100.0))
    assert read_detections(d).n_frames == 2
    with pytest.raises(CameraError, match="calibration has 2 cameras"):
        read_detections(d, n_cameras=2)
    np.savez(d, frame=np.array([0, 1]), camera=np.array([0, 1]), uv=np.zeros((3, 2)), rate=np.array(100.0))
    with pytest.raises(CameraError, match=r"\(n, 2\)"):
        read_detections(d)
    d.write_text("not a zip")
    with pytest.raises(CameraError, match="not a readable NPZ"):
        read_detections(d)


def test_tracking_a_simulated_squat_against_the_truth(tmp_path):
    model = load_model(MODEL)
    sim = simulate_squats(model, frames=120, noise_mm=0.0, seed=1)
    cs = simulate_cameras(sim, 8, seed=1)
    paths = write_camera_simulation(cs, tmp_path, sim.clean_markers)
    cams = read_cameras(paths["cameras"])
    det = read_detections(paths["detections"], len(cams))
    np.testing.assert_array_equal(det.frame, cs.detections.frame)
    np.testing.assert_allclose(det.uv, cs.detections.uv)
    truth = np.load(paths["truth_detections"])["marker"]
    assert isinstance(det, Detections) and det.n_frames == 120
    tracks = Tracker(cams).run(det)
    dt = tracks.detection_track
    label = np.array([np.bincount(truth[(dt == j) & (truth >= 0)], minlength=1).argmax()
                      for j in range(tracks.n_tracks)])
    # every marker tracked once, from the first frame to the last
    assert sorted(label) == list(range(len(model.markers)))
    right = (dt >= 0) & (truth >= 0) & (label[np.maximum(dt, 0)] == truth)
    assert right.sum() / np.sum(truth >= 0) > 0.995
    assert np.sum((dt >= 0) & (truth < 0)) <= 2  # false detections left alone
    err = np.linalg.norm(tracks.positions - sim.clean_markers[:, label], axis=2)
    assert np.sqrt(np.nanmean(err ** 2)) < 1.5e-3
    assert np.mean(tracks.gap <= 1e-6 * (1 + np.abs(tracks.primal))) > 0.95
    # the greedy baseline runs on the same input
    greedy = Tracker(cams, TrackSettings(method="greedy")).run(det)
    assert greedy.positions.shape[0] == 120


def test_end_to_end_from_detections_to_a_subject(tmp_path, capsys):
    """calibrate simulate --cameras 8, then calibrate track CAMERAS DETECTIONS MODEL: every track labelled with
    the marker it follows, the subject written with the tracker's figures in the report."""
    from calibrate.cli.main import main
    from calibrate.io.c3d import read_c3d

    out = tmp_path / "sim"
    assert main(["simulate", "--out", str(out), "--frames", "150", "--noise-mm", "0", "--cameras", "8",
                 "--seed", "2"]) == 0
    for name in ("cameras.toml", "detections.npz", "truth_detections.npz", "trial.c3d"):
        assert (out / name).exists()
    truth = np.load(out / "truth_detections.npz")["markers"]
    args = ["track", str(out / "cameras.toml"), str(out / "detections.npz"), MODEL, "-o", str(tmp_path / "s.urdf")]
    code = main(args)
    assert code in (0, 1)
    # progress on stderr while it works (the labelling alone takes seconds): each labelling step as it starts,
    # then the calibration's stages, in that order
    progress = [line.split("] ", 1)[1] for line in capsys.readouterr().err.splitlines() if line.startswith("  [")]
    stages = [line.split(":", 1)[0] for line in progress]
    rep = json.loads((out / "detections_report.json").read_text())
    assert progress[0] == (f"labels: {rep['tracker']['written_tracks']} tracks grouped into rigid segments by the "
                           "variance of their distances (seed 002)")
    assert any(x.startswith("labels: the scaled base model fitted to the tracks as well") for x in progress)
    assert "seed" in stages and "solve" in stages and stages.index("seed") > max(
        k for k, s in enumerate(stages) if s == "labels")
    tracked = read_c3d(out / "detections_tracks.c3d")
    names = load_model(MODEL).marker_names
    assert sorted(tracked.labels) == sorted(names)
    for i, label in enumerate(tracked.labels):  # each label on the track nearest that marker's truth
        err = np.linalg.norm(tracked.markers[:, i] - truth[:, names.index(label)], axis=1)
        assert np.nanmedian(err) < 3e-3, label
    assert rep["tracker"]["tracks"] >= 39 and rep["tracker"]["assigned_share"] > 0.95
    # every track is written, joined into another (a break) or left out as too short
    assert 0 <= rep["tracker"]["written_tracks"] + rep["tracker"]["breaks_joined"] <= rep["tracker"]["tracks"]
    assert (tmp_path / "s.urdf").exists() and (out / "detections_motion.csv").exists()
    # the subject URDF says first what it is: the tracked trial's C3D it was calibrated from, and its report
    assert (tmp_path / "s.urdf").read_text().split("\n")[1].startswith(
        "<!-- The subject of detections_tracks.c3d, calibrated by calibrate ")
    assert "its report: detections_report.json." in (tmp_path / "s.urdf").read_text().split("\n")[1]
    # again: refused (exit 2, one line), nothing overwritten
    before = (tmp_path / "s.urdf").stat().st_mtime_ns
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0]
    assert (tmp_path / "s.urdf").stat().st_mtime_ns == before
    # a calibration of the wrong number of cameras: one line, exit 2
    (tmp_path / "two.toml").write_text(cameras_toml(ring_cameras(2)))
    assert main(["track", str(tmp_path / "two.toml"), str(out / "detections.npz"), "--c3d",
                 str(tmp_path / "x.c3d")]) == 2
    assert "calibration has 2 cameras" in capsys.readouterr().err
    assert not (tmp_path / "x.c3d").exists()


def test_labelling_a_walk_whose_arms_move_as_one_body_with_spikes():
    """Unlabelled true trajectories of a walk (forearm, wrist and hand barely bend: their tracks form one
    rigid group per arm) with four tracks that follow another marker for three frames and one marker's track
    broken in two: every track gets the marker it follows (the simulator's truth), the arms through chains
    of segments, the broken track's two parts joined."""
    from calibrate.io.trial import Trial
    from calibrate.simulation.simulate import simulate_gait
    from calibrate.track.labels import label_tracks

    model = load_model(MODEL)
    sim = simulate_gait(model, frames=300, noise_mm=0.5, seed=2)
    rng = np.random.default_rng(2)
    perm = rng.permutation(sim.trial.n_markers)
    X = sim.trial.markers[:, perm].copy()
    truth = {f"T{i + 1}": sim.trial.labels[p] for i, p in enumerate(perm)}
    for _ in range(4):
        i, j = rng.choice(len(perm), 2, replace=False)
        f0 = int(rng.integers(20, 280))
        X[f0:f0 + 3, i] = X[f0:f0 + 3, j]
    # the pelvis marker RASI's track lost at frame 150 and found again as another track; the thigh marker
    # LTHI's likewise at frame 160, the two sharing two frames
    k, j = list(truth.values()).index("RASI"), list(truth.values()).index("LTHI")
    late = np.full_like(X[:, :2], np.nan)
    late[150:, 0], X[150:, k] = X[150:, k], np.nan
    late[158:, 1], X[160:, j] = X[158:, j], np.nan
    names = [*truth, "T40", "T41"]
    lab = label_tracks(model, Trial(names, np.concatenate([X, late], axis=1), sim.trial.rate, 0, None))
    assert {frozenset(p) for p in lab.merged.items()} == {frozenset({"T40", f"T{k + 1}"}),
                                                          frozenset({"T41", f"T{j + 1}"})}
    assert {t: lab.labels.get(lab.merged.get(t, t)) for t in truth} == truth
    assert set(lab.labels) == set(truth) - set(lab.merged) | set(lab.merged.values())
    # The arms through chains of segments where the grouping's labelling is kept; with the knee markers on their axes
    # (the simulator keeps them so) a knee marker stays rigid with both the thigh and the shank, and the base model's
    # fit labelled every track alike and was kept: no groups then.
    assert not lab.segments or {"ulna_l+radius_l+hand_l", "ulna_r+radius_r+hand_r"} <= set(lab.segments.values())
