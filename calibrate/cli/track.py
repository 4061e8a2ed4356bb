"""``calibrate track CAMERAS DETECTIONS [-o TRACKS.c3d]`` (seed 002's 3-D tracker from unlabelled 2-D camera
detections) and the cameras of ``calibrate simulate --cameras N``."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ..errors import CalibrateError
from ..io.outputs import check_targets, put_text, write_all


def add_track_parser(sub) -> None:
    """The 'track' sub-command's arguments."""
    tr = sub.add_parser("track", help="3-D marker trajectories from unlabelled 2-D camera detections (seed 002)",
                        description="Track every marker in 3-D from the unlabelled 2-D detections of calibrated "
                                    "cameras (seed 002, Section 2: prediction, the (M+1)-dimensional assignment by "
                                    "Lagrangian relaxation, triangulation).  Writes the trajectories as an "
                                    "unlabelled C3D (T1, T2, ...) and a report JSON with the tracker's figures "
                                    "(docs/tracking.md).")
    tr.add_argument("cameras", type=Path, help="camera calibration (.toml or .json; docs/tracking.md)")
    tr.add_argument("detections", type=Path, help="detections (.npz; docs/tracking.md)")
    tr.add_argument("-o", "--output", type=Path, default=None,
                    help="trajectories C3D (default: DETECTIONS' name + _tracks.c3d)")
    tr.add_argument("--report", type=Path, default=None,
                    help="report JSON (default: DETECTIONS' name + _tracks_report.json)")
    tr.add_argument("--min-frames", type=int, default=10, help="leave out tracks seen in fewer frames (default 10)")
    tr.add_argument("--greedy", action="store_true",
                    help="the baseline: nearest prediction per camera and pairs of cameras greedily, no relaxation")
    tr.add_argument("--overwrite", action="store_true", help="replace existing outputs")


def cmd_track(args: argparse.Namespace) -> int:
    from ..io.c3d import write_c3d
    from ..io.cameras import read_cameras, read_detections
    from ..track.tracker import Tracker, TrackSettings

    stem = args.detections.with_suffix("")
    out = args.output or stem.with_name(stem.name + "_tracks.c3d")
    report = args.report or stem.with_name(stem.name + "_tracks_report.json")
    check_targets([out, report], args.overwrite,
                  inputs={args.cameras: "that is the camera calibration; choose another -o",
                          args.detections: "that is the detections file; choose another -o"})
    cams = read_cameras(args.cameras)
    det = read_detections(args.detections, len(cams))
    if det.n_frames < 2:
        raise CalibrateError(f"{args.detections}: {det.n_frames} frames; tracking needs at least 2")
    t0 = time.perf_counter()
    tracks = Tracker(cams, TrackSettings(method="greedy" if args.greedy else "lagrangian")).run(det)
    seconds = time.perf_counter() - t0
    trial = tracks.trial(args.min_frames)
    fig = tracks.figures()
    fig.update({"written_tracks": trial.n_markers, "seconds": seconds, "cameras": len(cams),
                "detections": int(det.frame.size), "method": "greedy" if args.greedy else "lagrangian"})
    if trial.n_markers == 0:
        raise CalibrateError(f"{args.detections}: no track lasted {args.min_frames} frames; check that the "
                             "calibration belongs to these detections (or lower --min-frames)")
    write_all({out: lambda p: write_c3d(p, trial),
               report: lambda p: put_text(p, json.dumps({"tracker": fig}, indent=2) + "\n")})
    print(f"tracked {fig['frames']} frames of {len(cams)} cameras in {seconds:.2f} s "
          f"({fig['ms_per_frame']:.2f} ms/frame): {fig['tracks']} tracks ({trial.n_markers} written), "
          f"{100 * fig['assigned_share']:.1f} % of detections assigned, mean primal-dual gap {fig['mean_gap']:.3g}, "
          f"{100 * fig['optimal_frames']:.1f} % of frames proved optimal")
    print(f"wrote {out}\n      {report}")
    return 0


def write_simulated_cameras(sim, out: Path, n_cameras: int, seed: int) -> dict[str, Path]:
    """`n_cameras` synthetic cameras and their detections of a simulation, written into `out`."""
    from ..simulation.cameras import simulate_cameras, write_camera_simulation

    cs = simulate_cameras(sim, n_cameras, seed)
    markers = sim.clean_markers if sim.artefact is None else sim.clean_markers + sim.artefact
    paths = write_camera_simulation(cs, Path(out), markers)
    if not np.any(cs.marker >= 0):
        raise CalibrateError(f"{out}: the cameras saw no marker; this should not happen with the default volume")
    return paths
