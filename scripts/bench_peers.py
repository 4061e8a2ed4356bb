"""Benchmark calibrate against its peers on one synthetic squat (or gait) trial whose truth is known.

1. A squat trial of a random subject (`calibrate.simulation.simulate.simulate_squats`, 1 mm noise) and a
   1 s static trial of the same subject standing in the neutral pose
   (`calibrate.simulation.simulate.simulate_static`, same noise); `--motion gait`: a treadmill walking trial
   (`calibrate.simulation.simulate.simulate_gait`) in place of the squats; the base model (models/human.urdf)
   exported to .osim (`calibrate.io.osim_export`), both trials to .trc.
2. calibrate: `calibrate.calibrate(base model, squat trial)` (after one untimed warm-up that fills
   the compiled-code cache), scored by `calibrate.calibration.evaluate.compare_to_truth`.
3. OpenSim (`pip install -e '.[peers]'`): ScaleTool on the static trial — ModelScaler with one
   marker-pair measurement per segment (SCALE_PAIRS; isotropic scale factors, mass distribution
   kept) and MarkerPlacer (markers moved to the static trial) — then InverseKinematicsTool on the
   squat trial with the scaled model (all markers weight 1, accuracy 1e-5).  The static trial is the
   neutral pose, so MarkerPlacer also pulls every joint angle to 0 (IKCoordinateTask, weight
   --static-weight, default 1; 0 = markers only), as OpenSim's example setups pull the angles the
   markers cannot see.  Both tools' IK start from the root pose fitted to the first frame's pelvis
   markers (the root coordinates' default values), as the simulated subject faces any direction.
   Timed: the two tools' run() calls.  Then, in the lab frame, from the scaled model driven by the
   IK result:
   each joint centre = the origin of its joint's parent frame (the joint is exported as one
   CustomJoint whose parent offset frame is the URDF centre), each hinge axis = the CustomJoint's
   rotation axis expressed in ground, the joint angles = the IK coordinates (they mean exactly what
   calibrate's do: same model, same coordinate definitions), every model marker.
4. nimblephysics (AddBiomechanics' MarkerFitter): through `scripts/peer_nimble.py` when it exists
   (see the hook below), else "not run".

Every method is scored the same way, against the truth in the lab frame, as
`calibrate.calibration.evaluate` does: ball/universal centres: distance to the true centre, median over
frames; hinge centres: distance to the true axis line, median over frames; hinge axes: angle to
the true axis, median over frames; joint angles: RMS over frames and DoFs of the difference from
the truth, as is and with each DoF's constant offset removed; marker RMS: model markers against the
noisy trial markers.  One table, or one JSON object with --json.

OpenSim runs in a child process of this script (``--_opensim``) that never imports calibrate:
the opensim 4.6 wheel bundles a libcasadi with the same soname as, but another ABI than, the
casadi wheel calibrate needs, so the two cannot live in one process.

    python scripts/bench_peers.py [--frames 1000] [--seed 0] [--noise-mm 1] [--motion squats|gait] [--quick] [--json]
                                  [--keep DIR]
                                  [--static-weight 1] [--no-opensim] [--no-nimble] [--from-json FILE]
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import inspect
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "human.urdf"
NIMBLE = Path(__file__).resolve().parent / "peer_nimble.py"
STATIC_SECONDS = 1.0

# ScaleTool measurements: name -> (bodies scaled by it (x, y, z alike), marker pairs).  Pairs lie on
# one segment where it has two well-spread markers; the limbs' pairs span the proximal joint
# (acromion-elbow, ASIS-knee), measured in the static pose, which is the model's default pose.
SCALE_PAIRS: dict[str, tuple[list[str], list[tuple[str, str]]]] = {
    "pelvis": (["pelvis"], [("RASI", "LASI"), ("RPSI", "LPSI"), ("RASI", "RPSI"), ("LASI", "LPSI")]),
    "torso": (["torso"], [("RSHO", "LSHO"), ("C7", "T10"), ("CLAV", "STRN"), ("C7", "CLAV")]),
    "head": (["head"], [("LFHD", "RFHD"), ("LBHD", "RBHD"), ("LFHD", "LBHD"), ("RFHD", "RBHD")]),
}
for _s, _S in (("r", "R"), ("l", "L")):
    SCALE_PAIRS.update({
        f"thigh_{_s}": ([f"femur_{_s}"], [(f"{_S}ASI", f"{_S}KNE"), (f"{_S}PSI", f"{_S}KNE")]),
        f"shank_{_s}": ([f"tibia_{_s}"], [(f"{_S}KNE", f"{_S}ANK")]),
        f"foot_{_s}": ([f"talus_{_s}", f"calcn_{_s}"], [(f"{_S}HEE", f"{_S}TOE")]),
        f"upperarm_{_s}": ([f"humerus_{_s}"], [(f"{_S}SHO", f"{_S}ELB")]),
        f"forearm_{_s}": ([f"ulna_{_s}", f"radius_{_s}"], [(f"{_S}ELB", f"{_S}WRA"), (f"{_S}ELB", f"{_S}WRB")]),
        f"hand_{_s}": ([f"hand_{_s}"], [(f"{_S}WRA", f"{_S}FIN"), (f"{_S}WRB", f"{_S}FIN")]),
    })

ROWS = (("calibrate", "calibrate (squat)"), ("calibrate_static", "calibrate (static + squat)"),
        ("opensim", "OpenSim Scale+IK"), ("nimble", "nimblephysics"))


# ====================================================================== OpenSim child process
def opensim_worker(spec: dict) -> dict:
    """Scale + marker placement on the static trial, IK on the squat trial; lab-frame results (child process)."""
    import opensim as osim

    osim.Logger.setLevelString("warn")
    osim.Logger.removeFileSink()  # no opensim.log in the working directory
    work = Path(spec["workdir"])

    def strings(*xs: str):
        a = osim.ArrayStr()
        for x in xs:
            a.append(x)
        return a

    def time_range(t0: float, t1: float):
        a = osim.ArrayDouble()
        a.append(t0)
        a.append(t1)
        return a

    def marker_tasks(task_set) -> None:
        for name in spec["markers"]:
            t = osim.IKMarkerTask()
            t.setName(name)
            t.setWeight(1.0)
            t.setApply(True)
            task_set.cloneAndAppend(t)

    # Both tools' IK start from the model's default pose: give the root coordinates the pose of the
    # root segment's markers in the trial's first frame (Kabsch), as defaults, in a copy of the model.
    def start_from_first_frame(osim_in: str, trc: str, osim_out: Path) -> None:
        model = osim.Model(osim_in)
        model.initSystem()
        ms = model.getMarkerSet()
        table = osim.TimeSeriesTableVec3(trc)
        labels = list(table.getColumnLabels())
        row = table.getRowAtIndex(0)
        units = 1e-3 if table.getTableMetaDataString("Units").strip().lower() == "mm" else 1.0
        local = np.array([ms.get(n).get_location().to_numpy() for n in spec["root_markers"]])
        seen = np.array([[row[labels.index(n)].get(k) * units for k in range(3)] for n in spec["root_markers"]])
        R, t = _kabsch(local, seen)
        cs = model.getCoordinateSet()
        for name, v in zip(spec["root_coordinates"], [*_euler_zyx(R), *t], strict=True):
            cs.get(name).setDefaultValue(float(v))
        model.printToXML(str(osim_out))

    # ScaleTool: measurements + marker placement on the static trial.
    start_from_first_frame(spec["base_osim"], spec["static_trc"], work / "generic_start.osim")
    tool = osim.ScaleTool()
    tool.setName("subject")
    tool.setSubjectMass(spec["mass_kg"])
    tool.getGenericModelMaker().setModelFileName(str(work / "generic_start.osim"))
    scaler = tool.getModelScaler()
    scaler.setApply(True)
    scaler.setScalingOrder(strings("measurements"))
    scaler.setMarkerFileName(spec["static_trc"])
    scaler.setTimeRange(time_range(*spec["static_range"]))
    scaler.setPreserveMassDist(True)
    scaler.setOutputScaleFileName(str(work / "scale_factors.xml"))
    for name, (bodies, pairs) in spec["pairs"].items():
        m = osim.Measurement()
        m.setName(name)
        m.setApply(True)
        for a, b in pairs:
            mp = osim.MarkerPair()
            mp.setMarkerName(0, a)
            mp.setMarkerName(1, b)
            m.getMarkerPairSet().cloneAndAppend(mp)
        for body in bodies:
            bs = osim.BodyScale()
            bs.setName(body)
            bs.setAxisNames(strings("X", "Y", "Z"))
            m.getBodyScaleSet().cloneAndAppend(bs)
        scaler.addMeasurement(m)
    placer = tool.getMarkerPlacer()
    placer.setApply(True)
    placer.setStaticPoseFileName(spec["static_trc"])
    placer.setTimeRange(time_range(*spec["static_range"]))
    placer.setOutputModelFileName(str(work / "scaled.osim"))
    marker_tasks(placer.getIKTaskSet())
    if spec.get("static_coordinate_weight", 0.0) > 0:  # the static pose is the neutral pose: joint angles 0
        for name in spec["dofs"]:
            t = osim.IKCoordinateTask()
            t.setName(name)
            t.setWeight(spec["static_coordinate_weight"])
            t.setValueType(osim.IKCoordinateTask.DefaultValue)
            t.setApply(True)
            placer.getIKTaskSet().cloneAndAppend(t)
    tool.printToXML(str(work / "scale_setup.xml"))
    t0 = time.perf_counter()
    if not tool.run():
        raise RuntimeError("ScaleTool.run() failed")
    scale_s = time.perf_counter() - t0

    start_from_first_frame(str(work / "scaled.osim"), spec["squat_trc"], work / "scaled_ik_start.osim")

    ik = osim.InverseKinematicsTool()
    ik.set_model_file(str(work / "scaled_ik_start.osim"))
    ik.setMarkerDataFileName(spec["squat_trc"])
    ik.setStartTime(spec["squat_range"][0])
    ik.setEndTime(spec["squat_range"][1])
    ik.set_accuracy(1e-5)
    marker_tasks(ik.getIKTaskSet())
    ik.setResultsDir(str(work))
    ik.setOutputMotionFileName(str(work / "ik.mot"))
    ik.printToXML(str(work / "ik_setup.xml"))
    t0 = time.perf_counter()
    if not ik.run():
        raise RuntimeError("InverseKinematicsTool.run() failed")
    ik_s = time.perf_counter() - t0

    # The scaled model driven by the IK result, in the lab frame.
    model = osim.Model(str(work / "scaled.osim"))
    state = model.initSystem()
    cs = model.getCoordinateSet()
    mot = osim.TimeSeriesTable(str(work / "ik.mot"))
    cols = list(mot.getColumnLabels())
    Q = mot.getMatrix().to_numpy().copy()
    in_degrees = mot.getTableMetaDataString("inDegrees").strip().lower() == "yes"
    for k, name in enumerate(cols):
        if in_degrees and cs.get(name).getMotionType() == osim.Coordinate.Rotational:
            Q[:, k] = np.radians(Q[:, k])
    js = model.getJointSet()
    joints = [js.get(n) for n in spec["joints"]]
    hinge_axis = {}
    for n in spec["hinges"]:
        cj = osim.CustomJoint.safeDownCast(js.get(n))
        hinge_axis[n] = (cj.getParentFrame(), cj.getSpatialTransform().getTransformAxis(0).getAxis())
    coords = [cs.get(n) for n in cols]
    markers = [model.getMarkerSet().get(n) for n in spec["markers"]]
    nf = Q.shape[0]
    centres = np.zeros((nf, len(joints), 3))
    axes = np.zeros((nf, len(hinge_axis), 3))
    mk = np.zeros((nf, len(markers), 3))
    for f in range(nf):
        for c, v in zip(coords, Q[f], strict=True):
            c.setValue(state, float(v), False)
        model.realizePosition(state)
        for j, joint in enumerate(joints):
            centres[f, j] = joint.getParentFrame().getPositionInGround(state).to_numpy()
        for h, (frame, ax) in enumerate(hinge_axis.values()):
            axes[f, h] = frame.expressVectorInGround(state, ax).to_numpy()
        for k, m in enumerate(markers):
            mk[f, k] = m.getLocationInGround(state).to_numpy()
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)
    bodies = model.getBodySet()
    scale = _read_scale_factors(work / "scale_factors.xml")
    return {"time_s": scale_s + ik_s, "scale_s": scale_s, "ik_s": ik_s, "times": list(mot.getIndependentColumn()),
            "coordinates": cols, "q": Q, "centres": centres, "axes": axes, "markers": mk,
            "scale_factors": {bodies.get(i).getName(): scale.get(bodies.get(i).getName(), 1.0)
                              for i in range(bodies.getSize())}}


def _kabsch(local: np.ndarray, seen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising |R local + t - seen|."""
    cl, cs = local.mean(axis=0), seen.mean(axis=0)
    U, _, Vt = np.linalg.svd((local - cl).T @ (seen - cs))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cs - R @ cl


def _euler_zyx(R: np.ndarray) -> tuple[float, float, float]:
    """Body-fixed z, y', x'' angles of R = Rz Ry Rx (the exported root's coordinates)."""
    ry = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    return float(np.arctan2(R[1, 0], R[0, 0])), ry, float(np.arctan2(R[2, 1], R[2, 2]))


def _read_scale_factors(path: Path) -> dict[str, float]:
    import xml.etree.ElementTree as ET

    out = {}
    for s in ET.parse(path).getroot().iter("Scale"):
        seg, sc = s.findtext("segment"), s.findtext("scales")
        if seg and sc:
            out[seg.strip()] = float(np.mean([float(x) for x in sc.split()]))
    return out


# ====================================================================== data
def make_trials(model, frames: int, noise_mm: float, seed: int, motion: str = "squats"):
    """The squat (or gait) simulation and a static trial of the same subject
    (calibrate.simulation.simulate.simulate_static:
    standing in the neutral pose, a few mm of sway, about 0.5 deg of drift per joint)."""
    from calibrate.simulation.simulate import simulate_gait, simulate_squats, simulate_static

    simulate = simulate_gait if motion == "gait" else simulate_squats
    sim = simulate(model, frames=frames, noise_mm=noise_mm, seed=seed)
    n = max(2, int(round(STATIC_SECONDS * sim.trial.rate)))
    static = simulate_static(model, sim.truth, frames=n, rate=sim.trial.rate, noise_mm=noise_mm, seed=seed + 1)
    return sim, static.trial


def truth_of(sim) -> dict:
    from calibrate.simulation.simulate import joint_axes_world

    model = sim.model
    return {"kinds": {j.name: j.kind for j in model.joints},
            "centres": {j.name: sim.clean_centres[:, i] for i, j in enumerate(model.joints)},
            "axes": joint_axes_world(model, sim.truth, sim.motion),
            "angles": {d: sim.motion.angles[:, i] for i, d in enumerate(model.dof_names)},
            "markers": sim.trial.markers}


def marker_rms(model_markers: np.ndarray, observed: np.ndarray) -> float:
    """RMS over frames and markers of the 3-D distance (m), gaps ignored."""
    return float(np.sqrt(np.nanmean(np.sum((model_markers - observed) ** 2, axis=2))))


def score(truth: dict, centres: dict, axes: dict, angles: dict, rms: float | None) -> dict:
    """A method's lab-frame results against the truth (as calibrate.calibration.evaluate scores a calibration)."""
    centre, axis = {}, {}
    for name, kind in truth["kinds"].items():
        if name not in centres:
            continue
        d = np.asarray(centres[name], float) - truth["centres"][name]
        if kind == "hinge":
            a = truth["axes"][name]
            d = d - np.sum(d * a, axis=1, keepdims=True) * a
            if name in axes:
                cos = np.abs(np.sum(np.asarray(axes[name], float) * a, axis=1)).clip(0, 1)
                axis[name] = float(np.degrees(np.median(np.arccos(cos))))
        centre[name] = float(np.median(np.linalg.norm(d, axis=1)))
    ball = {k: v for k, v in centre.items() if truth["kinds"][k] != "hinge"}
    hinge = {k: v for k, v in centre.items() if truth["kinds"][k] == "hinge"}
    dofs = [d for d in truth["angles"] if d in angles]
    out: dict = {"centre_err_mm": {k: 1e3 * v for k, v in centre.items()}, "axis_err_deg": axis,
                 "missing": sorted(set(truth["kinds"]) - set(centres)),
                 "marker_rms_mm": None if rms is None else 1e3 * rms}
    if ball:
        out.update(ball_median_mm=1e3 * float(np.median(list(ball.values()))), ball_max_mm=1e3 * max(ball.values()),
                   worst_ball=max(ball, key=ball.get))
    if hinge:
        out.update(hinge_centre_median_mm=1e3 * float(np.median(list(hinge.values()))),
                   hinge_centre_max_mm=1e3 * max(hinge.values()), worst_hinge_centre=max(hinge, key=hinge.get))
    if axis:
        out.update(axis_max_deg=max(axis.values()), axis_median_deg=float(np.median(list(axis.values()))),
                   worst_axis=max(axis, key=axis.get))
    if dofs:
        est = np.column_stack([np.asarray(angles[d], float) for d in dofs])
        tru = np.column_stack([truth["angles"][d] for d in dofs])
        dang = np.degrees(np.angle(np.exp(1j * (est - tru))))
        out["angle_rms_deg"] = float(np.sqrt(np.mean(dang**2)))
        out["angle_rms_offset_free_deg"] = float(np.sqrt(np.mean((dang - dang.mean(axis=0)) ** 2)))
        per = np.sqrt(np.mean(dang**2, axis=0))
        out["angle_rms_per_dof_deg"] = dict(zip(dofs, per.tolist(), strict=True))
    return out


# ====================================================================== the methods
def run_calibrate(model, sim, truth: dict, log, static=None) -> dict:
    """calibrate on the squat trial (or, with `static`, on the static and the squat trial together, as
    OpenSim gets them); the figures are of the squat trial's frames."""
    from calibrate import calibrate
    from calibrate.calibration import compare_to_truth
    from calibrate.io.trial import Trial
    from calibrate.model.kinematics import build_kinematics
    from calibrate.simulation.simulate import joint_axes_world

    warm = Trial(sim.trial.labels, sim.trial.markers[: min(60, sim.trial.n_frames)], sim.trial.rate, 0, None)
    log("calibrate: warm-up (compiled-code cache)...")
    calibrate(model, warm)
    log("calibrate: calibrating" + (" (static + squat)..." if static is not None else "..."))
    t0 = time.perf_counter()
    cal = calibrate(model, sim.trial if static is None else [static, sim.trial])
    wall = time.perf_counter() - t0
    if static is not None:  # judge the squat trial's frames, as for the others
        squat = cal.trial_frames(1)
        cal = type(cal)(**{**cal.__dict__, "trials": (sim.trial,), "motions": (cal.motions[1],),
                           "residuals": cal.residuals[squat]})
    cmp = compare_to_truth(cal, sim)
    mo = cal.motion
    Z = np.column_stack([mo.root_translation, np.zeros((mo.n_frames, 3)), mo.angles])
    _, C = build_kinematics(model).batch(Z, mo.root_quaternion, cal.params)
    row = score(truth, {j.name: C[:, i] for i, j in enumerate(model.joints)}, joint_axes_world(model, cal.params, mo),
                {d: mo.angles[:, i] for i, d in enumerate(model.dof_names)}, cal.marker_rms)
    # the same figures as compare_to_truth's (a consistency check of score())
    assert abs(row["ball_max_mm"] - 1e3 * max(cmp.ball().values())) < 1e-6
    assert abs(row["angle_rms_deg"] - cmp.angle_rms_deg) < 1e-6
    row.update(status="ok", time_s=wall, converged=bool(cal.converged), floor_rms_mm=1e3 * cmp.floor_rms,
               scale_err_pct=_scale_err(model, sim, {s.name: float(cal.params.scale[i])
                                                     for i, s in enumerate(model.segments)}))
    return row


def _scale_err(model, sim, scales: dict[str, float]) -> dict[str, float]:
    """Segment scale factor error (%) against the truth's."""
    return {s.name: 100.0 * (scales[s.name] / float(sim.truth.scale[i]) - 1.0)
            for i, s in enumerate(model.segments) if s.name in scales}


def run_opensim(model, sim, truth: dict, work: Path, files: dict[str, Path], log, static_weight: float) -> dict:
    if importlib.util.find_spec("opensim") is None:
        return {"status": "not run: opensim is not installed (pip install -e '.[peers]')"}
    t = sim.trial.times
    n_static = int(round(STATIC_SECONDS * sim.trial.rate))
    spec = {"workdir": str(work), "base_osim": str(files["osim"]), "static_trc": str(files["static"]),
            "squat_trc": str(files["squat"]), "mass_kg": float(sum(s.mass for s in model.segments)),
            "static_range": [0.0, (n_static - 1) / sim.trial.rate], "squat_range": [float(t[0]), float(t[-1])],
            "pairs": SCALE_PAIRS, "markers": list(model.marker_names), "joints": [j.name for j in model.joints],
            "hinges": [j.name for j in model.joints if j.kind == "hinge"],
            "root_markers": list(model.segments[0].markers),
            "root_coordinates": ["root_rz", "root_ry", "root_rx", "root_x", "root_y", "root_z"],
            "dofs": list(model.dof_names), "static_coordinate_weight": static_weight}
    spec_path, out_path = work / "opensim_spec.json", work / "opensim_result.npz"
    spec_path.write_text(json.dumps(spec))
    log("OpenSim: ScaleTool + InverseKinematicsTool (child process)...")
    proc = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--_opensim", str(spec_path), str(out_path)],
                          capture_output=True, text=True)
    if proc.returncode != 0 or not out_path.exists():
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"status": f"not run: OpenSim failed ({last})"}
    r = np.load(out_path, allow_pickle=True)
    res = r["result"].item()
    if len(res["times"]) != sim.trial.n_frames:
        return {"status": f"not run: OpenSim IK gave {len(res['times'])} frames, expected {sim.trial.n_frames}"}
    cols = list(res["coordinates"])
    row = score(truth, {n: res["centres"][:, i] for i, n in enumerate(spec["joints"])},
                {n: res["axes"][:, i] for i, n in enumerate(spec["hinges"])},
                {d: res["q"][:, cols.index(d)] for d in model.dof_names if d in cols},
                marker_rms(res["markers"], truth["markers"]))
    row.update(status="ok", time_s=res["time_s"], scale_s=res["scale_s"], ik_s=res["ik_s"],
               scale_err_pct=_scale_err(model, sim, res["scale_factors"]))
    return row


def _opensim_child(spec_path: str, out_path: str) -> int:
    res = opensim_worker(json.loads(Path(spec_path).read_text()))
    np.savez(out_path, result=np.array(res, dtype=object))
    return 0


# ---------------------------------------------------------------------- nimblephysics hook
# scripts/peer_nimble.py is written separately (it makes its own venv with numpy<2).  Coordinated only
# through this call:
#     run_nimble(osim_path: str, trc_paths: list[str], **kwargs) -> dict
# trc_paths[0] is the squat trial: per-frame results refer to its frames.  Keyword arguments are passed
# only if run_nimble's signature names them: mass_kg (float, the model's), height_m (float: 1.75 m times
# the subject's mean segment scale), work_dir (str), urdf (str: the base URDF the .osim was exported from),
# static_trc (str), markers (labels), joints, hinges,
# dofs (names).  Only the squat trial is passed: nimble, like calibrate, needs no static trial.
# Expected keys of the returned dict:
#     "time_s": float                        wall time of the fit
#     "marker_rms_m": float                  RMS marker distance over the squat trial's frames (m)
#     "centres_world": {joint: (n_frames, 3)}   lab-frame joint centres (m), joints named as in the .osim
#     "axes_world": {hinge joint: (n_frames, 3)}  lab-frame unit hinge axes
#     "angles": {dof: (n_frames,)}           joint angles (rad), coordinates named as in the .osim
#     "error": str | None                    why it did not run (then the rest may be missing)
# Optional: "markers_world": (n_frames, n_markers, 3) in the order of `markers` (marker RMS computed here).
def run_nimble_peer(model, sim, truth: dict, work: Path, files: dict[str, Path], log, symmetric: bool = False) -> dict:
    if not NIMBLE.exists():
        return {"status": f"not run: {NIMBLE.relative_to(ROOT)} is not there"}
    try:
        spec = importlib.util.spec_from_file_location("peer_nimble", NIMBLE)
        mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
        fn = mod.run_nimble
    except Exception as e:  # a broken helper must not stop the benchmark
        return {"status": f"not run: cannot load {NIMBLE.name} ({type(e).__name__}: {e})"}
    offered = {"urdf": str(MODEL), "static_trc": str(files["static"]),
               "mass_kg": float(sum(s.mass for s in model.segments)),
               "height_m": 1.75 * float(np.mean(sim.truth.scale)), "work_dir": str(work / "nimble"),
               "markers": list(model.marker_names), "joints": [j.name for j in model.joints],
               "hinges": [j.name for j in model.joints if j.kind == "hinge"], "dofs": list(model.dof_names),
               "settings": {"symmetric": bool(symmetric)}}
    params = inspect.signature(fn).parameters
    kwargs = {k: v for k, v in offered.items() if k in params}
    (work / "nimble").mkdir(exist_ok=True)
    log("nimblephysics: run_nimble...")
    try:
        res = fn(str(files["osim"]), [str(files["squat"])], **kwargs)
    except Exception as e:
        return {"status": f"not run: run_nimble raised {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"}
    if not isinstance(res, dict):
        return {"status": f"not run: run_nimble returned {type(res).__name__}, not a dict"}
    if res.get("error"):
        return {"status": f"not run: {res['error']}"}
    nf = sim.trial.n_frames
    bad = [k for k, v in res.get("centres_world", {}).items() if np.shape(v) != (nf, 3)]
    if bad:
        return {"status": f"not run: centres_world['{bad[0]}'] has shape {np.shape(res['centres_world'][bad[0]])}, "
                          f"expected ({nf}, 3)"}
    rms = res.get("marker_rms_m")
    if res.get("markers_world") is not None:
        rms = marker_rms(np.asarray(res["markers_world"], float), truth["markers"])
    row = score(truth, res.get("centres_world", {}), res.get("axes_world", {}), res.get("angles", {}), rms)
    row.update(status="ok", time_s=float(res.get("time_s", float("nan"))))
    if res.get("total_s") is not None:
        row["total_s"] = float(res["total_s"])
    if isinstance(res.get("body_scales"), dict):
        row["scale_err_pct"] = _scale_err(model, sim, {k: float(np.mean(v)) for k, v in res["body_scales"].items()})
    return row


# ====================================================================== report
def collect(a: argparse.Namespace, log) -> dict:
    from calibrate import load_model
    from calibrate.io import write_trc
    from calibrate.io.osim_export import export_osim

    model = load_model(MODEL)
    log(f"simulating {a.frames} {a.motion} frames and a {STATIC_SECONDS:g} s static trial (seed {a.seed})...")
    sim, static = make_trials(model, a.frames, a.noise_mm, a.seed, a.motion)
    truth = truth_of(sim)
    work = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench_peers_"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        files = {"osim": work / "human.osim", "static": work / "static.trc", "squat": work / "squat.trc"}
        export_osim(model, files["osim"])
        write_trc(files["static"], static)
        write_trc(files["squat"], sim.trial)
        rows = {"calibrate": run_calibrate(model, sim, truth, log),
                "calibrate_static": run_calibrate(model, sim, truth, log, static=static)}
        rows["opensim"] = ({"status": "not run: --no-opensim"} if a.no_opensim
                           else run_opensim(model, sim, truth, work, files, log, a.static_weight))
        rows["nimble"] = ({"status": "not run: --no-nimble"} if a.no_nimble
                          else run_nimble_peer(model, sim, truth, work, files, log, a.nimble_symmetric))
    finally:
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
    base = rows["calibrate"]["time_s"]
    for r in rows.values():
        if r.get("status") == "ok":
            r["time_ratio"] = r["time_s"] / base
    return {"date": datetime.date.today().isoformat(), "machine": f"{platform.processor() or platform.machine()}, "
            f"{os.cpu_count()} cores", "python": platform.python_version(), "frames": a.frames,
            "motion": a.motion, "static_frames": static.n_frames, "rate_hz": sim.trial.rate, "noise_mm": a.noise_mm,
            "seed": a.seed,
            "floor_rms_mm": rows["calibrate"]["floor_rms_mm"], "scale_pairs": SCALE_PAIRS,
            "static_coordinate_weight": a.static_weight, "nimble_symmetric": a.nimble_symmetric, "rows": rows,
            "kinds": truth["kinds"]}


def _f(x, spec: str) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def report(res: dict) -> None:
    kind = "gait" if res.get("motion") == "gait" else "squat"
    print(f"Peers on one synthetic {kind} trial: {res['frames']} frames at {res['rate_hz']:g} Hz, "
          f"{res['noise_mm']:g} mm noise, seed {res['seed']} (+ a {res['static_frames']}-frame static trial for "
          f"OpenSim's ScaleTool); noise floor (true model refitted) {res['floor_rms_mm']:.3f} mm")
    head = ("method", "ball ctr med mm", "ball ctr max mm", "hinge ctr max mm", "hinge axis max deg",
            "angle RMS deg", "offset-free deg", "marker RMS mm", "time s", "× calibrate")
    print(" | ".join(head))
    for key, label in ROWS:
        r = res["rows"][key]
        if r.get("status") != "ok":
            print(f"{label} | {r.get('status')}")
            continue
        cells = [label, _f(r.get("ball_median_mm"), ".2f"), _f(r.get("ball_max_mm"), ".2f"),
                 _f(r.get("hinge_centre_max_mm"), ".2f"), _f(r.get("axis_max_deg"), ".2f"),
                 _f(r.get("angle_rms_deg"), ".2f"), _f(r.get("angle_rms_offset_free_deg"), ".2f"),
                 _f(r.get("marker_rms_mm"), ".3f"), _f(r.get("time_s"), ".2f"), _f(r.get("time_ratio"), ".2f")]
        print(" | ".join(cells))
    ok = [(label, res["rows"][k]) for k, label in ROWS if res["rows"][k].get("status") == "ok"]
    print("")
    print("per joint: centre error mm (hinges: from the true axis line) / hinge axis error deg")
    print("joint | kind | " + " | ".join(label for label, _ in ok))
    for name, kind in res["kinds"].items():
        cells = []
        for _, r in ok:
            c = r["centre_err_mm"].get(name)
            ax = r["axis_err_deg"].get(name)
            cells.append(_f(c, ".2f") + (f" / {ax:.2f}" if ax is not None else ""))
        print(f"{name} | {kind} | " + " | ".join(cells))
    print("")
    print("segment scale error % (vs truth): " + "; ".join(
        f"{label} median |e| {np.median(np.abs(list(r['scale_err_pct'].values()))):.2f}, max |e| "
        f"{np.max(np.abs(list(r['scale_err_pct'].values()))):.2f}" for label, r in ok if r.get("scale_err_pct")))
    if res["rows"]["opensim"].get("status") == "ok":
        o = res["rows"]["opensim"]
        print(f"OpenSim time: ScaleTool {o['scale_s']:.2f} s + InverseKinematicsTool {o['ik_s']:.2f} s")


def clean_json(x):
    if isinstance(x, dict):
        return {str(k): clean_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return clean_json(x.tolist())
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return clean_json(x.item())
    if isinstance(x, float) and not np.isfinite(x):
        return None
    return x


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=None, help="squat trial frames (default 1000; quick 300)")
    ap.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    ap.add_argument("--noise-mm", type=float, default=1.0, help="marker noise SD in mm (default 1)")
    ap.add_argument("--motion", choices=("squats", "gait"), default="squats",
                    help="the movement trial: squats (default) or treadmill gait (simulate_gait)")
    ap.add_argument("--quick", action="store_true", help="a short run (300 frames)")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    ap.add_argument("--static-weight", type=float, default=1.0,
                    help="OpenSim MarkerPlacer: weight of each joint angle's pull to 0 (the static trial is the "
                         "neutral pose); 0 = markers only (default 1)")
    ap.add_argument("--no-opensim", action="store_true", help="skip the OpenSim row")
    ap.add_argument("--no-nimble", action="store_true", help="skip the nimblephysics row (minutes per run)")
    ap.add_argument("--nimble-symmetric", action="store_true",
                    help="nimble with AddBiomechanics' default of shared left/right scales (the simulated subject is "
                         "asymmetric, so by default each side is scaled on its own)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the .osim/.trc/setup/IK files in this directory")
    ap.add_argument("--from-json", type=Path, default=None, help="print the tables of a saved --json result")
    ap.add_argument("--_opensim", nargs=2, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a._opensim:
        return _opensim_child(*a._opensim)
    if a.from_json:
        report(json.loads(a.from_json.read_text()))
        return 0
    if a.frames is None:
        a.frames = 300 if a.quick else 1000

    t_start = time.perf_counter()

    def log(msg: str) -> None:
        print(f"[bench_peers {time.perf_counter() - t_start:7.1f} s] {msg}", file=sys.stderr, flush=True)

    res = collect(a, log)
    for key, label in ROWS:
        status = res["rows"][key].get("status")
        if status != "ok":
            log(f"{label}: {status}")
    if a.json:
        print(json.dumps(clean_json(res), indent=1))
    else:
        report(res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
