"""Benchmark trials that mark part of the body: the pelvis riding with the one branch the markers place.

An upper-body trial (the trunk, head and arms marked) or a one-leg trial shows no marker on the pelvis; calibrate
then holds the joints between the pelvis and the marked part and lets the pelvis ride with it
(calibrate.model.resolve.carried_root).  Measured against the same trials calibrated from every marker, in the same
run:

1. The simulator's overhead arm arcs (models/human.urdf, and Rajagopal2016.osim from ../shared/data/real; `--frames`,
   1 mm noise, seed 3): each arm joint's (and the neck's) centre's mean distance from the simulator's truth over the
   frames, from every marker and from those of the trunk, head and arms; marker RMS and wall time.
2. pig_walk (../shared/data/real/pig_walk, static + walk, Plug-in Gait labels) with its pelvis and leg markers
   removed, and with all but the left leg's removed: marker RMS over the markers kept (from every marker: over the
   same markers), wall time, and each centre's median distance over the walk from Plug-in Gait's own (the segment
   origins Vicon puts at the distal joint centres: clavicle LCLO / RCLO the shoulder, humerus LHUO / RHUO the
   elbow, radius LRAO / RRAO the wrist, femur LFEO the knee, tibia LTIO the ankle).

    python scripts/bench_partial.py [--frames 600] [--json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np
from bench_calibrate import machine  # shared with the other benches

ROOT = Path(__file__).resolve().parent.parent
PIG = ROOT.parent / "shared" / "data" / "real" / "pig_walk"
RAJAGOPAL = ROOT.parent / "shared" / "data" / "real" / "rajagopal_walk" / "Rajagopal2016.osim"
UPPER = ("torso", "head", "humerus_l", "ulna_l", "radius_l", "hand_l", "humerus_r", "ulna_r", "radius_r", "hand_r")
LEG = ("femur_l", "tibia_l", "talus_l", "calcn_l")
PIG_CENTRES = {"shoulder_l": "LCLO", "shoulder_r": "RCLO", "elbow_l": "LHUO", "elbow_r": "RHUO", "wrist_l": "LRAO",
               "wrist_r": "RRAO", "knee_l": "LFEO", "ankle_l": "LTIO"}


def _markers(model, segments) -> list[str]:
    return [m for s in segments for m in model.segments[model.segment_index(s)].markers]


def _centres(kin, cal, trial: int) -> np.ndarray:
    """The calibrated joint centres in the lab over one trial's frames (n, n_joints, 3)."""
    mo = cal.motions[trial]
    Z = np.column_stack([mo.root_translation, np.zeros((mo.n_frames, 3)), mo.angles])
    return kin.batch(Z, mo.root_quaternion, cal.params)[1]


def _rms_mm(cal, names) -> float:
    r = cal.residuals[:, [cal.model.marker_index(n) for n in names]]
    return round(1e3 * float(np.sqrt(np.nanmean(np.sum(r ** 2, axis=2)))), 2)


def _timed(model, trials, settings):
    from calibrate import calibrate

    t0 = time.perf_counter()
    cal = calibrate(model, trials, settings)
    return cal, round(time.perf_counter() - t0, 2)


def simulated(frames: int, path: Path = ROOT / "models" / "human.urdf") -> dict:
    """The overhead arm arcs on the model at `path`, from every marker and from the trunk's and arms' (and head's)."""
    from calibrate import Settings
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_overhead

    human = load_model(path)
    kin = build_kinematics(human)
    sim = simulate_overhead(human, frames=frames, seed=3)
    upper = [s for s in UPPER if s in {sg.name for sg in human.segments}]
    joints = [j.name for j in human.joints if j.child in upper and j.dofs and j.child != "torso"]
    _timed(human, sim.trial, Settings())  # warm-up (imports, CasADi's first builds)
    out = {"model": path.name, "frames": frames}
    for name, trial in (("all", sim.trial), ("upper", sim.trial.select(_markers(human, upper)))):
        cal, wall = _timed(human, trial, Settings())
        C = _centres(kin, cal, 0)
        out[name] = {"markers": len(trial.labels), "wall_s": wall, "marker_rms_mm": round(1e3 * cal.marker_rms, 2),
                     "locked_for_root": list(cal.unresolved[0].coordinates) if cal.unresolved and
                     cal.unresolved[0].segment == human.root else [],
                     "centre_error_mm": {j: round(1e3 * float(np.linalg.norm(
                         C[:, human.joint_index(j)] - sim.clean_centres[:, human.joint_index(j)], axis=1).mean()), 1)
                         for j in joints}}
    return out


def pig_walk() -> dict:
    from calibrate import Settings
    from calibrate.io.c3d import read_c3d
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model

    human = load_model(ROOT / "models" / "human.urdf")
    kin = build_kinematics(human)
    trials = [read_c3d(PIG / "static.c3d"), read_c3d(PIG / "walk.c3d")]
    lab = trials[1].model_outputs
    _timed(human, trials, Settings())  # warm-up
    every, wall = _timed(human, trials, Settings())
    out = {"all": {"wall_s": wall, "marker_rms_mm": round(1e3 * every.marker_rms, 2)}}
    for name, segments in (("upper", UPPER), ("leg_l", LEG)):
        keep = set(_markers(human, segments))
        cal, wall = _timed(human, [t.select([x for x in t.labels if x in keep]) for t in trials], Settings())
        joints = [j for j in PIG_CENTRES if human.joints[human.joint_index(j)].child in segments]
        row = {"markers": len(keep & set(trials[1].labels)), "wall_s": wall, "marker_rms_mm": _rms_mm(cal, keep),
               "all_markers_rms_mm": _rms_mm(every, keep), "locked_for_root": list(cal.unresolved[0].coordinates)}
        for key, c in (("from_plugin_gait_mm", cal), ("all_markers_from_plugin_gait_mm", every)):
            C = _centres(kin, c, 1)
            row[key] = {j: round(float(np.nanmedian(1e3 * np.linalg.norm(
                C[:, human.joint_index(j)] - lab[PIG_CENTRES[j]], axis=1))), 1) for j in joints}
        out[name] = row
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600, help="frames of the simulated overhead trial")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    a = ap.parse_args()
    res = {"date": datetime.datetime.now().isoformat(timespec="minutes"), "machine": machine(),
           "simulated": simulated(a.frames),
           "simulated_osim": simulated(a.frames, RAJAGOPAL) if RAJAGOPAL.is_file() else None,
           "pig_walk": pig_walk() if PIG.is_dir() else None}
    if a.json:
        print(json.dumps(res))
        return 0
    for s in (res["simulated"], res["simulated_osim"]):
        if s is None:
            continue
        print(f"simulated overhead arcs on {s['model']}, {s['frames']} frames: centre error from the truth (mm), "
              "marker RMS, wall time")
        for name in ("all", "upper"):
            r = s[name]
            print(f"  {name:6s} {r['markers']:2d} markers  {r['marker_rms_mm']:.2f} mm  {r['wall_s']:.2f} s  "
                  + "  ".join(f"{j} {v:.1f}" for j, v in r["centre_error_mm"].items()))
    p = res["pig_walk"]
    if p is None:
        print(f"pig_walk: {PIG} not found")
        return 0
    print(f"pig_walk (static + walk), every marker: {p['all']['marker_rms_mm']:.2f} mm, {p['all']['wall_s']:.2f} s")
    for name in ("upper", "leg_l"):
        r = p[name]
        print(f"  {name}: {r['markers']} markers, {r['wall_s']:.2f} s, RMS over them {r['marker_rms_mm']:.2f} mm "
              f"(every marker's calibration: {r['all_markers_rms_mm']:.2f}); held: {', '.join(r['locked_for_root'])}")
        every = r["all_markers_from_plugin_gait_mm"]
        print("    median distance from Plug-in Gait's centre (mm), alone / every marker: " + ", ".join(
            f"{j} {v:.1f} / {every[j]:.1f}" for j, v in r["from_plugin_gait_mm"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
