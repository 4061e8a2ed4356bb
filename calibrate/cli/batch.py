"""``calibrate batch MANIFEST --out DIR [--workers N | --scheduler ADDRESS] [--config TOML] [--c3d] [--mjcf]
[--overwrite]``: a lab's subjects calibrated in parallel on Dask (calibrate.calibration.batch), a thin layer over
run_batch."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from calibrate.cli.args import positive_int

from ..errors import CalibrateError


def add_batch_parser(sub) -> None:
    """The 'batch' command's parser."""
    bp = sub.add_parser("batch", help="calibrate a manifest of subjects in parallel on Dask",
                        description="Calibrate every subject of MANIFEST (TOML or CSV: id, trials, base model, "
                                    "marker map, mass, settings file, ik trials; docs/batch.md) on a Dask cluster: one "
                                    "folder of outputs per subject in --out (subject.urdf, motion CSVs, report.json, "
                                    "report.html; each ik trial fitted to the calibrated subject as calibrate ik "
                                    "does), summary.csv and index.html across them.  Subjects already done are "
                                    "skipped unless --overwrite; a failing subject is reported and the others go on.")
    bp.add_argument("manifest", type=Path, metavar="MANIFEST", help="the subjects (.toml or .csv)")
    bp.add_argument("--out", type=Path, required=True, metavar="DIR", help="the folder of the outputs")
    where = bp.add_mutually_exclusive_group()
    where.add_argument("--workers", type=positive_int, default=2, metavar="N",
                       help="worker processes of the local cluster (default 2, one thread each)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="an existing Dask cluster's scheduler (e.g. tcp://10.0.0.5:8786) instead")
    bp.add_argument("--c3d", action="store_true",
                    help="also each trial as <trial>_calibrated.c3d in its subject's folder (as calibrate --c3d)")
    bp.add_argument("--mjcf", action="store_true",
                    help="also subject_mujoco.xml and each trial's <trial>_motion_qpos.csv in its subject's folder "
                         "(as calibrate --mjcf)")
    bp.add_argument("--overwrite", action="store_true", help="calibrate again the subjects already done")
    bp.add_argument("--config", type=Path, default=None, metavar="TOML",
                    help="the settings file (as calibrate --config) of every subject that names none of its own, "
                         "in place of the manifest's config")


def cmd_batch(args: argparse.Namespace) -> int:
    try:
        from ..calibration.batch import read_manifest, run_batch
    except ImportError as e:  # dask is an extra
        raise CalibrateError(f"calibrate batch needs dask.distributed ({e}); pip install -e \".[batch]\"") from None
    subjects = read_manifest(args.manifest, args.config)
    if args.out.exists() and not args.out.is_dir():
        raise CalibrateError(f"{args.out}: exists and is not a folder; choose another --out")

    def progress(row: dict, done: int, total: int) -> None:
        what = row["error"] if row["status"] == "failed" else (
            "already done" if row["status"] == "skipped" else
            f"marker RMS {row['marker_rms_mm']:.2f} mm, {row['iterations']} iterations, {row['seconds']:.1f} s"
            + (f"; {len(row['implausible'])} implausible (summary.csv)" if row.get("implausible") else ""))
        if row.get("ik_trials"):
            what += (f"; {row['ik_trials']} ik trials, worst marker RMS {row['ik_marker_rms_mm']:.2f} mm")
        if row["status"] != "failed" and row["error"]:  # an ik trial that failed
            what += f"; {row['error']}"
        print(f"  [{done}/{total}] {row['subject']}: {row['status']} ({what})", file=sys.stderr, flush=True)

    rows = run_batch(subjects, args.out, workers=args.workers, scheduler=args.scheduler, overwrite=args.overwrite,
                     progress=progress, c3d=args.c3d, mjcf=args.mjcf)
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "not converged", "failed", "skipped")}
    print(f"{len(rows)} subjects: " + ", ".join(f"{n} {s}" for s, n in counts.items() if n))
    print(f"wrote {args.out / 'summary.csv'}\n      {args.out / 'index.html'}")
    ik_failed = sum(bool(r["error"]) and r["status"] != "failed" for r in rows)
    if ik_failed:
        print(f"{ik_failed} subjects with ik trials that failed (summary.csv's error)")
    return 1 if counts["failed"] or counts["not converged"] or ik_failed else 0
