"""Benchmark the shoulder girdle: models/human_girdle.urdf against models/human.urdf on the same trials.

models/human_girdle.urdf carries each shoulder and its acromion marker on a clavicle (a sternoclavicular universal
joint on the torso); models/human.urdf carries the acromion marker on the torso, while the shoulder blade lifts it
with the arm (docs/model-format.md).  Both models calibrated in the same run on:

1. The simulator's overhead arm arcs of a girdle subject, whose clavicles rise with the arms
   (calibrate.simulation.motions.GIRDLE_RHYTHM; 400 frames, 1 mm noise; seed 1, and seed 2 with 3 mm of skin
   artefact) and of a models/human.urdf subject (seed 1): marker RMS (and the truth refitted, the floor), each
   shoulder centre's median and 95th-percentile distance from the truth's in the lab, the `implausible` lines.
2. pig_walk (../shared/data/real/pig_walk, static + walk): marker RMS, wall time, each shoulder's, elbow's and
   wrist's median distance over the walk from Plug-in Gait's own (the segment origins Vicon puts at the joint
   centres: clavicle LCLO / RCLO the shoulder, humerus LHUO / RHUO the elbow, radius LRAO / RRAO the wrist),
   the shoulders' and lumbar's distance from the scaled base model's, the `implausible` lines.
3. `--run NAME FILE [FILE ...]` (repeatable): any other trials at hand, as in 2 without Plug-in Gait's centres
   (docs/benchmarks.md ran the CMU database's 01_01 and AddBiomechanics' trials so).

    python scripts/bench_girdle.py [--run cmu 01_01.c3d] [--json]
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
from bench_partial import PIG, PIG_CENTRES, _centres

ROOT = Path(__file__).resolve().parent.parent
MODELS = {"human": ROOT / "models" / "human.urdf", "girdle": ROOT / "models" / "human_girdle.urdf"}


def _flags(cal) -> list[str]:  # noqa: ANN001
    """The summary's `implausible` lines, each by what it names (centre[shoulder_l], hip_l, a trial's file...)."""
    return [line.split("implausible", 1)[1].strip().split(":")[0].split(" ")[0]
            for line in cal.text().splitlines() if line.startswith("  implausible")]


def _timed(model, trials):  # noqa: ANN001, ANN202
    from calibrate import calibrate

    t0 = time.perf_counter()
    cal = calibrate(model, trials)
    return cal, round(time.perf_counter() - t0, 2)


def _from_base(cal) -> dict[str, float]:  # noqa: ANN001
    """The shoulders' and the lumbar's distance from the scaled base model's (mm: what the scales do not explain)."""
    out = {}
    for ch in cal.changes:
        if ch.group == "centre" and ch.item.startswith(("shoulder_", "lumbar")):
            out[ch.item] = round(ch.beyond_scale, 1)
    return out


def simulated(truth: str, seed: int, sta_mm: float) -> dict:
    """A `truth` subject's overhead arcs, calibrated from both models: shoulders against the truth."""
    from calibrate.calibration.evaluate import true_marker_floor
    from calibrate.model.blocks import FrameLayout
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_overhead

    sim = simulate_overhead(load_model(MODELS[truth]), frames=400, seed=seed, sta_mm=sta_mm)
    index = {j.name: i for i, j in enumerate(sim.model.joints)}
    out = {"truth": truth, "seed": seed, "sta_mm": sta_mm,
           "floor_rms_mm": round(1e3 * true_marker_floor(sim), 2) if sta_mm == 0 else None}
    for name, path in MODELS.items():
        model = load_model(path)
        cal, wall = _timed(model, sim.trial)
        mo = cal.motion
        _, C = build_kinematics(model).batch(FrameLayout.coordinates(mo.root_translation, mo.angles),
                                             mo.root_quaternion, cal.params)
        shoulders = {}
        for s in ("shoulder_l", "shoulder_r"):
            d = 1e3 * np.linalg.norm(C[:, model.joint_index(s)] - sim.clean_centres[:, index[s]], axis=1)
            shoulders[s] = [round(float(np.median(d)), 1), round(float(np.percentile(d, 95)), 1)]
        out[name] = {"marker_rms_mm": round(1e3 * cal.marker_rms, 2), "wall_s": wall,
                     "shoulders_from_truth_mm": shoulders, "implausible": _flags(cal)}
    return out


def real(trials_paths: list[Path], plugin_gait: bool = False) -> dict:
    """Both models on one set of real trials (the last is the moving trial Plug-in Gait's centres are read from)."""
    from calibrate import read_trial
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model

    trials = [read_trial(p) for p in trials_paths]
    out = {"trials": [p.name for p in trials_paths]}
    for name, path in MODELS.items():
        model = load_model(path)
        cal, wall = _timed(model, trials)
        row = {"marker_rms_mm": round(1e3 * cal.marker_rms, 2), "wall_s": wall, "from_base_mm": _from_base(cal),
               "implausible": _flags(cal)}
        if plugin_gait:
            lab = trials[-1].model_outputs
            C = _centres(build_kinematics(model), cal, len(trials) - 1)
            row["from_plugin_gait_mm"] = {j: round(float(np.nanmedian(1e3 * np.linalg.norm(
                C[:, model.joint_index(j)] - lab[PIG_CENTRES[j]], axis=1))), 1)
                for j in ("shoulder_l", "shoulder_r", "elbow_l", "elbow_r", "wrist_l", "wrist_r")}
        out[name] = row
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", nargs="+", action="append", default=[], metavar=("NAME", "FILE"),
                    help="a name and the trials of another real run (repeatable)")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    a = ap.parse_args()
    for run in a.run:
        missing = [f for f in run[1:] if not Path(f).is_file()]
        if len(run) < 2 or missing:
            ap.error(f"--run {' '.join(run)}: give a name and its trial files ({', '.join(missing) or 'none'} "
                     "not found)")
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_overhead

    _timed(load_model(MODELS["girdle"]), simulate_overhead(load_model(MODELS["girdle"]), frames=100).trial)  # warm
    res = {"date": datetime.datetime.now().isoformat(timespec="minutes"), "machine": machine(),
           "simulated": [simulated("girdle", 1, 0.0), simulated("girdle", 2, 3.0), simulated("human", 1, 0.0)],
           "pig_walk": real([PIG / "static.c3d", PIG / "walk.c3d"], plugin_gait=True) if PIG.is_dir() else None,
           "runs": {run[0]: real([Path(f) for f in run[1:]]) for run in a.run}}
    if a.json:
        print(json.dumps(res))
        return 0
    print("simulated overhead arcs, 400 frames: marker RMS (floor), shoulders' median / 95th-percentile distance from "
          "the truth (mm), implausible")
    for s in res["simulated"]:
        for name in MODELS:
            r = s[name]
            sh = "  ".join(f"{j} {v[0]:.1f} / {v[1]:.1f}" for j, v in r["shoulders_from_truth_mm"].items())
            print(f"  truth {s['truth']:6s} seed {s['seed']} artefact {s['sta_mm']:.0f} mm  {name:6s} "
                  f"{r['marker_rms_mm']:6.2f} mm ({s['floor_rms_mm'] or '-'})  {sh}  {', '.join(r['implausible'])}")
    named = ({"pig_walk": res["pig_walk"]} if res["pig_walk"] else {}) | res["runs"]
    for run, r in named.items():
        print(f"{run} ({', '.join(r['trials'])}):")
        for name in MODELS:
            x = r[name]
            pg = x.get("from_plugin_gait_mm")
            print(f"  {name:6s} {x['marker_rms_mm']:.2f} mm {x['wall_s']:.1f} s; from the base model "
                  + ", ".join(f"{j} {v:.0f}" for j, v in x["from_base_mm"].items())
                  + (("; from Plug-in Gait's " + ", ".join(f"{j} {v:.0f}" for j, v in pg.items())) if pg else "")
                  + f"; implausible: {', '.join(x['implausible']) or '-'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
