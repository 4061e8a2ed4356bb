"""Reproduce the simulations of Hang, Lasenby & Li (MTB joint estimation), Section IV.

Synthetic chains (calibrate.simulation.chains.simulate_chain) of rigid segments 1 apart, solved by
calibrate.seed.joints.estimate_joints three ways: the framework (MTB + solvability propagation
+ hybrid JMV) with the paper's affine basis (four markers, or three plus Eq. 9's auxiliary
point) -- the method of the paper; the same framework with calibrate's default basis (the
least-squares rigid frame of all of a segment's points); and the JMV-only baseline
(per-frame joint-marker-variance optimisation).

- accuracy (paper Tables I, III, IV): chains #1 <4-3-3>, #2 <4-3-3-4-3>, #3 <4-3-3-4-3-3-3-3>,
  #4 <3-2-2-2-2>, #5 <3-1-2-2-2-2>; F = 100; mean over runs of the RSE of Eq. 10,
  xi = sqrt(sum_frames sum_joints |error|^2) / (M F), and of the time per joint
  (wall time of estimate_joints / M);
- speed (paper Table II): chain #1 with F = 100, 150, ..., 300;
- the accuracy table again with marker noise of 0.1 % of the joint spacing (not in the paper).

    python scripts/bench_mtb.py [--runs 50] [--quick] [--seed 0] [--json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import sys
import time

import numpy as np
import scipy

from calibrate.seed.joints import JointSpec, estimate_joints
from calibrate.simulation.chains import Chain, simulate_chain

CHAINS: dict[str, tuple[int, ...]] = {
    "1": (4, 3, 3),
    "2": (4, 3, 3, 4, 3),
    "3": (4, 3, 3, 4, 3, 3, 3, 3),
    "4": (3, 2, 2, 2, 2),
    "5": (3, 1, 2, 2, 2, 2),
}
MODES = ("framework", "rigid", "jmv")
SUFFIX = {"framework": "", "rigid": "_rigid", "jmv": "_jmv"}
OPTIONS = {"framework": {"mode": "framework", "basis": "affine"}, "rigid": {"mode": "framework", "basis": "rigid"},
           "jmv": {"mode": "jmv"}}
TIMING_FRAMES = (100, 150, 200, 250, 300)
NOISE = 0.001  # 0.1 % of the joint spacing
# the paper's figures (Tables I-IV; Intel i7-2620M, MATLAB); time per joint in ms
PAPER_RSE = {"1": 3.9e-7, "2": 2.9e-7, "3": 1.8e-7, "4": 1.5e-6, "5": 2.8e-2}
PAPER_RSE_JMV = {"1": 1.1e-2, "2": 3.4e-3, "3": 4.4e-3, "4": 1.6e-2, "5": 4.5e-2}
PAPER_RSE_SEQ = {"1": 5.7e-17, "2": 3.3e-17, "3": 3.1e-17}
PAPER_MS = {"1": 21.1, "4": 18.0, "5": 650.0}
PAPER_MS_JMV = {"1": 6772.0, "4": 5630.0, "5": 5350.0}
PAPER_TIMING = {100: (21.1, 6772.0), 150: (22.6, 7186.0), 200: (30.0, 7879.0), 250: (30.4, 14872.0),
                300: (31.3, 18143.0)}
PAPER_SEQ_MS = {100: 56.0, 150: 84.0, 200: 112.0, 250: 138.0, 300: 166.0}
# targets
RSE_EXACT = 1e-9  # noise-free chains #1-#4
RSE_CHAIN5 = 2.8e-2  # below the paper's framework figure for chain #5
MS_PER_JOINT = 2.0  # framework, chain #1, every F
FLATNESS = 2.0  # t(F=300) / t(F=100)


def rse(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Eq. 10: sqrt of the summed squared errors over frames and joints, over M F; arrays (F, M, 3)."""
    F, M, _ = truth.shape
    return float(np.sqrt(np.sum((estimate - truth) ** 2)) / (M * F))


def solve(chain: Chain, mode: str) -> tuple[float, float, list[str], list[str]]:
    """One estimate_joints call: (RSE, ms per joint, what failed (empty if nothing), method per joint)."""
    specs = [JointSpec(name, parent, child) for name, parent, child in chain.joints]
    points = chain.points()
    t0 = time.perf_counter()
    est = estimate_joints(points, chain.groups, specs, **OPTIONS[mode])
    seconds = time.perf_counter() - t0
    got = [est[name] for name, _, _ in chain.joints]
    centres = np.stack([np.asarray(j.centre, dtype=float) for j in got], axis=1)
    failed = [f"{j.name}: " + (str(getattr(j, "reason", "")) or "not ok" if not j.ok else "NaN in centre")
              for j in got if not j.ok or not np.all(np.isfinite(j.centre))]
    err = rse(centres, chain.centres) if np.all(np.isfinite(centres)) else math.nan
    return err, 1e3 * seconds / len(specs), failed, [str(j.method) for j in got]


def mean(values: list[float]) -> float:
    """Mean of the finite values (NaN if none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def run_chains(counts: tuple[int, ...], frames: int, noise: float, runs: int, seeds: list[list[int]]) -> dict:
    """Both modes on the same `runs` chains; means, worst RSE, failed-run counts, methods of the first run."""
    acc: dict[str, dict[str, list]] = {m: {"rse": [], "ms": [], "failed": [], "methods": []} for m in MODES}
    for r in range(runs):
        chain = simulate_chain(counts, frames=frames, noise=noise, seed=np.random.default_rng(seeds[r]))
        for m in MODES:
            e, ms, failed, methods = solve(chain, m)
            acc[m]["rse"].append(e)
            acc[m]["ms"].append(ms)
            acc[m]["failed"].append(failed)
            acc[m]["methods"].append(methods)
    out = {}
    for m in MODES:
        a = acc[m]
        suffix = SUFFIX[m]
        out["rse" + suffix] = mean(a["rse"])
        finite = np.isfinite(a["rse"])
        out["rse_median" + suffix] = float(np.median(np.asarray(a["rse"])[finite])) if finite.any() else math.nan
        out["rse_max" + suffix] = float(np.nanmax(a["rse"])) if finite.any() else math.nan
        out["ms_per_joint" + suffix] = mean(a["ms"])
        out["failed_runs" + suffix] = int(sum(bool(f) for f in a["failed"]))
        out["failures" + suffix] = [f"run {r}: " + "; ".join(f) for r, f in enumerate(a["failed"]) if f][:5]
        out["methods" + suffix] = a["methods"][0]
    return out


def human(seeds: list[int], frames: int = 1000, noise_mm: float = 1.0) -> dict:
    """Issue 3 item 9 on models/human.urdf: simulated squats, estimate_model_joints, errors against truth."""
    from pathlib import Path

    from calibrate.model.model import load_model
    from calibrate.seed.association import associate
    from calibrate.seed.joints import estimate_model_joints
    from calibrate.simulation.simulate import joint_axes_world, simulate_squats

    model = load_model(Path(__file__).resolve().parent.parent / "models" / "human.urdf")
    rows = []
    for seed in seeds:
        sim = simulate_squats(model, frames=frames, noise_mm=noise_mm, seed=seed)
        est = estimate_model_joints(model, sim.trial)
        axes = joint_axes_world(model, sim.truth, sim.motion)
        row = {"seed": seed, "seconds": est.seconds, "ok": sum(j.ok for j in est), "joints": len(est),
               "methods": {j.name: j.method for j in est}}
        for j in est:
            k = model.joint_index(j.name)
            err = np.linalg.norm(j.centre - sim.clean_centres[:, k], axis=1)
            row[f"{j.name}_centre_mm"] = 1e3 * float(np.nanmedian(err))
            if j.name in axes and j.axis is not None:
                ax = axes[j.name]
                v = j.centre - sim.clean_centres[:, k]
                off = np.linalg.norm(v - np.sum(v * ax, axis=1)[:, None] * ax, axis=1)
                ang = np.degrees(np.arccos(np.clip(np.abs(np.sum(j.axis * ax, axis=1)), 0, 1)))
                row[f"{j.name}_off_axis_mm"] = 1e3 * float(np.nanmedian(off))
                row[f"{j.name}_axis_deg"] = float(np.nanmedian(ang))
        # marker-to-segment association on the unlabelled trajectories (seed 002 Section 3)
        t0 = time.perf_counter()
        assoc = associate(sim.trial.markers)
        row["association_s"] = time.perf_counter() - t0
        truth_sets = {frozenset(i for i, m in enumerate(model.markers) if m.segment == s.name)
                      for s in model.segments if s.markers}
        right = [i for g in assoc.groups if frozenset(g) in truth_sets for i in g]
        row["association_right"] = len(right)
        row["association_markers"] = len(model.markers)
        row["association_wrong"] = [model.markers[i].name for i in range(len(model.markers)) if i not in set(right)]
        row["association_ambiguous"] = [model.markers[i].name for i in assoc.ambiguous]
        rows.append(row)

    def worst(key: str) -> float:
        return max(r[key] for r in rows if key in r)

    out = {"frames": frames, "noise_mm": noise_mm, "seeds": seeds, "runs": rows,
           "seconds_mean": mean([r["seconds"] for r in rows]),
           "association_right_fraction": sum(r["association_right"] for r in rows)
           / sum(r["association_markers"] for r in rows)}
    for side in "lr":
        out[f"hip_{side}_mm_worst"] = worst(f"hip_{side}_centre_mm")
        for j in ("knee", "elbow"):
            out[f"{j}_{side}_off_axis_mm_worst"] = worst(f"{j}_{side}_off_axis_mm")
            out[f"{j}_{side}_axis_deg_worst"] = worst(f"{j}_{side}_axis_deg")
    return out


def warm_up() -> None:
    """First-call overheads (imports, caches) out of the timings."""
    for counts in ((4, 3, 3), (3, 1, 2, 2)):
        chain = simulate_chain(counts, frames=50, seed=12345)
        for m in MODES:
            solve(chain, m)


def clean_json(x):
    """NaN/inf -> None, recursively, so the output is strict JSON."""
    if isinstance(x, dict):
        return {k: clean_json(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [clean_json(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def fmt(x: float | None, spec: str = ".1e") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def spread3(c: dict, suffix: str) -> str:
    """'mean [median, worst]' of a result's RSE."""
    return f"{fmt(c['rse' + suffix])} [{fmt(c['rse_median' + suffix])}, {fmt(c['rse_max' + suffix])}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=None, help="simulations per chain / frame count (default 50; "
                                                           "--quick: 5)")
    ap.add_argument("--quick", action="store_true", help="5 runs and 2 squat seeds (CI smoke)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args()
    runs = a.runs if a.runs is not None else (5 if a.quick else 50)
    if runs < 1:
        ap.error("--runs: need at least 1")
    say = (lambda *_: None) if a.json else (lambda s="": print(s, flush=True))

    warm_up()
    res: dict = {"runs": runs, "frames": 100, "seed": a.seed, "chains": {}, "timing": {}, "noise": {}}
    say(f"MTB joint estimation on synthetic chains (seed 000, Section IV): {runs} runs each, seed {a.seed}")
    for cid, counts in CHAINS.items():
        seeds = [[a.seed, 0, int(cid), r] for r in range(runs)]
        res["chains"][cid] = run_chains(counts, 100, 0.0, runs, seeds)
    for F in TIMING_FRAMES:
        seeds = [[a.seed, 1, F, r] for r in range(runs)]
        t = run_chains(CHAINS["1"], F, 0.0, runs, seeds)
        res["timing"][str(F)] = {k + s: t[k + s] for k in ("ms_per_joint", "rse", "failed_runs")
                                 for s in SUFFIX.values()}
    for cid, counts in CHAINS.items():  # the same chains as the accuracy table, with noise
        seeds = [[a.seed, 0, int(cid), r] for r in range(runs)]
        n = run_chains(counts, 100, NOISE, runs, seeds)
        res["noise"][cid] = {k: v for k, v in n.items() if not k.startswith("methods")}

    res["human"] = human(list(range(a.seed, a.seed + (2 if a.quick else 5))))

    ch, tm = res["chains"], res["timing"]
    checks = []
    for cid in ("1", "2", "3", "4"):
        checks.append((f"chain #{cid}: framework RSE {fmt(ch[cid]['rse'])} <= {RSE_EXACT:.0e}",
                       ch[cid]["rse"] <= RSE_EXACT))
    checks.append((f"chain #5: framework RSE {fmt(ch['5']['rse'])} < {RSE_CHAIN5:.1e} (paper's figure)",
                   ch["5"]["rse"] < RSE_CHAIN5))
    worst = max(tm[str(F)]["ms_per_joint"] for F in TIMING_FRAMES)
    checks.append((f"chain #1: framework time per joint, worst over F, {worst:.2f} ms <= {MS_PER_JOINT} ms",
                   worst <= MS_PER_JOINT))
    ratio = tm["300"]["ms_per_joint"] / tm["100"]["ms_per_joint"]
    checks.append((f"chain #1: framework t(F=300)/t(F=100) = {ratio:.2f} < {FLATNESS}", ratio < FLATNESS))
    hu = res["human"]
    hip = max(hu["hip_l_mm_worst"], hu["hip_r_mm_worst"])
    checks.append((f"human squats: hip centres {hip:.2f} mm (worst median over runs) <= 5 mm", hip <= 5.0))
    off = max(hu[f"{j}_{s}_off_axis_mm_worst"] for j in ("knee", "elbow") for s in "lr")
    checks.append((f"human squats: knee/elbow centres {off:.2f} mm from the true axis <= 5 mm", off <= 5.0))
    ang = max(hu[f"{j}_{s}_axis_deg_worst"] for j in ("knee", "elbow") for s in "lr")
    checks.append((f"human squats: knee/elbow axes {ang:.2f} deg <= 3 deg", ang <= 3.0))
    frac = hu["association_right_fraction"]
    checks.append((f"human squats: markers on the right segment (unlabelled association) {100 * frac:.1f} % "
                   "= 100 %", frac == 1.0))
    failed = sum(ch[c]["failed_runs"] for c in CHAINS)
    checks.append((f"framework: runs with a joint not ok or NaN (noise-free chains) = {failed}", failed == 0))
    res["checks"] = [{"target": t, "pass": bool(p)} for t, p in checks]
    res["machine"] = {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                      "system": platform.system(), "numpy": np.__version__, "scipy": scipy.__version__}
    res["date"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    if a.json:
        print(json.dumps(clean_json(res)))
        return

    say()
    say(f"Accuracy, F = 100, no noise (paper Tables I, III, IV): RSE per joint per frame (Eq. 10), mean "
        f"[median, worst] over {runs} runs; failed = runs with a joint not ok or NaN")
    say(f"{'chain':26s} {'framework (affine)':>28s} {'paper':>8s} {'JMV':>28s} {'paper':>8s} {'seq.paper':>9s} "
        f"{'rigid basis':>10s} {'failed fw/rigid/JMV':>19s}")
    for cid, counts in CHAINS.items():
        c = ch[cid]
        name = f"#{cid} <{'-'.join(map(str, counts))}>"
        say(f"{name:26s} {spread3(c, ''):>28s} {fmt(PAPER_RSE.get(cid)):>8s} "
            f"{spread3(c, '_jmv'):>28s} {fmt(PAPER_RSE_JMV.get(cid)):>8s} "
            f"{fmt(PAPER_RSE_SEQ.get(cid)):>9s} {fmt(c['rse_rigid']):>10s} "
            f"{c['failed_runs']:>6d}/{c['failed_runs_rigid']}/{c['failed_runs_jmv']:<6d}")
    say()
    say("Time per joint, F = 100 (ms; paper: Tables II, III, IV)")
    say(f"{'chain':26s} {'framework':>10s} {'paper':>8s} {'JMV':>10s} {'paper':>8s} {'rigid':>7s}  "
        "methods (framework, first run)")
    for cid, counts in CHAINS.items():
        c = ch[cid]
        name = f"#{cid} <{'-'.join(map(str, counts))}>"
        say(f"{name:26s} {fmt(c['ms_per_joint'], '.2f'):>10s} {fmt(PAPER_MS.get(cid), '.1f'):>8s} "
            f"{fmt(c['ms_per_joint_jmv'], '.2f'):>10s} {fmt(PAPER_MS_JMV.get(cid), '.0f'):>8s} "
            f"{fmt(c['ms_per_joint_rigid'], '.2f'):>7s}  " + ", ".join(c["methods"]))
    say()
    say("Speed, chain #1 <4-3-3> (paper Table II): time per joint (ms)")
    say(f"{'F':>5s} {'framework':>10s} {'paper':>8s} {'JMV':>10s} {'paper':>8s} {'seq.paper':>9s} "
        f"{'RSE fw':>9s} {'RSE JMV':>9s} {'rigid':>7s} {'failed fw/JMV':>13s}")
    for F in TIMING_FRAMES:
        t = tm[str(F)]
        fw_p, jmv_p = PAPER_TIMING[F]
        say(f"{F:5d} {fmt(t['ms_per_joint'], '.2f'):>10s} {fw_p:8.1f} {fmt(t['ms_per_joint_jmv'], '.2f'):>10s} "
            f"{jmv_p:8.0f} {PAPER_SEQ_MS[F]:9.0f} {fmt(t['rse']):>9s} {fmt(t['rse_jmv']):>9s} "
            f"{fmt(t['ms_per_joint_rigid'], '.2f'):>7s} "
            f"{t['failed_runs']:>6d}/{t['failed_runs_jmv']:<6d}")
    say()
    say(f"Accuracy with marker noise {NOISE} (0.1 % of the joint spacing), F = 100: RSE mean "
        "[median, worst] (no paper figures)")
    say(f"{'chain':26s} {'framework (affine)':>28s} {'framework (rigid basis)':>28s} {'JMV':>28s} "
        f"{'failed fw/rigid/JMV':>19s}")
    for cid, counts in CHAINS.items():
        c = res["noise"][cid]
        name = f"#{cid} <{'-'.join(map(str, counts))}>"
        say(f"{name:26s} {spread3(c, ''):>28s} {spread3(c, '_rigid'):>28s} {spread3(c, '_jmv'):>28s} "
            f"{c['failed_runs']:>6d}/{c['failed_runs_rigid']}/{c['failed_runs_jmv']:<6d}")
    shown = [(f"#{cid} {m}", f) for cid in CHAINS for m, key in (("framework", "failures"), ("JMV", "failures_jmv"))
             for f in ch[cid][key][:2]]
    if shown:
        say()
        say("Failed runs, noise-free (first 2 per chain and mode)")
        for where, f in shown:
            say(f"  {where:14s} {f}")
    say()
    say(f"Human squats (models/human.urdf, {hu['frames']} frames, {hu['noise_mm']} mm noise, seeds {hu['seeds']}): "
        "median over frames, per run")
    say(f"{'seed':>4s} {'time s':>7s} {'hip_l':>6s} {'hip_r':>6s}  {'knee_l':>13s} {'knee_r':>13s} "
        f"{'elbow_l':>13s} {'elbow_r':>13s}   (hip: centre error mm; hinges: mm off the true axis / axis deg)")
    for r in hu["runs"]:
        hinge = "  ".join(f"{r[f'{j}_off_axis_mm']:5.2f} / {r[f'{j}_axis_deg']:4.2f}"
                          for j in ("knee_l", "knee_r", "elbow_l", "elbow_r"))
        wrong = ", ".join(r["association_wrong"]) or "-"
        amb = ", ".join(r["association_ambiguous"]) or "-"
        say(f"{r['seed']:4d} {r['seconds']:7.2f} {r['hip_l_centre_mm']:6.2f} {r['hip_r_centre_mm']:6.2f}  {hinge}"
            f"   association {r['association_right']}/{r['association_markers']} right "
            f"({r['association_s']:.2f} s; wrong: {wrong}; flagged ambiguous: {amb})")
    say()
    say("Targets")
    for t, p in checks:
        say(f"  {'PASS' if p else 'FAIL'}  {t}")
    m = res["machine"]
    say(f"\n{m['cpu']}, Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}; {res['date']}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
