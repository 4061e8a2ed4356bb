"""Worker for scripts/peer_nimble.py: runs nimblephysics inside its own venv (numpy < 2).

    python -I _nimble_worker.py IN.json OUT.json

IN.json holds ``mode`` ("fit" or "fk") and its inputs; OUT.json gets the results, or
``{"error": "one line"}``.  Only the standard library, numpy and nimblephysics' native module
are imported (``import nimblephysics`` itself would import torch, which this venv leaves out).

* ``fit`` — AddBiomechanics' kinematics pass (server/engine/src/kinematics_pass/subject.py,
  ``run_kinematics_pass``): MarkerFitter with its default weights, marker clean-up
  (``generateDataErrorsReport``), ``runMultiTrialKinematicsPipeline``; then per frame the joint
  centres, hinge axes, coordinates and marker positions of the fitted skeleton.
* ``fk`` — the unfitted model's marker positions and joint centres at given coordinates: to
  check that nimble reads an .osim the way its writer meant it.

Positions are in the lab frame of the .trc: observations are turned by ``lab_to_nimble`` (the
rotation the .osim's ground frame was given so that nimble sees y up) and results turned back.
"""

from __future__ import annotations

import json
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

T_START = time.perf_counter()
from nimblephysics_libs import _nimblephysics as nimble  # noqa: E402  (timed import)

IMPORT_S = time.perf_counter() - T_START


def one_line(text: object) -> str:
    """`text` on one line, trimmed."""
    return " ".join(str(text).split())[:500]


def load_osim(path: str, geometry: str | None) -> Any:
    """Parse an .osim, with the meshes in folder `geometry` (if given), or raise."""
    parse = nimble.biomechanics.OpenSimParser.parseOsim
    osim = parse(str(Path(path).resolve()), geometry, False) if geometry else parse(str(Path(path).resolve()), "", True)
    if osim is None or osim.skeleton is None:
        raise RuntimeError(f"nimble could not parse {path}")
    return osim


def load_trc(path: str, rot: np.ndarray) -> tuple[list[dict[str, np.ndarray]], float, list[float]]:
    """Marker observations (nimble frame), time step and time stamps of a .trc."""
    trc = nimble.biomechanics.OpenSimParser.loadTRC(str(Path(path).resolve()))
    obs = []
    for frame in trc.markerTimesteps:
        obs.append({k: rot @ np.asarray(v, dtype=float).reshape(3) for k, v in frame.items()
                    if np.all(np.isfinite(v))})
    stamps = [float(t) for t in trc.timestamps]
    dt = (stamps[-1] - stamps[0]) / (len(stamps) - 1) if len(stamps) > 1 else 1.0 / float(trc.framesPerSecond)
    return obs, dt, stamps


def joint_frame(joint: Any) -> tuple[np.ndarray, np.ndarray]:
    """World rotation and origin of `joint`'s frame (on its child body)."""
    child = joint.getChildBodyNode().getWorldTransform()
    local = joint.getTransformFromChildBodyNode()
    return child.rotation() @ local.rotation(), child.rotation() @ local.translation() + child.translation()


def hinge_axis(joint: Any) -> np.ndarray:
    """World direction of a one-DoF rotational joint's axis (from its relative Jacobian)."""
    jac = np.asarray(joint.getRelativeJacobian(), dtype=float)[:3, 0]  # angular part, child frame
    world = joint.getChildBodyNode().getWorldTransform().rotation() @ jac
    return world / np.linalg.norm(world)


def is_hinge(joint: Any) -> bool:
    """One DoF that rotates without translating."""
    if joint.getNumDofs() != 1:
        return False
    jac = np.asarray(joint.getRelativeJacobian(), dtype=float)[:, 0]
    return bool(np.linalg.norm(jac[:3]) > 1e-9 and np.linalg.norm(jac[3:]) < 1e-9)


def trajectories(skel: Any, markers: dict[str, Any], poses: np.ndarray, back: np.ndarray) -> dict[str, Any]:
    """Per-frame joint centres, hinge axes, coordinates and marker positions (lab frame)."""
    joints = [skel.getJoint(i) for i in range(skel.getNumJoints())]
    hinges = [j for j in joints if is_hinge(j)]
    names = sorted(markers)
    pairs = [markers[n] for n in names]
    n = poses.shape[1]
    centres = {j.getName(): np.zeros((n, 3)) for j in joints}
    axes = {j.getName(): np.zeros((n, 3)) for j in hinges}
    mpos = np.zeros((n, len(names), 3))
    for t in range(n):
        skel.setPositions(poses[:, t])
        for j in joints:
            centres[j.getName()][t] = back @ joint_frame(j)[1]
        for j in hinges:
            axes[j.getName()][t] = back @ hinge_axis(j)
        mpos[t] = (back @ np.asarray(skel.getMarkerWorldPositions(pairs)).reshape(-1, 3).T).T
    dofs = [skel.getDofByIndex(i).getName() for i in range(skel.getNumDofs())]
    return {
        "centres_world": {k: v.tolist() for k, v in centres.items()},
        "axes_world": {k: v.tolist() for k, v in axes.items()},
        "angles": {d: poses[i].tolist() for i, d in enumerate(dofs)},
        "marker_names": names,
        "markers_world": mpos,
    }


def marker_rms(names: list[str], mpos: np.ndarray, obs: list[dict[str, np.ndarray]], back: np.ndarray) -> float:
    """RMS over all observed (frame, marker) pairs of the model-to-observation distance."""
    index = {n: i for i, n in enumerate(names)}
    sq = []
    for t, frame in enumerate(obs):
        for k, v in frame.items():
            if k in index:
                sq.append(float(np.sum((back @ v - mpos[t, index[k]]) ** 2)))
    return float(np.sqrt(np.mean(sq))) if sq else float("nan")


def configure(fitter: Any, osim: Any, cfg: dict[str, Any], notes: list[str]) -> None:
    """MarkerFitter settings as AddBiomechanics' kinematics pass sets them."""
    fitter.setInitialIKSatisfactoryLoss(1e-5)
    fitter.setInitialIKMaxRestarts(int(cfg.get("initial_ik_restarts", 150)))
    fitter.setIterationLimit(int(cfg.get("iterations", 500)))
    fitter.setIgnoreJointLimits(bool(cfg.get("ignore_joint_limits", False)))
    if cfg.get("markers") == "file" or len(osim.anatomicalMarkers) > 10:
        fitter.setTrackingMarkers(osim.trackingMarkers)  # the .osim's <fixed>false</fixed> markers
    else:
        fitter.setTriadsToTracking()
        notes.append(f"{len(osim.anatomicalMarkers)} markers <fixed>true</fixed>: all but triads treated as anatomical "
                     "(AddBiomechanics' fallback)")
    fitter.setRegularizeAnatomicalMarkerOffsets(10.0)
    fitter.setRegularizeTrackingMarkerOffsets(0.05)
    fitter.setMinSphereFitScore(0.01)
    fitter.setMinAxisFitScore(0.001)
    fitter.setMaxJointWeight(1.0)
    fitter.setRegularizePelvisJointsWithVirtualSpring(0.1)


def clean_markers(fitter: Any, obs: list[dict[str, np.ndarray]], dt: float) -> list[dict[str, np.ndarray]]:
    """AddBiomechanics' marker clean-up (MarkerFixer); keeps the raw data if it changes the frame count."""
    report = fitter.generateDataErrorsReport(obs, dt, rippleReduce=True, rippleReduceUseSparse=True,
                                             rippleReduceUseIterativeSolver=True,
                                             rippleReduceSolverIterations=int(1e5))
    if report.getNumTimesteps() != len(obs):
        return obs
    return [{m: np.asarray(report.getMarkerPositionOnTimestep(t, m), dtype=float).reshape(3)
             for m in report.getMarkerNamesOnTimestep(t)} for t in range(report.getNumTimesteps())]


def fit(req: dict[str, Any]) -> dict[str, Any]:
    """The kinematics pass on every trial; results per trial."""
    t0 = time.perf_counter()
    cfg = req.get("settings", {})
    rot = np.asarray(req.get("lab_to_nimble", np.eye(3)), dtype=float)
    back = rot.T
    notes: list[str] = []
    osim = load_osim(req["osim"], req.get("geometry"))
    skel = osim.skeleton
    if cfg.get("symmetric", True):
        skel.autogroupSymmetricSuffixes()  # as AddBiomechanics: left and right segments share scales
    root = skel.getJoint(0)
    if root.getNumDofs() == 6:  # unconstrained root translation, as AddBiomechanics
        for i in range(3, 6):
            skel.setPositionLowerLimit(i, -1000.0)
            skel.setPositionUpperLimit(i, 1000.0)
    trials = [load_trc(p, rot) for p in req["trcs"]]
    raw = [t[0] for t in trials]
    fitter = nimble.biomechanics.MarkerFitter(skel, osim.markersMap)
    configure(fitter, osim, cfg, notes)
    for obs in raw:
        if not fitter.checkForEnoughMarkers(obs):
            raise RuntimeError("fewer than 8 of the model's markers are in the trial")
    height = float(req.get("height_m") or -1.0)
    if height > 0 and cfg.get("height_prior", True):
        try:  # nimble measures a model's height on its meshes: none, no prior
            model_height = float(skel.getHeight(np.zeros(skel.getNumDofs()), np.array([0.0, 1.0, 0.0])))
        except Exception:
            model_height = 0.0
        if model_height > 0:
            fitter.setExplicitHeightPrior(height, 0.1)
            notes.append(f"height prior {height:.3f} m (weight 0.1); unscaled model {model_height:.3f} m on its meshes")
        else:
            notes.append("height prior skipped: nimble measures height on the model's meshes and this .osim has none")
    load_s = time.perf_counter() - t0

    t1 = time.perf_counter()
    obs_list = [clean_markers(fitter, obs, dt) for obs, (_, dt, _) in zip(raw, trials, strict=True)] \
        if cfg.get("clean_markers", True) else raw
    params = (nimble.biomechanics.InitialMarkerFitParams()
              .setMaxTrialsToUseForMultiTrialScaling(5)
              .setMaxTimestepsToUseForMultiTrialScaling(4000))
    if "analytical_ik" in cfg:
        params = params.setUseAnalyticalIKToInitialize(bool(cfg["analytical_ik"]))
    results = fitter.runMultiTrialKinematicsPipeline(obs_list, params, int(cfg.get("bilevel_samples", 150)))
    fit_s = time.perf_counter() - t1

    t2 = time.perf_counter()
    skel.setGroupScales(results[0].groupScales)
    markers = dict(results[0].updatedMarkerMap)
    out_trials = []
    for res, obs in zip(results, raw, strict=True):
        if res.error:
            out_trials.append({"error": one_line(res.errorMsg)})
            continue
        poses = np.asarray(res.poses, dtype=float)
        tr = trajectories(skel, markers, poses, back)
        mpos = tr.pop("markers_world")
        tr["marker_rms_m"] = marker_rms(tr["marker_names"], mpos, obs, back)
        if cfg.get("marker_positions"):  # every frame's model markers (lab frame), for a caller's own scoring
            tr["markers_world"] = mpos.tolist()
        report = nimble.biomechanics.IKErrorReport(skel, markers, poses, obs)
        tr["nimble_ik_rms_m"] = float(report.averageRootMeanSquaredError)
        tr["error"] = None
        out_trials.append(tr)
    scales = {skel.getBodyNode(i).getName(): np.asarray(skel.getBodyNode(i).getScale(), dtype=float).ravel().tolist()
              for i in range(skel.getNumBodyNodes())}
    fitted = {k: [b.getName(), np.asarray(off, dtype=float).ravel().tolist()] for k, (b, off) in markers.items()}
    return {
        "error": None,
        "trials": out_trials,
        "body_scales": scales,
        "markers": fitted,
        "notes": notes,
        "import_s": IMPORT_S,
        "load_s": load_s,
        "fit_s": fit_s,
        "extract_s": time.perf_counter() - t2,
    }


def fk(req: dict[str, Any]) -> dict[str, Any]:
    """Marker positions and joint centres of the unfitted model at given coordinates."""
    rot = np.asarray(req.get("lab_to_nimble", np.eye(3)), dtype=float)
    osim = load_osim(req["osim"], req.get("geometry"))
    skel = osim.skeleton
    dofs = [skel.getDofByIndex(i).getName() for i in range(skel.getNumDofs())]
    coords = req["coordinates"]
    missing = [d for d in dofs if d not in coords]
    if missing:
        raise RuntimeError(f"no values for nimble coordinates {missing[:5]}")
    poses = np.array([coords[d] for d in dofs], dtype=float).reshape(len(dofs), -1)
    tr = trajectories(skel, osim.markersMap, poses, rot.T)
    tr["markers_world"] = tr["markers_world"].tolist()
    tr["joints"] = [[skel.getJoint(i).getName(), skel.getJoint(i).getType()] for i in range(skel.getNumJoints())]
    tr["error"] = None
    return tr


def main(argv: list[str]) -> int:
    """Read the request, run it, write the answer (an error as one line)."""
    if len(argv) != 3:
        print("usage: _nimble_worker.py IN.json OUT.json", file=sys.stderr)
        return 2
    req = json.loads(Path(argv[1]).read_text())
    try:
        out = fit(req) if req.get("mode", "fit") == "fit" else fk(req)
    except Exception as exc:  # reported to the caller as one line
        traceback.print_exc()
        out = {"error": f"{type(exc).__name__}: {one_line(exc)}"}
    Path(argv[2]).write_text(json.dumps(out))
    return 0 if out.get("error") is None else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
