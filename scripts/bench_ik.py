"""`calibrate ik` against OpenSim's IK tool on the same subject, setup and frames.

For each OpenSim pipeline of ../shared/data/real (gait2392, rajagopal_walk): calibrate's command line calibrates the
subject from the generic .osim (``--scale-setup``, ``--ik-setup``: as a lab moving its pipeline would), writing
subject.osim; then, with that subject held fixed, the walk's IK frames are fitted twice:

* ``calibrate ik`` (calibrate.calibration.subject_ik.fit_trial, in this process: its checks for damaged positions,
  then calibrate.solve.ik.inverse_kinematics): the IK setup's marker weights, its held coordinates and the subject's
  locked ones, its time range;
* OpenSim's InverseKinematicsTool from the lab's IK setup with the model replaced by subject.osim (a child process
  that imports OpenSim only), its model marker locations reported.

Both are scored the same way: per frame the weighted squared marker error (the setup's weights, over its tracked
markers: the objective both minimise) and the unweighted RMS, each coordinate's largest and RMS difference between
the two fits, and the fit's wall time (calibrate's in-process call; OpenSim's ``tool.run()``).

    PYTHONPATH=. python scripts/bench_ik.py [--json out.json] [--only gait2392|rajagopal]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_osim  # noqa: E402  (the pipelines' files and their preparation)

CASES = {"gait2392": ("subject01_static.trc", "subject01_walk1.trc", "gait2392.osim", "subject01_Setup_Scale.xml",
                      "subject01_Setup_IK.xml", "gait2392_Scale_MarkerSet.xml"),
         "rajagopal": ("static_walk_1.trc", "motion_capture_walk.trc", "Rajagopal2016.osim",
                       "scale_setup_walk_scaleOnly.xml", "ik_setup_walk.xml", None)}


def child(setup: str, model: str, trc: str, out_dir: str) -> int:
    """OpenSim's IK (imports OpenSim only): the lab's setup, `model` and `trc` in its stead; marker locations."""
    import opensim as osim

    osim.Logger.setLevelString("error")
    os.chdir(out_dir)
    tool = osim.InverseKinematicsTool(setup)
    subject = osim.Model(model)  # held: the tool keeps a reference
    tool.setModel(subject)
    tool.setMarkerDataFileName(trc)
    tool.setResultsDir(out_dir)
    tool.setOutputMotionFileName(str(Path(out_dir) / "opensim_ik.mot"))
    tool.set_report_errors(True)
    tool.set_report_marker_locations(True)
    t0 = time.perf_counter()
    if not tool.run():
        print("IK failed", file=sys.stderr)
        return 1
    print(json.dumps({"seconds": time.perf_counter() - t0}))
    return 0


def plain_setup(src: Path, dst: Path) -> Path:
    """The IK setup with its results directory at the child's folder (OpenSim writes its marker files there)."""
    tree = ET.parse(src)
    tool = tree.getroot().find(".//InverseKinematicsTool")
    el = tool.find("results_directory")
    if el is None:
        el = ET.SubElement(tool, "results_directory")
    el.text = "."
    tree.write(dst)
    return dst


def bench(case: str, work: Path, log) -> dict:
    from calibrate.calibration.subject_ik import fit_trial
    from calibrate.io.labels import map_labels
    from calibrate.io.osim_info import with_locked
    from calibrate.io.osim_setup import ik_setup_range, ik_setup_weights, with_ik_setup
    from calibrate.io.read import read_trial
    from calibrate.model.model import load_model
    from calibrate.problem.settings import Settings
    from calibrate.solve.ik import marker_columns

    static, walk, osim, scale, ik, marker_set = CASES[case]
    d = bench_osim.REAL / ("gait2392" if case == "gait2392" else "rajagopal_walk")
    out = work / case
    out.mkdir()
    trials = out / "trials"  # the trials under their own names (the setups name them), headers as OpenSim reads them
    trials.mkdir()
    for name in (static, walk):
        bench_osim._plain_trc(str(d / name), str(out)).rename(trials / name)
    trc = trials / walk
    log(f"{case}: calibrate (command line) ...")
    argv = ["calibrate", str(trials / static), str(trc), str(d / osim),
            "--scale-setup", str(d / scale), "--ik-setup", str(d / ik), "-o", str(out / "subject.osim"), "-q"]
    if marker_set:
        argv += ["--marker-set", str(d / marker_set)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"calibrate failed:\n{proc.stderr[-2000:]}")
    subject = load_model(out / "subject.osim")
    span = ik_setup_range(d / ik)
    trial = read_trial(trc)
    trial = trial.time_range(span.start, span.stop) if span is not None else trial
    trial, _ = map_labels(trial, subject.marker_names, None, aliases=True)
    weights = ik_setup_weights(d / ik)
    locked = dict(with_ik_setup(subject, with_locked(subject, Settings()), d / ik).lock)
    log(f"{case}: calibrate ik ...")
    t0 = time.perf_counter()
    got = fit_trial(subject, trial, subject.parameters(), locked, weights)  # as `calibrate ik` fits
    ours_s = time.perf_counter() - t0
    fit = got.fit
    log(f"{case}: OpenSim's IK on calibrate's subject (child process) ...")
    setup = plain_setup(d / ik, out / "ik_setup.xml")
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--_child", str(setup),
                           str(out / "subject.osim"), str(trc), str(out)], capture_output=True, text=True,
                          timeout=1800)
    if proc.returncode != 0:
        raise RuntimeError(f"OpenSim IK child failed:\n{proc.stderr[-3000:]}")
    theirs_s = json.loads(proc.stdout.strip().splitlines()[-1])["seconds"]
    # OpenSim's model marker locations -> its weighted error, as ours, against the same trial frames
    loc = next(out.glob("*_ik_model_marker_locations.sto"))
    lines = loc.read_text().splitlines()
    end = next(i for i, ln in enumerate(lines) if ln.strip() == "endheader")
    head = lines[end + 1].split()
    table = np.array([[float(v) for v in ln.split()] for ln in lines[end + 2:] if ln.strip()])
    obs = marker_columns(subject, trial)
    if table.shape[0] != obs.shape[0]:
        raise RuntimeError(f"{case}: OpenSim's IK fitted {table.shape[0]} frames, calibrate {obs.shape[0]}")
    w = np.array([weights.get(n, 0.0) for n in subject.marker_names])
    tracked = [k for k, n in enumerate(subject.marker_names) if w[k] > 0 and f"{n}_tx" in head]
    err_theirs = np.zeros((obs.shape[0], len(tracked)))
    for j, k in enumerate(tracked):
        n = subject.marker_names[k]
        at = table[:, [head.index(n + s) for s in ("_tx", "_ty", "_tz")]]
        err_theirs[:, j] = np.sum((at - obs[:, k]) ** 2, axis=1)
    err_ours = np.sum(fit.residuals[:, tracked] ** 2, axis=2)
    seen = np.isfinite(err_ours) & np.isfinite(err_theirs)
    wt = w[tracked]
    ours_w = np.sum(np.where(seen, err_ours, 0.0) * wt, axis=1)
    theirs_w = np.sum(np.where(seen, err_theirs, 0.0) * wt, axis=1)
    rms = lambda e: 1000 * float(np.mean(np.sqrt(np.sum(np.where(seen, e, 0.0), axis=1) / seen.sum(axis=1))))  # noqa: E731
    cols, q = bench_osim.read_mot(str(out / "opensim_ik.mot"))[1:]
    angles = {}
    for i, name in enumerate(fit.motion.dof_names):
        if name in cols and name not in locked:
            diff = np.degrees(fit.motion.angles[:, i] - q[:, cols.index(name)])
            angles[name] = {"max_deg": float(np.abs(diff).max()), "rms_deg": float(np.sqrt(np.mean(diff**2)))}
    ratio = ours_w / theirs_w
    return {"case": case, "frames": int(obs.shape[0]), "tracked_markers": len(tracked),
            "weighted_sse_calibrate": float(ours_w.mean()), "weighted_sse_opensim": float(theirs_w.mean()),
            "frames_calibrate_lower": int(np.sum(ours_w < theirs_w)),
            "ratio_median": float(np.median(ratio)), "ratio_max": float(ratio.max()),
            "rms_mm_calibrate": rms(err_ours), "rms_mm_opensim": rms(err_theirs),
            "seconds_calibrate": ours_s, "seconds_opensim": theirs_s, "angles": angles,
            "left_out_calibrate": got.left_out, "held_unplaced_calibrate": sorted(got.unplaced_held)}


def report(res: dict) -> None:
    for r in res["results"]:
        worst = max(r["angles"].items(), key=lambda kv: kv[1]["max_deg"])
        med = float(np.median([v["max_deg"] for v in r["angles"].values()]))
        print(f"== {r['case']}: {r['frames']} IK frames, {r['tracked_markers']} tracked markers, calibrate's subject "
              "held fixed")
        print(f"  weighted squared marker error, mean per frame: calibrate {r['weighted_sse_calibrate']:.4e}, "
              f"OpenSim's IK {r['weighted_sse_opensim']:.4e} m^2; calibrate lower on {r['frames_calibrate_lower']} of "
              f"{r['frames']} frames (per frame {r['ratio_median']:.3f}x at the median, {r['ratio_max']:.3f}x at most)")
        print(f"  unweighted RMS over the tracked markers: {r['rms_mm_calibrate']:.2f} / {r['rms_mm_opensim']:.2f} mm")
        print(f"  coordinates: largest difference {worst[1]['max_deg']:.2f} deg ({worst[0]}), the median "
              f"coordinate's {med:.2f} deg")
        print(f"  time: calibrate ik {r['seconds_calibrate']:.3f} s, OpenSim's IK {r['seconds_opensim']:.3f} s "
              f"({r['seconds_calibrate'] / r['seconds_opensim']:.2f}x)")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    ap.add_argument("--only", choices=tuple(CASES), default=None)
    ap.add_argument("--_child", nargs=4, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a._child:
        return child(*a._child)
    if not bench_osim.REAL.exists():
        print(f"bench_ik: {bench_osim.REAL} not found (the real trials)", file=sys.stderr)
        return 2

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="bench_ik_") as tmp:
        res = {"results": [bench(c, Path(tmp), log) for c in ([a.only] if a.only else list(CASES))]}
    report(res)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
