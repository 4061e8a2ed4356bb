"""Benchmark long recordings (issue 22): time and peak memory of a calibration against the number of frames.

For squats and treadmill gait of models/human.urdf (1 mm noise) at 1 000, 10 000, 30 000 and 100 000
frames: each trial is simulated and written in a child process (C3D up to 65 535 frames, TRC beyond:
a C3D file holds no more), then read and calibrated in a fresh child process of its own, which also
writes the outputs (subject URDF, motion CSV, report), so that its peak resident memory
(getrusage's ru_maxrss, recorded before anything else runs in it) is that of reading, calibrating
and writing alone.  Reported per size: wall time per stage, peak memory, iterations, marker RMS, and
the accuracy against the simulator's truth (computed in the same child after the peak is taken:
ball-joint centre errors, median and worst; hinge axes, worst; joint angles RMS).  Then the fitted
slopes (s and MB per 1000 frames), the time ratio 100 000 / 10 000 frames (target <= 10) and the
memory targets (10 000 frames <= 600 MB, 100 000 frames <= 2 GB).  Also reading alone: the peak memory
of reading the longest C3D and TRC over the size of the marker array it holds.

    python scripts/bench_scale.py [--frames 1000,10000,30000,100000] [--motions squats,gait] [--quick] [--json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_calibrate import machine, output_args, run_child, worker_or_saved  # shared with the other benches

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "human.urdf"
C3D_MAX_FRAMES = 65535
TARGET_RATIO = 10.0  # time of 100 000 frames over that of 10 000
TARGET_MB = {10000: 600.0, 100000: 2048.0}


# ====================================================================== child processes
def worker(kind: str, spec: dict, cap: float) -> dict:
    """`kind` (see WORKERS) in a fresh process of this script: its result, or what went wrong."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "result.json"
        child = run_child([sys.executable, str(Path(__file__).resolve()), "--_worker", kind, "--_spec",
                           json.dumps(spec), "--_out", str(out)], cap)
        res = json.loads(out.read_text()) if out.exists() else {}
        res["process_s"], res["process_peak_mb"] = child["seconds"], child["peak_mb"]
        if not out.exists():
            res["error"] = (f"exit {child['rc']}: " + (child["stderr"].strip().splitlines() or ["no output"])[-1])
        return res


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS"):
                return int(line.split()[1]) / 1024
    return math.nan


def _simulate(spec: dict):
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_gait, simulate_squats

    simulate = simulate_gait if spec["motion"] == "gait" else simulate_squats
    return simulate(load_model(MODEL), spec["frames"], noise_mm=1.0, seed=spec["seed"])


def work_simulate(spec: dict) -> dict:
    """Simulate the trial and write it (C3D, or TRC past C3D's frame limit) where spec says."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.trc import write_trc

    sim = _simulate(spec)
    path = Path(spec["trial"])
    (write_trc if path.suffix == ".trc" else write_c3d)(path, sim.trial)
    return {"bytes": path.stat().st_size}


def work_calibrate(spec: dict) -> dict:
    """Read the trial file, calibrate, write the outputs; peak memory taken then; then the accuracy
    against the truth (the same simulation again: deterministic in its seed)."""
    from calibrate.calibration.evaluate import compare_to_truth
    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.read import read_trial
    from calibrate.model.model import load_model

    model = load_model(MODEL)
    base_mb = _rss_mb()
    t0 = time.perf_counter()
    trial = read_trial(spec["trial"])
    read_s = time.perf_counter() - t0
    log: list[tuple[float, str]] = []
    t1 = time.perf_counter()
    cal = calibrate(model, trial, progress=lambda m: log.append((time.perf_counter() - t1, str(m))))
    calibrate_s = time.perf_counter() - t1
    out = Path(spec["out"])
    t2 = time.perf_counter()
    cal.write(out / "subject.urdf", out / "subject_motion.csv", out / "subject_report.json")
    write_s = time.perf_counter() - t2
    peak = _peak_mb()
    s = cal.summary
    full = [(t, m) for t, m in log if m.startswith("solve: all frames, iteration")]
    res = {"frames": trial.n_frames, "read_s": read_s, "calibrate_s": calibrate_s, "write_s": write_s,
           "times": dict(cal.times), "peak_mb": peak, "baseline_mb": base_mb, "iterations": s.iterations,
           "coarse_iterations": s.coarse.iterations if s.coarse is not None else 0,
           "full_iterations": len(full), "converged": bool(s.converged), "marker_rms_mm": 1000 * cal.marker_rms,
           "progress_lines": len(log), "eta_lines": sum("s left" in m or "more," in m for _, m in log)}
    del trial
    sim = _simulate(spec)
    c = compare_to_truth(cal, sim)
    balls = [v for k, v in c.centre_error.items() if c.kinds[k] == "ball"]
    res.update({"ball_median_mm": 1000 * float(np.median(balls)), "ball_max_mm": 1000 * float(np.max(balls)),
                "hinge_axis_max_deg": float(max(c.axis_error_deg.values())), "angle_rms_deg": c.angle_rms_deg})
    return res


def work_read(spec: dict) -> dict:
    """Read one trial file: peak memory over the resident memory before, against the marker array's size."""
    from calibrate.io.read import read_trial

    before = _rss_mb()
    t0 = time.perf_counter()
    trial = read_trial(spec["trial"])
    return {"frames": trial.n_frames, "seconds": time.perf_counter() - t0, "array_mb": trial.markers.nbytes / 2**20,
            "peak_over_before_mb": _peak_mb() - before}


WORKERS = {"simulate": work_simulate, "calibrate": work_calibrate, "read": work_read}


# ====================================================================== the run
def slope(x: list[float], y: list[float]) -> float:
    """Least-squares slope of y against x (per 1000 frames when x is in frames / 1000)."""
    if len(x) < 2:
        return math.nan
    return float(np.polyfit(np.asarray(x), np.asarray(y), 1)[0])


def collect(a: argparse.Namespace) -> dict:
    res = {"date": datetime.datetime.now().isoformat(timespec="minutes"), "machine": machine(),
           "frames": a.frames, "motions": a.motions, "runs": {}, "read": {}}
    with tempfile.TemporaryDirectory() as tmp:
        warm = Path(tmp) / "warm.c3d"  # compile the model's C code once, untimed
        worker("simulate", {"motion": "squats", "frames": 100, "seed": a.seed, "trial": str(warm)}, a.cap)
        (Path(tmp) / "warm").mkdir()
        worker("calibrate", {"motion": "squats", "frames": 100, "seed": a.seed, "trial": str(warm),
                             "out": str(Path(tmp) / "warm")}, a.cap)
        longest: dict[str, str] = {}
        for motion in a.motions:
            runs = []
            for frames in a.frames:
                path = Path(tmp) / f"{motion}_{frames}.{'trc' if frames > C3D_MAX_FRAMES else 'c3d'}"
                spec = {"motion": motion, "frames": frames, "seed": a.seed, "trial": str(path)}
                sim = worker("simulate", spec, a.cap)
                if "error" in sim:
                    runs.append({"frames": frames, "error": "simulate: " + sim["error"]})
                    continue
                out = Path(tmp) / f"out_{motion}_{frames}"
                out.mkdir()
                r = worker("calibrate", {**spec, "out": str(out)}, a.cap)
                r["frames"] = frames
                r["file_mb"] = sim["bytes"] / 2**20
                runs.append(r)
                print(f"  {motion} {frames}: {r.get('calibrate_s', math.nan):.1f} s, "
                      f"{r.get('peak_mb', math.nan):.0f} MB {r.get('error', '')}", file=sys.stderr, flush=True)
                longest[path.suffix] = str(path)
                if frames < max(a.frames):
                    path.unlink()
            res["runs"][motion] = runs
        for suffix, path in longest.items():
            if Path(path).exists():
                res["read"][suffix] = worker("read", {"trial": path}, a.cap)
    for motion, runs in res["runs"].items():
        ok = [r for r in runs if "error" not in r]
        x = [r["frames"] / 1000 for r in ok]
        total = [r["read_s"] + r["calibrate_s"] + r["write_s"] for r in ok]
        per_it = [r["calibrate_s"] for r in ok]
        res.setdefault("slopes", {})[motion] = {
            "s_per_1000_frames": slope(x, total), "mb_per_1000_frames": slope(x, [r["peak_mb"] for r in ok]),
            "calibrate_s_per_1000_frames": slope(x, per_it)}
        by = {r["frames"]: r for r in ok}
        if 10000 in by and 100000 in by:
            t = lambda r: r["read_s"] + r["calibrate_s"] + r["write_s"]  # noqa: E731
            res["slopes"][motion]["ratio_100k_10k"] = t(by[100000]) / t(by[10000])
    return res


def checks(res: dict) -> list[tuple[str, bool]]:
    out = []
    for motion, runs in res["runs"].items():
        by = {r["frames"]: r for r in runs if "error" not in r}
        for frames, mb in TARGET_MB.items():
            if frames in by:
                out.append((f"{motion} {frames} frames: peak {by[frames]['peak_mb']:.0f} MB <= {mb:.0f} MB",
                            by[frames]["peak_mb"] <= mb))
        ratio = res.get("slopes", {}).get(motion, {}).get("ratio_100k_10k")
        if ratio is not None:
            out.append((f"{motion}: time 100k / 10k frames {ratio:.2f} <= {TARGET_RATIO:g}", ratio <= TARGET_RATIO))
    return out


def report(res: dict) -> None:
    m = res["machine"]
    print(f"bench_scale  {res['date']}  {m['cpu']}, {m['cores']} cores, Python {m['python']}")
    for motion, runs in res["runs"].items():
        print(f"\n{motion} (1 mm noise): read + calibrate + write in one fresh process per size")
        print(f"  {'frames':>7} {'read s':>7} {'seed':>6} {'start':>6} {'solve':>7} {'cov':>6} {'write':>6} "
              f"{'total s':>8} {'peak MB':>8} {'its':>4} {'all-fr':>6} {'RMS mm':>7} {'ball med/max mm':>16} "
              f"{'hinge ax deg':>12}")
        for r in runs:
            if "error" in r:
                print(f"  {r['frames']:>7}  {r['error']}")
                continue
            t = r["times"]
            total = r["read_s"] + r["calibrate_s"] + r["write_s"]
            print(f"  {r['frames']:>7} {r['read_s']:7.2f} {t.get('seed', 0):6.2f} {t.get('start', 0):6.2f} "
                  f"{t.get('solve', 0):7.2f} {t.get('covariance', 0):6.2f} {r['write_s']:6.2f} {total:8.2f} "
                  f"{r['peak_mb']:8.0f} {r['iterations']:>4} {r['full_iterations']:>6} {r['marker_rms_mm']:7.3f} "
                  f"{r['ball_median_mm']:7.2f}/{r['ball_max_mm']:<8.2f} {r['hinge_axis_max_deg']:12.3f}")
        sl = res.get("slopes", {}).get(motion, {})
        print(f"  slopes: {sl.get('s_per_1000_frames', math.nan):.2f} s and "
              f"{sl.get('mb_per_1000_frames', math.nan):.1f} MB per 1000 frames"
              + (f"; time 100k / 10k = {sl['ratio_100k_10k']:.2f}" if "ratio_100k_10k" in sl else ""))
    for suffix, r in res.get("read", {}).items():
        if "error" in r:
            print(f"\nreading {suffix}: {r['error']}")
            continue
        print(f"\nreading the longest {suffix} ({r['frames']} frames): {r['seconds']:.2f} s, peak "
              f"{r['peak_over_before_mb']:.0f} MB over the memory before, the marker array {r['array_mb']:.0f} MB "
              f"({r['peak_over_before_mb'] / r['array_mb']:.2f}x)")
    print()
    for text, ok in checks(res):
        print(f"  {'PASS' if ok else 'FAIL'}  {text}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", default=None, help="comma-separated sizes (default 1000,10000,30000,100000)")
    ap.add_argument("--motions", default="squats,gait", help="comma-separated: squats, gait (default both)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cap", type=float, default=3600.0, help="time cap (s) of each child process")
    ap.add_argument("--quick", action="store_true", help="CI smoke: 300 and 1500 frames of squats")
    a = output_args(ap).parse_args()
    if worker_or_saved(a, WORKERS, report):
        return
    if a.quick:
        a.frames, a.motions = a.frames or "300,1500", "squats"
    a.frames = [int(x) for x in (a.frames or "1000,10000,30000,100000").split(",")]
    a.motions = [x.strip() for x in a.motions.split(",") if x.strip()]
    res = collect(a)
    if a.json:
        print(json.dumps(res, indent=1, default=float))
    else:
        report(res)


if __name__ == "__main__":
    main()
