"""The time target of issue 17 item 5 against the trial's length: calibrate's whole run (load, scaling, marker
placement, every frame's pose) and OpenSim's IK alone on the first N frames of the IK setup's range.

Issue 17 asks the whole run in at most 0.5x OpenSim's IK on gait2392 (121 IK frames) and rajagopal_walk (238); the
ratio falls as the trial grows, since calibrate's scaling and start are a fixed cost and OpenSim's IK is a cost per
frame.  This measures where it crosses 0.5x (owner question 9: read the target per trial length?).  For each case
(bench_osim's pipelines; ``hamner`` and ``rajagopal_run`` need ``--opensim-models DIR``): OpenSim's Scale once, then
its IK tool on each range [first IK frame, N-th] (a child process that imports OpenSim only, bench_osim's); calibrate
on the static + the same N walk frames, in this process, as bench_osim times it (one warm-up run first).  One run
each: within a run the ratio holds to a few per cent, between runs the machine's phase moves both (docs/benchmarks.md,
"The time ratio, repeated").

    PYTHONPATH=. python scripts/bench_length.py [--json out.json] [--opensim-models DIR] [--only CASE] [--lengths N,...]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_osim  # noqa: E402  (the pipelines' files, OpenSim's child, calibrate's timed run)

LENGTHS = (60, 120, 240, 360, 480, 600)  # frames of the IK range (each case up to its own)


def measure(case: str, work: Path, repo: Path | None, lengths: tuple[int, ...], log) -> dict:
    """Times of OpenSim's IK and calibrate's whole run on the first N IK frames of `case`, for each N in `lengths`
    the case has (and its whole IK range)."""
    spec = {**bench_osim.prepare(case, work, repo), "whole_trials": False}
    log(f"{case}: OpenSim's Scale + IK on the setup's range, to find its frames ...")
    full = bench_osim.run_opensim(spec, work)
    t_walk = bench_osim.trc_times(spec["walk"])
    first = int(np.argmin(np.abs(t_walk - full["times"][0])))
    total = len(full["times"])
    counts = sorted({n for n in lengths if n < total} | {total})
    spec["ik_ranges"] = [[float(t_walk[first]), float(t_walk[first + n - 1])] for n in counts]
    log(f"{case}: OpenSim's IK on the first {', '.join(map(str, counts))} frames ...")
    ranged = bench_osim.run_opensim(spec, work)
    log(f"{case}: warm-up (compiles the model's C code once per machine) ...")
    bench_osim.run_calibrate(spec, slice(first, first + 30), 0.0)
    rows = []
    for n, ik_s, (start, end) in zip(counts, ranged["ik_range_s"], spec["ik_ranges"], strict=True):
        log(f"{case}: calibrate on the static + {n} walk frames ...")
        cal = bench_osim.run_calibrate(spec, slice(first, first + n), 0.0)
        rows.append({"frames": n, "span_s": end - start, "opensim_ik_s": ik_s,
                     "calibrate_s": cal["wall_s"], "ratio": cal["wall_s"] / ik_s, "converged": cal["converged"]})
    return {"case": case, "static_frames": int(cal["static_frames"]), "rows": rows}


def report(res: dict) -> None:
    print("calibrate's whole run against OpenSim's IK alone, on the first N frames of each IK range (s)")
    for r in res["results"]:
        print(f"== {r['case']} (static: {r['static_frames']} frames)")
        print(f"  {'frames':>7s} {'span s':>8s} {'OpenSim IK':>11s} {'calibrate':>10s} {'ratio':>6s}")
        for x in r["rows"]:
            print(f"  {x['frames']:7d} {x['span_s']:8.2f} {x['opensim_ik_s']:11.2f} {x['calibrate_s']:10.2f} "
                  f"{x['ratio']:6.2f}" + ("" if x["converged"] else "  (not converged)"))
        below = [x["frames"] for x in r["rows"] if x["ratio"] <= 0.5]
        print("  at or below 0.5x from " + (f"{below[0]} frames" if below else "no length measured"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, help="write the results here")
    ap.add_argument("--only", choices=["gait2392", "rajagopal", *bench_osim.EXTRA_CASES])
    ap.add_argument("--opensim-models", type=Path, default=None, metavar="DIR",
                    help="a checkout of opensim-models: adds its Hamner and Rajagopal running pipelines")
    ap.add_argument("--lengths", default=",".join(map(str, LENGTHS)), metavar="N,...",
                    help=f"frames of the IK range to time (default {','.join(map(str, LENGTHS))}; each case up to "
                         "its own, whose whole range is always timed)")
    a = ap.parse_args()
    try:
        lengths = tuple(int(x) for x in a.lengths.split(",") if x.strip())
    except ValueError:
        print(f"bench_length: --lengths {a.lengths}: give whole numbers of frames, e.g. 60,120,240", file=sys.stderr)
        return 2
    if not lengths or min(lengths) < 30:
        print(f"bench_length: --lengths {a.lengths}: give lengths of 30 frames or more", file=sys.stderr)
        return 2
    repo = a.opensim_models
    if repo is not None or a.only in bench_osim.EXTRA_CASES:
        missing = [f for f in bench_osim.extra_files(repo or Path("(none given)")) if not f.is_file()]
        if missing:
            print(f"bench_length: --opensim-models {repo}: {missing[0]} not found; give a checkout of "
                  "opensim-models", file=sys.stderr)
            return 2

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    cases = [a.only] if a.only else ["gait2392", "rajagopal"] + (list(bench_osim.EXTRA_CASES) if repo else [])
    with tempfile.TemporaryDirectory(prefix="bench_length_") as tmp:
        res = {"lengths": list(lengths),
               "results": [measure(c, Path(tmp), repo, lengths, log) for c in cases]}
    report(res)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
