"""Other labs' Plug-in Gait walks: the Biomechanical ToolKit's test data (BTKData), calibrated as a user would.

BTKData (github.com/Biomechanical-ToolKit/BTKData, BSD licence) holds Vicon Plug-in Gait statics and walks from
several subjects, and a functional hip trial, each file carrying Plug-in Gait's own joint centres (``LFEP`` / ``RFEP``
hips by Davis' regression, ``LFEO`` knees, ``LTIO`` ankles).  Each subject is calibrated on models/human.urdf from
the command line (``python -m calibrate.cli STATIC WALK human.urdf``, a child process, wall clock timed), by
default and with ``--hip-regression``; from the files it writes (the subject URDF through Pinocchio, the motion
CSVs) and its report:

- the hips against Harrington's regression on the same frames' pelvis markers (the report's ``hip_motion``:
  ``from_regression_mm``, ``hip_width_mm``, ``asis_width_mm``, ``implausible``);
- every hip, knee and ankle centre against Plug-in Gait's own in the walk (median over its frames,
  ``bench_real.pig_distances``);
- marker RMS over every position (``bench_real.marker_fit``), converged, time.

The data are not in ../shared: point ``--btkdata`` at a checkout (or the ``fetch`` tool's snapshot, whose files
are read with ``git show``).  No targets: the figures are recorded in docs/benchmarks.md ("Other labs' Plug-in
Gait walks").

    python scripts/bench_btk.py --btkdata DIR [--json] [--only full,hole,ff3,func] [--no-regression]
    python scripts/bench_btk.py --labs DIR [--json] [--only AUC,FMC,...] [--no-regression]

``--labs`` runs C3D-parser's seven labs' sessions (``LAB_CASES``) instead of BTKData's.
"""

from __future__ import annotations

import argparse
import datetime
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_real as br  # noqa: E402  (the real-recordings bench's command line and read-back helpers)
from bench_calibrate import machine  # noqa: E402

SAMPLES = "Input/C3DSamples"
#: Subject -> its trials in BTKData (static first; the last trial is the walk the centres are compared on).
CASES: dict[str, tuple[str, ...]] = {
    "full": ("PiG/PiG_Calibration-FlatFoot-Full.c3d", "PiG/PiG_Motion-FlatFoot-Full.c3d"),
    "hole": ("PiG/PiG_Calibration-FlatFoot-Hole.c3d", "PiG/PiG_Motion-FlatFoot-Hole.c3d"),
    "ff3": ("PiG/PiG_Calibration3_FF.c3d", "PiG/PiG_Motion3_FF.c3d"),
    "func": ("others/FunctionalStatic.c3d", "others/FunctionalLHip.c3d", "others/FunctionalWalk.c3d"),
}


#: C3D-parser's test sessions (github.com/tsalemink/C3D-parser, ``tests/data``): a static and a walk from each of seven
#: clinical gait labs (Plug-in Gait with medial knee and ankle markers or a knee alignment device in the static only,
#: other labs' trunk and foot markers, segment axes written under names of their own), PROCESSING widths and Plug-in
#: Gait's own centres in most files.
LAB_SAMPLES = "tests/data"
LAB_CASES: dict[str, tuple[str, ...]] = {
    "AUC": ("AUC/static/CB_Static0001.c3d", "AUC/dynamic/CB_Dynamic0003.c3d"),
    "FMC": ("FMC/static/MH0222_BP08.c3d", "FMC/dynamic/MH0222_BP06.c3d"),
    "FMC-KAD": ("FMC/static/MH0222_BP01.c3d", "FMC/dynamic/MH0222_BP15.c3d"),
    "MH": ("MH/static/MH_Cal 01.c3d", "MH/dynamic/MH_Dynamic_BF08.c3d"),
    "QCMAS": ("QCMAS/static/QCMAS.static.c3d", "QCMAS/dynamic/QCMAS.dynamic.c3d"),
    "RBWH": ("RBWH/calibration/Max Cal 01.c3d", "RBWH/dynamic/bfnd w1.c3d"),
    "RCH": ("RCH/static/RCH.01.c3d", "RCH/dynamic/RCH.08.c3d"),
    "Sydney": ("Sydney/static/S4 AM Cal 01.c3d", "Sydney/dynamic/S4-AMGait03.c3d"),
}


def fetch_trials(root: Path, names: tuple[str, ...], into: Path, samples: str = SAMPLES) -> list[Path]:
    """The case's C3D files copied into `into`: from a checkout's work tree, or from a bare snapshot by git show."""
    out = []
    for name in names:
        dst = into / Path(name).name.replace(" ", "_")
        src = root / samples / name
        if src.exists():
            dst.write_bytes(src.read_bytes())
        else:
            git = root if (root / "HEAD").exists() else root / ".git"
            blob = subprocess.run(["git", "--git-dir", str(git), "show", f"HEAD:{samples}/{name}"],
                                  capture_output=True, check=True)
            dst.write_bytes(blob.stdout)
        out.append(dst)
    return out


def figures(run: dict) -> dict:
    """What one run gives: fit, hips against Harrington's and Plug-in Gait's, time."""
    if "error" in run:
        return {"error": run["error"], "command": run["command"]}
    rep = run["report"]
    kin = br.UrdfKinematics(run["urdf"])
    fit = br.marker_fit(kin, list(zip(run["trials"], run["motions"], strict=True)), rep)
    hips = {h["joint"]: h for h in rep.get("hip_motion", [])}
    pig = br.pig_distances(kin, run["motions"][-1], run["trials"][-1])
    return {"command": run["command"], "rc": run["rc"], "wall_s": run["seconds"],
            "converged": bool(rep["solver"]["converged"]), "marker_rms_mm": fit["rms_mm"],
            "hips": {j: {"places_centre": h.get("places_centre"), "from_regression_mm": h.get("from_regression_mm"),
                         "implausible": h.get("implausible")} for j, h in hips.items()},
            "hip_width_mm": next((h.get("hip_width_mm") for h in hips.values()), None),
            "asis_width_mm": next((h.get("asis_width_mm") for h in hips.values()), None),
            "from_plugin_gait_mm": {j: v["median_mm"] for j, v in pig.items()
                                    if j.split("_")[0] in ("hip", "knee", "ankle")}}


def collect(a: argparse.Namespace, log) -> dict:
    root, cases, samples = ((a.btkdata, CASES, SAMPLES) if a.btkdata else (a.labs, LAB_CASES, LAB_SAMPLES))
    res: dict = {"cases": {}, "btkdata" if a.btkdata else "labs": str(root)}
    only = a.only.split(",") if a.only else list(cases)
    variants = [("default", [])] + ([] if a.no_regression else [("hip_regression", ["--hip-regression"])])
    with tempfile.TemporaryDirectory(prefix="bench_btk_") as tmp:
        tmp = Path(tmp)
        log("warm-up: a 100-frame calibration (the model's C code, the bytecode)")
        res["warmup"] = br.warm_up(tmp, a.cap, log)
        for case in only:
            d = tmp / case
            d.mkdir()
            trials = fetch_trials(root, cases[case], d, samples)
            res["cases"][case] = {"trials": [t.name for t in trials]}
            for name, extra in variants:
                log(f"{case}: calibrate {' '.join(t.name for t in trials)} {' '.join(extra)}")
                run = br.calibrate_cli(trials, d / name, a.cap, extra)
                res["cases"][case][name] = figures(run)
    return stamped(res)


def stamped(res: dict) -> dict:
    """`res` with the machine and the date (UTC) it was measured on."""
    res["machine"] = machine()
    res["date"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    return res


def mm(v: float | None) -> str:
    """A distance in whole mm for the tables, a dash where there is none."""
    return "—" if v is None else f"{v:.0f}"


def report(res: dict) -> None:
    which = "BTKData's Plug-in Gait subjects" if "btkdata" in res else "C3D-parser's seven labs"
    print(f"{which} on human.urdf ({res['date']}; {res['machine'].get('cpu', '')})")
    print(f"{'case':7s} {'run':15s} {'RMS mm':>7s} {'hips from Harrington l/r':>25s} {'hips/ASIS mm':>14s} "
          f"{'from PiG hip l/r':>17s} {'knee l/r':>9s} {'ankle l/r':>10s} {'time s':>7s}  flags")
    for case, c in res["cases"].items():
        for name in ("default", "hip_regression"):
            f = c.get(name)
            if f is None:
                continue
            if "error" in f:
                print(f"{case:7s} {name:15s} {f['error']}")
                continue
            h, p = f["hips"], f["from_plugin_gait_mm"]
            flags = ", ".join(j for j, v in h.items() if v.get("implausible")) or ""
            reg = [mm(h.get(j, {}).get("from_regression_mm")) for j in ("hip_l", "hip_r")]
            pig = {j: mm(p.get(j)) for j in ("hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r")}
            print(f"{case:7s} {name:15s} {f['marker_rms_mm']:7.2f} {reg[0]:>12s} / {reg[1]:<10s} "
                  f"{mm(f['hip_width_mm']):>6s} / {mm(f['asis_width_mm']):<5s} "
                  f"{pig['hip_l']:>8s} / {pig['hip_r']:<6s} {pig['knee_l']:>4s} / {pig['knee_r']:<3s} "
                  f"{pig['ankle_l']:>4s} / {pig['ankle_r']:<4s} {f['wall_s']:7.1f}  "
                  + (f"implausible: {flags}" if flags else "") + ("" if f["converged"] else " NOT CONVERGED"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    data = ap.add_mutually_exclusive_group(required=True)
    data.add_argument("--btkdata", type=Path, help="a BTKData checkout (or the fetch tool's snapshot: its .git folder)")
    data.add_argument("--labs", type=Path,
                      help="a C3D-parser checkout (or the fetch tool's snapshot): its seven labs' sessions instead")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    ap.add_argument("--only", default=None, help=f"comma-separated cases among {','.join(CASES)}, or with --labs "
                                                 f"{','.join(LAB_CASES)} (default all)")
    ap.add_argument("--no-regression", action="store_true", help="leave out the --hip-regression runs")
    ap.add_argument("--cap", type=float, default=600.0, help="time cap (s) of each command (default 600)")
    a = ap.parse_args()
    cases = CASES if a.btkdata else LAB_CASES
    if a.only and (bad := set(a.only.split(",")) - set(cases)):
        ap.error(f"--only: unknown case {', '.join(sorted(bad))}; choose among {', '.join(cases)}")
    for flag, root in (("--btkdata", a.btkdata), ("--labs", a.labs)):
        if root is not None and not root.exists():
            ap.error(f"{flag}: {root} does not exist; give a checkout or the fetch tool's snapshot")
    br.run_bench(a, collect, report)


if __name__ == "__main__":
    main()
