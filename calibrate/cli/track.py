"""``calibrate track CAMERAS DETECTIONS [MODEL]`` (seed 002 from unlabelled 2-D camera detections: the 3-D
tracker, then with MODEL the labels and the calibration) and the cameras of ``calibrate simulate --cameras N``."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ..calibration.records import Countdown
from ..errors import CalibrateError
from ..io.outputs import check_targets, put_text, write_all


def add_track_parser(sub) -> None:
    """The 'track' sub-command's arguments."""
    tr = sub.add_parser("track", help="from unlabelled 2-D camera detections to tracks (and a calibrated subject)",
                        description="Track every marker in 3-D from the unlabelled 2-D detections of calibrated "
                                    "cameras (seed 002, Section 2: prediction, the (M+1)-dimensional assignment by "
                                    "Lagrangian relaxation, triangulation).  Without MODEL: writes the trajectories "
                                    "as an unlabelled C3D (T1, T2, ...) and a report JSON with the tracker's "
                                    "figures.  With MODEL: groups the tracks into segments (seed 002, Section 3), "
                                    "labels them with MODEL's markers and calibrates MODEL to them; writes the "
                                    "labelled C3D, the subject URDF, the motion CSV and the report (calibration, "
                                    "tracker figures, labels).  See docs/tracking.md.")
    tr.add_argument("cameras", type=Path, help="camera calibration (.toml or .json; docs/tracking.md)")
    tr.add_argument("detections", type=Path, help="detections (.npz; docs/tracking.md)")
    tr.add_argument("model", type=Path, nargs="?", default=None, help="base model (.urdf) to label and calibrate")
    tr.add_argument("-o", "--output", type=Path, default=None,
                    help="with MODEL: the subject URDF (default: DETECTIONS' name + .urdf)")
    tr.add_argument("--c3d", type=Path, default=None,
                    help="the trajectories (default: DETECTIONS' name + _tracks.c3d)")
    tr.add_argument("--motion", type=Path, default=None,
                    help="with MODEL: the motion CSV (default: DETECTIONS' name + _motion.csv)")
    tr.add_argument("--report", type=Path, default=None,
                    help="report JSON (default: DETECTIONS' name + _tracks_report.json, with MODEL _report.json)")
    tr.add_argument("--min-frames", type=int, default=10, help="leave out tracks seen in fewer frames (default 10)")
    tr.add_argument("--greedy", action="store_true",
                    help="the baseline: nearest prediction per camera and pairs of cameras greedily, no relaxation")
    tr.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    tr.add_argument("-q", "--quiet", action="store_true",
                    help="no progress on stderr (the tracking's frames, the labelling's steps, the calibration's)")


def cmd_track(args: argparse.Namespace) -> int:
    from ..io.c3d import write_c3d
    from ..io.cameras import read_cameras, read_detections
    from ..track.tracker import Tracker, TrackSettings

    stem = args.detections.with_suffix("")
    out = args.c3d or stem.with_name(stem.name + "_tracks.c3d")
    if args.model is None:
        if args.output is not None or args.motion is not None:
            raise CalibrateError("-o and --motion name the subject's files: give MODEL too (or --c3d for the tracks)")
        report = args.report or stem.with_name(stem.name + "_tracks_report.json")
        targets = [out, report]
    else:
        report = args.report or stem.with_name(stem.name + "_report.json")
        urdf = args.output or stem.with_name(stem.name + ".urdf")
        motion = args.motion or stem.with_name(stem.name + "_motion.csv")
        targets = [out, urdf, motion, report]
    check_targets(targets, args.overwrite,
                  inputs={args.cameras: "that is the camera calibration; choose another name",
                          args.detections: "that is the detections file; choose another name",
                          **({args.model: "that is the base model; refusing to overwrite it (choose another -o)"}
                             if args.model else {})})
    cams = read_cameras(args.cameras)
    det = read_detections(args.detections, len(cams))
    if det.n_frames < 2:
        raise CalibrateError(f"{args.detections}: {det.n_frames} frames; tracking needs at least 2")
    if args.model is not None:
        return _track_subject(args, cams, det, out, urdf, motion, report)
    t0 = time.perf_counter()
    with _progress(args) as say:
        count = Countdown(say, "track", f"tracking {det.n_frames} frames of {len(cams)} cameras")
        tracks = Tracker(cams, TrackSettings(method="greedy" if args.greedy else "lagrangian")).run(
            det, lambda k, n: count(k / n))
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


def _progress(args: argparse.Namespace):
    """The progress on stderr, as the calibrate command shows it (nothing with --quiet)."""
    from ..problem.settings import Settings
    from .commands import Timed
    from .report import progress_for

    return progress_for(args.quiet, Settings().max_iterations, Timed)


def write_simulated_cameras(sim, out: Path, n_cameras: int, seed: int) -> dict[str, Path]:
    """`n_cameras` synthetic cameras and their detections of a simulation, written into `out`."""
    from ..simulation.cameras import simulate_cameras, write_camera_simulation

    cs = simulate_cameras(sim, n_cameras, seed)
    markers = sim.clean_markers if sim.artefact is None else sim.clean_markers + sim.artefact
    paths = write_camera_simulation(cs, Path(out), markers)
    if not np.any(cs.marker >= 0):
        raise CalibrateError(f"{out}: the cameras saw no marker; this should not happen with the default volume")
    return paths


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON: {type(x).__name__}")


def _track_subject(args, cams, det, c3d: Path, urdf: Path, motion: Path, report: Path) -> int:
    from ..calibration.report import provenance
    from ..io.c3d import write_c3d
    from ..io.motion import motion_csv_text
    from ..model.model import load_model
    from ..model.urdf import urdf_text, with_comment
    from ..track.subject import track_subject
    from ..track.tracker import TrackSettings

    model = load_model(args.model)
    t0 = time.perf_counter()
    with _progress(args) as say:
        res = track_subject(cams, det, model, TrackSettings(method="greedy" if args.greedy else "lagrangian"),
                            args.min_frames, progress=say)
    seconds = time.perf_counter() - t0
    cal = res.calibration
    rep = res.report()
    rep["tracker"]["seconds_total"] = seconds
    rep["outputs"] = {"c3d": str(c3d), "urdf": str(urdf), "motion": str(motion), "report": str(report)}
    # the subject URDF's first words: the tracked trial (the C3D written beside it) it was calibrated from
    named = provenance(cal, report, [c3d.name])
    write_all({c3d: lambda p: write_c3d(p, res.trial),
               urdf: lambda p: put_text(p, with_comment(urdf_text(cal.model, cal.params, cal.mass), named)),
               motion: lambda p: put_text(p, motion_csv_text(cal.motion)),
               report: lambda p: put_text(p, json.dumps(rep, indent=1, default=_json_default) + "\n")})
    fig = rep["tracker"]
    print(f"tracked {fig['frames']} frames of {len(cams)} cameras ({fig['ms_per_frame']:.2f} ms/frame): "
          f"{fig['tracks']} tracks, {100 * fig['assigned_share']:.1f} % of detections assigned, mean primal-dual "
          f"gap {fig['mean_gap']:.3g}; {len(res.labelling.labels)} of {res.trial.n_markers} written tracks "
          f"labelled with {model.path.name}'s markers")
    print(cal.text())
    print(f"\nwrote {c3d}\n      {urdf}\n      {motion}\n      {report}")
    return 0 if cal.converged else 1
