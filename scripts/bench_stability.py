"""How stable is a calibration against changes far below the measurement's precision?

pig_walk (../shared/data/real/pig_walk: static + walk) is calibrated several times in-process
(`calibrate.calibrate`, default Settings), each time with every marker coordinate moved by
independent N(0, SD) noise (default SD 1e-9 m: a nanometre, a thousandth of a C3D file's float32
resolution at these coordinates) — the size of the difference that another BLAS, another CPU or
another order of summation makes.  A calibration whose answer changes with such a change is
reporting the path its solver took, not the subject.

Per run: iterations (all frames; the subsample solve's), final cost, axes held, outliers rejected, the
femur and pelvis scales, hip and knee centres (mm, parent frame at the subject's scale) and knee axes.
Then, over the runs: the largest spread of every joint centre (mm), hinge axis (deg) and segment scale
(%) beside its largest posterior SD, and the runs whose femur scale is more than 10 % from the median
run's ("another basin").

    python scripts/bench_stability.py [--runs 6] [--sd 1e-9] [--atol A] [--json] [--quick]
    python scripts/bench_stability.py --every 1,2,3 [--json]

`--every K,...`: instead of moved markers, one run per K with both trials read at every K-th frame (their
rate / K; 1: as recorded): how much of the answer is the capture rate's, not the subject's.

`--quick` (CI smoke run): 2 runs (fewer with --runs) on 100 static + 160 walk frames; its figures are not
the benchmark's.
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibrate import clean_json, machine  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
PIG = ROOT.parent / "shared" / "data" / "real" / "pig_walk"


def one_run(model, trials, sd: float, seed: int, settings=None) -> dict:
    """Calibrate `trials` with their markers moved by N(0, sd) (seeded) under `settings` (default
    Settings()); the figures of one run."""
    from calibrate import Settings, calibrate

    rng = np.random.default_rng(seed)
    moved = [replace(t, markers=t.markers + rng.normal(0.0, sd, t.markers.shape)) if sd > 0 else t for t in trials]
    t0 = time.perf_counter()
    cal = calibrate(model, moved, settings or Settings())
    seconds = time.perf_counter() - t0
    changes = {c.name: c for c in cal.changes}
    s = cal.summary
    return {
        "seed": seed, "seconds": seconds, "converged": cal.converged,
        "iterations": s.iterations, "coarse_iterations": s.coarse.iterations if s.coarse else None,
        "final_cost": s.final_cost, "held_axes": sorted(cal.held_axes), "outliers": len(cal.outliers),
        "marker_rms_mm": 1e3 * cal.marker_rms,
        "values": {name: np.asarray(c.value, float).tolist() for name, c in changes.items()},
        "std": {name: np.asarray(c.std, float).tolist() for name, c in changes.items()},
    }


def every(trial, k: int):
    """`trial` read at every `k`-th frame: its rate / k (the modelling program's outputs dropped: calibration
    does not read them)."""
    if k == 1:
        return trial
    return replace(trial, markers=trial.markers[::k], rate=trial.rate / k, model_outputs={}, output_kinds={},
                   output_units={})


def spread(runs: list[dict]) -> dict:
    """Per parameter, the largest departure of a run from the runs' mean (mm, deg or %) and the largest
    posterior SD any run reported for it (same units)."""
    names = sorted(set.intersection(*[set(r["values"]) for r in runs]))
    out = {}
    for name in names:
        v = np.array([r["values"][name] for r in runs], dtype=float)
        sd = np.array([r["std"][name] for r in runs], dtype=float)
        group = name.split("[")[0]
        if group == "axis":
            m = v.mean(0) / np.linalg.norm(v.mean(0))
            d = np.degrees(np.arccos(np.clip(np.abs(v @ m), 0.0, 1.0)))
        elif group == "scale":
            d = 100 * np.abs(v[:, 0] - v[:, 0].mean())
            sd = 100 * sd
        else:
            d = 1e3 * np.linalg.norm(v - v.mean(0), axis=1)
        out[name] = {"spread": float(d.max()), "sd": float(np.nanmax(sd)) if np.isfinite(sd).any() else None}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("--sd", type=float, default=1e-9, help="SD of the change of every marker coordinate (m)")
    ap.add_argument("--atol", type=float, default=None,
                    help="the solver's absolute cost tolerance (default Settings'; smaller: closer to the minimum)")
    ap.add_argument("--still-weight", type=float, default=0.0, metavar="FRAMES",
                    help="Settings.still_weight: the static counted as FRAMES frames (default 0: each frame once)")
    ap.add_argument("--every", default=None, metavar="K,...",
                    help="one run per K, the trials read at every K-th frame (rate / K), instead of moved markers")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args(argv)
    steps = [int(k) for k in a.every.split(",")] if a.every else None
    if steps is not None and (not steps or min(steps) < 1):
        print(f"bench_stability: --every {a.every}: give frame steps of 1 or more, e.g. --every 1,2,3", file=sys.stderr)
        return 2
    from calibrate import Settings, load_model, read_trial

    if not PIG.is_dir():
        print(f"bench_stability: {PIG} not found; the real trials live in ../shared/data/real", file=sys.stderr)
        return 2
    model = load_model(ROOT / "models" / "human.urdf")
    trials = [read_trial(PIG / "static.c3d"), read_trial(PIG / "walk.c3d")]
    runs_n = a.runs
    if a.quick:
        trials = [trials[0].frames(0, 100), trials[1].frames(0, 160)]
        runs_n = min(a.runs, 2)
    settings = Settings() if a.atol is None else Settings(atol=a.atol, max_iterations=400)
    settings = replace(settings, still_weight=a.still_weight)
    runs = []
    for seed in range(runs_n if steps is None else len(steps)):
        if steps is None:
            r = one_run(model, trials, a.sd if seed else 0.0, seed, settings)  # run 0: the trials as recorded
        else:
            r = one_run(model, [every(t, steps[seed]) for t in trials], 0.0, seed, settings)
            r["every"], r["rate_hz"] = steps[seed], trials[-1].rate / steps[seed]
        runs.append(r)
        if not a.json:
            v = r["values"]
            at = f" (1 frame in {r['every']}: {r['rate_hz']:g} Hz)" if steps is not None else ""
            print(f"run {seed}{at}: {r['iterations']} iterations ({r['coarse_iterations']} on the subsample), "
                  f"cost {r['final_cost']:.6g}, {len(r['held_axes'])} axes held, {r['outliers']} outliers, "
                  f"femur scales {v['scale[femur_l]'][0]:.3f} {v['scale[femur_r]'][0]:.3f}, "
                  f"pelvis {v['scale[pelvis]'][0]:.3f}, {r['seconds']:.1f} s", flush=True)
    femur = np.array([r["values"]["scale[femur_l]"][0] for r in runs])
    median = float(np.median(femur))
    other = [r["seed"] for r, f in zip(runs, femur, strict=True) if abs(f / median - 1) > 0.10]
    sp = spread(runs)
    worst = {g: sorted(((v["spread"], k, v["sd"]) for k, v in sp.items() if k.startswith(g + "[")), reverse=True)[:5]
             for g in ("centre", "axis", "scale", "marker")}
    result = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": machine(),
        "sd_m": a.sd if steps is None else 0.0, "every": steps, "quick": a.quick, "atol": settings.atol,
        "runs": [{k: v for k, v in r.items() if k not in ("values", "std")} for r in runs],
        "iterations": [r["iterations"] for r in runs], "final_costs": [r["final_cost"] for r in runs],
        "other_basin_runs": other, "largest_spread": {g: [{"name": n, "spread": s, "sd": d} for s, n, d in w]
                                                      for g, w in worst.items()},
    }
    if steps is not None:  # each run's joint centres against the first run's (the trials as the first K reads them)
        centres = sorted(k for k in runs[0]["values"] if k.startswith("centre["))
        result["centres_from_first_run_mm"] = []
        for r in runs[1:]:
            d = [1e3 * float(np.linalg.norm(np.subtract(r["values"][k], runs[0]["values"][k]))) for k in centres]
            result["centres_from_first_run_mm"].append(
                {"every": r["every"], "min": min(d), "median": float(np.median(d)), "max": max(d)})
    if a.json:
        print(json.dumps(clean_json(result), indent=1))
        return 0
    how = f"markers moved by N(0, {a.sd:g} m)" if steps is None else f"trials read at 1 frame in {a.every}"
    print(f"\n{len(runs)} runs, {how}: iterations {min(result['iterations'])}-"
          f"{max(result['iterations'])}, final cost {min(result['final_costs']):.6g}-{max(result['final_costs']):.6g}; "
          f"runs in another basin (femur scale > 10 % from the median run's): {other or 'none'}")
    for c in result.get("centres_from_first_run_mm", []):
        print(f"  joint centres at 1 frame in {c['every']} against the first run's: {c['min']:.1f}-{c['max']:.1f} mm, "
              f"median {c['median']:.1f}")
    units = {"centre": "mm", "axis": "deg", "scale": "%", "marker": "mm"}
    for g, w in worst.items():
        print(f"  largest spread, {g} ({units[g]}): " + ", ".join(
            f"{n.split('[')[1][:-1]} {s:.1f}" + (f" (SD {d:.1f})" if d is not None else "") for s, n, d in w))
    return 0


if __name__ == "__main__":
    sys.exit(main())
