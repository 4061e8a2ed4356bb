"""Benchmark CAST sessions: a static with the landmarks and the clusters, movement trials with the clusters alone.

A lab following the CAST protocol (Cappozzo et al. 1995) records its movement trials by technical clusters only; the
marker map's `[segments]` names each cluster's segment, and calibrate places the clusters from the static and poses the
movement trials by them, all solved together (docs/calibration.md, "Trials of clusters alone").  Measured in one run:

1. The simulator (models/human.urdf with a cluster of 4 markers on the pelvis, each femur and tibia and 3 on each
   calcaneus; a 100-frame static and `--frames` of gait or squats, 1 mm noise, with and without 5 mm of skin
   artefact): each hip, knee and ankle centre's median distance from the truth over the movement trial's frames, the
   SD of each hip, knee and ankle angle's difference from the truth's (offset-free), and wall time, for the session
   calibrated together, the same movement trial with every marker (the reference), and the static calibrated alone
   with the movement trial posed on it (`calibrate ik`: what worked before).
2. `--expert1 DIR` (AddBiomechanics' Expert1 `static1.trc` and `walking1.trc`): a CAST session made of a real one, the
   pelvis's, feet's, trunk's and arms' landmarks copied as technical markers (1 mm of noise of their own) in both
   trials, the walk keeping the copies and the clusters only, all declared; the lab's R_HJC / L_HJC left out.  Against
   the same trials by their names: walk marker RMS, each hip's median distance from the lab's functional centre over
   the walk, wall time; the session as it is and with --hip-regression.

    python scripts/bench_cast.py [--frames 600] [--expert1 DIR] [--json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from bench_calibrate import machine  # shared with the other benches

ROOT = Path(__file__).resolve().parent.parent
LEGS = ("hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r")
CLUSTERS = {"pelvis": ("PV", (-0.17, 0.0, 0.0)), "femur_l": ("LTH", (0.0, -0.2, -0.07)),
            "femur_r": ("RTH", (0.0, -0.2, 0.07)), "tibia_l": ("LSK", (0.0, -0.2, -0.06)),
            "tibia_r": ("RSK", (0.0, -0.2, 0.06)), "calcn_l": ("LFT", (0.12, 0.05, 0.0)),
            "calcn_r": ("RFT", (0.12, 0.05, 0.0))}
PLATE = [(-0.04, -0.06), (0.04, -0.06), (0.04, 0.06), (-0.04, 0.06)]  # m: a rectangular plate's corners, in turn


def cast_subject(model, plate: bool = False, seed: int = 1):
    """`model` with a CAST protocol's technical clusters (CLUSTERS: four markers on the pelvis, each femur and tibia,
    three on each calcaneus, each within 40 mm of its cluster's centre) and segment -> its cluster's labels.
    `plate`: the left thigh's a rectangular plate (LTH1..4 at its corners in turn, 80 x 120 mm, 120 mm lateral),
    which a turn of 180 deg about its normal maps onto itself."""
    from calibrate.model.model import add_markers

    rng = np.random.default_rng(seed)
    places, segments = {}, {}
    for segment, (prefix, centre) in CLUSTERS.items():
        for i in range(3 if segment.startswith("calcn") else 4):
            x = np.array(centre) + rng.uniform(-0.04, 0.04, 3)
            if plate and segment == "femur_l":
                x = np.array([PLATE[i][0], -0.2 + PLATE[i][1], -0.12])
            places[f"{prefix}{i + 1}"] = (segment, x)
            segments.setdefault(segment, []).append(f"{prefix}{i + 1}")
    return add_markers(model, places), segments


def world_centres(model, params, motion, names) -> np.ndarray:
    """The joints `names`' centres in the lab over `motion`'s frames, (frames, joints, 3) m."""
    from calibrate.model.blocks import FrameLayout
    from calibrate.model.kinematics import build_kinematics

    Z = FrameLayout.coordinates(motion.root_translation, motion.angles)
    _, C = build_kinematics(model).batch(Z, motion.root_quaternion, params)
    index = [j.name for j in model.joints]
    return C[:, [index.index(n) for n in names]]


def _score(model, params, motion, sim, truth, wall: float) -> dict:
    want = sim.clean_centres[:, [[j.name for j in truth.joints].index(n) for n in LEGS]]
    off = np.median(np.linalg.norm(world_centres(model, params, motion, LEGS) - want, axis=2), axis=0)
    dofs = [k for k, n in enumerate(model.dof_names) if n.split("_")[0] in ("hip", "knee", "ankle")]
    sd = np.degrees(np.std(motion.angles[:, dofs] - sim.motion.angles[:, dofs], axis=0))
    return {"centre_mm": {j: round(1e3 * float(v), 1) for j, v in zip(LEGS, off, strict=True)},
            "angle_sd_max_deg": round(float(sd.max()), 2), "angle_sd_mean_deg": round(float(sd.mean()), 2),
            "wall_s": round(wall, 2)}


def simulated(motion: str, frames: int, sta_mm: float) -> dict:
    """One simulated CAST session, calibrated three ways (module docstring, 1)."""
    from calibrate import Settings, calibrate
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model
    from calibrate.simulation import simulate_gait, simulate_squats
    from calibrate.simulation.simulate import simulate_static
    from calibrate.solve.ik import inverse_kinematics

    human = load_model(ROOT / "models" / "human.urdf")
    truth, segments = cast_subject(human)
    sim = (simulate_gait if motion == "gait" else simulate_squats)(truth, frames=frames, noise_mm=1.0, seed=3,
                                                                    sta_mm=sta_mm)
    static = simulate_static(truth, sim.truth, frames=100, noise_mm=1.0, seed=4).trial
    only = sim.trial.select([lab for labs in segments.values() for lab in labs])
    given = {"segments": segments}
    out = {"motion": motion, "frames": frames, "sta_mm": sta_mm}
    for name, trial in (("together", only), ("every_marker", sim.trial)):
        t0 = time.perf_counter()
        cal = calibrate(human, [static, trial], Settings(), marker_map=given)
        out[name] = _score(cal.model, cal.params, cal.motions[1], sim, truth, time.perf_counter() - t0)
    t0 = time.perf_counter()
    alone = calibrate(human, static, Settings(), marker_map=given)
    posed = inverse_kinematics(build_kinematics(alone.model), only, alone.params).motion
    out["static_then_ik"] = _score(alone.model, alone.params, posed, sim, truth, time.perf_counter() - t0)
    return out


def expert1(folder: Path) -> dict:
    """Expert1's static and walk made a CAST session (module docstring, 2)."""
    from calibrate import Settings, calibrate, read_trial
    from calibrate.io.labels import map_labels
    from calibrate.model.model import load_model
    from calibrate.seed.geometry import marker_rms

    human = load_model(ROOT / "models" / "human.urdf")
    nohjc = [read_trial(folder / f) for f in ("static1.trc", "walking1.trc")]
    nohjc = [t.select([x for x in t.labels if "HJC" not in x]) for t in nohjc]
    t0 = time.perf_counter()
    names = calibrate(human, nohjc, Settings())
    out = {"names": {"wall_s": round(time.perf_counter() - t0, 2)}}
    seg = {m.name: m.segment for m in names.model.markers}
    hosts = {m.label: m.segment for m in names.new_markers if m.segment}
    renamed = map_labels(nohjc[1], human.marker_names)[1].renamed
    rng = np.random.default_rng(0)
    declared: dict[str, str] = {}

    def emulate(t, landmarks: bool):
        labels, cols = [], []
        for i, lab in enumerate(t.labels):
            model_label = renamed.get(lab, lab)
            if lab in hosts:  # a cluster's marker
                labels.append(lab)
                cols.append(t.markers[:, i])
                declared[lab] = hosts[lab]
            elif model_label in seg:
                if seg[model_label] not in ("femur_l", "femur_r", "tibia_l", "tibia_r"):
                    labels.append("c_" + lab)
                    cols.append(t.markers[:, i] + rng.normal(0.0, 0.001, t.markers[:, i].shape))
                    declared["c_" + lab] = seg[model_label]
                if landmarks:
                    labels.append(lab)
                    cols.append(t.markers[:, i])
        return replace(t, labels=tuple(labels), markers=np.stack(cols, axis=1))

    session = [emulate(nohjc[0], True), emulate(nohjc[1], False)]
    segments: dict[str, list[str]] = {}
    for lab, s in declared.items():
        segments.setdefault(s, []).append(lab)
    hjc = read_trial(folder / "walking1.trc")
    runs = {"names": names}
    for key, settings in (("cast", Settings()), ("cast_regression", Settings(hip_regression=True))):
        t0 = time.perf_counter()
        runs[key] = calibrate(human, session, settings, marker_map={"segments": segments})
        out[key] = {"wall_s": round(time.perf_counter() - t0, 2),
                    "relabelled": [x.to_json() for x in runs[key].relabelled]}
    for key, cal in runs.items():
        C = world_centres(cal.model, cal.params, cal.motions[1], ("hip_r", "hip_l"))
        out[key]["walk_marker_rms_mm"] = round(1e3 * marker_rms(cal.residuals[cal.trial_frames(1)]), 2)
        out[key]["hips_from_lab_mm"] = {side: round(1e3 * float(np.nanmedian(np.linalg.norm(
            C[:, k] - hjc.marker(lab), axis=1))), 1) for k, (side, lab) in enumerate((("right", "R_HJC"),
                                                                                     ("left", "L_HJC")))}
    out["walk_labels"] = len(session[1].labels)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600, help="frames of the simulated movement trials (default 600)")
    ap.add_argument("--expert1", type=Path, default=None, help="folder with Expert1's static1.trc and walking1.trc")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    a = ap.parse_args()
    res = {"date": datetime.datetime.now().isoformat(timespec="minutes"), "machine": machine(),
           "simulated": [simulated(m, a.frames, sta) for sta in (0.0, 5.0) for m in ("gait", "squats")],
           "expert1": expert1(a.expert1) if a.expert1 is not None else None}
    if a.json:
        print(json.dumps(res))
        return 0
    print("simulated CAST sessions: centres from the truth (mm: " + " ".join(LEGS) + "), angle SD from the truth "
          "(max / mean, deg), wall time")
    for s in res["simulated"]:
        for name in ("together", "every_marker", "static_then_ik"):
            r = s[name]
            print(f"  {s['motion']:6s} sta {s['sta_mm']:.0f} mm  {name:14s} "
                  + " ".join(f"{v:5.1f}" for v in r["centre_mm"].values())
                  + f" | {r['angle_sd_max_deg']:4.1f} / {r['angle_sd_mean_deg']:4.1f} deg | {r['wall_s']:.1f} s")
    e = res["expert1"]
    if e is not None:
        print(f"Expert1 made a CAST session ({e['walk_labels']} walk labels): walk marker RMS, hips from the lab's "
              "R_HJC / L_HJC, wall time")
        for key in ("names", "cast", "cast_regression"):
            r = e[key]
            print(f"  {key:16s} {r['walk_marker_rms_mm']} mm  hips {r['hips_from_lab_mm']['right']} / "
                  f"{r['hips_from_lab_mm']['left']} mm  {r['wall_s']} s"
                  + (f"  relabelled {len(r['relabelled'])}" if r.get("relabelled") else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
