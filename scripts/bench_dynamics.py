"""The lab's dynamics on calibrate's subject: OpenSim's Inverse Dynamics and RRA, run from the Hamner pipeline's own
setups on the subject OpenSim's Scale + IK makes and on the one calibrate makes (issue 17 item 4: the exported
subject keeps the names a lab's ID / RRA / CMC setups read, so they run on it unchanged).

Needs a checkout of opensim-models (``--opensim-models DIR``; not in ../shared): ``Pipelines/Hamner`` carries a
runner's static and 600 running frames, FullBodyModel_Hamner2010_v2_0.osim, the Scale and IK setups, and what the
dynamics read — the ground reaction forces (subject02_running_grf.mot, External_Loads.xml: one force on each
calcaneus) and the RRA setup with its actuators and tasks (Setup_RRA.xml, 0.7 to 1.6 s, 15 Hz).

* OpenSim: Scale + IK from the pipeline's setups (as ``bench_osim``'s ``hamner`` case runs them);
* calibrate: the command line as a user runs it, ``calibrate subject02_static.trc subject02_running.trc
  FullBodyModel_Hamner2010_v2_0.osim --scale-setup Setup_Scale.xml --ik-setup Setup_IK.xml -o subject.osim``;
* on each subject with its own motion, in a child process that imports OpenSim only: the InverseDynamicsTool
  (External_Loads.xml, the RRA setup's window and cutoff, muscles excluded) and the RRATool (Setup_RRA.xml with
  its model and desired kinematics replaced, nothing else changed).

Reported: ID's residual forces and moments at the pelvis (RMS over the window: what the model and motion leave
the ground forces unexplained), each hip, knee and ankle moment's RMS difference between the two subjects, RRA's
average residuals (its own file) and RRA's position errors (RMS of how far it moved each coordinate from the
motion to make the dynamics consistent), both subjects' body masses.  The repository's reference RRA residuals
(outputReference/ResultsRRA) are printed beside.

    PYTHONPATH=. python scripts/bench_dynamics.py --opensim-models DIR [--json out.json] [--no-rra]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_osim  # noqa: E402  (the OpenSim Scale + IK run and the Hamner case's files)

DYNAMICS_FILES = ("External_Loads.xml", "subject02_running_grf.mot", "Setup_RRA.xml", "Actuators_RRA.xml",
                  "Tasks_RRA.xml")
REFERENCE_RRA = "outputReference/ResultsRRA/rra_run_1_avgResiduals.txt"
PELVIS = ("pelvis_tx_force", "pelvis_ty_force", "pelvis_tz_force", "pelvis_tilt_moment", "pelvis_list_moment",
          "pelvis_rotation_moment")
JOINTS = tuple(f"{c}_{s}" for s in ("r", "l") for c in bench_osim.COORDS)


def child(kind: str, workdir: str, model: str, motion: str, out: str) -> int:
    """In a process that imports OpenSim only: ID or RRA of `model` driven by `motion`, in `workdir` (the lab's
    files); the RRA setup's window and cutoff for both.  Writes the generalized forces (ID) or RRA's results."""
    import xml.etree.ElementTree as ET

    import opensim as osim

    osim.Logger.setLevelString("error")
    os.chdir(workdir)
    rra = ET.parse("Setup_RRA.xml").getroot().find("RRATool")
    t0, t1 = float(rra.findtext("initial_time")), float(rra.findtext("final_time"))
    cutoff = float(rra.findtext("lowpass_cutoff_frequency"))
    start = time.perf_counter()
    if kind == "id":
        subject = osim.Model(model)  # held here: the tool keeps only a reference (a temporary is freed: segfault)
        tool = osim.InverseDynamicsTool()
        tool.setModel(subject)
        tool.setCoordinatesFileName(motion)
        tool.setExternalLoadsFileName("External_Loads.xml")
        tool.setLowpassCutoffFrequency(cutoff)
        tool.setStartTime(t0)
        tool.setEndTime(t1)
        tool.setResultsDir(str(Path(out).parent))
        tool.setOutputGenForceFileName(Path(out).name)
        excluded = osim.ArrayStr()
        excluded.append("Muscles")
        tool.setExcludedForces(excluded)
    else:
        tree = ET.parse("Setup_RRA.xml")
        tool_el = tree.getroot().find("RRATool")
        tool_el.find("model_file").text = model
        tool_el.find("desired_kinematics_file").text = motion
        tool_el.find("results_directory").text = out
        tree.write("Setup_RRA_run.xml")
        tool = osim.RRATool("Setup_RRA_run.xml")
    if not tool.run():
        print(f"{kind} failed", file=sys.stderr)
        return 1
    print(json.dumps({"seconds": time.perf_counter() - start, "window": [t0, t1], "cutoff_hz": cutoff}))
    return 0


def run_child(kind: str, workdir: Path, model: Path, motion: Path, out: Path) -> dict:
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--_child", kind, str(workdir), str(model),
                           str(motion), str(out)], capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise RuntimeError(f"OpenSim {kind} child failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def read_sto(path: Path) -> tuple[list[str], np.ndarray]:
    """(columns, rows) of an OpenSim .sto / .mot (values as written)."""
    lines = path.read_text().splitlines()
    end = next(i for i, ln in enumerate(lines) if ln.strip().lower() == "endheader")
    return lines[end + 1].split(), np.array([[float(v) for v in ln.split()] for ln in lines[end + 2:] if ln.strip()])


def avg_residuals(path: Path) -> dict[str, float]:
    """RRA's average residuals file: FX .. MZ."""
    out = {}
    for line in path.read_text().splitlines():
        if "average =" in line:
            name, value = line.split("average =")
            out[name.strip()] = float(value)
    return out


def body_mass(model: Path) -> float:
    import xml.etree.ElementTree as ET

    return sum(float(b.findtext("mass") or 0.0) for b in ET.parse(model).getroot().iter("Body"))


def bench(repo: Path, work: Path, log, rra: bool = True) -> dict:
    hamner = repo / "Pipelines" / "Hamner"
    spec = bench_osim.prepare("hamner", work, repo)
    log("OpenSim Scale + IK (child process) ...")
    osr = bench_osim.run_opensim(spec, work)
    d = Path(spec["dir"])
    subjects = {"opensim": (d / "subject02_registered.osim", d / "ResultsIK" / "subject02_running_ik.mot")}
    log("calibrate, the command line ...")
    cal = work / "calibrate"
    cal.mkdir()
    t0 = time.perf_counter()
    proc = subprocess.run(["calibrate", str(hamner / "subject02_static.trc"), str(hamner / "subject02_running.trc"),
                           str(hamner / "FullBodyModel_Hamner2010_v2_0.osim"), "--scale-setup",
                           str(hamner / "Setup_Scale.xml"), "--ik-setup", str(hamner / "Setup_IK.xml"), "-o",
                           str(cal / "subject.osim"), "-q"], capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise RuntimeError(f"calibrate failed:\n{proc.stderr[-3000:]}")
    subjects["calibrate"] = (cal / "subject.osim", cal / "subject02_running_motion.mot")
    res: dict = {"calibrate_wall_s": time.perf_counter() - t0, "opensim_scale_s": osr["scale_s"],
                 "opensim_ik_s": osr["ik_s"], "subjects": {}}
    for name, (model, motion) in subjects.items():
        lab = work / f"lab_{name}"  # the lab's files, as its setups name them
        lab.mkdir()
        for f in DYNAMICS_FILES:
            shutil.copy(hamner / f, lab / f)
        log(f"{name}: inverse dynamics ...")
        run = run_child("id", lab, model, motion, lab / "id.sto")
        cols, rows = read_sto(lab / "id.sto")
        row = {"body_mass_kg": body_mass(model), "id_s": run["seconds"], "window_s": run["window"],
               "cutoff_hz": run["cutoff_hz"], "id": {"times": rows[:, 0].tolist()}}
        for c in PELVIS + tuple(f"{j}_moment" for j in JOINTS):
            if c in cols:
                row["id"][c] = rows[:, cols.index(c)].tolist()
        if rra:
            log(f"{name}: RRA (the lab's Setup_RRA.xml) ...")
            run = run_child("rra", lab, model, motion, lab / "ResultsRRA")
            row["rra_s"] = run["seconds"]
            row["rra_residuals"] = avg_residuals(next((lab / "ResultsRRA").glob("*avgResiduals.txt")))
            pcols, perr = read_sto(next((lab / "ResultsRRA").glob("*pErr.sto")))
            row["rra_position_error"] = {
                c: float(np.sqrt(np.mean(perr[:, k] ** 2)) * (1000.0 if c.endswith(("_tx", "_ty", "_tz"))
                                                                 else np.degrees(1.0)))
                for k, c in enumerate(pcols) if k and (c.startswith("pelvis") or c in JOINTS or c.startswith("lumbar"))}
        res["subjects"][name] = row
    ref = repo / "Pipelines" / "Hamner" / REFERENCE_RRA
    res["reference_rra_residuals"] = avg_residuals(ref) if ref.is_file() else None
    # the two subjects' ID on one time grid (OpenSim's grid follows the TRC's rounded times, calibrate's the rate)
    a, b = res["subjects"]["opensim"]["id"], res["subjects"]["calibrate"]["id"]
    t = np.array(b["times"])
    t = t[(t >= a["times"][0]) & (t <= a["times"][-1])]
    res["id_compared"] = {}
    for c in PELVIS + tuple(f"{j}_moment" for j in JOINTS):
        if c in a and c in b:
            x, y = np.interp(t, a["times"], a[c]), np.interp(t, b["times"], b[c])
            res["id_compared"][c] = {"opensim_rms": float(np.sqrt(np.mean(x**2))),
                                     "calibrate_rms": float(np.sqrt(np.mean(y**2))),
                                     "difference_rms": float(np.sqrt(np.mean((x - y) ** 2)))}
    return res


def report(res: dict) -> None:
    o, c = res["subjects"]["opensim"], res["subjects"]["calibrate"]
    print(f"Hamner's runner: ID and RRA from the lab's setups, {o['window_s'][0]:g} to {o['window_s'][1]:g} s, "
          f"coordinates low-passed at {o['cutoff_hz']:g} Hz; body mass {o['body_mass_kg']:.2f} kg (OpenSim's "
          f"subject) and {c['body_mass_kg']:.2f} kg (calibrate's)")
    print(f"  {'':26s} {'OpenSim':>9s} {'calibrate':>10s} {'difference':>11s}  (RMS over the window; N, N m)")
    for name, row in res["id_compared"].items():
        print(f"  {name:26s} {row['opensim_rms']:9.1f} {row['calibrate_rms']:10.1f} {row['difference_rms']:11.1f}")
    if "rra_residuals" in o:
        ref = res["reference_rra_residuals"] or {}
        print("  RRA average residuals (N, N m):    OpenSim's subject / calibrate's / the repository's reference")
        nan = float("nan")
        for k in ("FX", "FY", "FZ", "MX", "MY", "MZ"):
            print(f"    {k}  {o['rra_residuals'].get(k, nan):8.2f} {c['rra_residuals'].get(k, nan):8.2f}"
                  f" {ref.get(k, nan):8.2f}")
        print("  RRA position errors, RMS (deg; pelvis translations mm): OpenSim's subject / calibrate's")
        for k in o["rra_position_error"]:
            print(f"    {k:22s} {o['rra_position_error'][k]:7.2f} {c['rra_position_error'].get(k, nan):7.2f}")
    print(f"  times: calibrate {res['calibrate_wall_s']:.2f} s (command line); OpenSim Scale "
          f"{res['opensim_scale_s']:.2f} + IK {res['opensim_ik_s']:.2f} s; ID {o['id_s']:.2f} / {c['id_s']:.2f} s"
          + (f"; RRA {o['rra_s']:.1f} / {c['rra_s']:.1f} s" if "rra_s" in o else ""))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--opensim-models", type=Path, default=None, metavar="DIR",
                    help="a checkout of opensim-models (its Pipelines/Hamner)")
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    ap.add_argument("--no-rra", action="store_true", help="inverse dynamics only (RRA takes ~15 s per subject)")
    ap.add_argument("--_child", nargs=5, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a._child:
        return child(*a._child)
    repo = a.opensim_models
    need = [repo / "Pipelines" / "Hamner" / f for f in (*bench_osim.HAMNER_FILES, *DYNAMICS_FILES)] if repo else []
    missing = [f for f in need if not f.is_file()] if repo else ["(no --opensim-models given)"]
    if missing:
        print(f"bench_dynamics: --opensim-models {repo}: {missing[0]} not found; give a checkout of opensim-models "
              "(its Pipelines/Hamner)", file=sys.stderr)
        return 2

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory(prefix="bench_dynamics_") as tmp:
        res = bench(repo, Path(tmp), log, rra=not a.no_rra)
    report(res)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
