"""Pose2Sim's demo against OpenSim: video keypoints on Pose2Sim's full-body model, whose lumbar spine follows L5/S1's
coordinates through CoordinateCouplerConstraints (calibrate.io.osim's lumped chain).

From perfanalytics/pose2sim at a948c205 (a checkout or a git directory, e.g. a `fetch` snapshot): the static and
balancing trials' filtered keypoints (`pose-3d/*_filt_butterworth.trc`), `Model_Pose2Sim_Halpe26.osim` and Pose2Sim's
own Scale and IK setups, their file names pointed at these files.  In one run:

1. the import against OpenSim itself: the model's markers at random poses (every coordinate uniform over its range
   at once), OpenSim in a child process, against calibrate's kinematics (Pinocchio) with each coordinate times its
   ratio;
2. OpenSim's Scale (Pose2Sim's ModelScaler; its MarkerPlacer is off) and IK (its coordinate task holds
   ``L5_S1_Flex_Ext`` at the default) in a child process (bench_osim's), and its mean per-frame marker RMS;
3. calibrate (the command line, in this process) on the static + balancing trials with and without ``--ik-setup``:
   marker RMS, and each coordinate's RMS difference from OpenSim's IK on the balancing trial in OpenSim's units (the
   motion CSV's angle over the coordinate's ratio);
4. the subject calibrate wrote (its defaults' subject.osim) held fixed, the balancing trial fitted again by
   ``calibrate ik --ik-setup`` (the command line) and by OpenSim's IK tool from the same setup (child process): mean
   per-frame marker RMS over the markers OpenSim's IK tracks, beside the calibration's own fit of that trial, and
   each one's time;
5. the two-person session (S00_P01): each participant's static with each person's part of the shared trial (the
   trial's P1 is participant 2, the child, and its P2 participant 1), from the video keypoints and from Pose2Sim's
   LSTM-augmented markers on its `Model_Pose2Sim_LSTM.osim`: the command line's exit and error line where it refuses
   two subjects, else each trial's marker RMS, the implausible flags and the hips' and knees' flexion range.

    PYTHONPATH=. python scripts/bench_pose2sim.py --pose2sim DIR [--commit a948c205] [--json out.json]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_import  # noqa: E402  (the import against OpenSim at random poses)
import bench_osim  # noqa: E402  (OpenSim's IK child and its marker scores)

COMMIT = "a948c205"
SETUP = "Pose2Sim/OpenSim_Setup/"
TRIALS = "Pose2Sim/S00_Demo_Session/S00_P00_SingleParticipant/"
FILES = {"model.osim": SETUP + "Model_Pose2Sim_Halpe26.osim",
         "scale_setup.xml": SETUP + "Scaling_Setup_Pose2Sim_Halpe26.xml",
         "ik_setup.xml": SETUP + "IK_Setup_Pose2Sim_Halpe26.xml",
         "static.trc": TRIALS + "S00_P00_T00_StaticTrial/pose-3d/S00_P00_T00_StaticTrial_0-12_filt_butterworth.trc",
         "balancing.trc": TRIALS + "S00_P00_T01_BalancingTrial/pose-3d/"
                                   "S00_P00_T01_BalancingTrial_0-100_filt_butterworth.trc"}
TWO = "Pose2Sim/S00_Demo_Session/S00_P01_MultiParticipants/"
# The two-person session (item 5): each participant's static and each person's part of the shared trial, as video
# keypoints (Halpe26) and as Pose2Sim's LSTM-augmented markers (its Model_Pose2Sim_LSTM.osim).
for _kind, _suffix in (("halpe", ""), ("lstm", "_LSTM")):
    FILES |= {f"{_kind}_static1.trc": TWO + "S00_P01_T00_StaticTrialParticipant1/pose-3d/"
                                            f"S00_P01_T00_StaticTrialParticipant1_0-12_filt_butterworth{_suffix}.trc",
              f"{_kind}_static2.trc": TWO + "S00_P01_T01_StaticTrialParticipant2/pose-3d/"
                                            f"S00_P01_T01_StaticTrialParticipant2_0-12_filt_butterworth{_suffix}.trc",
              **{f"{_kind}_trial_P{k}.trc": TWO + "S00_P01_T02_Participants1-2/pose-3d/"
                                                  f"S00_P01_T02_Participants1-2_P{k}_0-100_filt_butterworth{_suffix}.trc"
                 for k in (1, 2)}}
FILES["model_lstm.osim"] = SETUP + "Model_Pose2Sim_LSTM.osim"
COORDS = ("L5_S1_Flex_Ext", "L5_S1_Lat_Bending", "L5_S1_axial_rotation", "hip_flexion_r", "hip_flexion_l",
          "hip_adduction_r", "hip_adduction_l", "knee_angle_r", "knee_angle_l", "ankle_angle_r", "ankle_angle_l")

# Child: Pose2Sim's Scale setup (its MarkerPlacer off, so run() reports failure though the scaled model is written).
_SCALE = r"""
import os, sys
import opensim as osim
osim.Logger.removeFileSink()
osim.Logger.setLevelString("error")
os.chdir(sys.argv[1])
osim.ScaleTool("scale_setup.xml").run()
sys.exit(0 if os.path.exists("scaled.osim") else 1)
"""


def read_files(repo: Path, commit: str, work: Path) -> None:
    """The demo's files into `work`, from a checkout (the commit checked out) or a git directory."""
    for name, path in FILES.items():
        if (repo / path).is_file():
            (work / name).write_bytes((repo / path).read_bytes())
            continue
        git = repo if (repo / "HEAD").is_file() else repo / ".git"
        proc = subprocess.run(["git", "--git-dir", str(git), "show", f"{commit}:{path}"], capture_output=True)
        if proc.returncode != 0:
            raise SystemExit(f"{repo}: no {path} at {commit} ({proc.stderr.decode().strip()[:200]}); give a "
                             f"perfanalytics/pose2sim checkout or git directory that has commit {commit}")
        (work / name).write_bytes(proc.stdout)


SETUP_FILES = {"scale_setup.xml": {"model_file": "model.osim", "marker_file": "static.trc",
                                   "output_model_file": "scaled.osim"},
               "ik_setup.xml": {"model_file": "scaled.osim", "marker_file": "balancing.trc",
                                "output_motion_file": "ik.mot"}}


def adapt_setups(work: Path) -> None:
    """Point Pose2Sim's setups at the files in `work` (its demo's relative paths name its own folders): every
    <tag> of SETUP_FILES in each setup gets its file name (the generic model's <model_file>: the first only)."""
    for setup, names in SETUP_FILES.items():
        text = (work / setup).read_text()
        for tag, name in names.items():
            once = 1 if tag == "model_file" else 0
            text = re.sub(rf"<{tag}>[^<]*</{tag}>", f"<{tag}>{name}</{tag}>", text, count=once)
        (work / setup).write_text(text)


def run_calibrate(work: Path, ik_setup: bool, log) -> dict:
    """The command line on the static + balancing trials; its marker RMS and the balancing trial's angles in
    OpenSim's units."""
    from calibrate.cli import main
    from calibrate.io.motion import read_motion_csv
    from calibrate.io.osim_info import osim_info
    from calibrate.model.model import load_model

    out = work / ("cal_ik" if ik_setup else "cal")
    out.mkdir(exist_ok=True)
    args = [str(work / "static.trc"), str(work / "balancing.trc"), str(work / "model.osim"), "-o",
            str(out / "subject.urdf"), "--overwrite", "-q"] + (["--ik-setup", str(work / "ik_setup.xml")]
                                                             if ik_setup else [])
    log(f"calibrate{' --ik-setup' if ik_setup else ''} ...")
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):  # its summary and the files it wrote (the figures are below)
        code = main(args)
    wall = time.perf_counter() - t0
    if code != 0:
        raise RuntimeError(f"calibrate exited {code}")
    report = json.loads((out / "static_report.json").read_text())
    motion = read_motion_csv(out / "balancing_motion.csv")
    info = osim_info(load_model(out / "subject.urdf"))
    angles = {d: motion.angles[:, k] / info.ratio(d) for k, d in enumerate(motion.dof_names)}
    return {"wall_s": wall, "marker_rms_mm": report["markers"]["rms_mm"],
            "trials_rms_mm": {Path(t["source"]).stem: t["rms_mm"] for t in report["trials"]},
            "times": motion.times, "angles": angles,
            "implausible": [b["segment"] for b in report.get("implausible", [])]}


def ik_on_subject(work: Path, use: list[str], log) -> dict:
    """calibrate's defaults subject (cal/subject.osim) held fixed: the balancing trial by ``calibrate ik`` and by
    OpenSim's IK tool, both from Pose2Sim's IK setup; their marker scores over `use` and times."""
    from calibrate.cli import main
    from calibrate.io.motion import read_motion_csv
    from calibrate.io.trc import read_trc
    from calibrate.model.kinematics import FrameLayout, build_kinematics
    from calibrate.model.model import load_model

    sub = work / "ik_subject"  # the IK setup names the model scaled.osim and the trial balancing.trc
    (sub / "out").mkdir(parents=True)
    for src, dst in (("cal/subject.osim", "scaled.osim"), ("ik_setup.xml", "ik_setup.xml"),
                     ("balancing.trc", "balancing.trc")):
        (sub / dst).write_bytes((work / src).read_bytes())
    log("calibrate ik on calibrate's subject ...")
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["ik", str(sub / "balancing.trc"), str(sub / "scaled.osim"), "--ik-setup",
                     str(sub / "ik_setup.xml"), "-o", str(sub / "out"), "-q"])
    wall = time.perf_counter() - t0
    if code != 0:
        raise RuntimeError(f"calibrate ik exited {code}")
    subject = load_model(sub / "scaled.osim")
    motion = read_motion_csv(sub / "out" / "balancing_motion.csv")
    ours, _ = build_kinematics(subject).batch(FrameLayout.coordinates(motion.root_translation, motion.angles),
                                              motion.root_quaternion, subject.parameters())
    trial = read_trc(work / "balancing.trc")
    log("OpenSim's IK on calibrate's subject (child process) ...")
    osr = bench_osim.run_opensim({"dir": str(sub), "scale": [], "ik": "ik_setup.xml"}, work)
    for name, frames in (("calibrate ik", motion.n_frames), ("OpenSim's IK", len(osr["times"]))):
        if frames != trial.n_frames:
            raise RuntimeError(f"{name} fitted {frames} frames of the balancing trial's {trial.n_frames}")
    return {"calibrate_ik": {**bench_osim.marker_scores(np.asarray(ours), list(subject.marker_names), trial, use),
                             "wall_s": wall},
            "opensim_ik": {**bench_osim.marker_scores(osr["markers"], osr["marker_names"], trial, use),
                           "ik_s": osr["ik_s"]}}


def two_person(work: Path, log) -> list[dict]:
    """Item 5: the command line on each participant's static with each person's part of the two-person trial, from
    the keypoints (Halpe26) and from the LSTM-augmented markers: its exit code and error line where it refuses,
    else each trial's marker RMS, the implausible flags, and the hips' and knees' flexion range in each trial."""
    from calibrate.cli import main
    from calibrate.io.motion import read_motion_csv

    rows = []
    for kind, model in (("halpe", "model.osim"), ("lstm", "model_lstm.osim")):
        for static in (1, 2):
            for person in (1, 2):
                out = work / f"two_{kind}_{static}_{person}"
                out.mkdir()
                args = [str(work / f"{kind}_static{static}.trc"), str(work / f"{kind}_trial_P{person}.trc"),
                        str(work / model), "-o", str(out / "subject.urdf"), "-q"]
                log(f"two-person session, {kind}: participant {static}'s static, trial person P{person} ...")
                err = io.StringIO()
                with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                    code = main(args)
                row = {"markers": kind, "static": static, "trial_person": person, "rc": code,
                       "error": next((ln for ln in err.getvalue().splitlines() if ln.startswith("calibrate: error")),
                                     None)}
                if code in (0, 1):
                    report = json.loads(next(out.glob("*_report.json")).read_text())
                    row["trials_rms_mm"] = {Path(t["source"]).stem: t["rms_mm"] for t in report["trials"]}
                    row["implausible"] = [b.get("segment") or b.get("text", "")[:60]
                                          for b in report.get("implausible", [])]
                    ranges = {}
                    for f in sorted(out.glob("*_motion.csv")):
                        motion = read_motion_csv(f)
                        ranges[f.stem.removesuffix("_motion")] = {
                            c: [float(np.degrees(motion.angles[:, i].min())),
                                float(np.degrees(motion.angles[:, i].max()))]
                            for i, c in enumerate(motion.dof_names) if c.startswith(("hip_flexion", "knee_angle"))}
                    row["flexion_deg"] = ranges
                rows.append(row)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pose2sim", type=Path, required=False, help="a perfanalytics/pose2sim checkout or git directory")
    ap.add_argument("--commit", default=COMMIT, help=f"the commit whose demo is read (default {COMMIT})")
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    a = ap.parse_args()
    if a.pose2sim is None:
        ap.error("--pose2sim DIR is required (a perfanalytics/pose2sim checkout or git directory)")

    def log(msg: str) -> None:
        print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="bench_pose2sim_") as tmp:
        work = Path(tmp)
        read_files(a.pose2sim, a.commit, work)
        adapt_setups(work)
        res: dict = {"commit": a.commit, "import": bench_import.import_check(work / "model.osim", log)}
        log("OpenSim's Scale (Pose2Sim's setup, child process) ...")
        proc = subprocess.run([sys.executable, "-c", _SCALE, str(work)], capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"OpenSim's Scale wrote no scaled model:\n{proc.stderr[-2000:]}")
        log("OpenSim's IK (Pose2Sim's setup, child process) ...")
        osr = bench_osim.run_opensim({"dir": str(work), "scale": [], "ik": "ik_setup.xml"}, work)
        from calibrate.io.trc import read_trc

        trial = read_trc(work / "balancing.trc")
        use = [m for m in osr["tracked"] if m in trial.labels]
        res["opensim"] = {**bench_osim.marker_scores(osr["markers"], osr["marker_names"], trial, use),
                          "ik_s": osr["ik_s"], "frames": len(osr["times"])}
        for key, with_setup in (("calibrate", False), ("calibrate_ik_setup", True)):
            cr = run_calibrate(work, with_setup, log)
            diffs = {}
            for c in COORDS:
                if c in cr["angles"] and c in osr["coords"]:
                    theirs = np.interp(cr["times"], osr["times"], osr["q"][:, osr["coords"].index(c)])
                    d = np.degrees(cr["angles"][c] - theirs)
                    diffs[c] = {"rms_deg": float(np.sqrt(np.mean(d**2))), "offset_free_deg": float(np.std(d))}
            res[key] = {k: v for k, v in cr.items() if k not in ("times", "angles")} | {"vs_opensim_ik": diffs}
        res["ik_on_subject"] = ik_on_subject(work, use, log)
        res["two_person"] = two_person(work, log)
    report(res)
    if a.json is not None:
        a.json.write_text(json.dumps(res, indent=1))
    return 0


def report(res: dict) -> None:
    """The figures as tables on stdout."""
    print(f"Pose2Sim's demo (perfanalytics/pose2sim at {res['commit']})\n")
    bench_import.report(res["import"])
    o = res["opensim"]
    print(f"\nOpenSim's Scale + IK (Pose2Sim's setups): mean per-frame marker RMS {o['rms_mm']:.2f} mm over "
          f"{o['frames']} frames of the balancing trial, IK {o['ik_s']:.2f} s")
    for key in ("calibrate", "calibrate_ik_setup"):
        c = res[key]
        trials = ", ".join(f"{k} {v:.2f}" for k, v in c["trials_rms_mm"].items())
        print(f"{key}: marker RMS {c['marker_rms_mm']:.2f} mm ({trials}), {c['wall_s']:.1f} s; implausible: "
              f"{', '.join(c['implausible']) or 'none'}")
        print("  vs OpenSim's IK (deg RMS): " + ", ".join(f"{n} {v['rms_deg']:.1f}"
                                                         for n, v in c["vs_opensim_ik"].items()))
    k = res["ik_on_subject"]
    own = res["calibrate"]["trials_rms_mm"].get("balancing", float("nan"))
    print(f"\ncalibrate's subject held fixed, the balancing trial again (Pose2Sim's IK setup; the calibration's "
          f"own fit {own:.2f} mm):")
    for key, name, t in (("calibrate_ik", "calibrate ik", "wall_s"), ("opensim_ik", "OpenSim's IK", "ik_s")):
        print(f"  {name:13s}  marker RMS {k[key]['rms_mm']:.2f} mm, max {k[key]['max_mm']:.1f} mm, {k[key][t]:.2f} s")
    print("\nThe two-person session: each participant's static with each person's part of the shared trial")
    for r in res.get("two_person", []):
        head = f"  {r['markers']:5s} static {r['static']} + trial P{r['trial_person']}: "
        if r["error"]:
            print(head + f"exit {r['rc']}: {r['error'][:150]}")
            continue
        rms = ", ".join(f"{v:.2f}" for v in r["trials_rms_mm"].values())
        flex = "; ".join(f"{', '.join(f'{c} {lo:.0f}..{hi:.0f}' for c, (lo, hi) in v.items())}"
                         for v in r["flexion_deg"].values())
        print(head + f"exit {r['rc']}, marker RMS {rms} mm (static, trial); implausible: "
              f"{len(r['implausible'])}; flexion (static; trial) {flex}")


if __name__ == "__main__":
    raise SystemExit(main())
