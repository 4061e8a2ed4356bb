"""Reading one trial from each file format calibrate reads: C3D, TRC, Qualisys QTM's .tsv and OptiTrack Motive's
.csv, the same positions in each (F frames x N markers, 2 % gaps), written by calibrate's writers (C3D, TRC) and in
the vendors' layouts (tests/test_tables.py's writers); numpy's genfromtxt on the TSV as the plain alternative.
Wall time (best of --repeat) and the peak of Python's allocations (tracemalloc) per reader.

    PYTHONPATH=. python scripts/bench_read.py [--frames 20000] [--markers 64] [--repeat 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_tables import motive_text, qtm_text  # noqa: E402

from calibrate.io.c3d import write_c3d  # noqa: E402
from calibrate.io.read import read_trial  # noqa: E402
from calibrate.io.trc import write_trc  # noqa: E402
from calibrate.io.trial import Trial  # noqa: E402


def timed(read: Callable[[], object], repeat: int) -> tuple[float, float, object]:
    """(best wall time s, peak traced MB of one more call, the result)."""
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = read()
        best = min(best, time.perf_counter() - t0)
    tracemalloc.start()
    read()
    peak = tracemalloc.get_traced_memory()[1] / 1e6
    tracemalloc.stop()
    return best, peak, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--markers", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    markers = rng.uniform(-1.5, 1.5, size=(args.frames, args.markers, 3))
    markers[rng.random((args.frames, args.markers)) < 0.02] = np.nan
    trial = Trial(tuple(f"M{k:02d}" for k in range(args.markers)), markers, 200.0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        write_c3d(d / "t.c3d", trial)
        write_trc(d / "t.trc", trial)
        (d / "t.tsv").write_text(qtm_text(trial))
        (d / "t.csv").write_text(motive_text(trial))
        for name in ("t.c3d", "t.trc", "t.tsv", "t.csv"):
            wall, peak, got = timed(lambda n=name: read_trial(d / n), args.repeat)
            err = float(np.nanmax(np.abs(got.markers - markers)))  # type: ignore[attr-defined]
            rows.append({"reader": f"calibrate read_trial {name[2:]}", "wall_s": wall, "peak_mb": peak,
                         "file_mb": (d / name).stat().st_size / 1e6, "max_error_m": err})
        wall, peak, got = timed(lambda: np.genfromtxt(d / "t.tsv", delimiter="\t", skip_header=13), args.repeat)
        rows.append({"reader": "numpy genfromtxt .tsv (numbers only: no names, units, gaps)", "wall_s": wall,
                     "peak_mb": peak, "file_mb": (d / "t.tsv").stat().st_size / 1e6, "max_error_m": None})
    base = rows[0]["wall_s"]
    print(f"{args.frames} frames x {args.markers} markers; array {markers.nbytes / 1e6:.0f} MB")
    print(f"{'reader':62s} {'wall s':>7s} {'x C3D':>6s} {'peak MB':>8s} {'file MB':>8s}")
    for r in rows:
        r["ratio_to_c3d"] = r["wall_s"] / base
        print(f"{r['reader']:62s} {r['wall_s']:7.2f} {r['ratio_to_c3d']:6.2f} {r['peak_mb']:8.0f} {r['file_mb']:8.0f}")
    if args.json is not None:
        args.json.write_text(json.dumps({"frames": args.frames, "markers": args.markers, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
