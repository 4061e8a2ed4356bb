"""`calibrate ik --report` on a subject's other trials: the calibration's learnt noise weighing every trial's markers
against the markers weighed alike where they scatter beyond it (subject_ik.LEARNT_NOISE_HOLDS), each trial's fit
(marker RMS, the pelvis markers' RMS) and, where the lab's own IK of the trial lies beside it (<trial>.mot, as
AddBiomechanics' Expert1 folder has them), each hip, knee and ankle angle's RMS difference from it (its mean offset
removed: the two models' zeros differ), over the frames both cover.

    python scripts/bench_ik_noise.py SUBJECT REPORT TRIAL [TRIAL ...] [--json]
    python scripts/bench_ik_noise.py --simulated [--seeds 1 2 3] [--json]

SUBJECT and REPORT are what `calibrate` wrote (subject.osim or subject.urdf and its report JSON).  --simulated: a
subject of models/human.urdf calibrated from 400 simulated squat frames with 5 mm soft-tissue artefact, its gait and
overhead trials (300 frames, the same subject and artefact) fitted both ways, each hip, knee and ankle angle's RMS
error from the simulator's truth.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate.calibration.ik_trials import fit_planned, plan_trials


def read_mot(path: Path) -> tuple[list[str], np.ndarray] | None:
    """A .mot's columns and rows (degrees as written), or None where there is none."""
    if not path.is_file():
        return None
    lines = path.read_text().splitlines()
    start = next(k for k, line in enumerate(lines) if line.strip() == "endheader")
    return lines[start + 1].split(), np.array([[float(v) for v in line.split()] for line in lines[start + 2:]
                                               if line.strip()])


def angle_rms(motion, ref: tuple[list[str], np.ndarray]) -> dict[str, float]:
    """Each hip, knee and ankle coordinate both name: the RMS difference (deg) from the lab's IK, its mean removed."""
    cols, rows = ref
    t = motion.times
    inside = (t >= rows[0, 0] - 1e-6) & (t <= rows[-1, 0] + 1e-6)
    out = {}
    for k, name in enumerate(motion.dof_names):
        if name in cols and name.split("_")[0] in ("hip", "knee", "ankle") and "beta" not in name:
            d = np.degrees(motion.angles[inside, k]) - np.interp(t[inside], rows[:, 0], rows[:, cols.index(name)])
            out[name] = float(np.sqrt(np.mean((d - d.mean()) ** 2)))
    return out


def simulated(seeds: list[int]) -> list[dict]:
    """The simulator's subjects (module docstring): per seed and motion, the learnt weights' and the checked fit's
    hip, knee and ankle RMS error from the truth (deg), and whether the check fired."""
    import subprocess
    import sys
    import tempfile

    from calibrate.io.motion import read_motion_csv
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_gait, simulate_overhead, simulate_squats, write_simulation

    human = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
    model = load_model(human)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            d = Path(tmp) / f"s{seed}"
            write_simulation(simulate_squats(model, frames=400, noise_mm=1.0, seed=seed, sta_mm=5.0), d / "cal")
            for kind, make in (("gait", simulate_gait), ("overhead", simulate_overhead)):
                write_simulation(make(model, frames=300, noise_mm=1.0, seed=seed, sta_mm=5.0), d / kind)
            subprocess.run([sys.executable, "-m", "calibrate.cli", str(d / "cal" / "trial.c3d"), str(human), "-o",
                            str(d / "subject.urdf"), "-q"], check=False, capture_output=True)
            for kind in ("gait", "overhead"):
                plan = plan_trials(d / "subject.urdf", [d / kind / "trial.c3d"], report=d / "trial_report.json")
                truth = read_motion_csv(d / kind / "truth_motion.csv")
                row = {"seed": seed, "motion": kind}
                for label, p in (("learnt", replace(plan, noise_sd=None)), ("checked", plan),
                                 ("alike", replace(plan, noise_sd=None, weights={k: 1.0 for k in plan.weights}))):
                    one = fit_planned(p, ahead=False)[0]
                    a = one.got.fit.motion
                    idx = [k for k, n in enumerate(a.dof_names) if n.split("_")[0] in ("hip", "knee", "ankle")]
                    row[f"{label}_deg"] = float(np.degrees(np.sqrt(np.mean((a.angles[:, idx]
                                                                            - truth.angles[:, idx]) ** 2))))
                    if label == "checked":
                        row["fired"] = one.got.weighed_alike
                rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("subject", type=Path, nargs="?")
    ap.add_argument("report", type=Path, nargs="?")
    ap.add_argument("trials", type=Path, nargs="*")
    ap.add_argument("--simulated", action="store_true", help="the simulator's subjects instead (module docstring)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--json", action="store_true", help="machine-readable output")
    args = ap.parse_args()
    if args.simulated:
        rows = simulated(args.seeds)
        if args.json:
            print(json.dumps(rows, indent=1))
        for r in [] if args.json else rows:
            print(f"seed {r['seed']} {r['motion']:8s}: check fired {r['fired']}; hip/knee/ankle RMS from the truth: "
                  f"learnt {r['learnt_deg']:.2f}, checked {r['checked_deg']:.2f}, alike {r['alike_deg']:.2f} deg")
        return
    if args.subject is None or args.report is None or not args.trials:
        ap.error("give SUBJECT REPORT TRIAL ..., or --simulated")
    plan = plan_trials(args.subject, args.trials, report=args.report)
    if plan.noise_sd is None:
        raise SystemExit(f"{args.report}: learnt no noise; nothing to compare")
    model = plan.model
    pelvis = [k for k, m in enumerate(model.markers) if m.segment == model.root]
    rows = []
    for label, p in (("learnt", replace(plan, noise_sd=None)), ("checked", plan)):
        t0 = time.perf_counter()
        done = fit_planned(p, ahead=False)
        seconds = time.perf_counter() - t0
        for one in done:
            fit = one.got.fit
            err = np.linalg.norm(fit.residuals, axis=2)
            ref = read_mot(one.job.path.with_suffix(".mot"))
            angles = angle_rms(fit.motion, ref) if ref is not None else {}
            rows.append({"weights": label, "trial": one.job.path.stem, "marker_rms_mm": 1e3 * fit.rms,
                         "pelvis_rms_mm": 1e3 * float(np.sqrt(np.nanmean(err[:, pelvis] ** 2))),
                         "weighed_alike": one.got.weighed_alike,
                         "largest_ratio": max(one.got.noise_beyond.values(), default=None),
                         "angles_vs_lab_ik_deg": angles,
                         "mean_angle_deg": float(np.mean(list(angles.values()))) if angles else None,
                         "seconds": one.seconds})
        rows.append({"weights": label, "trial": "(all)", "seconds": seconds})
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    by = {(r["weights"], r["trial"]): r for r in rows}
    print(f"{'trial':14s} {'alike?':6s} | learnt: RMS, pelvis, angles vs lab IK | checked: RMS, pelvis, angles")
    for one in plan.jobs:
        a, b = by[("learnt", one.path.stem)], by[("checked", one.path.stem)]
        f = lambda r: (f"{r['marker_rms_mm']:6.2f} {r['pelvis_rms_mm']:6.1f} "  # noqa: E731
                       + (f"{r['mean_angle_deg']:5.2f}" if r["mean_angle_deg"] is not None else "   - "))
        print(f"{one.path.stem:14s} {'yes' if b['weighed_alike'] else 'no':6s} | {f(a)} | {f(b)}")
    took = {w: by[(w, "(all)")]["seconds"] for w in ("learnt", "checked")}
    print(f"time: learnt {took['learnt']:.2f} s, checked {took['checked']:.2f} s (one core)")


if __name__ == "__main__":
    main()
