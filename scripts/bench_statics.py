"""A static alone, as OpenSim's Scale tool takes one: real Plug-in Gait statics calibrated with no movement trial.

No joint turns in a static, so nothing places the joint centres and axes but the priors and the lab's
measurements.  Each static is calibrated alone on models/human.urdf from the command line, three ways: by default
(the lateral markers drawn onto their held hinge axes, ``Priors.on_axis``; the hips', lumbar's and shoulders'
centres held at the base model's offset from their segments' markers, ``Calibration.still_centres``), with that
prior off (``[priors] on_axis_mm = 0``), and with ``--hip-regression``.  From the files each run writes (the
subject URDF through Pinocchio, the motion CSV) and its report:

- each knee's and ankle's lateral marker (KNE, ANK) across its hinge axis: its distance from the axis line through
  the centre (the base model's: 2 and 6 mm);
- every hip, knee and ankle centre against Plug-in Gait's own in the static (median over its frames,
  ``bench_real.pig_distances``), the hips also against Harrington's regression on its pelvis markers.

The statics: BTKData's six Plug-in Gait calibrations (``--btkdata``, as ``bench_btk.py``; its one-frame static is
refused, too few frames) and ../shared/data/real/pig_walk's.  No targets: the figures are recorded in
docs/benchmarks.md ("A static alone").

    python scripts/bench_statics.py --btkdata DIR [--json] [--cap S]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_real as br  # noqa: E402  (the real-recordings bench's command line and read-back helpers)
from bench_btk import fetch_trials, figures, mm, stamped  # noqa: E402

STATICS = ("PiG/PiG_Calibration-FlatFoot-Full.c3d", "PiG/PiG_Calibration-FlatFoot-Hole.c3d",
           "PiG/PiG_Calibration2-NoOption.c3d", "PiG/PiG_Calibration3_FF.c3d", "PiG/PiG_Calibration3_FF_N18.c3d",
           "PiG/PiG_Calibration3_noFF.c3d")
PIG_WALK_STATIC = br.PIG / "static.c3d"
LATERAL = (("knee_l", "LKNE"), ("knee_r", "RKNE"), ("ankle_l", "LANK"), ("ankle_r", "RANK"))


def across_axis_mm(kin: br.UrdfKinematics, joint: str, marker: str) -> float:
    """A lateral marker's distance from its hinge's axis line through the centre (mm)."""
    a, d = br.hinge_offset(kin, joint, marker)
    return 1000 * float(np.linalg.norm(d - a * (a @ d)))


def collect(a: argparse.Namespace, log) -> dict:
    res: dict = {"statics": {}, "btkdata": str(a.btkdata)}
    with tempfile.TemporaryDirectory(prefix="bench_statics_") as tmp:
        tmp = Path(tmp)
        off = tmp / "on_axis_off.toml"
        off.write_text("[priors]\non_axis_mm = 0.0\n")
        variants = [("default", []), ("on_axis_off", ["--config", off]), ("hip_regression", ["--hip-regression"])]
        log("warm-up: a 100-frame calibration (the model's C code, the bytecode)")
        res["warmup"] = br.warm_up(tmp, a.cap, log)
        statics = [(Path(n).stem, fetch_trials(a.btkdata, (n,), tmp)[0]) for n in STATICS]
        if PIG_WALK_STATIC.exists():
            statics.append(("pig_walk static", PIG_WALK_STATIC))
        for name, trial in statics:
            res["statics"][name] = {}
            for variant, extra in variants:
                log(f"{name}: calibrate {trial.name} {' '.join(str(x) for x in extra)}")
                run = br.calibrate_cli([trial], tmp / name / variant, a.cap, extra)
                f = figures(run)
                if "error" not in f:
                    kin = br.UrdfKinematics(run["urdf"])
                    f["across_axis_mm"] = {m: across_axis_mm(kin, j, m) for j, m in LATERAL}
                    f["on_axis_markers"] = run["report"].get("on_axis_markers", [])
                res["statics"][name][variant] = f
    return stamped(res)


def report(res: dict) -> None:
    print(f"Plug-in Gait statics calibrated alone on human.urdf ({res['date']}; {res['machine'].get('cpu', '')})")
    print(f"{'static':30s} {'run':15s} {'KNE/ANK across axis l/r/l/r':>28s} {'from PiG: knee l/r':>19s} "
          f"{'ankle l/r':>10s} {'hip l/r':>9s} {'hips from Harrington':>21s} {'RMS mm':>7s}")
    for name, runs in res["statics"].items():
        for variant, f in runs.items():
            if "error" in f:
                print(f"{name:30s} {variant:15s} {f['error']}")
                continue
            ax = "/".join(mm(f["across_axis_mm"][m]) for _, m in LATERAL)
            p = f["from_plugin_gait_mm"]
            h = f["hips"]
            print(f"{name:30s} {variant:15s} {ax:>28s} {mm(p.get('knee_l')):>9s}/{mm(p.get('knee_r')):<9s} "
                  f"{mm(p.get('ankle_l')):>5s}/{mm(p.get('ankle_r')):<4s} {mm(p.get('hip_l')):>4s}/"
                  f"{mm(p.get('hip_r')):<4s} {mm(h.get('hip_l', {}).get('from_regression_mm')):>10s}/"
                  f"{mm(h.get('hip_r', {}).get('from_regression_mm')):<10s} {f['marker_rms_mm']:7.2f}"
                  + ("" if f["converged"] else " NOT CONVERGED"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--btkdata", type=Path, required=True,
                    help="a BTKData checkout (or the fetch tool's snapshot: its .git folder)")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    ap.add_argument("--cap", type=float, default=600.0, help="time cap (s) of each command (default 600)")
    a = ap.parse_args()
    if not a.btkdata.exists():
        ap.error(f"--btkdata: {a.btkdata} does not exist; give a BTKData checkout")
    br.run_bench(a, collect, report)


if __name__ == "__main__":
    main()
