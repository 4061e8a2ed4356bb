"""Benchmark of seed 002's 3-D tracker (calibrate.track) on simulated cameras (docs/tracking.md).

A squat trial of the simulator (39 markers, no 3-D noise: the truth is the markers' true positions) is
seen by N synthetic cameras (0.3 px noise, occlusion by the body, 1 % missed and 0.5 false detections per
camera and frame).  For the Lagrangian-relaxation tracker and the greedy baseline:

* share of marker-frames whose detections were all assigned to the marker's track and nothing else;
* 3-D RMS of the tracked positions against the truth, and the RMS of triangulating the true assignment;
* track breaks (tracks beyond one per marker, plus markers never tracked);
* primal–dual gap per frame and share of frames proved optimal; time per frame;
* the per-frame assignment problems of the first frames solved exhaustively (split into independent
  components), against what the relaxation kept.

    python scripts/bench_tracking.py [--frames 1000] [--cameras 4 8] [--quick] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from calibrate.model.model import load_model  # noqa: E402
from calibrate.simulation.cameras import simulate_cameras  # noqa: E402
from calibrate.simulation.simulate import simulate_squats  # noqa: E402
from calibrate.track.assignment import exhaustive_assignment, solve_assignment  # noqa: E402
from calibrate.track.geometry import triangulate  # noqa: E402
from calibrate.track.tracker import Tracker, TrackSettings  # noqa: E402

MODEL = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


def track_labels(tracks, truth: np.ndarray) -> np.ndarray:
    """The marker each track follows: the most frequent true marker of its detections (-1: none)."""
    dt = tracks.detection_track
    out = np.full(tracks.n_tracks, -1)
    for j in range(tracks.n_tracks):
        m = truth[(dt == j) & (truth >= 0)]
        if m.size:
            out[j] = np.bincount(m).argmax()
    return out


def correct_share(tracks, det, truth: np.ndarray, n_markers: int) -> float:
    """Share of marker-frames (the marker detected at least once) whose detections, and only those, went to
    a track of that marker."""
    lab = track_labels(tracks, truth)
    dt = tracks.detection_track
    F = det.n_frames
    ok = np.ones((F, n_markers), dtype=bool)
    seen = np.zeros((F, n_markers), dtype=bool)
    real = truth >= 0
    seen[det.frame[real], truth[real]] = True
    # a true detection not on a track of its marker
    wrong = real & ((dt < 0) | (lab[np.maximum(dt, 0)] != truth))
    ok[det.frame[wrong], truth[wrong]] = False
    # a track of marker n taking a detection that is not n's
    stolen = (dt >= 0) & (lab[np.maximum(dt, 0)] >= 0) & (truth != lab[np.maximum(dt, 0)])
    ok[det.frame[stolen], lab[dt[stolen]]] = False
    # a marker's detections split over two tracks in one frame
    key = det.frame[real & (dt >= 0)] * n_markers + truth[real & (dt >= 0)]
    pairs = np.unique(np.column_stack([key, dt[real & (dt >= 0)]]), axis=0)
    k, c = np.unique(pairs[:, 0], return_counts=True)
    split = k[c > 1]
    ok[split // n_markers, split % n_markers] = False
    return float(ok[seen].mean())


def rms_against_truth(tracks, truth: np.ndarray, markers: np.ndarray) -> float:
    lab = track_labels(tracks, truth)
    keep = lab >= 0
    err = np.linalg.norm(tracks.positions[:, keep] - markers[:, lab[keep]], axis=2)
    return float(np.sqrt(np.nanmean(err ** 2)))


def true_assignment_rms(cams, det, truth: np.ndarray, markers: np.ndarray) -> float:
    """RMS of triangulating every marker-frame from its true detections (two or more cameras)."""
    X = true_assignment_positions(cams, det, truth, markers)
    err = np.sum((X - markers) ** 2, axis=2)
    return float(np.sqrt(np.nanmean(err)))


def true_assignment_positions(cams, det, truth: np.ndarray, markers: np.ndarray) -> np.ndarray:
    """(F, N, 3) every marker-frame triangulated from its true detections (two or more cameras; NaN
    otherwise): what a perfect tracker and labeller would give with these cameras."""
    focal = np.array([c.focal for c in cams])
    out = np.full(markers.shape, np.nan)
    real = np.flatnonzero(truth >= 0)
    key = det.frame[real] * markers.shape[1] + truth[real]
    order = np.argsort(key, kind="stable")
    real, key = real[order], key[order]
    bounds = np.flatnonzero(np.diff(key)) + 1
    for rows in np.split(real, bounds):
        if rows.size < 2:
            continue
        f, n = det.frame[rows[0]], truth[rows[0]]
        c = det.camera[rows]
        centres = np.array([cams[m].centre for m in c])
        dirs = np.array([cams[m].rays(det.uv[r][None])[0] for m, r in zip(c, rows, strict=True)])
        depth = np.linalg.norm(markers[f, n] - centres, axis=1)
        out[f, n], _ = triangulate(centres, dirs, (focal[c] / depth) ** 2)
    return out


def breaks(tracks, truth: np.ndarray, n_markers: int) -> int:
    lab = track_labels(tracks, truth)
    counts = np.bincount(lab[lab >= 0], minlength=n_markers)
    return int(np.sum(np.maximum(counts - 1, 0)) + np.sum(counts == 0))


def components(edges: np.ndarray) -> list[np.ndarray]:
    """Hyperedges split into groups that share no index (independent sub-problems)."""
    parent = list(range(len(edges)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    owner: dict = {}
    for h, e in enumerate(edges):
        for d, i in enumerate(e):
            if i >= 0:
                o = owner.setdefault((d, int(i)), h)
                a, b = find(o), find(h)
                if a != b:
                    parent[a] = b
    roots = np.array([find(h) for h in range(len(edges))])
    return [np.flatnonzero(roots == r) for r in np.unique(roots)]


class Recorder(Tracker):
    """A tracker that keeps its first frames' assignment problems for the exhaustive check."""

    def __init__(self, *a, keep: int = 30, **k):
        super().__init__(*a, **k)
        self.keep, self.problems = keep, []

    def _associate(self, fr, pred, sd):
        import calibrate.track.tracker as tk

        if len(self.problems) < self.keep:
            original = tk.solve_assignment

            def spy(edges, cost, sizes, iters):
                self.problems.append((edges.copy(), cost.copy(), list(sizes)))
                return original(edges, cost, sizes, iters)

            tk.solve_assignment = spy
            try:
                return super()._associate(fr, pred, sd)
            finally:
                tk.solve_assignment = original
        return super()._associate(fr, pred, sd)


def exhaustive_check(problems) -> dict:
    """The relaxation against exhaustive search, component by component, on recorded frame problems."""
    n = optimal = 0
    excess = []
    skipped = 0
    for edges, cost, sizes in problems:
        a = solve_assignment(edges, cost, sizes)
        best = 0.0
        for comp in components(edges):
            if len(np.unique(edges[comp, 0])) > 3:  # more than three tracks: too many for the search
                skipped += 1
                best = np.nan
                break
            best += exhaustive_assignment(edges[comp], cost[comp])[1]
        if np.isnan(best):
            continue
        n += 1
        optimal += abs(a.primal - best) <= 1e-6 * (1 + abs(best))
        excess.append(a.primal - best)
    return {"frames": n, "optimal_share": optimal / max(n, 1), "max_excess": float(max(excess, default=0.0)),
            "skipped": skipped}


def random_check(count: int = 200, seed: int = 0) -> dict:
    """The relaxation against exhaustive search on small dense random instances (3-4 dimensions)."""
    import itertools

    rng = np.random.default_rng(seed)
    optimal, honest, gaps = 0, 0, []
    for _ in range(count):
        D = int(rng.integers(3, 5))
        sizes = rng.integers(2, 4, D)
        every = [e for e in itertools.product(*[range(-1, s) for s in sizes]) if sum(x >= 0 for x in e) >= 2]
        pick = rng.choice(len(every), size=min(len(every), 25), replace=False)
        edges = np.array([every[i] for i in pick])
        cost = rng.normal(-1.0, 1.0, len(edges))
        a = solve_assignment(edges, cost, sizes, max_iterations=50)
        best = exhaustive_assignment(edges, cost)[1]
        optimal += abs(a.primal - best) < 1e-9
        honest += a.dual <= best + 1e-9 <= a.primal + 2e-9
        gaps.append(a.gap)
    return {"instances": count, "optimal_share": optimal / count, "bounds_honest_share": honest / count,
            "mean_gap": float(np.mean(gaps))}


def run(frames: int, n_cameras: int, seed: int) -> dict:
    model = load_model(MODEL)
    sim = simulate_squats(model, frames=frames, noise_mm=0.0, seed=seed)
    cs = simulate_cameras(sim, n_cameras, seed)
    det, truth, markers = cs.detections, cs.marker, sim.clean_markers
    n = len(model.markers)
    out = {"cameras": n_cameras, "frames": frames, "markers": n, "detections": int(truth.size),
           "false_detections": int(np.sum(truth < 0)),
           "true_assignment_rms_mm": 1e3 * true_assignment_rms(cs.cameras, det, truth, markers)}
    for method in ("lagrangian", "greedy"):
        tracker = Recorder(cs.cameras, TrackSettings(method=method)) if method == "lagrangian" else Tracker(
            cs.cameras, TrackSettings(method=method))
        t0 = time.perf_counter()
        tracks = tracker.run(det)
        total = time.perf_counter() - t0
        fig = tracks.figures()
        res = {"correct_share": correct_share(tracks, det, truth, n),
               "rms_mm": 1e3 * rms_against_truth(tracks, truth, markers), "breaks": breaks(tracks, truth, n),
               "tracks": fig["tracks"], "assigned_share": fig["assigned_share"],
               "false_assigned": int(np.sum((tracks.detection_track >= 0) & (truth < 0))),
               "ms_per_frame": 1e3 * total / frames}
        if method == "lagrangian":
            res.update({"mean_gap": fig["mean_gap"], "max_gap": fig["max_gap"],
                        "optimal_frames": fig["optimal_frames"], "mean_iterations": fig["mean_iterations"],
                        "exhaustive": exhaustive_check(tracker.problems)})
        res["rms_ratio"] = res["rms_mm"] / out["true_assignment_rms_mm"]
        out[method] = res
    return out


def subject(frames: int, n_cameras: int, seed: int) -> dict:
    """The subject calibrated from the detections (track, label, calibrate) against the subject calibrated from
    the true 3-D trajectories: median joint-centre error against the truth."""
    from calibrate.calibration.evaluate import compare_to_truth
    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.trial import Trial
    from calibrate.track.subject import track_subject

    model = load_model(MODEL)
    sim = simulate_squats(model, frames=frames, noise_mm=0.0, seed=seed)
    cs = simulate_cameras(sim, n_cameras, seed)
    t0 = time.perf_counter()
    res = track_subject(cs.cameras, cs.detections, model)
    t_track = time.perf_counter() - t0
    # labels against the truth: the marker each labelled track follows
    lab = track_labels(res.tracks, cs.marker)
    kept = np.isfinite(res.tracks.positions[..., 0]).sum(0) >= 10
    names = model.marker_names
    true_names = {f"T{j + 1}": names[lab[j]] for j in np.flatnonzero(kept) if lab[j] >= 0}
    lab_of = res.labelling.labels
    merged = res.labelling.merged  # a track joined into another: that one's label
    _, chains = res.tracks.stitched()  # a track stitched onto another goes by the first one's name
    head = {f"T{j + 1}": f"T{c[0] + 1}" for c in chains for j in c}
    right = sum(lab_of.get(merged.get(head[k], head[k])) == v for k, v in true_names.items())
    t0 = time.perf_counter()
    cal_true = calibrate(model, sim.trial)
    t_true = time.perf_counter() - t0
    # the floor set by the cameras: the true assignment triangulated (a perfect tracker and labeller)
    tri = true_assignment_positions(cs.cameras, cs.detections, cs.marker, sim.clean_markers)
    cal_tri = calibrate(model, Trial(list(names), tri, sim.trial.rate, 0, None))
    a, b, c = (compare_to_truth(x, sim) for x in (res.calibration, cal_true, cal_tri))
    joints = sorted(set(a.centre_error) & set(b.centre_error) & set(c.centre_error))
    ea, eb, ec = (np.array([x.centre_error[j] for j in joints]) for x in (a, b, c))
    foot = np.array([j.startswith(("ankle", "subtalar", "mtp")) for j in joints])  # hinges squats barely turn
    return {"frames": frames, "cameras": n_cameras, "labels_right": int(right), "tracks_labelled": len(true_names),
            "from_detections_seconds": t_track, "from_truth_seconds": t_true,
            "centre_error_mm_detections": float(1e3 * np.median(ea)),
            "centre_error_mm_truth": float(1e3 * np.median(eb)),
            "centre_error_mm_true_assignment": float(1e3 * np.median(ec)),
            "centre_error_mm_max_difference": float(1e3 * np.max(np.abs(ea - eb))),
            "centre_error_mm_max_difference_true_assignment_vs_truth": float(1e3 * np.max(np.abs(ec - eb))),
            "centre_error_worst_joint": joints[int(np.argmax(np.abs(ea - eb)))],
            "centre_error_mm_max_difference_without_feet": float(1e3 * np.max(np.abs(ea - eb)[~foot])),
            "centre_error_mm_max_difference_true_assignment_vs_truth_without_feet":
                float(1e3 * np.max(np.abs(ec - eb)[~foot])),
            "centre_error_mm_max_difference_detections_vs_true_assignment": float(1e3 * np.max(np.abs(ea - ec))),
            "marker_rms_mm_detections": float(1e3 * res.calibration.marker_rms),
            "marker_rms_mm_truth": float(1e3 * cal_true.marker_rms),
            "marker_rms_mm_true_assignment": float(1e3 * cal_tri.marker_rms)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--cameras", type=int, nargs="+", default=[4, 8])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="300 frames, 8 cameras (< 60 s)")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.cameras = 300, [8]
    results = {"random_instances": random_check(100 if args.quick else 300),
               "runs": [run(args.frames, c, args.seed) for c in args.cameras],
               "subject": subject(args.frames, max(args.cameras), args.seed)}
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    r = results["random_instances"]
    print(f"random 3-4-dimensional instances: {r['instances']}, optimal {100 * r['optimal_share']:.1f} %, bounds "
          f"honest {100 * r['bounds_honest_share']:.1f} %, mean gap {r['mean_gap']:.3f}")
    for run_ in results["runs"]:
        print(f"\n{run_['cameras']} cameras, {run_['frames']} frames, {run_['markers']} markers, {run_['detections']} "
              f"detections ({run_['false_detections']} false); triangulating the true assignment: "
              f"{run_['true_assignment_rms_mm']:.3f} mm RMS")
        for m in ("lagrangian", "greedy"):
            x = run_[m]
            line = (f"  {m:10s} correct {100 * x['correct_share']:6.2f} %  RMS {x['rms_mm']:7.3f} mm "
                    f"({x['rms_ratio']:.2f}x)  breaks {x['breaks']:3d}  false assigned {x['false_assigned']:4d}  "
                    f"{x['ms_per_frame']:.2f} ms/frame")
            if m == "lagrangian":
                e = x["exhaustive"]
                line += (f"\n             gap mean {x['mean_gap']:.3g} max {x['max_gap']:.3g}, "
                         f"{100 * x['optimal_frames']:.1f} % frames proved optimal, {x['mean_iterations']:.2f} "
                         f"iterations; exhaustive check of {e['frames']} frames: {100 * e['optimal_share']:.1f} % "
                         f"optimal ({e['skipped']} left out: a component of more than 3 tracks)")
            print(line)
    s = results["subject"]
    print(f"\nsubject from {s['cameras']} cameras' detections ({s['frames']} frames): {s['labels_right']} of "
          f"{s['tracks_labelled']} tracks labelled right; median joint-centre error "
          f"{s['centre_error_mm_detections']:.2f} mm (from the true trajectories: {s['centre_error_mm_truth']:.2f} "
          f"mm; largest difference per joint "
          f"{s['centre_error_mm_max_difference']:.2f} mm, worst {s['centre_error_worst_joint']}); "
          f"{s['from_detections_seconds']:.1f} s from detections, {s['from_truth_seconds']:.1f} s from the trajectories"
          f"\n  the cameras' floor, the true assignment triangulated: median {s['centre_error_mm_true_assignment']:.2f}"
          f" mm, largest difference per joint from the true trajectories' subject "
          f"{s['centre_error_mm_max_difference_true_assignment_vs_truth']:.2f} mm, from the detections' subject "
          f"{s['centre_error_mm_max_difference_detections_vs_true_assignment']:.2f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
