"""Benchmark `calibrate batch` (issue 21): a database of generated subjects calibrated on Dask.

16 subjects (simulated squats, 1000 frames each, random sizes from the simulator's seeds) are written
with a manifest; then run_batch calibrates them on a LocalCluster of 1 and of 2 worker processes (one
thread each), each run into a fresh output folder, the model's C code compiled beforehand.  Reported:
wall time, subjects per minute, the speed-up of 2 workers over 1, each worker's peak resident memory
(getrusage in the worker), the first and later subjects' times on a worker (the compiled functions
reused), and the hours a 1000-subject database would take on N workers, projected from the measured
cost per subject (wall time x workers / subjects).

    python scripts/bench_batch.py [--subjects 16] [--frames 1000] [--quick] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench_calibrate import machine

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "human.urdf"


def _worker_peak_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def make_lab(root: Path, subjects: int, frames: int) -> Path:
    """`subjects` simulated squat trials (seeds 0..) and their TOML manifest in `root`."""
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_squats, write_simulation

    model = load_model(MODEL)
    lines = []
    for k in range(subjects):
        sid = f"S{k + 1:02d}"
        write_simulation(simulate_squats(model, frames=frames, noise_mm=1.0, seed=k), root / sid)
        lines.append(f'[[subject]]\nid = "{sid}"\ntrials = ["{sid}/trial.c3d"]\nmodel = "{MODEL}"\n')
    (root / "lab.toml").write_text("\n".join(lines))
    return root / "lab.toml"


def run(manifest: Path, out: Path, workers: int) -> dict:
    """run_batch on a fresh LocalCluster of `workers` processes: times and each worker's peak memory."""
    from dask.distributed import Client, LocalCluster

    from calibrate.calibration.batch import read_manifest, run_batch

    subjects = read_manifest(manifest)
    finished: list[tuple[float, dict]] = []
    t0 = time.perf_counter()
    rows = run_batch(subjects, out, workers=workers,
                     progress=lambda r, k, n: finished.append((time.perf_counter() - t0, r)))
    wall = time.perf_counter() - t0
    # The peak memory of worker processes like the batch's: a cluster of the same size runs one subject
    # each (the batch's own cluster is closed by then), its workers' peak read with getrusage.
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        from calibrate.calibration.batch import calibrate_subject

        futs = [client.submit(calibrate_subject, s, str(out / "peak"), True, pure=False) for s in subjects[:workers]]
        client.gather(futs)
        peaks = list(client.run(_worker_peak_mb).values())
    secs = [r["seconds"] for r in rows]
    return {"workers": workers, "wall_s": wall, "subjects": len(rows), "per_minute": 60 * len(rows) / wall,
            "ok": sum(r["status"] == "ok" for r in rows), "failed": sum(r["status"] == "failed" for r in rows),
            "subject_s_median": statistics.median(secs), "subject_s_first": secs[0],
            "worker_peak_mb": peaks, "finish_s": [t for t, _ in finished]}


def collect(a: argparse.Namespace) -> dict:
    res = {"date": time.strftime("%Y-%m-%dT%H:%M"), "machine": machine(), "subjects": a.subjects,
           "frames": a.frames, "runs": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        manifest = make_lab(tmp / "lab", a.subjects, a.frames)
        res["generate_s"] = time.perf_counter() - t0
        from calibrate.calibration.pipeline import calibrate
        from calibrate.model.model import load_model
        from calibrate.simulation.simulate import simulate_squats

        model = load_model(MODEL)  # compile (or load) the model's C code before the timed runs
        calibrate(model, simulate_squats(model, frames=100, seed=99).trial)
        for workers in (1, 2):
            print(f"  {workers} worker(s)...", file=sys.stderr, flush=True)
            res["runs"].append(run(manifest, tmp / f"out{workers}", workers))
    one, two = res["runs"]
    res["speedup"] = one["wall_s"] / two["wall_s"]
    per_subject = {r["workers"]: r["wall_s"] * r["workers"] / r["subjects"] for r in res["runs"]}
    res["per_subject_worker_s"] = per_subject
    cost = per_subject[2]  # worker-seconds per subject as the cluster runs them
    res["projection_hours_1000"] = {n: 1000 * cost / n / 3600 for n in (2, 8, 32, 128)}
    return res


def report(res: dict) -> None:
    m = res["machine"]
    print(f"bench_batch  {res['date']}  {m['cpu']}, {m['cores']} cores, Python {m['python']}")
    print(f"{res['subjects']} simulated subjects, {res['frames']} squat frames each (generated in "
          f"{res['generate_s']:.0f} s)")
    print(f"  {'workers':>7} {'wall s':>7} {'subj/min':>8} {'ok':>3} {'failed':>6} {'median s':>8} "
          f"{'first s':>7} {'worker peak MB':>16}")
    for r in res["runs"]:
        print(f"  {r['workers']:>7} {r['wall_s']:7.1f} {r['per_minute']:8.2f} {r['ok']:>3} {r['failed']:>6} "
              f"{r['subject_s_median']:8.2f} {r['subject_s_first']:7.2f} "
              f"{', '.join(f'{p:.0f}' for p in r['worker_peak_mb']):>16}")
    print(f"  speed-up 2 vs 1 worker: {res['speedup']:.2f}x; cost per subject: "
          + ", ".join(f"{s:.2f} worker-s ({w} worker{'s' if int(w) > 1 else ''})"
                      for w, s in res["per_subject_worker_s"].items()))
    print("  1000 subjects: " + ", ".join(f"{h:.1f} h on {n} workers"
                                          for n, h in res["projection_hours_1000"].items()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=None, help="subjects (default 16; --quick: 4)")
    ap.add_argument("--frames", type=int, default=None, help="frames per subject (default 1000; --quick: 100)")
    ap.add_argument("--quick", action="store_true", help="CI smoke: 4 subjects of 100 frames")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    ap.add_argument("--from-json", type=Path, default=None, help="print the tables of a saved --json result")
    a = ap.parse_args()
    if a.from_json:
        report(json.loads(a.from_json.read_text()))
        return
    a.subjects = a.subjects if a.subjects is not None else (4 if a.quick else 16)
    a.frames = a.frames if a.frames is not None else (100 if a.quick else 1000)
    res = collect(a)
    if a.json:
        print(json.dumps(res, indent=1, default=float))
    else:
        report(res)


if __name__ == "__main__":
    main()
