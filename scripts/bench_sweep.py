#!/usr/bin/env python
"""Every C3D or TRC file under some folders calibrated on one model with the command line's defaults, a few at a
time: what other labs' trials do to calibrate (docs/benchmarks.md's public sweeps).

    python scripts/bench_sweep.py DIR [DIR ...] [--model models/human.urdf] [--jobs 2] [--timeout 600]
                                  [--json OUT.json] [--compare BEFORE.json]

Each file is one run of ``python -m calibrate FILE MODEL -o DIR/`` in a folder of its own.  Per file: the exit
status; for a calibration its marker RMS (mm, the report's ``markers.rms_mm``), whether it converged, the summary's
``implausible`` lines (the report's ``implausible_flags``), its unreliable parameters, the share of its frames that
do not place the root (the report's ``unplaced_frames``: their poses bridged), wall time, and the md5 of the
subject URDF (the same bits or not, run to run); for a refusal its one line.  ``--compare`` lists the files whose
status, URDF bits, RMS or implausible lines differ from an earlier run's JSON.  The data is not in ../shared
(public repositories: BTKData's ``Input/C3DSamples``, kineticstoolkit's ``data/``, ...): give their folders
(``scripts/public_data.py`` writes a repository's trial files into one, under the names docs/benchmarks.md gives).
Timings are of a machine running ``--jobs`` calibrations at once: compare them only within a run.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import platform
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

SUFFIXES = {".c3d", ".trc"}


def trial_files(folders: list[Path]) -> list[Path]:
    """The C3D and TRC files under `folders` (any case of suffix), sorted; empty files kept (a refusal to record)."""
    found = {p.resolve() for d in folders for p in Path(d).rglob("*") if p.is_file() and p.suffix.lower() in SUFFIXES}
    return sorted(found)


def outputs(folder: Path) -> dict:
    """What a finished calibration wrote in `folder`: its figures from the report JSON and the URDF's md5."""
    report = next(iter(sorted(folder.glob("*_report.json"))), None)
    urdf = next(iter(sorted(folder.glob("*.urdf"))), None)
    if report is None or urdf is None:
        return {}
    r = json.loads(report.read_text())
    frames = sum(t["frames"] for t in r["trials"])
    bridged = sum(len(u["frames"]) for u in r.get("unplaced_frames") or [])
    return {"rms_mm": float(r["markers"]["rms_mm"]), "converged": bool(r["solver"]["converged"]),
            "implausible": list(r.get("implausible_flags") or []), "unreliable": list(r.get("unreliable") or []),
            "root_unplaced": bridged / frames if frames else 0.0,
            "urdf_md5": hashlib.md5(urdf.read_bytes()).hexdigest()}


def run_one(path: Path, model: Path, timeout: float) -> dict:
    """One file calibrated by the command line in a scratch folder of its own."""
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as tmp:
        out = Path(tmp) / "out"
        out.mkdir()
        t0 = time.perf_counter()
        try:
            proc = subprocess.run([sys.executable, "-m", "calibrate", str(path), str(model), "-o", f"{out}/"],
                                  cwd=tmp, capture_output=True, text=True, timeout=timeout)
            rc, err = proc.returncode, proc.stderr
        except subprocess.TimeoutExpired:
            rc, err = None, f"timed out after {timeout:g} s"
        row = {"file": str(path), "rc": rc, "wall_s": time.perf_counter() - t0}
        if rc == 0:
            row.update(outputs(out))
        else:
            lines = [ln for ln in err.strip().splitlines() if ln.strip()]
            row["error"] = (lines[-1] if lines else "").replace(tmp, "<scratch>")  # the same line run to run
    return row


def compare(before: dict, now: dict) -> list[str]:
    """Lines naming what changed per file between two runs' JSON (status, URDF bits, RMS, implausible lines)."""
    old = {Path(r["file"]).name: r for r in before["files"]}
    lines = []
    for r in now["files"]:
        name = Path(r["file"]).name
        b = old.get(name)
        if b is None:
            lines.append(f"{name}: new (rc {r['rc']})")
            continue
        if b["rc"] != r["rc"]:
            lines.append(f"{name}: rc {b['rc']} -> {r['rc']}" + (f" ({r.get('error', '')})" if r["rc"] else ""))
            continue
        if r["rc"] != 0:
            if b.get("error") != r.get("error"):
                lines.append(f"{name}: refused otherwise: {r.get('error', '')}")
            continue
        if b.get("urdf_md5") != r.get("urdf_md5"):
            lines.append(f"{name}: URDF changed, marker RMS {b.get('rms_mm', float('nan')):.3f} -> "
                         f"{r.get('rms_mm', float('nan')):.3f} mm")
        if b.get("implausible") != r.get("implausible"):
            n0, n1 = len(b.get("implausible", [])), len(r.get("implausible", []))
            lines.append(f"{name}: implausible lines {n0} -> {n1}")
    gone = sorted(set(old) - {Path(r["file"]).name for r in now["files"]})
    lines.extend(f"{name}: not run now" for name in gone)
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+", type=Path, help="folders searched for .c3d and .trc files")
    ap.add_argument("--model", type=Path, default=Path(__file__).resolve().parents[1] / "models" / "human.urdf")
    ap.add_argument("--jobs", type=int, default=2, help="calibrations at once (default 2)")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds per file (default 600)")
    ap.add_argument("--json", type=Path, default=None, help="write every file's row here")
    ap.add_argument("--compare", type=Path, default=None, help="an earlier run's --json: list what changed")
    a = ap.parse_args(argv)
    for d in a.folders:
        if not d.is_dir():
            print(f"bench_sweep: {d}: not a folder; give the folders holding the trials", file=sys.stderr)
            return 2
    if not a.model.is_file():
        print(f"bench_sweep: {a.model}: not found; give the model (--model)", file=sys.stderr)
        return 2
    before = None
    if a.compare is not None:
        try:
            before = json.loads(a.compare.read_text())
        except (OSError, ValueError) as e:
            print(f"bench_sweep: {a.compare}: not a bench_sweep JSON ({e}); give an earlier run's --json",
                  file=sys.stderr)
            return 2
    files = trial_files(a.folders)
    if not files:
        print(f"bench_sweep: no .c3d or .trc file under {', '.join(map(str, a.folders))}", file=sys.stderr)
        return 2
    print(f"{len(files)} files on {a.model.name}, {a.jobs} at a time ...", file=sys.stderr)
    with ThreadPoolExecutor(max(1, a.jobs)) as pool:
        rows = list(pool.map(lambda p: run_one(p, a.model, a.timeout), files))
    ok = [r for r in rows if r["rc"] == 0]
    for r in rows:
        name = Path(r["file"]).name
        if r["rc"] == 0:
            bridged = f"  root unplaced in {100 * r['root_unplaced']:.0f} % of frames" if r.get("root_unplaced") else ""
            print(f"  {name:48s} {r.get('rms_mm', float('nan')):7.3f} mm  "
                  f"{len(r.get('implausible', [])):2d} implausible  {r['wall_s']:6.1f} s{bridged}")
        else:
            print(f"  {name:48s} refused (rc {r['rc']}): {r.get('error', '')[:150]}")
    print(f"{len(ok)} of {len(rows)} calibrate; {sum(len(r.get('implausible', [])) for r in ok)} implausible lines on "
          f"{sum(bool(r.get('implausible')) for r in ok)} files")
    result = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "machine": platform.processor()
              or platform.machine(), "python": platform.python_version(), "model": str(a.model), "jobs": a.jobs,
              "files": rows}
    if before is not None:
        changed = compare(before, result)
        print(f"against {a.compare.name}: " + ("nothing changed" if not changed else f"{len(changed)} changes"))
        for line in changed:
            print(f"  {line}")
        result["changes"] = changed
    if a.json is not None:
        a.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
