"""OpenSim's Scale + IK against calibrate, from the same generic OpenSim model and marker set, on the
OpenSim example pipelines in ../shared/data/real (issue 17, item 5):

* ``gait2392``: subject01_static.trc + subject01_walk1.trc, gait2392.osim with gait2392_Scale_MarkerSet.xml;
  OpenSim runs the pipeline's own subject01_Setup_Scale.xml and subject01_Setup_IK.xml;
* ``rajagopal``: static_walk_1.trc + motion_capture_walk.trc, Rajagopal2016.osim (its own markers);
  OpenSim runs scale_setup_walk_scaleOnly.xml, scale_setup_walk.xml (its static trial, absent here,
  replaced by static_walk_1.trc) and ik_setup_walk.xml;
* with ``--opensim-models DIR`` only (DIR a checkout of opensim-models; these are not in ../shared/data/real),
  two running subjects:
  ``hamner``: ``Pipelines/Hamner`` (subject02_static.trc + subject02_running.trc, 600 frames at 60 Hz,
  FullBodyModel_Hamner2010_v2_0.osim with its own markers, Setup_Scale.xml, Setup_IK.xml, and the repository's
  reference IK in outputReference/ResultsIK/subject02_running_ik.mot).  Two names adapted in the copies OpenSim
  runs: the Scale setup's generic model (``Unassigned``) is the .osim, and the IK setup's model
  (``subject01_registered.osim``) is the Scale setup's output, ``subject02_registered.osim``;
  ``rajagopal_run``: ``Pipelines/Rajagopal`` (ExpData/static_run.trc + motion_capture_run.trc, 100 Hz,
  scale_setup_run.xml and ik_setup_run.xml) with ``Models/Rajagopal/Rajagopal2016.osim`` (its own markers) as the
  ``generic_unscaled.osim`` the setups name; no reference IK.

OpenSim runs in a child process of this script (``--_opensim``) that never imports calibrate (the
opensim wheel's libcasadi clashes with casadi's).  Both are scored on the IK setup's frames and on
the markers OpenSim's IK tracks (weight > 0) that the trial has: mean over frames of the per-frame
marker RMS and of the per-frame largest marker error (mm); each hip, knee and ankle coordinate's RMS
difference from OpenSim's IK (deg; gait2392 also from the repository's reference IK); wall times
(calibrate: the whole run, load + scaling + marker placement + every frame's pose; OpenSim: Scale and
IK separately) and their ratio; where the static carries the lab's hip joint centres (Rajagopal's R_HJC /
L_HJC), each hip centre's median distance from them in the static.  calibrate runs with its default settings,
the .osim's locked coordinates locked, the coordinates the IK setup's coordinate tasks hold locked as the
command line's ``--ik-setup`` does (Gait2392's pipeline holds its subtalar and mtp angles at 0; a row without
them follows), the static cut to the time range the (first) Scale setup's scaler and marker placer use, as the
command line's ``--scale-setup`` cuts it (gait2392: 1 to 2 s, 61 of 300 frames; ``--whole-trials``: every
frame), and outlier rejection off (``--outlier-sigmas``), since OpenSim's IK keeps every marker.
Rows with the axes held, without the IK setup, with ``--moved-markers``, with ``--hip-regression`` and with the
lumbar centre held (``--hold-centres back``) follow.  A hip, knee or ankle coordinate further than 5 deg from
OpenSim's IK without its constant offset is measured once more (``attribute_shapes``, the JSON's ``attribution``):
OpenSim's own scaled subject fitted to the walk with only that segment's markers placed where the walk puts them,
against OpenSim's IK and against calibrate; and any over 5 deg with its offset has that offset set beside the
static's pose as the two read it (``attribute_offsets``: calibrate's mean angle in the static minus OpenSim's marker
placer's static pose, the Scale setup's output motion).

nimblephysics' MarkerFitter (AddBiomechanics' kinematics pass, ``scripts/peer_nimble.py``: its own venv
with numpy < 2, made on first use) is the third row, unless ``--no-nimble``: the same generic .osim with
the marker set's markers written into it (replacing those of the same name, as the ScaleTool does), the
same static trial and the same walk frames, AddBiomechanics' settings (left and right scaled together, no
height prior: the trials give no height); scored as the others on the IK frames and tracked markers, its
time the fit alone (marker clean-up and the multi-trial pipeline; the venv, imports and model loading left
out, as calibrate's imports are).

    PYTHONPATH=. python scripts/bench_osim.py [--json out.json] [--only CASE] [--no-nimble] [--opensim-models DIR]
        [--whole-trials] [--repeat N]
"""

from __future__ import annotations

import argparse
import importlib
import json
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
COORDS = ("hip_flexion", "hip_adduction", "hip_rotation", "knee_angle", "ankle_angle")
ARM_COORDS = ("arm_flex", "arm_add", "arm_rot", "elbow_flex", "pro_sup")  # beyond issue 17's list: shown, no target
LUMBAR = "back"  # the lumbar joint of Gait2392, Rajagopal2016 and Hamner2010 (pelvis to torso): its --hold-centres row
TRUNK_COORDS = ("lumbar_extension", "lumbar_bending", "lumbar_rotation")  # likewise (no side)


# ---------------------------------------------------------------------- the OpenSim child
def opensim_child(spec_path: str, out_path: str) -> int:
    """Run the pipeline's Scale and IK setups in spec['dir']; evaluate the scaled model at the IK result."""
    import os

    import opensim as osim

    osim.Logger.setLevelString("error")
    osim.Logger.removeFileSink()
    spec = json.loads(Path(spec_path).read_text())
    root = Path(spec["dir"])
    scale_s = 0.0
    for step in spec["scale"]:  # [setup file, static trc to use instead of the setup's (or None)]
        os.chdir(root / Path(step[0]).parent)
        tool = osim.ScaleTool(Path(step[0]).name)
        if step[1]:
            tool.getMarkerPlacer().setStaticPoseFileName(step[1])
            if tool.getModelScaler().getApply() and tool.getModelScaler().getMarkerFileName() not in ("", "Unassigned"):
                tool.getModelScaler().setMarkerFileName(step[1])
        t0 = time.perf_counter()
        if not tool.run():
            raise RuntimeError(f"{step[0]}: ScaleTool.run() failed")
        scale_s += time.perf_counter() - t0
    os.chdir(root / Path(spec["ik"]).parent)
    ik = osim.InverseKinematicsTool(Path(spec["ik"]).name)
    tracked = []
    tasks = ik.getIKTaskSet()
    for i in range(tasks.getSize()):
        t = tasks.get(i)
        if osim.IKMarkerTask.safeDownCast(t) is not None and t.getApply() and t.getWeight() > 0:
            tracked.append(t.getName())
    t0 = time.perf_counter()
    if not ik.run():
        raise RuntimeError("InverseKinematicsTool.run() failed")
    ik_s = time.perf_counter() - t0
    # spec["ik_ranges"] (scripts/bench_length.py): the same IK again on each [start, end] time range, timed alike.
    range_s = []
    for k, (start, end) in enumerate(spec.get("ik_ranges", [])):
        part = osim.InverseKinematicsTool(Path(spec["ik"]).name)
        part.setStartTime(float(start))
        part.setEndTime(float(end))
        part.setOutputMotionFileName(f"range_{k}.mot")
        t0 = time.perf_counter()
        if not part.run():
            raise RuntimeError(f"InverseKinematicsTool.run() failed on {start}-{end} s")
        range_s.append(time.perf_counter() - t0)
    model_file = (root / Path(spec["ik"]).parent / ik.get_model_file()).resolve()
    mot_file = (root / Path(spec["ik"]).parent / ik.getOutputMotionFileName()).resolve()
    model = osim.Model(str(model_file))
    state = model.initSystem()
    cs = model.getCoordinateSet()
    for i in range(cs.getSize()):
        cs.get(i).setLocked(state, False)
    mot = osim.TimeSeriesTable(str(mot_file))
    cols = list(mot.getColumnLabels())
    Q = mot.getMatrix().to_numpy().copy()
    for k, name in enumerate(cols):
        if cs.get(name).getMotionType() == osim.Coordinate.Rotational:
            Q[:, k] = np.radians(Q[:, k])
    ms = model.getMarkerSet()
    names = [ms.get(i).getName() for i in range(ms.getSize())]
    markers = np.zeros((Q.shape[0], len(names), 3))
    for f in range(Q.shape[0]):
        for k, name in enumerate(cols):
            cs.get(name).setValue(state, float(Q[f, k]), False)
        model.realizePosition(state)
        for m in range(len(names)):
            markers[f, m] = ms.get(m).getLocationInGround(state).to_numpy()
    np.savez(out_path, times=np.array(list(mot.getIndependentColumn())), q=Q, coords=np.array(cols),
             markers=markers, marker_names=np.array(names), tracked=np.array(tracked), scale_s=scale_s, ik_s=ik_s,
             ik_range_s=np.array(range_s))
    return 0


# ---------------------------------------------------------------------- the two pipelines
HAMNER_FILES = ("FullBodyModel_Hamner2010_v2_0.osim", "Setup_Scale.xml", "Setup_IK.xml", "subject02_static.trc",
                "subject02_running.trc")
HAMNER_REFERENCE = "outputReference/ResultsIK/subject02_running_ik.mot"


RAJAGOPAL_RUN = ("ExpData/static_run.trc", "ExpData/motion_capture_run.trc", "Scale/scale_setup_run.xml",
                 "IK/ik_setup_run.xml")
EXTRA_CASES = ("hamner", "rajagopal_run")  # from an opensim-models checkout (--opensim-models)


def extra_files(repo: Path) -> list[Path]:
    """The files of an opensim-models checkout that the EXTRA_CASES read."""
    return ([repo / "Pipelines" / "Hamner" / f for f in HAMNER_FILES]
            + [repo / "Pipelines" / "Rajagopal" / f for f in RAJAGOPAL_RUN]
            + [repo / "Models" / "Rajagopal" / "Rajagopal2016.osim"])


def prepare(case: str, work: Path, repo: Path | None = None) -> dict:
    """Copy the pipeline's files under the names its setups expect; the spec for the child and calibrate.
    `repo`: an opensim-models checkout (the EXTRA_CASES)."""
    if case == "rajagopal_run":
        src = repo / "Pipelines" / "Rajagopal"
        d = work / "rajagopal_run"
        for f in RAJAGOPAL_RUN:
            (d / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(src / f, d / f)
        osim = repo / "Models" / "Rajagopal" / "Rajagopal2016.osim"
        shutil.copy(osim, d / "generic_unscaled.osim")
        (d / "IK" / "results_run").mkdir()
        mass = float(ET.parse(src / "Scale" / "scale_setup_run.xml").getroot().findtext(".//mass"))
        return {"dir": str(d), "scale": [["Scale/scale_setup_run.xml", None]], "ik": "IK/ik_setup_run.xml",
                "osim": str(osim), "marker_set": None, "static": str(src / RAJAGOPAL_RUN[0]),
                "walk": str(src / RAJAGOPAL_RUN[1]), "mass": mass, "reference": None}
    if case == "hamner":
        hamner = repo / "Pipelines" / "Hamner"
        d = work / "hamner"
        d.mkdir()
        for f in HAMNER_FILES:
            shutil.copy(hamner / f, d / f)
        osim = hamner / HAMNER_FILES[0]
        scale = (d / "Setup_Scale.xml").read_text()
        scale = scale.replace("<model_file> Unassigned </model_file>", f"<model_file>{osim.name}</model_file>", 1)
        (d / "Setup_Scale.xml").write_text(scale)
        ik = (d / "Setup_IK.xml").read_text().replace("subject01_registered.osim", "subject02_registered.osim")
        (d / "Setup_IK.xml").write_text(ik)
        (d / "ResultsIK").mkdir()  # where the IK setup writes its motion (OpenSim does not make the folder)
        ref = hamner / HAMNER_REFERENCE
        return {"dir": str(d), "scale": [["Setup_Scale.xml", None]], "ik": "Setup_IK.xml", "osim": str(osim),
                "marker_set": None, "static": str(hamner / "subject02_static.trc"),
                "walk": str(hamner / "subject02_running.trc"), "mass": 65.9,
                "reference": str(ref) if ref.exists() else None}
    if case == "gait2392":
        src = REAL / "gait2392"
        d = work / "gait2392"
        d.mkdir()
        for f in ("gait2392_Scale_MarkerSet.xml", "subject01_static.trc", "subject01_walk1.trc",
                  "subject01_Setup_Scale.xml", "subject01_Setup_IK.xml"):
            shutil.copy(src / f, d / f)
        shutil.copy(src / "gait2392.osim", d / "gait2392_simbody.osim")
        return {"dir": str(work / "gait2392"), "scale": [["subject01_Setup_Scale.xml", None]],
                "ik": "subject01_Setup_IK.xml", "osim": str(src / "gait2392.osim"),
                "marker_set": str(src / "gait2392_Scale_MarkerSet.xml"), "static": str(src / "subject01_static.trc"),
                "walk": str(src / "subject01_walk1.trc"), "mass": 72.6,
                "reference": str(src / "subject01_walk1_ik_reference.mot")}
    src = REAL / "rajagopal_walk"
    d = work / "rajagopal"
    for sub in ("Scale", "ExpData", "IK"):
        (d / sub).mkdir(parents=True)
    shutil.copy(src / "Rajagopal2016.osim", d / "generic_unscaled.osim")
    for f in ("scale_setup_walk_scaleOnly.xml", "scale_setup_walk.xml", "markerset_walk_preScale.xml"):
        shutil.copy(src / f, d / "Scale" / f)
    for f in ("static_walk_1.trc", "motion_capture_walk.trc"):
        shutil.copy(src / f, d / "ExpData" / f)
    shutil.copy(src / "ik_setup_walk.xml", d / "IK" / "ik_setup_walk.xml")
    (d / "IK" / "results_walk").mkdir()
    return {"dir": str(d), "scale": [["Scale/scale_setup_walk_scaleOnly.xml", None],
                                      ["Scale/scale_setup_walk.xml", "../ExpData/static_walk_1.trc"]],
            "ik": "IK/ik_setup_walk.xml", "osim": str(src / "Rajagopal2016.osim"),
            "marker_set": str(src / "markerset_walk_preScale.xml"), "static": str(src / "static_walk_1.trc"),
            "walk": str(src / "motion_capture_walk.trc"), "mass": 85.0668, "reference": None}


def run_opensim(spec: dict, work: Path) -> dict:
    spec_path, out_path = work / f"{Path(spec['dir']).name}_spec.json", work / f"{Path(spec['dir']).name}_out.npz"
    spec_path.write_text(json.dumps(spec))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--_opensim", str(spec_path),
                           str(out_path)], capture_output=True, text=True, timeout=1800)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"OpenSim child failed:\n{proc.stderr[-3000:]}")
    z = np.load(out_path)
    return {"times": z["times"], "q": z["q"], "coords": [str(c) for c in z["coords"]], "markers": z["markers"],
            "marker_names": [str(c) for c in z["marker_names"]], "tracked": [str(c) for c in z["tracked"]],
            "scale_s": float(z["scale_s"]), "ik_s": float(z["ik_s"]), "child_wall_s": wall,
            "ik_range_s": [float(x) for x in z["ik_range_s"]] if "ik_range_s" in z else []}


def trc_times(path: str) -> np.ndarray:
    """The Time column of a TRC file (s)."""
    rows = [ln.split("\t") for ln in Path(path).read_text().splitlines()[5:] if ln.strip()]
    return np.array([float(r[1]) for r in rows])


def read_mot(path: str) -> tuple[np.ndarray, list[str], np.ndarray]:
    """(times, columns, values in rad/m) of an OpenSim .mot (angles in degrees when inDegrees=yes)."""
    lines = Path(path).read_text().splitlines()
    end = next(i for i, ln in enumerate(lines) if ln.strip().lower() == "endheader")
    degrees = not any(ln.strip().lower() == "indegrees=no" for ln in lines[:end])  # SIMM files: degrees
    cols = lines[end + 1].split()
    data = np.array([[float(v) for v in ln.split()] for ln in lines[end + 2:] if ln.strip()])
    vals = data[:, 1:]
    if degrees:
        rot = np.array([not c.endswith(("_tx", "_ty", "_tz")) for c in cols[1:]])
        vals = np.where(rot, np.radians(vals), vals)
    return data[:, 0], cols[1:], vals


def _plain_trc(path: str, spec_dir: str) -> Path:
    """The TRC with its header's values one tab apart (Rajagopal's files pad them with empty fields,
    which OpenSim skips), beside the pipeline's copy in the work directory."""
    lines = Path(path).read_text().splitlines(keepends=True)
    lines[2] = "\t".join(v.strip() for v in lines[2].split("\t") if v.strip()) + "\n"
    out = Path(spec_dir) / ("plain_" + Path(path).name)
    out.write_text("".join(lines))
    return out


def run_calibrate(spec: dict, frames: slice, outliers: float, hold_axes: bool = False, ik_setup: bool = True,
                  moved: bool = False, hip_regression: bool = False, hold_centres: tuple[str, ...] = ()) -> dict:
    """calibrate on static + walk (the walk cut to the IK frames) from the generic .osim; markers and angles.
    `ik_setup`: the coordinates the pipeline's IK setup holds by its coordinate tasks locked, as the command line's
    --ik-setup does (the lab's pipeline moved to calibrate).  `moved`: Settings.moved_markers (--moved-markers);
    `hip_regression`: Settings.hip_regression (--hip-regression); `hold_centres`: Settings.hold_centres
    (--hold-centres)."""
    import pinocchio as pin

    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.osim_info import with_locked
    from calibrate.model.model import load_model, write_model
    from calibrate.problem.settings import Settings

    # The OpenSim readers' modules (and scipy's, which only they need) imported outside the timing, as the
    # opensim package is outside OpenSim's: the timings compare the work, not Python's imports.
    importlib.import_module("calibrate.io.osim")
    t0 = time.perf_counter()
    model, static, walk = read_case(spec)
    walk = walk.frames(frames.start, frames.stop)
    free = ("scale", "centre", "marker") if hold_axes else ("scale", "centre", "axis", "marker")
    settings = with_setup(spec, model, with_locked(model, Settings(outliers=outliers, free=free, moved_markers=moved,
                                                                   hip_regression=hip_regression,
                                                                   hold_centres=hold_centres)), ik_setup)
    cal = calibrate(model, [static, walk], settings, mass=spec["mass"], **static_pose_of(spec, model, static, walk))
    wall = time.perf_counter() - t0
    # The part of the run OpenSim's IK does: every walk frame's pose fitted to the subject model, frame by frame
    # from scratch, the locked coordinates held (calibrate.solve.ik.inverse_kinematics, as `calibrate ik` runs it;
    # its kinematics built inside the timing).
    from calibrate.model.kinematics import build_kinematics, locked_balls
    from calibrate.problem.problem import LIMIT_MARGIN
    from calibrate.solve.ik import inverse_kinematics

    t0 = time.perf_counter()
    ik_fit = inverse_kinematics(build_kinematics(cal.model, euler=locked_balls(cal.model, cal.locked)), walk,
                                cal.params, locked=cal.locked, margin=LIMIT_MARGIN)
    ik_wall = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        subject = load_model(write_model(cal.model, Path(tmp) / "subject.urdf", cal.params))
    m = cal.motions[1]
    data = subject.pin.createData()
    mk = np.zeros((m.n_frames, len(subject.markers), 3))
    for f in range(m.n_frames):
        q = subject.pin_configuration(m.root_translation[f], m.root_quaternion[f], m.angles[f])
        pin.framesForwardKinematics(subject.pin, data, q)
        for k, name in enumerate(subject.marker_names):
            mk[f, k] = data.oMf[subject.pin.getFrameId(name, pin.FrameType.BODY)].translation
    trial = cal.trials[1]
    return {"wall_s": wall, "ik_only_s": ik_wall, "ik_only_rms_mm": 1000 * ik_fit.rms,
            "static_frames": static.n_frames, "static_seconds": [float(static.times[0]), float(static.times[-1])],
            "lab_hjc_mm": lab_hip_distances(cal, subject),
            "markers": mk, "marker_names": list(subject.marker_names), "trial": trial,
            "angles": {d: m.angles[:, i] for i, d in enumerate(m.dof_names)}, "times": cal.times,
            # the static's pose as calibrate reads it (each coordinate's mean over its frames, rad)
            "static_angles": {d: float(np.mean(cal.motions[0].angles[:, i]))
                              for i, d in enumerate(cal.motions[0].dof_names)},
            "converged": cal.converged, "approximations": [a.text() for a in model.osim.approximations],
            "locked": [f"{n} {np.degrees(v):g} deg" for n, v in settings.lock],
            # (a position: its distance from the base model's at the subject's scale, which the flag judges)
            "unreliable": [f"{c.group} {c.item} {c.change if c.group == 'axis' else c.beyond_scale:.0f} "
                           f"{'deg' if c.group == 'axis' else 'mm'}"
                           for c in cal.changes if c.unreliable],
            "static_asymmetry": [f"{cal.trials[h.trial].source or 'static'}: {h.text()}" for h in cal.static_asymmetry],
            "moved": [f"{m.marker} {1e3 * m.distance:.0f} mm" for m in cal.moved]}


def lab_hip_distances(cal, subject) -> dict[str, float]:
    """Per hip whose joint-centre marker the static carries (Rajagopal's R_HJC / L_HJC, the lab's hip joint
    centres): the median over the static's frames of its distance (mm) from our hip centre, the subject URDF
    posed by Pinocchio at the static's calibrated coordinates."""
    import pinocchio as pin

    static, m = cal.trials[0], cal.motions[0]
    data = subject.pin.createData()
    out = {}
    for side in ("r", "l"):
        label = f"{side.upper()}_HJC"
        joint = next((j for j in cal.model.joints if j.name == f"hip_{side}"), None)
        if label not in static.labels or joint is None:
            continue
        jid = subject.pin.getJointId(joint.urdf_joints[0])
        seen = static.markers[:, static.labels.index(label)]
        d = []
        for f in range(m.n_frames):
            if np.all(np.isfinite(seen[f])):
                q = subject.pin_configuration(m.root_translation[f], m.root_quaternion[f], m.angles[f])
                pin.forwardKinematics(subject.pin, data, q)
                d.append(np.linalg.norm(data.oMi[jid].translation - seen[f]))
        if d:
            out[f"hip_{side}"] = 1000 * float(np.median(d))
    return out


def with_setup(spec: dict, model, settings, ik_setup: bool):
    """`settings` with the coordinates the pipeline's IK setup holds locked (calibrate.io.osim_setup), if `ik_setup`."""
    from calibrate.io.osim_setup import with_ik_setup

    return with_ik_setup(model, settings, Path(spec["dir"]) / spec["ik"]) if ik_setup else settings


def static_pose_of(spec: dict, model, static, walk) -> dict:
    """calibrate's `neutral` and `pose` from the pipeline's Scale setups, as the command line's --scale-setup takes
    them (calibrate.io.osim_setup.setup_pose: the static pose its MarkerPlacer's coordinate tasks hold); {} where
    they hold none."""
    from calibrate.io.osim_setup import setup_pose

    for step in spec["scale"]:
        k, pose, _ = setup_pose(Path(spec["dir"]) / step[0], model, [static, walk],
                                [Path(spec["static"]).name, Path(spec["walk"]).name])
        if pose is not None:
            return {"neutral": k, "pose": pose}
    return {}


def read_case(spec: dict):
    """The case's generic model (with its marker set) and its static and walking trials, as calibrate reads them:
    the static cut to the time range the pipeline's (first) Scale setup uses, as the command line's --scale-setup
    cuts it, unless spec["whole_trials"] (--whole-trials)."""
    from calibrate.io.osim_setup import apply_time_ranges, scale_setup
    from calibrate.io.read import read_trial
    from calibrate.model.model import load_model

    static = read_trial(_plain_trc(spec["static"], spec["dir"]))
    if not spec.get("whole_trials"):
        ranges = scale_setup(Path(spec["dir"]) / spec["scale"][0][0]).ranges
        (static,), _ = apply_time_ranges([static], ranges, names=[spec["static"]])
    return load_model(spec["osim"], spec["marker_set"]), static, read_trial(_plain_trc(spec["walk"], spec["dir"]))


def run_heldout(spec: dict, frames: slice, outliers: float, still_weight: float, ik_setup: bool = True,
                moved: bool = False) -> dict:
    """calibrate on the static and the first half of the IK frames, then the subject fixed and the second half's
    poses fitted frame by frame (calibrate.solve.ik): the markers it predicts there, for the held-out row."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.osim_info import with_locked
    from calibrate.model.kinematics import build_kinematics, locked_balls
    from calibrate.problem.problem import LIMIT_MARGIN
    from calibrate.problem.settings import Settings
    from calibrate.solve.ik import inverse_kinematics, marker_columns

    model, static, walk = read_case(spec)
    half = (frames.start + frames.stop) // 2
    first, second = walk.frames(frames.start, half), walk.frames(half, frames.stop)
    settings = with_setup(spec, model, with_locked(model, Settings(outliers=outliers, still_weight=still_weight,
                                                                   moved_markers=moved)), ik_setup)
    cal = calibrate(model, [static, first], settings, mass=spec["mass"], **static_pose_of(spec, model, static, first))
    fit = inverse_kinematics(build_kinematics(cal.model, euler=locked_balls(cal.model, cal.locked)), second,
                             cal.params, locked=cal.locked, margin=LIMIT_MARGIN)  # as `calibrate ik` fits
    return {"markers": marker_columns(cal.model, second) + fit.residuals, "marker_names": list(cal.model.marker_names),
            "in_sample_rms_mm": 1000 * float(np.sqrt(np.nanmean(np.sum(cal.residuals[cal.trials[0].n_frames:] ** 2,
                                                                       axis=2)))),
            "second_half_from": half - frames.start}


HELDOUT_STILL_WEIGHT = 16.0  # the held-out row's second calibrate: the static counted as this many frames


def run_static_only(spec: dict, frames: slice, outliers: float) -> dict:
    """OpenSim's order of work: calibrate on the static alone (the Scale setup's pose, the IK setup's held
    coordinates), then the walk's IK frames fitted with the subject fixed as `calibrate ik --ik-setup --report` fits
    them (the setup's marker weights, Calibration.locked_elsewhere, the calibration's limits); the markers it predicts
    and the time of both steps, in this process."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.labels import map_labels
    from calibrate.io.osim_info import with_locked
    from calibrate.io.osim_setup import ik_setup_weights
    from calibrate.model.kinematics import build_kinematics, locked_balls
    from calibrate.problem.problem import LIMIT_MARGIN
    from calibrate.problem.settings import Settings
    from calibrate.solve.ik import inverse_kinematics, marker_columns

    model, static, walk = read_case(spec)
    walk = walk.frames(frames.start, frames.stop)
    settings = with_setup(spec, model, with_locked(model, Settings(outliers=outliers)), True)
    t0 = time.perf_counter()
    cal = calibrate(model, [static], settings, mass=spec["mass"], **static_pose_of(spec, model, static, walk))
    t1 = time.perf_counter()
    held = cal.locked_elsewhere
    trial, _ = map_labels(walk, cal.model.marker_names, None, aliases=True)
    fit = inverse_kinematics(build_kinematics(cal.model, euler=locked_balls(cal.model, held)), trial, cal.params,
                             locked=held, weights=ik_setup_weights(Path(spec["dir"]) / spec["ik"]), default_weight=0.0,
                             margin=LIMIT_MARGIN)
    t2 = time.perf_counter()
    return {"markers": marker_columns(cal.model, trial) + fit.residuals, "marker_names": list(cal.model.marker_names),
            "calibrate_s": t1 - t0, "ik_s": t2 - t1, "released": sorted(set(cal.locked) - set(held))}


#: issue 17's angle target (deg RMS from OpenSim's IK): a hip, knee or ankle coordinate further than this from it
#: without its constant offset is measured against OpenSim's own model with its segment's markers re-placed
#: (attribute_shapes), and one further than this with its offset has the offset set beside the static's pose
#: (attribute_offsets).
ANGLE_TARGET_DEG = 5.0


def _segment_markers(model, joint_child: str, shown: set[str]) -> tuple[str, list[str]]:
    """The markers of `shown` (the walk's labels) on the segment a coordinate turns (its joint's child), or on the
    first segments below it that carry any (an ankle's talus: none the walk shows, its foot's), and the name of
    that segment."""
    children: dict[str, list[str]] = {}
    for j in model.joints:
        children.setdefault(j.parent, []).append(j.child)
    level = [joint_child]
    while level:
        names = [m.name for m in model.markers if m.segment in level and m.name in shown]
        if names:
            return ", ".join(level), names
        level = [c for s in level for c in children.get(s, [])]
    return joint_child, []


def placer_pose(spec: dict) -> dict[str, float]:
    """The static pose OpenSim's marker placer solved (coordinate -> rad): the last Scale step's MarkerPlacer
    <output_motion_file>, which OpenSim writes beside that setup; {} where the setups write none."""
    for step in reversed(spec["scale"]):
        setup = Path(spec["dir"]) / step[0]
        placer = ET.parse(setup).getroot().find(".//MarkerPlacer")
        name = (placer.findtext("output_motion_file") or "").strip() if placer is not None else ""
        mot = setup.parent / name
        if name and name != "Unassigned" and mot.exists():
            _, cols, vals = read_mot(str(mot))
            return {c.split("/")[-2] if c.endswith("/value") else c: float(np.mean(vals[:, k]))
                    for k, c in enumerate(cols)}
    return {}


def attribute_offsets(spec: dict, static_angles: dict[str, float], diffs: dict[str, dict]) -> dict:
    """Each hip, knee and ankle coordinate further than ANGLE_TARGET_DEG from OpenSim's IK (RMS, with its offset):
    its mean offset over the walk beside the two tools' reading of the static pose (calibrate's mean angle there
    minus OpenSim's marker placer's, deg).  Where the two agree, the walk's offset is the static's: both read the
    walk's motion from the static alike and differ on how the subject stood."""
    pose = placer_pose(spec)
    out = {}
    for name, d in diffs.items():
        if name.rsplit("_", 1)[0] not in COORDS or d["vs_opensim_ik_deg"] <= ANGLE_TARGET_DEG:
            continue
        if name in pose and name in static_angles:
            out[name] = {"walk_offset_deg": d["offset_deg"],
                         "static_calibrate_deg": float(np.degrees(static_angles[name])),
                         "static_opensim_placer_deg": float(np.degrees(pose[name])),
                         "static_difference_deg": float(np.degrees(static_angles[name] - pose[name]))}
    return out


def attribute_shapes(spec: dict, frames: slice, osr: dict, angles: dict[str, np.ndarray],
                     coords: list[str]) -> dict:
    """Where calibrate's coordinate differs from OpenSim's IK by more than ANGLE_TARGET_DEG without its constant
    offset, how much of that comes from where the two place the markers of the segment it turns.  OpenSim's own
    subject (its Scale tool's output, the model its IK ran on) is fitted to the walk by calibrate's IK with the IK
    setup's marker weights and held coordinates (`opensim_reproduced`: the coordinate's RMS from OpenSim's IK,
    the same model and weights); then its markers, and nothing else, are placed where the walk puts them
    (calibrate with only the markers free, the walk alone, the same weights, nothing rejected), and for each
    coordinate only the markers of its segment are moved there and the walk fitted again.  `calibrate_vs_replaced`:
    calibrate's coordinate against that fit (RMS, and without its mean offset: deg); `opensim_vs_replaced`:
    OpenSim's IK against it, what moving those markers alone does on OpenSim's own model."""
    from dataclasses import replace

    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.osim_info import with_locked
    from calibrate.io.osim_setup import ik_setup_weights
    from calibrate.io.read import read_trial
    from calibrate.model.kinematics import build_kinematics, locked_balls
    from calibrate.model.model import load_model
    from calibrate.problem.settings import Settings
    from calibrate.solve.ik import inverse_kinematics

    if not coords:
        return {}
    ik_xml = Path(spec["dir"]) / spec["ik"]
    scaled = (ik_xml.parent / ET.parse(ik_xml).getroot().findtext(".//model_file").strip()).resolve()
    model = load_model(str(scaled))
    walk = read_trial(_plain_trc(spec["walk"], spec["dir"])).frames(frames.start, frames.stop)
    weights = ik_setup_weights(ik_xml)
    noise = Settings().noise
    settings = with_setup(spec, model, with_locked(model, Settings(
        free=("marker",), outliers=0.0, learn_noise=False, hip_regression=False, segment_frames=None,
        marker_noise=tuple((n, noise / np.sqrt(w)) for n, w in weights.items() if w > 0 and n in model.marker_names))),
        True)
    locked = dict(settings.lock)
    kin = build_kinematics(model, euler=locked_balls(model, tuple(settings.lock)))
    base = model.parameters()
    placed = calibrate(model, [walk], settings).params
    names = list(model.marker_names)
    osim_q = {c: np.degrees(osr["q"][:, osr["coords"].index(c)]) for c in coords}

    def fitted(params) -> dict[str, np.ndarray]:
        motion = inverse_kinematics(kin, walk, params, locked=locked, weights=weights).motion
        return {d: np.degrees(motion.angles[:, i]) for i, d in enumerate(motion.dof_names)}

    def rms(d: np.ndarray) -> list[float]:
        return [float(np.sqrt(np.mean(d ** 2))), float(np.std(d))]

    own = fitted(base)
    out = {}
    for c in coords:
        joint = next(j for j in model.joints if c in j.dofs)
        segment, moved = _segment_markers(model, joint.child, set(walk.labels))
        on = [m.name for m in model.markers if m.segment in segment.split(", ")]
        marker = base.marker.copy()
        for n in moved:
            marker[names.index(n)] = placed.marker[names.index(n)]
        again = fitted(replace(base, marker=marker))[c]
        out[c] = {"model": str(scaled.name), "segment": segment, "markers_replaced": moved,
                  "markers_kept": [n for n in on if n not in moved],
                  "opensim_reproduced_deg": rms(own[c] - osim_q[c])[0],
                  "calibrate_vs_opensim_deg": rms(np.degrees(angles[c]) - osim_q[c]),
                  "calibrate_vs_replaced_deg": rms(np.degrees(angles[c]) - again),
                  "opensim_vs_replaced_deg": rms(osim_q[c] - again),
                  "replaced_shift_mm": {n: float(1000 * np.linalg.norm(placed.marker[names.index(n)]
                                                                       - base.marker[names.index(n)]))
                                        for n in moved}}
    return out


def osim_with_markers(spec: dict, out: Path) -> Path:
    """The generic .osim with the marker set file's markers in its MarkerSet (replacing those of the same
    name, as OpenSim's ScaleTool does), each in OpenSim 4's form (socket_parent_frame): the model nimble reads."""

    tree = ET.parse(spec["osim"])
    model = tree.getroot().find("Model")
    ms = model.find("MarkerSet")
    if ms is None:
        ms = ET.SubElement(model, "MarkerSet", name="markerset")
    objects = ms.find("objects")
    if objects is None:
        objects = ET.SubElement(ms, "objects")
    if spec.get("marker_set"):
        for mk in ET.parse(spec["marker_set"]).getroot().iter("Marker"):
            name = mk.get("name", "")
            for old in [o for o in objects.findall("Marker") if o.get("name") == name]:
                objects.remove(old)
            body = (mk.findtext("body") or "").strip()
            frame = (mk.findtext("socket_parent_frame") or "").strip() or ("/ground" if body == "ground"
                                                                           else f"/bodyset/{body}")
            el = ET.SubElement(objects, "Marker", name=name)
            ET.SubElement(el, "socket_parent_frame").text = frame
            ET.SubElement(el, "location").text = " ".join((mk.findtext("location") or "0 0 0").split())
            ET.SubElement(el, "fixed").text = (mk.findtext("fixed") or "false").strip()
    tree.write(out, encoding="UTF-8", xml_declaration=True)
    return out


def nimble_reading(mod, osim: Path, poses: int = 20) -> dict:
    """How nimble reads `osim`: its marker positions against calibrate's kinematics of the same file (equal to
    OpenSim's where the import is exact: tests/test_osim_import.py) at random poses within the coordinates' ranges;
    the largest difference on the markers above every approximated joint, and on all markers (below an
    approximated joint: within the import's reported bound)."""
    from scipy.spatial.transform import Rotation

    from calibrate.io.motion import Motion
    from calibrate.io.osim_export import mot_columns
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model

    model = load_model(osim)
    rng = np.random.default_rng(0)
    lo = np.array([d.lower if np.isfinite(d.lower) else -np.pi for d in model.dofs])
    hi = np.array([d.upper if np.isfinite(d.upper) else np.pi for d in model.dofs])
    angles = lo + (hi - lo) * rng.uniform(0.1, 0.9, (poses, len(model.dofs)))
    quat, root = Rotation.random(poses, random_state=0).as_quat(), rng.uniform(-1, 1, (poses, 3))
    ours, _ = build_kinematics(model).batch(np.hstack([np.zeros((poses, 6)), angles]), quat, model.parameters())
    cols, values = mot_columns(model, Motion(np.arange(poses, dtype=float), root, quat, angles, model.dof_names))
    try:
        ans = mod.nimble_fk(osim, {c: values[:, i] for i, c in enumerate(cols) if c != "time"})
    except RuntimeError as e:
        return {"error": str(e)}
    approximated = {c for a in model.osim.approximations for c in a.coordinates}
    below: set[str] = set()
    for j in model.joints:  # parents before children
        if j.parent in below or approximated & set(j.dofs):
            below.add(j.child)
    names = list(ans["marker_names"])
    err = np.linalg.norm(ans["markers_world"] - (ours + root[:, None, :])[:, [model.marker_index(m) for m in names]],
                         axis=2).max(axis=0)
    exact = np.array([model.markers[model.marker_index(m)].segment not in below for m in names])
    return {"exact_max_mm": 1000 * float(err[exact].max(initial=0.0)), "exact_markers": int(exact.sum()),
            "all_max_mm": 1000 * float(err.max()), "worst_marker": names[int(np.argmax(err))],
            "below_approximated": sorted(below)}


def run_nimble_row(spec: dict, frames: slice, work: Path, trial, use: list[str], osr: dict) -> dict:
    """nimblephysics' MarkerFitter on the generic .osim (with the marker set), the static trial and the walk's IK
    frames, scored as the other rows; {"status": "not run: ..."} when it cannot run."""
    from calibrate.io.read import read_trial
    from calibrate.io.trc import write_trc
    from calibrate.io.trial import Trial

    try:
        import peer_nimble as mod  # beside this script (scripts/ is on the path when it runs)
    except Exception as e:  # a broken helper must not stop the benchmark
        return {"status": f"not run: cannot load scripts/peer_nimble.py ({type(e).__name__}: {e})"}
    d = Path(spec["dir"])
    osim = osim_with_markers(spec, d / "generic_with_markers_nimble.osim")
    walk = read_trial(_plain_trc(spec["walk"], spec["dir"]))
    walk_trc = d / "walk_ik_frames.trc"
    write_trc(walk_trc, Trial(walk.labels, walk.markers[frames], walk.rate, walk.first_frame + frames.start,
                              walk.source))
    res = mod.run_nimble(osim, [_plain_trc(spec["static"], spec["dir"]), walk_trc], mass_kg=float(spec["mass"]),
                         height_m=0.0, work_dir=d / "nimble", settings={"symmetric": True, "marker_positions": True})
    if res.get("error"):
        return {"status": f"not run: {res['error']}"}
    tr = res["trials"][1]
    if tr.get("error"):
        return {"status": f"not run: the walk trial: {tr['error']}"}
    pred, names = np.asarray(tr["markers_world"]), list(tr["marker_names"])
    if pred.shape[0] != trial.n_frames:
        return {"status": f"not run: nimble returned {pred.shape[0]} walk frames, expected {trial.n_frames}"}
    scored = [m for m in use if m in names]
    row = marker_scores(pred, names, trial, scored)
    row.update(status="ran", time_s=float(res["time_s"]), total_s=float(res["total_s"]),
               ratio_to_opensim_ik=float(res["time_s"]) / osr["ik_s"],
               markers_used=sum(m in trial.labels for m in names), notes=list(res.get("notes", [])))
    coords = {}
    for side in ("r", "l"):
        for c in COORDS:
            name = f"{c}_{side}"
            if name in tr["angles"] and name in osr["coords"]:
                diff = np.degrees(np.asarray(tr["angles"][name]) - osr["q"][:, osr["coords"].index(name)])
                rms, offset, spread = np.sqrt(np.mean(diff**2)), np.mean(diff), np.std(diff)
                coords[name] = {"vs_opensim_ik_deg": float(rms), "offset_deg": float(offset),
                                "vs_opensim_ik_offset_free_deg": float(spread)}
    row["coordinates"] = coords
    row["reading"] = nimble_reading(mod, osim)
    return row


def marker_scores(pred: np.ndarray, names: list[str], trial, use: list[str]) -> dict:
    """Mean per-frame RMS and mean per-frame max error (mm) over markers `use` seen in the frame."""
    idx_p = [names.index(u) for u in use]
    idx_t = [trial.labels.index(u) for u in use]
    err = np.linalg.norm(pred[:, idx_p] - trial.markers[:, idx_t], axis=2)
    rms = np.sqrt(np.nanmean(err**2, axis=1))
    return {"rms_mm": 1000 * float(np.nanmean(rms)), "max_mm": 1000 * float(np.nanmean(np.nanmax(err, axis=1))),
            "markers": len(use)}


def bench(case: str, work: Path, log, outliers: float, nimble: bool = True, repo: Path | None = None,
          whole_trials: bool = False, repeat: int = 1) -> dict:
    spec = {**prepare(case, work, repo), "whole_trials": whole_trials}
    log(f"{case}: OpenSim Scale + IK (child process) ...")
    osr = run_opensim(spec, work)
    t_walk = trc_times(spec["walk"])
    first = int(np.argmin(np.abs(t_walk - osr["times"][0])))
    frames = slice(first, first + len(osr["times"]))
    if not np.allclose(t_walk[frames], osr["times"], atol=1e-6):
        raise RuntimeError(f"{case}: the IK frames are not consecutive trial frames")
    # Warm-up, untimed: a calibration on 30 walk frames compiles the model's per-frame C code where this machine
    # has none for its structure (once per machine and structure, kept on disk; bench_real warms up likewise), so
    # that the timed run is the work alone, as OpenSim's is.
    log(f"{case}: warm-up (compiles the model's C code once per machine) ...")
    run_calibrate(spec, slice(frames.start, frames.start + 30), outliers)
    log(f"{case}: calibrate on the static + walk trials ({len(osr['times'])} IK frames) ...")
    cr = run_calibrate(spec, frames, outliers)
    # `repeat`: OpenSim's Scale + IK and calibrate timed again, one after the other, so that both meet the same phases
    # of the machine; the medians are the figures (this machine's run-to-run spread is 15-25 %).
    ik_runs, cal_runs = [osr["ik_s"]], [cr["wall_s"]]
    for k in range(1, repeat):
        log(f"{case}: timing run {k + 1} of {repeat} (OpenSim Scale + IK, then calibrate) ...")
        ik_runs.append(run_opensim(spec, work)["ik_s"])
        cal_runs.append(run_calibrate(spec, frames, outliers)["wall_s"])
    osr["ik_s"], cr["wall_s"] = float(np.median(ik_runs)), float(np.median(cal_runs))
    log(f"{case}: calibrate again, every axis held at the model's (OpenSim's angle definitions) ...")
    ch = run_calibrate(spec, frames, outliers, hold_axes=True)
    log(f"{case}: calibrate again, without the IK setup's held coordinates ...")
    cn = run_calibrate(spec, frames, outliers, ik_setup=False)
    log(f"{case}: held-out: calibrate on the static + the first half of the IK frames, the second half fitted ...")
    log(f"{case}: calibrate again, markers the static shows elsewhere left out there (--moved-markers) ...")
    cm = run_calibrate(spec, frames, outliers, moved=True)
    log(f"{case}: calibrate again, the hips by Harrington's regression (--hip-regression) ...")
    cg = run_calibrate(spec, frames, outliers, hip_regression=True)
    log(f"{case}: calibrate again, the lumbar centre held (--hold-centres {LUMBAR}) ...")
    cb = run_calibrate(spec, frames, outliers, hold_centres=(LUMBAR,))
    log(f"{case}: OpenSim's order: calibrate on the static alone, then the walk's IK frames with the subject fixed ...")
    so = run_static_only(spec, frames, outliers)
    held = {"calibrate": run_heldout(spec, frames, outliers, 0.0),
            f"calibrate_still_weight_{HELDOUT_STILL_WEIGHT:g}":
                run_heldout(spec, frames, outliers, HELDOUT_STILL_WEIGHT),
            "calibrate_moved_markers": run_heldout(spec, frames, outliers, 0.0, moved=True)}
    trial = cr["trial"]
    use = [m for m in osr["tracked"] if m in trial.labels and m in cr["marker_names"] and m in osr["marker_names"]]
    missing = [m for m in osr["tracked"] if m in trial.labels and m not in cr["marker_names"]]
    out = {"case": case, "frames": len(osr["times"]), "markers_tracked_by_opensim": osr["tracked"],
           "markers_scored": use, "opensim_tracked_markers_calibrate_lacks": missing,
           "approximations": cr["approximations"], "calibrate_converged": cr["converged"],
           "static_frames": cr["static_frames"], "static_seconds": cr["static_seconds"]}
    out["opensim"] = marker_scores(osr["markers"], osr["marker_names"], trial, use)
    out["calibrate"] = marker_scores(cr["markers"], cr["marker_names"], trial, use)
    out["calibrate"]["markers_used"] = sum(m in trial.labels for m in cr["marker_names"])
    out["calibrate_axes_held"] = marker_scores(ch["markers"], ch["marker_names"], trial, use)
    out["calibrate_axes_held"].update(wall_s=ch["wall_s"], converged=ch["converged"])
    out["calibrate_moved_markers"] = marker_scores(cm["markers"], cm["marker_names"], trial, use)
    out["calibrate_moved_markers"].update(wall_s=cm["wall_s"], converged=cm["converged"], moved=cm["moved"],
                                          unreliable=cm["unreliable"], static_asymmetry=cm["static_asymmetry"])
    out["calibrate_hip_regression"] = marker_scores(cg["markers"], cg["marker_names"], trial, use)
    out["calibrate_hip_regression"].update(wall_s=cg["wall_s"], converged=cg["converged"], lab_hjc_mm=cg["lab_hjc_mm"],
                                           unreliable=cg["unreliable"])
    out["calibrate_lumbar_held"] = marker_scores(cb["markers"], cb["marker_names"], trial, use)
    out["calibrate_lumbar_held"].update(wall_s=cb["wall_s"], converged=cb["converged"], unreliable=cb["unreliable"])
    out["calibrate_locked"] = cr["locked"]  # the model's locked coordinates and those the IK setup holds
    out["calibrate_no_ik_setup"] = marker_scores(cn["markers"], cn["marker_names"], trial, use)
    out["calibrate_no_ik_setup"].update(wall_s=cn["wall_s"], converged=cn["converged"], locked=cn["locked"],
                                        unreliable=cn["unreliable"], static_asymmetry=cn["static_asymmetry"])
    out["opensim"].update(scale_s=osr["scale_s"], ik_s=osr["ik_s"], total_s=osr["scale_s"] + osr["ik_s"])
    out["calibrate"].update(wall_s=cr["wall_s"], stages_s=cr["times"], lab_hjc_mm=cr["lab_hjc_mm"],
                            wall_s_runs=cal_runs)
    out["opensim"]["ik_s_runs"] = ik_runs
    out["calibrate_moved_markers"]["lab_hjc_mm"] = cm["lab_hjc_mm"]
    out["ratio_calibrate_to_opensim_ik"] = cr["wall_s"] / osr["ik_s"]
    out["calibrate_static_only"] = marker_scores(so["markers"], so["marker_names"], trial, use)
    out["calibrate_static_only"].update(calibrate_s=so["calibrate_s"], ik_s=so["ik_s"], released=so["released"],
                                        ratio_to_opensim_ik=(so["calibrate_s"] + so["ik_s"]) / osr["ik_s"])
    out["calibrate_ik_only"] = {"wall_s": cr["ik_only_s"], "rms_mm_all_markers": cr["ik_only_rms_mm"],
                                "ratio_to_opensim_ik": cr["ik_only_s"] / osr["ik_s"]}
    diffs: dict[str, dict[str, float]] = {}
    ref = read_mot(spec["reference"]) if spec["reference"] else None
    for label, run in (("coordinates", cr), ("coordinates_axes_held", ch), ("coordinates_no_ik_setup", cn),
                       ("coordinates_moved_markers", cm), ("coordinates_hip_regression", cg),
                       ("coordinates_lumbar_held", cb)):
        diffs = {}
        for side in ("r", "l", ""):
            for c in (TRUNK_COORDS if not side else COORDS + ARM_COORDS):
                name = f"{c}_{side}" if side else c
                if name not in run["angles"] or name not in osr["coords"]:
                    continue
                ours = np.degrees(run["angles"][name])
                d = ours - np.degrees(osr["q"][:, osr["coords"].index(name)])
                row = {"vs_opensim_ik_deg": float(np.sqrt(np.mean(d**2))),
                       "vs_opensim_ik_offset_free_deg": float(np.std(d)), "offset_deg": float(np.mean(d))}
                if ref is not None and name in ref[1]:
                    r = np.interp(osr["times"], ref[0], np.degrees(ref[2][:, ref[1].index(name)]))
                    row["vs_reference_ik_deg"] = float(np.sqrt(np.mean((ours - r) ** 2)))
                diffs[name] = row
        out[label] = diffs
    # A hip, knee or ankle coordinate beyond issue 17's target without its offset: where that comes from.
    over = [n for n, d in out["coordinates"].items() if n.rsplit("_", 1)[0] in COORDS
            and d["vs_opensim_ik_offset_free_deg"] > ANGLE_TARGET_DEG]
    if over:
        log(f"{case}: {', '.join(over)} beyond {ANGLE_TARGET_DEG:g} deg without the offset: OpenSim's own subject "
            "with that segment's markers placed by the walk ...")
    out["attribution"] = attribute_shapes(spec, frames, osr, cr["angles"], over)
    out["offsets"] = attribute_offsets(spec, cr["static_angles"], out["coordinates"])
    if nimble:
        log(f"{case}: nimblephysics' MarkerFitter (its own venv; minutes) ...")
        out["nimble"] = run_nimble_row(spec, frames, work, trial, use, osr)
    else:
        out["nimble"] = {"status": "not run: --no-nimble"}
    # Held out: the second half of the IK frames, which neither OpenSim's scaling (the static) nor calibrate's
    # (the static + the first half) saw; OpenSim's IK and calibrate's frame-by-frame fit with the subject fixed.
    k = held["calibrate"]["second_half_from"]
    second = trial.frames(k, trial.n_frames)
    out["heldout"] = {"frames": second.n_frames, "opensim": marker_scores(osr["markers"][k:], osr["marker_names"],
                                                                           second, use)}
    for key, h in held.items():
        row = marker_scores(h["markers"], h["marker_names"], second, use)
        row["in_sample_rms_mm_all_markers"] = h["in_sample_rms_mm"]
        out["heldout"][key] = row
    out["static_asymmetry"] = cr["static_asymmetry"]
    # Axes, centres and markers the trial did not identify that ended beyond 3 prior SDs from where their priors
    # put them (the report's `unreliable`)
    out["calibrate_unreliable"] = cr["unreliable"]
    return out


def report(res: dict) -> None:
    for r in res["results"]:
        o, c = r["opensim"], r["calibrate"]
        t0, t1 = r["static_seconds"]
        print(f"\n== {r['case']}: {r['frames']} IK frames (walk or run), static {r['static_frames']} frames "
              f"({t0:g} to {t1:g} s), {len(r['markers_scored'])} markers scored "
              f"(OpenSim's IK tracks {len(r['markers_tracked_by_opensim'])}; calibrate uses {c['markers_used']})")
        print(f"  {'':22s} {'RMS mm':>8s} {'max mm':>8s} {'time s':>10s}")
        print(f"  {'OpenSim Scale + IK':22s} {o['rms_mm']:8.2f} {o['max_mm']:8.2f} {o['total_s']:10.2f} "
              f"(scale {o['scale_s']:.2f}, IK {o['ik_s']:.2f})")
        print(f"  {'calibrate':22s} {c['rms_mm']:8.2f} {c['max_mm']:8.2f} {c['wall_s']:10.2f} "
              f"(/ OpenSim IK: {r['ratio_calibrate_to_opensim_ik']:.2f})")
        runs = c.get("wall_s_runs") or []
        if len(runs) > 1:
            ratios = [a / b for a, b in zip(runs, o["ik_s_runs"], strict=True)]
            print(f"  {'':22s} times: medians of {len(runs)} runs each; calibrate {min(runs):.2f}-{max(runs):.2f} s, "
                  f"OpenSim IK {min(o['ik_s_runs']):.2f}-{max(o['ik_s_runs']):.2f} s, run by run "
                  f"{min(ratios):.2f}-{max(ratios):.2f}x")
        h = r["calibrate_axes_held"]
        print(f"  {'calibrate, axes held':22s} {h['rms_mm']:8.2f} {h['max_mm']:8.2f} {h['wall_s']:10.2f}")
        n = r.get("calibrate_no_ik_setup")
        if n:
            print(f"  {'calibrate, no IK setup':22s} {n['rms_mm']:8.2f} {n['max_mm']:8.2f} {n['wall_s']:10.2f} "
                  f"(the IK setup's coordinate tasks not held; locked: {', '.join(n['locked']) or 'none'})")
        mm = r.get("calibrate_moved_markers")
        if mm:
            print(f"  {'calibrate, moved markers':22s} {mm['rms_mm']:8.2f} {mm['max_mm']:8.2f} {mm['wall_s']:10.2f} "
                  f"(--moved-markers; the static's positions of {', '.join(mm['moved']) or 'none'} left out)")
        hr = r.get("calibrate_hip_regression")
        if hr:
            print(f"  {'calibrate, hip regr.':22s} {hr['rms_mm']:8.2f} {hr['max_mm']:8.2f} {hr['wall_s']:10.2f} "
                  f"(--hip-regression; unreliable: {', '.join(hr['unreliable']) or 'none'})")
        lb = r.get("calibrate_lumbar_held")
        if lb:
            print(f"  {'calibrate, lumbar held':22s} {lb['rms_mm']:8.2f} {lb['max_mm']:8.2f} {lb['wall_s']:10.2f} "
                  f"(--hold-centres {LUMBAR}; unreliable: {', '.join(lb['unreliable']) or 'none'})")
        locks = ", ".join(r.get("calibrate_locked", [])) or "none"
        print(f"  calibrate locks: {locks} (the model's locked coordinates and those the IK setup's coordinate tasks "
              "hold)")
        nb = r.get("nimble", {})
        if nb.get("status") == "ran":
            print(f"  {'nimble MarkerFitter':22s} {nb['rms_mm']:8.2f} {nb['max_mm']:8.2f} {nb['time_s']:10.2f} "
                  f"(/ OpenSim IK: {nb['ratio_to_opensim_ik']:.2f}; AddBiomechanics' kinematics pass, the fit alone; "
                  f"{nb['markers']} of the markers scored)")
        elif nb:
            print(f"  {'nimble MarkerFitter':22s} {nb['status']}")
        so = r.get("calibrate_static_only")
        if so:
            print(f"  {'calibrate, static only':22s} {so['rms_mm']:8.2f} {so['max_mm']:8.2f} "
                  f"{so['calibrate_s'] + so['ik_s']:10.2f} (/ OpenSim IK: {so['ratio_to_opensim_ik']:.2f}; OpenSim's "
                  f"order: calibrated on the static alone in {so['calibrate_s']:.2f} s, then the walk fitted with the "
                  f"subject fixed as calibrate ik --ik-setup fits it, {so['ik_s']:.2f} s"
                  + (f"; the static's auto-locks {', '.join(so['released'])} not held there)" if so["released"]
                     else ")"))
        k = r.get("calibrate_ik_only")
        if k:
            print(f"  {'calibrate, IK only':22s} {k['rms_mm_all_markers']:8.2f} {'':>8s} {k['wall_s']:10.2f} "
                  f"(/ OpenSim IK: {k['ratio_to_opensim_ik']:.2f}; every walk frame's pose, frame by frame, with the "
                  "subject model fixed; RMS over every marker)")
        print(f"  marker RMS ratio calibrate / OpenSim: {c['rms_mm'] / o['rms_mm']:.2f} (axes held "
              f"{h['rms_mm'] / o['rms_mm']:.2f})")
        if c.get("lab_hjc_mm"):
            mm = r.get("calibrate_moved_markers", {}).get("lab_hjc_mm", {})
            hg = r.get("calibrate_hip_regression", {}).get("lab_hjc_mm", {})
            print("  hip centres from the lab's HJC markers in the static (median mm): "
                  + ", ".join(f"{j} {v:.1f}" + (f" (moved markers {mm[j]:.1f})" if j in mm else "")
                              + (f" (hip regression {hg[j]:.1f})" if j in hg else "")
                              for j, v in c["lab_hjc_mm"].items()))
        ho = r.get("heldout")
        if ho:
            print(f"  held out (the last {ho['frames']} IK frames; scaled on the static + the first half, the subject "
                  "then fixed):")
            for key, row in ho.items():
                if key == "frames":
                    continue
                label = {"opensim": "OpenSim Scale + IK", "calibrate_moved_markers": "calibrate, --moved-markers"}.get(
                    key, key.replace("calibrate_still_weight_", "calibrate, still_weight "))
                extra = (f"  (in-sample, first half: {row['in_sample_rms_mm_all_markers']:.2f} mm over every marker)"
                         if "in_sample_rms_mm_all_markers" in row else "")
                ratio = f", / OpenSim {row['rms_mm'] / ho['opensim']['rms_mm']:.2f}" if key != "opensim" else ""
                print(f"    {label:28s} {row['rms_mm']:8.2f} {row['max_mm']:8.2f}{ratio}{extra}")
        for label in ("coordinates", "coordinates_axes_held", "coordinates_no_ik_setup", "coordinates_moved_markers",
                      "coordinates_hip_regression", "coordinates_lumbar_held"):
            if label not in r:
                continue
            print("  joint angles, " + {"coordinates": "calibrate", "coordinates_axes_held": "calibrate with axes held",
                                        "coordinates_no_ik_setup": "calibrate without the IK setup",
                                        "coordinates_moved_markers": "calibrate with --moved-markers",
                                        "coordinates_hip_regression": "calibrate with --hip-regression",
                                        "coordinates_lumbar_held": f"calibrate with --hold-centres {LUMBAR}"}[label]
                  + ":")
            for name, d in r[label].items():
                extra = f", vs reference IK {d['vs_reference_ik_deg']:.2f}" if "vs_reference_ik_deg" in d else ""
                if name.rsplit("_", 1)[0] in ARM_COORDS:
                    extra += " [arm: beyond issue 17's list, no target]"
                elif name in TRUNK_COORDS:
                    extra += " [trunk: beyond issue 17's list, no target]"
                print(f"    {name:18s} RMS difference vs OpenSim IK {d['vs_opensim_ik_deg']:6.2f} deg (mean offset "
                      f"{d['offset_deg']:+6.2f}, without it {d['vs_opensim_ik_offset_free_deg']:5.2f}){extra}")
        offs = r.get("offsets", {})
        if offs:
            print(f"  over {ANGLE_TARGET_DEG:g} deg RMS from OpenSim's IK with the offset: the walk's offset beside "
                  "the static's pose as calibrate reads it minus OpenSim's marker placer's (deg):")
            print("    " + ", ".join(f"{n} {o['walk_offset_deg']:+.1f} / {o['static_difference_deg']:+.1f}"
                                     for n, o in offs.items()))
        for name, a in r.get("attribution", {}).items():
            cv, cr_, orr = a["calibrate_vs_opensim_deg"], a["calibrate_vs_replaced_deg"], a["opensim_vs_replaced_deg"]
            shifts = ", ".join(f"{n} {v:.0f}" for n, v in sorted(a["replaced_shift_mm"].items(), key=lambda x: -x[1]))
            print(f"  {name}: {cv[1]:.2f} deg from OpenSim's IK without its offset ({cv[0]:.2f} with it); "
                  f"OpenSim's own subject ({a['model']}, its IK reproduced within "
                  f"{a['opensim_reproduced_deg']:.2f} deg) with "
                  f"{a['segment']}'s markers placed where the walk puts them ({shifts} mm from its marker placer's) "
                  f"reads it {orr[1]:.2f} deg from OpenSim's IK without the offset, and calibrate {cr_[1]:.2f} deg "
                  f"from that ({cr_[0]:.2f} with it): where the static and the walk put {a['segment']}'s markers")
        if nb.get("status") == "ran":
            rd = nb.get("reading", {})
            print("  nimble's reading of the .osim: " + (f"not checked ({rd['error']})" if "error" in rd else
                  f"its markers {rd['exact_max_mm']:.4f} mm from calibrate's where the import is exact "
                  f"({rd['exact_markers']} markers), {rd['all_max_mm']:.2f} mm below the approximated joints "
                  f"({rd['worst_marker']}); 20 random poses"))
            print("  joint angles, nimble MarkerFitter (RMS difference vs OpenSim IK, deg; mean offset):")
            print("    " + ", ".join(f"{n} {d['vs_opensim_ik_deg']:.1f} ({d['offset_deg']:+.1f})"
                                     for n, d in nb["coordinates"].items()))
        if r.get("calibrate_unreliable"):
            far = ", ".join(r["calibrate_unreliable"])
            print("  unreliable (beyond their priors unidentified, or centres placed over 3 prior SDs from the scaled "
                  f"base; change from the base model): {far}")
        for line in r.get("static_asymmetry", []):
            print(f"  static pose flagged (calibrate): {line}")
        for a in r["approximations"]:
            print(f"  approximated: {a}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    ap.add_argument("--only", choices=("gait2392", "rajagopal", *EXTRA_CASES), default=None)
    ap.add_argument("--opensim-models", type=Path, default=None, metavar="DIR",
                    help="a checkout of opensim-models: adds its Hamner and Rajagopal running pipelines as cases")
    ap.add_argument("--outlier-sigmas", type=float, default=0.0,
                    help="calibrate's outlier rejection (noise SDs; default 0: off, as OpenSim's IK keeps every "
                         "marker; calibrate's own default, 6, rejects gait2392's rigid-trunk markers in most frames)")
    ap.add_argument("--no-nimble", action="store_true",
                    help="leave out nimblephysics' MarkerFitter (run by default: scripts/peer_nimble.py, its own venv)")
    ap.add_argument("--repeat", type=int, default=1, metavar="N",
                    help="time OpenSim's Scale + IK and calibrate N times each, alternately, and report the medians "
                         "(default 1)")
    ap.add_argument("--whole-trials", action="store_true",
                    help="calibrate on every frame of the static, not the Scale setup's time range (OpenSim's Scale "
                         "uses that range either way)")
    ap.add_argument("--_opensim", nargs=2, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a._opensim:
        return opensim_child(*a._opensim)
    if a.repeat < 1:
        print(f"bench_osim: --repeat {a.repeat}: give 1 or more runs", file=sys.stderr)
        return 2
    if not REAL.exists():
        print(f"bench_osim: {REAL} not found (the real trials)", file=sys.stderr)
        return 2

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    repo = a.opensim_models
    if repo is not None or a.only in EXTRA_CASES:
        missing = [f for f in extra_files(repo or Path("(none given)")) if not f.is_file()]
        if missing:
            print(f"bench_osim: --opensim-models {repo}: {missing[0]} not found; give a checkout of opensim-models "
                  f"(its Pipelines/Hamner, Pipelines/Rajagopal and Models/Rajagopal)", file=sys.stderr)
            return 2
    cases = [a.only] if a.only else ["gait2392", "rajagopal"] + (list(EXTRA_CASES) if repo else [])
    with tempfile.TemporaryDirectory(prefix="bench_osim_") as tmp:
        res = {"outlier_sigmas": a.outlier_sigmas, "whole_trials": a.whole_trials,
               "repeat": a.repeat,
               "results": [bench(c, Path(tmp), log, a.outlier_sigmas, not a.no_nimble, repo, a.whole_trials,
                                 a.repeat) for c in cases]}
    report(res)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
