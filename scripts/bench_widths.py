"""The population's joint widths against measured ones: on real Plug-in Gait sessions that carry their subject's knee
and ankle widths (PROCESSING:LKneeWidth, ...), each calibrated with the measurements set aside (Priors.width = 0),
once with the population's width placing the hinges along their axes (Priors.population_width, the default) and once
without it; each lateral marker's calibrated distance from its centre along the axis against the measured one (half
the width plus the marker's radius, as Plug-in Gait places the centre).

    python scripts/bench_widths.py --btkdata DIR [--pig-walk DIR] [--simulated N] [--used] [--no-feet] [--json OUT.json]

DIR: a folder of BTKData's C3D files as scripts/public_data.py lays them out (btk__PiG__*.c3d, btk__others__*.c3d);
--pig-walk: ../shared/data/real/pig_walk (static.c3d + walk.c3d) by default.  --used: each session also calibrated
with its widths used ("used", the default run; the elbows' among them beside a walk), and every run's shoulder, elbow
and wrist centres against Plug-in Gait's own in the last trial (median over its frames).  --no-feet: every session
without its heel and toe markers (a lower-limb set without feet: the ankles locked, the tali held,
Problem.unslid_width_terms); implies --used.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_real import PIG_CENTRES, read_c3d_points  # noqa: E402  (Plug-in Gait's own centres in a C3D)

from calibrate import calibrate  # noqa: E402
from calibrate.calibration.report import lateral_sides
from calibrate.errors import CalibrateError
from calibrate.io.measurements import lateral_distance
from calibrate.io.read import read_trial
from calibrate.model.blocks import FrameLayout
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model
from calibrate.problem import gauge
from calibrate.problem.options import Priors
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats

HERE = Path(__file__).resolve().parent
MODEL = HERE.parent / "models" / "human.urdf"
# One file per subject and session among BTKData's (the _FF_N18 / _noFF copies repeat PiG_Motion3_FF's data).
BTK = ("btk__PiG__PiG_Motion-FlatFoot-Full.c3d", "btk__PiG__PiG_Motion-FlatFoot-Hole.c3d",
       "btk__PiG__PiG_Motion3_FF.c3d", "btk__PiG__PiG_Calibration2-NoOption.c3d", "btk__others__FunctionalWalk.c3d")


LABELS = ("population", "without", "used")  # ("used": the measured widths used; its key never "measured_mm")


def without_feet(trial):
    """The trial without its heel and toe markers (Plug-in Gait's HEE, TOE)."""
    keep = [i for i, label in enumerate(trial.labels) if label[1:] not in ("HEE", "TOE")]
    return replace(trial, labels=[trial.labels[i] for i in keep], markers=trial.markers[:, keep])


def case(model, trials, name: str, measured_too: bool = False) -> dict:
    """One session calibrated with and without the population's width, its measured widths set aside (and, with
    `measured_too`, with them used)."""
    measured = next(t.measurements for t in trials if getattr(t, "measurements", None) is not None)
    out = {"case": name, "joints": {}}
    runs = [("population", Priors(width=0.0)), ("without", Priors(width=0.0, population_width=0.0))]
    for label, priors in runs + ([("used", Priors())] if measured_too else []):
        t0 = time.perf_counter()
        cal = calibrate(model, trials, Settings(priors=priors))
        out[f"{label}_s"] = time.perf_counter() - t0
        out[f"{label}_rms_mm"] = 1000 * cal.marker_rms
        out.setdefault("population_widths", list(cal.population_widths))
        out.setdefault("locked", sorted(cal.locked))
        if measured_too:
            out.setdefault("pig_mm", {})[label] = arm_from_pig(cal, trials[-1])
        sides = lateral_sides(cal)  # read against the base model's markers by name (a subject's new ones among them)
        for joint in cal.population_widths or (j for j, _, _ in cal.settings.lateral_markers):
            truth = measured.lateral_distance(joint)
            if truth is None or joint not in sides:  # (lateral_sides leaves out a marker no trial shows)
                continue
            marker = sides[joint]["marker"]
            row = out["joints"].setdefault(joint, {"marker": marker, "measured_mm": 1000 * truth})
            row[f"{label}_mm"] = sides[joint]["lateral_mm"]
    for row in out["joints"].values():
        for label in LABELS:
            if f"{label}_mm" in row:
                row[f"{label}_error_mm"] = row[f"{label}_mm"] - row["measured_mm"]
    return out


def arm_from_pig(cal, trial) -> dict[str, float]:
    """Each shoulder, elbow and wrist centre of the calibration against Plug-in Gait's own in `trial` (its last
    motion; LHUP, LHUO, LRAO, ...): median distance over the frames, mm."""
    motion = cal.motions[-1]
    Z = FrameLayout.coordinates(motion.root_translation, motion.angles)
    _, centres = build_kinematics(cal.model).batch(Z, motion.root_quaternion, cal.params)
    joints = [f"{j}_{s}" for j in ("shoulder", "elbow", "wrist") for s in "lr"]
    labels = {j: ("L" if j.endswith("_l") else "R") + PIG_CENTRES[j[:-2]] for j in joints}
    ref = read_c3d_points(Path(trial.source), list(labels.values()))
    out = {}
    for j, label in labels.items():
        if label in ref and len(ref[label]) == len(Z):
            d = np.linalg.norm(centres[:, cal.model.joint_index(j)] - ref[label], axis=1)
            if np.isfinite(d).any():
                out[j] = 1000 * float(np.nanmedian(d))
    return out


def simulated(model, seeds: int) -> dict:
    """Squats of `seeds` simulated subjects (200 frames, seeds 0..seeds-1): each knee's and ankle's lateral distance
    from its centre minus the truth's (mm), with the population's width and without it."""
    pairs = [("knee_l", "LKNE"), ("knee_r", "RKNE"), ("ankle_l", "LANK"), ("ankle_r", "RANK")]
    base = model.parameters()
    out = {"population": [], "without": []}
    for seed in range(seeds):
        sim = simulate_squats(model, frames=200, noise_mm=1.0, seed=seed)
        for label, priors in (("population", Priors()), ("without", Priors(population_width=0.0))):
            cal = calibrate(model, sim.trial, Settings(outliers=0.0, priors=priors))
            out[label] += [1000 * (lateral_distance(model, cal.params, base, j, mk)
                                   - lateral_distance(model, sim.truth, base, j, mk)) for j, mk in pairs]
    return {label: {"errors_mm": e, "rms_mm": float(np.sqrt(np.mean(np.square(e)))),
                    "max_abs_mm": float(np.abs(e).max())} for label, e in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--btkdata", type=Path, required=True, help="folder of BTKData's C3D files (public_data.py)")
    ap.add_argument("--pig-walk", type=Path, default=HERE.parent.parent / "shared" / "data" / "real" / "pig_walk")
    ap.add_argument("--simulated", type=int, default=0, metavar="N",
                    help="also N simulated subjects' squats against their truth (the simulator's markers sit near the "
                         "base model's)")
    ap.add_argument("--used", action="store_true", help="each session also calibrated with its widths used, and the "
                    "arm's centres against Plug-in Gait's own")
    ap.add_argument("--no-feet", action="store_true", help="every session without its heel and toe markers (implies "
                    "--used)")
    ap.add_argument("--slide-with-markers", action="store_true",
                    help="the hinges' slides along their axes pulled by their child's markers' priors too, as before "
                         "2026-12-07 (calibrate.problem.gauge.SLIDE_WITHOUT_MARKERS off)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    gauge.SLIDE_WITHOUT_MARKERS = not args.slide_with_markers
    model = load_model(MODEL)
    sim = simulated(model, args.simulated) if args.simulated else None
    if sim is not None:
        for label, r in sim.items():
            print(f"simulated  {label:10s} lateral distance - the truth's: RMS {r['rms_mm']:.1f} mm, worst "
                  f"{r['max_abs_mm']:.1f} mm")
    sessions = [(f, [read_trial(args.btkdata / f)]) for f in BTK if (args.btkdata / f).exists()]
    if (args.pig_walk / "static.c3d").exists():
        walk = [read_trial(args.pig_walk / n) for n in ("static.c3d", "walk.c3d")]
        sessions.append(("pig_walk", walk))
    if args.no_feet:
        sessions = [(name, [without_feet(t) for t in trials]) for name, trials in sessions]
    used = args.used or args.no_feet
    results = []
    for name, trials in sessions:
        if all(getattr(t, "measurements", None) is None for t in trials):
            continue
        try:
            r = case(model, trials, name, used)
        except CalibrateError as e:  # a file whose labels are not the model's (BTKData's parameterOverflow)
            print(f"{name[:44]:44s} refused: {str(e)[:100]}")
            continue
        results.append(r)
        labels = LABELS if used else LABELS[:2]
        rms = " / ".join(f"{r[x + '_rms_mm']:.3f}" for x in labels)
        print(f"{name[:44]:44s} marker RMS {rms} mm; "
              f"lateral marker to centre, calibrated - measured (mm), {' / '.join(labels)}:")
        for j, row in r["joints"].items():
            errors = " / ".join(f"{row.get(f'{x}_error_mm', float('nan')):+6.1f}" for x in labels)
            held = " (locked)" if j in r["locked"] else ""
            print(f"    {j:8s} {row['marker']:5s} measured {row['measured_mm']:5.1f}  {errors}{held}")
        for label, pig in r.get("pig_mm", {}).items():
            print(f"    {label:10s} centres from Plug-in Gait's (mm): "
                  + ", ".join(f"{j} {d:.0f}" for j, d in pig.items()))
    summary = {}
    for label in LABELS if used else LABELS[:2]:
        rows = [row for r in results for row in r["joints"].values() if f"{label}_error_mm" in row]
        e = np.array([row[f"{label}_error_mm"] for row in rows])
        summary[label] = {"hinges": len(rows), "rms_mm": float(np.sqrt(np.mean(e ** 2))) if rows else None,
                          "max_abs_mm": float(np.abs(e).max()) if rows else None,
                          "medial": sum(row[f"{label}_mm"] < 0 for row in rows)}
    for label, s in summary.items():
        print(f"{label:10s} {s['hinges']} hinges: calibrated - measured RMS {s['rms_mm']:.1f} mm, worst "
              f"{s['max_abs_mm']:.1f} mm, {s['medial']} ended medial of their centre")
    if args.json:
        args.json.write_text(json.dumps({"date": time.strftime("%Y-%m-%dT%H:%M:%S"), "machine": platform.machine(),
                                         "python": platform.python_version(), "model": str(MODEL),
                                         "used": used, "no_feet": args.no_feet,
                                         "slide_with_markers": args.slide_with_markers,
                                         "sessions": results, "summary": summary,
                                         "simulated": sim},
                                        indent=1, default=float))


if __name__ == "__main__":
    main()
