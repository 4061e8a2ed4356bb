"""Benchmark the HTML report (`--html`, `calibrate report`): the time to make the page from a report JSON.

calibrate writes each plotly figure as plain data (plotly.js's schema) without plotly's per-value
validation (calibrate.calibration.html._figure).  The alternative, in the same run: the same figures
passed through plotly's validated path (plotly.io.to_html with validate=True builds a
plotly.graph_objects.Figure of each, as the report did until 2026-11-30).  Both pages are checked to
carry the same figures (every trace and layout value alike, Viridis by name against plotly's
expansion of it).  The report: `--report FILE` (a _report.json a calibration wrote), else the
calibration of a simulated walk (models/human.urdf, `--frames`, 1 mm noise) made here first.

    python scripts/bench_html.py [--report FILE] [--frames 600] [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import statistics
import sys
import time
from pathlib import Path

from bench_calibrate import machine  # shared with the other benches

ROOT = Path(__file__).resolve().parent.parent

FIGURE = re.compile(r'Plotly\.newPlot\(\s*"(figure-\d+)",\s*(\[.*?\]),\s*(\{.*?\}),\s*\{"displaylogo"', re.S)


def _report(a: argparse.Namespace) -> tuple[dict, str]:
    if a.report is not None:
        return json.loads(a.report.read_text()), str(a.report)
    from calibrate import Settings, calibrate
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_gait

    human = load_model(ROOT / "models" / "human.urdf")
    sim = simulate_gait(human, frames=a.frames, noise_mm=1.0, seed=1)
    return calibrate(human, sim.trial, Settings()).report(), f"simulated walk, {a.frames} frames"


def _figures(page: str) -> list[tuple[list, dict]]:
    return [(json.loads(m.group(2)), json.loads(m.group(3))) for m in FIGURE.finditer(page)]


def _same(a, b) -> bool:
    """Two figures' JSON alike: numbers to 1e-9, a colorscale named on one side and expanded on the other."""
    if isinstance(a, dict) and isinstance(b, dict):
        return set(a) == set(b) and all(k == "colorscale" or _same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float):
        return abs(float(a) - float(b)) <= 1e-9 * max(1.0, abs(float(a)))
    return a == b


def collect(a: argparse.Namespace) -> dict:
    import plotly.io as pio

    from calibrate.calibration.html import report_html

    report, source = _report(a)
    report_html(report)  # plotly's imports and first template out of the timing

    def timed() -> tuple[float, str]:
        t = time.perf_counter()
        page = report_html(report)
        return time.perf_counter() - t, page

    ours = [timed() for _ in range(a.repeat)]
    plain = pio.to_html

    def validated(fig, *args, **kw):  # the same figure, through plotly's graph objects
        kw["validate"] = True
        return plain(fig, *args, **kw)

    pio.to_html = validated
    try:
        theirs = [timed() for _ in range(a.repeat)]
    finally:
        pio.to_html = plain
    fa, fb = _figures(ours[0][1]), _figures(theirs[0][1])
    same = len(fa) == len(fb) > 0 and all(_same(list(x), list(y)) for x, y in zip(fa, fb, strict=True))
    t_ours = statistics.median(t for t, _ in ours)
    t_theirs = statistics.median(t for t, _ in theirs)
    return {"date": datetime.datetime.now().isoformat(timespec="minutes"), "machine": machine(), "report": source,
            "figures": len(fa), "page_mb": round(len(ours[0][1]) / 1e6, 2), "repeat": a.repeat,
            "calibrate_s": t_ours, "validated_s": t_theirs, "ratio": t_ours / t_theirs, "same_figures": same}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--report", type=Path, default=None, help="a _report.json (default: a simulated walk's)")
    ap.add_argument("--frames", type=int, default=600, help="frames of the simulated walk (no --report)")
    ap.add_argument("--repeat", type=int, default=5, help="pages made by each way (the median is reported)")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    a = ap.parse_args()
    res = collect(a)
    if a.json:
        print(json.dumps(res))
    else:
        print(f"HTML report of {res['report']}: {res['figures']} figures, {res['page_mb']} MB")
        print(f"  calibrate (plain figure data)   {res['calibrate_s']:.3f} s (median of {res['repeat']})")
        print(f"  plotly's validated figures      {res['validated_s']:.3f} s   ratio {res['ratio']:.3f}")
        print(f"  the same figures: {'yes' if res['same_figures'] else 'NO'}")
    return 0 if res["same_figures"] else 1


if __name__ == "__main__":
    sys.exit(main())
