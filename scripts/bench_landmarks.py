"""A lab's named arm landmarks on other trials of its subject: AddBiomechanics' Expert1 (a static, a walk and 23 other
trials: walks, squats, jumps, sit-to-stands) calibrated on static1 + walking1 with each base model, every other trial
then fitted to the subject held fixed (`calibrate batch` with `ik_trials`, as a lab would run it).

Per model: the calibration's marker RMS, its unreliable and implausible lines, the static's elbow and forearm angles
(left against right: the static-asymmetry check's figures), and over the other trials (walks and the rest apart) the
mean per-trial marker RMS over every marker fitted and over the arm markers.  With `--compare DIR` (the `--keep` folder
of another run, e.g. the code before a change in a worktree: `PYTHONPATH=worktree python scripts/bench_landmarks.py`),
each trial's RMS is also taken over the markers both runs fit, against that run's.

    PYTHONPATH=. python scripts/bench_landmarks.py --expert1 DIR [--models M ...] [--keep OUT] [--compare DIR]
        [--json out.json]

DIR: AddBiomechanics' `paper_data/Expert1` (keenon/AddBiomechanics; TRCs and generic.osim).  Models: `human`
(models/human.urdf), `girdle` (models/human_girdle.urdf), `osim` (DIR/generic.osim).
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ARM = ("R_elbow_med", "R_elbow_lat", "R_wrist_radius", "R_wrist_ulna", "R_forearm", "R_humerus", "L_elbow_med",
       "L_elbow_lat", "L_wrist_radius", "L_wrist_ulna", "L_forearm", "L_humerus", "RELB", "RFRM", "RUPA", "RWRA",
       "RWRB", "LELB", "LFRM", "LUPA", "LWRA", "LWRB", "R_Shoulder", "L_Shoulder", "RSHO", "LSHO")


def manifest(expert: Path, models: list[str], out: Path) -> Path:
    """A batch manifest: one subject per base model, static1 + walking1, every other trial an ik trial."""
    paths = {"human": ROOT / "models" / "human.urdf", "girdle": ROOT / "models" / "human_girdle.urdf",
             "osim": expert / "generic.osim"}
    lines = []
    for m in models:
        lines += ["[[subject]]", f'id = "{m}"',
                  f'trials = ["{expert / "static1.trc"}", "{expert / "walking1.trc"}"]',
                  f'model = "{paths[m]}"', f'ik_trials = ["{expert / "*.trc"}"]', ""]
    out.write_text("\n".join(lines))
    return out


def static_angles(folder: Path) -> dict[str, float]:
    """The static's mean elbow and forearm angles (deg) from its motion CSV."""
    rows = list(csv.reader(x for x in open(folder / "static1_motion.csv") if not x.startswith("#")))
    head, a = rows[0], np.degrees(np.array(rows[1:], float)).mean(axis=0)
    keys = ("elbow", "radioulnar", "pro_sup")
    return {c: round(float(a[i]), 1) for i, c in enumerate(head) if any(k in c for k in keys)}


def per_trial(folder: Path) -> dict[str, dict]:
    """Each ik trial's per-marker RMS (mm), from its ik report."""
    return {Path(f).name.removesuffix("_ik_report.json"): json.load(open(f))["markers"]["per_marker"]
            for f in sorted(glob.glob(str(folder / "*_ik_report.json")))}


def rms(table: dict, names) -> float:
    vals = [table[m]["rms_mm"] for m in names if m in table]
    return float(np.sqrt(np.mean(np.square(vals)))) if vals else float("nan")


def score(folder: Path, other: Path | None) -> dict:
    rep = json.load(open(folder / "report.json"))
    trials = per_trial(folder)
    theirs = per_trial(other) if other is not None and other.exists() else {}
    out = {"calibration_rms_mm": rep["markers"]["rms_mm"], "unreliable": rep["unreliable"],
           "implausible": rep["implausible_flags"], "ignored_labels": rep["marker_set"]["ignored_labels"],
           "static_deg": static_angles(folder), "trials": {}}
    for name, t in trials.items():
        row = {"rms_mm": rms(t, t), "arm_rms_mm": rms(t, [m for m in t if m in ARM]), "markers": len(t)}
        if name in theirs:
            both = [m for m in t if m in theirs[name]]
            row.update(common_markers=len(both), common_rms_mm=rms(t, both), compared_rms_mm=rms(theirs[name], both))
        out["trials"][name] = row
    for kind, pick in (("walks", lambda n: n.startswith("walking")), ("others", lambda n: not n.startswith("walking"))):
        rows = [r for n, r in out["trials"].items() if pick(n)]
        out[kind] = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k.endswith("_mm")} if rows else {}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--expert1", required=True, type=Path, help="AddBiomechanics' paper_data/Expert1")
    ap.add_argument("--models", nargs="+", default=["human", "girdle", "osim"], choices=["human", "girdle", "osim"])
    ap.add_argument("--keep", type=Path, help="write the batch's outputs here (kept) rather than in a temporary folder")
    ap.add_argument("--compare", type=Path, help="another run's --keep folder: RMS over the markers both fit")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    if not (args.expert1 / "static1.trc").exists():
        print(f"bench_landmarks: {args.expert1}: no static1.trc (give AddBiomechanics' paper_data/Expert1)")
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        out = args.keep or Path(tmp) / "out"
        toml = manifest(args.expert1, args.models, Path(tmp) / "expert1.toml")
        t0 = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "calibrate", "batch", str(toml), "--out", str(out), "--overwrite"],
                              capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if not (out / "summary.csv").exists():
            print(done.stderr[-2000:])
            return 1
        res = {"batch_s": wall, "models": {m: score(out / m, args.compare / m if args.compare else None)
                                           for m in args.models}}
    for m, r in res["models"].items():
        print(f"== {m}: calibration {r['calibration_rms_mm']:.2f} mm; static {r['static_deg']}")
        print(f"   unreliable {r['unreliable']}; labels ignored {r['ignored_labels']}")
        for x in r["implausible"]:
            print(f"   implausible: {x[:150]}")
        for kind in ("walks", "others"):
            k = r[kind]
            line = f"   {kind:6s} marker RMS {k['rms_mm']:6.2f} mm, arm markers {k['arm_rms_mm']:6.2f}"
            if "common_rms_mm" in k:
                line += f"; over the markers both fit {k['compared_rms_mm']:6.2f} -> {k['common_rms_mm']:6.2f}"
            print(line)
    print(f"batch (calibrations and ik trials, {len(args.models)} models): {res['batch_s']:.1f} s")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
