"""Reproduce the simulations of Hang, Lasenby & Li (MTB joint estimation), Section IV.

Synthetic chains (calibrate.chains.simulate_chain) of rigid segments 1 apart, solved by
calibrate.joints.estimate_joints in two modes: the framework (MTB + solvability propagation
+ hybrid JMV) and the JMV-only baseline (per-frame joint-marker-variance optimisation).

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

from calibrate.chains import Chain, simulate_chain
from calibrate.joints import JointSpec, estimate_joints

CHAINS: dict[str, tuple[int, ...]] = {
    "1": (4, 3, 3),
    "2": (4, 3, 3, 4, 3),
    "3": (4, 3, 3, 4, 3, 3, 3, 3),
    "4": (3, 2, 2, 2, 2),
    "5": (3, 1, 2, 2, 2, 2),
}
MODES = ("framework", "jmv")
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
    est = estimate_joints(points, chain.groups, specs, mode=mode)
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
        suffix = "" if m == "framework" else "_jmv"
        out["rse" + suffix] = mean(a["rse"])
        finite = np.isfinite(a["rse"])
        out["rse_median" + suffix] = float(np.median(np.asarray(a["rse"])[finite])) if finite.any() else math.nan
        out["rse_max" + suffix] = float(np.nanmax(a["rse"])) if finite.any() else math.nan
        out["ms_per_joint" + suffix] = mean(a["ms"])
        out["failed_runs" + suffix] = int(sum(bool(f) for f in a["failed"]))
        out["failures" + suffix] = [f"run {r}: " + "; ".join(f) for r, f in enumerate(a["failed"]) if f][:5]
        out["methods" + suffix] = a["methods"][0]
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
    ap.add_argument("--runs", type=int, default=50, help="simulations per chain / frame count (default 50)")
    ap.add_argument("--quick", action="store_true", help="5 runs (CI smoke)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args()
    runs = 5 if a.quick else a.runs
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
        res["timing"][str(F)] = {"ms_per_joint": t["ms_per_joint"], "ms_per_joint_jmv": t["ms_per_joint_jmv"],
                                 "rse": t["rse"], "rse_jmv": t["rse_jmv"], "failed_runs": t["failed_runs"],
                                 "failed_runs_jmv": t["failed_runs_jmv"]}
    for cid, counts in CHAINS.items():  # the same chains as the accuracy table, with noise
        seeds = [[a.seed, 0, int(cid), r] for r in range(runs)]
        n = run_chains(counts, 100, NOISE, runs, seeds)
        res["noise"][cid] = {k: v for k, v in n.items() if not k.startswith("methods")}

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
    say(f"{'chain':26s} {'framework':>28s} {'paper':>8s} {'JMV':>28s} {'paper':>8s} {'seq.paper':>9s} "
        f"{'failed fw/JMV':>13s}")
    for cid, counts in CHAINS.items():
        c = ch[cid]
        name = f"#{cid} <{'-'.join(map(str, counts))}>"
        say(f"{name:26s} {spread3(c, ''):>28s} {fmt(PAPER_RSE.get(cid)):>8s} "
            f"{spread3(c, '_jmv'):>28s} {fmt(PAPER_RSE_JMV.get(cid)):>8s} "
            f"{fmt(PAPER_RSE_SEQ.get(cid)):>9s} {c['failed_runs']:>6d}/{c['failed_runs_jmv']:<6d}")
    say()
    say("Time per joint, F = 100 (ms; paper: Tables II, III, IV)")
    say(f"{'chain':26s} {'framework':>10s} {'paper':>8s} {'JMV':>10s} {'paper':>8s}  methods (framework, first run)")
    for cid, counts in CHAINS.items():
        c = ch[cid]
        name = f"#{cid} <{'-'.join(map(str, counts))}>"
        say(f"{name:26s} {fmt(c['ms_per_joint'], '.2f'):>10s} {fmt(PAPER_MS.get(cid), '.1f'):>8s} "
            f"{fmt(c['ms_per_joint_jmv'], '.2f'):>10s} {fmt(PAPER_MS_JMV.get(cid), '.0f'):>8s}  "
            + ", ".join(c["methods"]))
    say()
    say("Speed, chain #1 <4-3-3> (paper Table II): time per joint (ms)")
    say(f"{'F':>5s} {'framework':>10s} {'paper':>8s} {'JMV':>10s} {'paper':>8s} {'seq.paper':>9s} "
        f"{'RSE fw':>9s} {'RSE JMV':>9s} {'failed fw/JMV':>13s}")
    for F in TIMING_FRAMES:
        t = tm[str(F)]
        fw_p, jmv_p = PAPER_TIMING[F]
        say(f"{F:5d} {fmt(t['ms_per_joint'], '.2f'):>10s} {fw_p:8.1f} {fmt(t['ms_per_joint_jmv'], '.2f'):>10s} "
            f"{jmv_p:8.0f} {PAPER_SEQ_MS[F]:9.0f} {fmt(t['rse']):>9s} {fmt(t['rse_jmv']):>9s} "
            f"{t['failed_runs']:>6d}/{t['failed_runs_jmv']:<6d}")
    say()
    say(f"Accuracy with marker noise {NOISE} (0.1 % of the joint spacing), F = 100: RSE mean "
        "[median, worst] (no paper figures)")
    say(f"{'chain':26s} {'framework':>28s} {'JMV':>28s} {'failed fw/JMV':>13s}")
    for cid, counts in CHAINS.items():
        c = res["noise"][cid]
        name = f"#{cid} <{'-'.join(map(str, counts))}>"
        say(f"{name:26s} {spread3(c, ''):>28s} {spread3(c, '_jmv'):>28s} "
            f"{c['failed_runs']:>6d}/{c['failed_runs_jmv']:<6d}")
    shown = [(f"#{cid} {m}", f) for cid in CHAINS for m, key in (("framework", "failures"), ("JMV", "failures_jmv"))
             for f in ch[cid][key][:2]]
    if shown:
        say()
        say("Failed runs, noise-free (first 2 per chain and mode)")
        for where, f in shown:
            say(f"  {where:14s} {f}")
    say()
    say("Targets")
    for t, p in checks:
        say(f"  {'PASS' if p else 'FAIL'}  {t}")
    m = res["machine"]
    say(f"\n{m['cpu']}, Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}; {res['date']}")
    sys.stdout.flush()


if __name__ == "__main__":
    main()
