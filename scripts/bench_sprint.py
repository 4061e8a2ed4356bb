"""Another lab's marker set on our model: AddBiomechanics' Expert2 (Dorn's sprinter set: four runs at 3.5-9 m/s,
250 Hz, no static) calibrated on models/human.urdf from the command line, run by run, as a lab would try it.

Per run: the markers used (the model's, the new ones placed) and the labels left out, the marker RMS, the report's
implausible lines, the hips' width against the ASIS markers', and each hip flexion, knee and ankle angle against the
expert's inverse kinematics on the expert's hand-scaled model (the trial's ``.mot``): the SD over frames of their
difference, the mean offset removed (the two models' zero poses and signs differ; the sign is taken that fits).
Compare two versions of the code with ``PYTHONPATH=worktree`` for one of them.

    python scripts/bench_sprint.py --expert2 DIR [--model M.urdf] [--keep OUT] [--json out.json]

DIR: AddBiomechanics' ``paper_data/Expert2`` (github.com/keenon/AddBiomechanics: the TRCs and the expert's .mot).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from calibrate.io.motion import Motion, read_motion_csv

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibrate import machine  # noqa: E402
from bench_osim import read_mot  # noqa: E402  (an OpenSim .mot: times, columns, values in rad)

ROOT = Path(__file__).resolve().parents[1]
RUNS = ("run0350cms", "run0500cms", "run0700cms", "run0900cms")
#: our coordinate -> the expert's (models/human.urdf against the sprinter model's OpenSim names)
PAIRS = {"hip_r_flexion": "hip_flexion_r", "hip_l_flexion": "hip_flexion_l", "knee_r": "knee_angle_r",
         "knee_l": "knee_angle_l", "ankle_r": "ankle_angle_r", "ankle_l": "ankle_angle_l"}


def against_expert(ours: Motion, expert: Path) -> dict[str, float]:
    """Each PAIRS angle's SD (deg) of its difference from the expert's .mot, on our frames, offset and sign aside."""
    times, cols, vals = read_mot(str(expert))  # (rad)
    out = {}
    for a, b in PAIRS.items():
        if a not in ours.dof_names or b not in cols:
            continue
        x = ours.angles[:, ours.dof_names.index(a)]
        y = np.interp(ours.times, times, vals[:, cols.index(b)])
        out[a] = float(np.degrees(min(np.std(x - y), np.std(x + y))))
    return out


def run_one(trc: Path, model: Path, out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "calibrate", str(trc), str(model), "-o", str(out / "subject.urdf"),
                           "--overwrite", "-q"], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        return {"error": (done.stderr or done.stdout).strip().splitlines()[-1:]}
    rep = json.load(open(out / f"{trc.stem}_report.json"))
    hips = rep["hip_motion"][0] if rep["hip_motion"] else {}
    ms = rep["marker_set"]
    return {"seconds": wall, "marker_rms_mm": rep["markers"]["rms_mm"], "used": len(ms["used"]), "new": len(ms["new"]),
            "left_out": ms["left_out"], "implausible": rep["implausible_flags"],
            "hip_width_mm": hips.get("hip_width_mm"), "asis_width_mm": hips.get("asis_width_mm"),
            "vs_expert_sd_deg": against_expert(read_motion_csv(out / f"{trc.stem}_motion.csv"),
                                               trc.with_suffix(".mot"))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--expert2", required=True, type=Path, help="AddBiomechanics' paper_data/Expert2")
    ap.add_argument("--model", type=Path, default=ROOT / "models" / "human.urdf")
    ap.add_argument("--keep", type=Path, help="write each run's outputs here (kept)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    missing = [r for r in RUNS if not (args.expert2 / f"{r}.trc").exists() or not (args.expert2 / f"{r}.mot").exists()]
    if missing:
        print(f"bench_sprint: {args.expert2}: no {missing[0]}.trc / .mot (give AddBiomechanics' paper_data/Expert2)")
        return 2
    res = {"machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M"), "model": str(args.model), "runs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        base = args.keep or Path(tmp)
        for r in RUNS:
            row = run_one(args.expert2 / f"{r}.trc", args.model, base / r)
            res["runs"][r] = row
            if "error" in row:
                print(f"{r}: failed: {row['error']}")
                continue
            sd = ", ".join(f"{k} {v:.1f}" for k, v in row["vs_expert_sd_deg"].items())
            print(f"{r}: {row['used']} markers used ({row['new']} new), {len(row['left_out'])} labels left out, "
                  f"marker RMS {row['marker_rms_mm']:.2f} mm, hips {row['hip_width_mm'] or float('nan'):.0f} mm "
                  f"apart (ASIS {row['asis_width_mm'] or float('nan'):.0f}), {row['seconds']:.1f} s")
            print(f"    vs the expert's IK, SD of the difference (deg): {sd}")
            for x in row["implausible"]:
                print(f"    implausible: {x[:140]}")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
