"""Benchmark the checks for damaged samples on long trials with many of them: how long each check takes on 1 000 to
100 000 frames, and what it catches against the simulator's truth.

Each trial is simulated squats of models/human.urdf (3 mm soft-tissue artefact, 1 mm noise, 120 Hz) with one
swapped-label episode per 500 frames and one spike per 50 (the simulator's own corruptions, their samples known), and
LKNE given 50 mm of white noise in one stretch of a tenth of the trial (from its middle).  Timed, each alone and in
this process, as the calibration runs them once per trial before the seed:

- ``jump_episodes`` (spikes, swapped labels, a ghost at a gap's edge),
- ``jittery_samples`` (white noise: calibrate.seed.jitter),
- ``broken_samples`` (rigid distances broken) and ``fallen_samples`` (a marker left behind),
- ``without_broken``: all of them, as the seed and the checks by rigidity use them.

Caught: the share of the corrupted samples (spikes, swaps) each flags, and of the jittering stretch; false: the clean
samples it flags, per 1000 seen.  A 100 000-frame trial with 310 jumps once took jump_episodes 238 s (a gap-edge test
walked each jump's run to the next gap; docs/benchmarks.md): this is the run that would show it.

    python scripts/bench_damage_checks.py [--frames 1000,10000,100000] [--json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np
from bench_calibrate import machine, output_args, worker_or_saved

ROOT = Path(__file__).resolve().parent.parent
JITTER_MM = 50.0


def _trial(model, frames: int, seed: int):
    """The damaged squats and the truth (n_frames, n_labels) of the simulator's corruptions and of the jitter."""
    from calibrate.io.trial import Trial
    from calibrate.simulation.simulate import simulate_squats

    sim = simulate_squats(model, frames=frames, rate=120.0, seed=seed, sta_mm=3.0, swaps=max(1, frames // 500),
                          spikes=max(1, frames // 50))
    t = sim.trial
    corrupt = np.zeros((t.n_frames, len(t.labels)), dtype=bool)
    for c in sim.corruptions:
        corrupt[c.frame, t.labels.index(c.marker)] = True
    X = np.array(t.markers)
    k = t.labels.index("LKNE")
    a, n = frames // 2, max(60, frames // 10)
    X[a:a + n, k] += np.random.default_rng(seed).normal(scale=JITTER_MM / 1e3, size=(n, 3))
    noisy = np.zeros_like(corrupt)
    noisy[a:a + n, k] = np.all(np.isfinite(X[a:a + n, k]), axis=1)
    return Trial(t.labels, X, t.rate, t.first_frame, "squats"), corrupt, noisy


def _timed(f):
    t0 = time.perf_counter()
    out = f()
    return out, time.perf_counter() - t0


def run(frames: int, seed: int = 0) -> dict:
    from calibrate import load_model
    from calibrate.seed.jitter import jittery_samples
    from calibrate.seed.seeding import broken_samples, fallen_samples, jump_episodes, without_broken

    model = load_model(ROOT / "models" / "human.urdf")
    trial, corrupt, noisy = _trial(model, frames, seed)
    order = [trial.labels.index(n) for n in model.marker_names if n in trial.labels]
    seen = np.all(np.isfinite(trial.markers), axis=2)
    jumps, t_jump = _timed(lambda: jump_episodes(trial))
    (jitter, found), t_jitter = _timed(lambda: jittery_samples(trial))
    broken, t_broken = _timed(lambda: broken_samples(model, trial))
    fallen, t_fallen = _timed(lambda: fallen_samples(model, trial))
    (_, n_out), t_all = _timed(lambda: without_broken(model, trial))
    in_model = np.zeros_like(seen)
    in_model[:, order] = True

    def score(flags: np.ndarray, truth: np.ndarray) -> dict:
        clean = seen & ~corrupt & ~noisy
        return {"caught": float((flags & truth).sum() / max(1, truth.sum())),
                "false_per_1000": float(1000 * (flags & clean).sum() / max(1, clean.sum()))}

    rigid = np.zeros_like(seen)  # broken and fallen come in the model's marker order: back to the trial's
    rigid[:, order] = (broken | fallen)[:, [model.marker_index(trial.labels[i]) for i in order]]
    return {
        "frames": frames, "markers": len(trial.labels), "corrupted_samples": int(corrupt.sum()),
        "jittering_samples": int(noisy.sum()),
        "seconds": {"jump_episodes": t_jump, "jittery_samples": t_jitter, "broken_samples": t_broken,
                    "fallen_samples": t_fallen, "without_broken": t_all},
        "jump_episodes": score(jumps, corrupt), "jittery_samples": score(jitter, noisy),
        "broken_and_fallen": score(rigid & in_model, corrupt),
        "jittery_named": [x.label for x in found], "left_out_by_without_broken": n_out,
    }


def report(res: dict) -> None:
    """The result's table, one line per trial length."""
    print(f"checks for damaged samples, {res['date']}, {res['machine']}")
    for r in res["runs"]:
        s = r["seconds"]
        print(f"{r['frames']:7d} frames: jump_episodes {s['jump_episodes']:6.2f} s (caught "
              f"{100 * r['jump_episodes']['caught']:.1f} %, false {r['jump_episodes']['false_per_1000']:.2f}/1000), "
              f"jittery_samples {s['jittery_samples']:6.2f} s (caught {100 * r['jittery_samples']['caught']:.1f} %, "
              f"false {r['jittery_samples']['false_per_1000']:.2f}/1000), broken+fallen "
              f"{s['broken_samples'] + s['fallen_samples']:6.2f} s (caught "
              f"{100 * r['broken_and_fallen']['caught']:.1f} %), "
              f"without_broken {s['without_broken']:6.2f} s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", default="1000,10000,100000", help="comma-separated trial lengths")
    ap.add_argument("--seed", type=int, default=0)
    output_args(ap)
    a = ap.parse_args()
    if worker_or_saved(a, {}, report):
        return 0
    rows = [run(int(v), a.seed) for v in a.frames.split(",")]
    res = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": machine(), "runs": rows}
    if a.json:
        print(json.dumps(res, indent=1))
    else:
        report(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
