"""An imported OpenSim model against OpenSim itself: every marker of calibrate's model (Pinocchio, each coordinate
times its ratio) against OpenSim's (the `opensim` package in a child process) at random poses, every coordinate
uniform over its range at once; per marker the mean and largest distance, and what the import reported of each
approximated joint (largest effect, one coordinate at a time, the bound).

    PYTHONPATH=. python scripts/bench_import.py MODEL.osim [--marker-set FILE.xml] [--poses N] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

POSES = 100  # random poses

# Child: {"jobs": [{"osim", "marker_set", "poses": [{coordinate: value}], "bodies": [name]}]} -> per job, per pose:
# marker -> xyz in ground, and "body NAME" -> its pose in ground (R row-major, p).  Coupled (dependent) coordinates
# are set from their CoordinateCouplerConstraint's function.  (tests/test_osim_import.py's reference too.)
MARKERS_WORKER = r"""
import json, sys
import opensim as osim
osim.Logger.removeFileSink()
osim.Logger.setLevelString("error")
out = []
for job in json.load(open(sys.argv[1]))["jobs"]:
    model = osim.Model(job["osim"])
    if job.get("marker_set"):
        model.updateMarkerSet(osim.MarkerSet(job["marker_set"]))
    state = model.initSystem()
    cs = model.getCoordinateSet()
    couplers = []
    for i in range(model.getConstraintSet().getSize()):
        c = osim.CoordinateCouplerConstraint.safeDownCast(model.getConstraintSet().get(i))
        if c is not None:
            names = c.getIndependentCoordinateNames()
            couplers.append((c.getDependentCoordinateName(), names.get(0), c.getFunction(),
                             osim.PropertyHelper.getValueDouble(c.getPropertyByName("scale_factor"))))
    for i in range(cs.getSize()):  # a locked coordinate keeps its value in setValue
        cs.get(i).setLocked(state, False)
    poses = []
    for pose in job["poses"]:
        for name, value in pose.items():
            cs.get(name).setValue(state, value, False)
        for dep, ind, f, s in couplers:
            v = osim.Vector(1, cs.get(ind).getValue(state))
            cs.get(dep).setValue(state, s * f.calcValue(v), False)
        model.realizePosition(state)
        ms = model.getMarkerSet()
        res = {ms.get(i).getName(): ms.get(i).getLocationInGround(state).to_numpy().tolist()
               for i in range(ms.getSize())}
        for b in job["bodies"]:  # pose of a body in ground: R (row-major 9), p (3)
            X = model.getBodySet().get(b).getTransformInGround(state)
            R = X.R().asMat33()
            res["body " + b] = [R.get(i, j) for i in range(3) for j in range(3)] + X.p().to_numpy().tolist()
        poses.append(res)
    out.append(poses)
json.dump(out, open(sys.argv[2], "w"))
"""


def import_check(osim: Path, log, marker_set: Path | None = None, poses_n: int = POSES, seed: int = 1) -> dict:
    """Markers of the imported model (Pinocchio, each coordinate times its ratio) against OpenSim's at `poses_n`
    random poses (every coordinate uniform over its range, within one turn): per marker the mean and largest
    distance (mm), and each approximation's reported figures."""
    import pinocchio as pin
    from scipy.spatial.transform import Rotation

    from calibrate.io.osim_info import osim_info, root_coordinates
    from calibrate.io.osim_read import parse_xml
    from calibrate.model.model import load_model

    model = load_model(osim, marker_set)
    info = osim_info(model)
    ranges = {}
    for c in parse_xml(osim.read_text()).iter("Coordinate"):  # (as the import reads it: C++ scoped tags too)
        lo, hi = (float(v) for v in c.findtext("range", "0 0").split())
        ranges[c.get("name")] = (max(lo, -np.pi), min(hi, np.pi))
    rng = np.random.default_rng(seed)
    poses, roots = [], []
    for k in range(poses_n):
        coords = {d: float(rng.uniform(*ranges[d])) for d in model.dof_names}
        t, quat = rng.normal(0, 0.5, 3), Rotation.random(random_state=seed * 1000 + k).as_quat()
        if info.root is not None:
            coords.update({n: float(v[0]) for n, v in root_coordinates(info, t[None], quat[None]).items()})
        poses.append(coords)
        roots.append((t, quat))
    # A ground joint that is not six coordinates (a weld: Arm26's base; a planar joint: Gait10dof18musc's pelvis) is
    # the import's floating base: there the root segment is put where OpenSim's default pose puts its body, and the
    # markers compared below it.
    bodies = [] if info.root is not None else [model.root]
    with tempfile.TemporaryDirectory(prefix="bench_import_") as tmp:
        spec, result = Path(tmp) / "poses.json", Path(tmp) / "out.json"
        spec.write_text(json.dumps({"jobs": [{"osim": str(osim), "marker_set": str(marker_set) if marker_set else None,
                                              "poses": poses, "bodies": bodies}]}))
        log(f"{osim.name}: OpenSim's markers at {poses_n} random poses (child process) ...")
        proc = subprocess.run([sys.executable, "-c", MARKERS_WORKER, str(spec), str(result)], capture_output=True,
                              text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"OpenSim child failed:\n{proc.stderr[-2000:]}")
        theirs = json.loads(result.read_text())[0]
    pm = model.pin
    data = pm.createData()
    ours = []
    for coords, (t, quat), o in zip(poses, roots, theirs, strict=True):
        if bodies:
            X = np.array(o["body " + model.root])
            t, quat = X[9:], Rotation.from_matrix(X[:9].reshape(3, 3)).as_quat()
        angles = np.array([info.urdf_angle(d, coords) for d in model.dof_names])  # the URDF's angles
        pin.framesForwardKinematics(pm, data, model.pin_configuration(t, quat, angles))
        ours.append({m: data.oMf[pm.getFrameId(m, pin.FrameType.BODY)].translation.copy() for m in model.marker_names})
    err = {m: np.array([np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(theirs, ours, strict=True)])
           for m in model.marker_names}
    return {"model": str(osim), "poses": poses_n, "dofs": model.n_dofs,
            "markers_mm": {m: {"mean": 1e3 * float(e.mean()), "max": 1e3 * float(e.max())} for m, e in err.items()},
            "approximations": [{"joint": a.joint, "kind": a.kind, "ratios": {c: info.ratio(c) for c in a.coordinates
                                                                             if c in info.ratios},
                                "max_marker_mm": a.max_marker_mm, "one_coordinate_mm": a.one_mm,
                                "bound_mm": a.bound_mm, "markers": list(a.markers)}
                               for a in info.approximations if a.markers],
            # the approximations' joint effect on the markers below two or more, as the import measured it
            "together": None if info.together is None else {
                "max_marker_mm": info.together.max_marker_mm, "marker": info.together.marker,
                "mean_mm": info.together.mean_mm, "poses": info.together.poses}}


def report(res: dict) -> None:
    """One line per approximated joint: what the import reported and what OpenSim shows."""
    ms = res["markers_mm"]
    print(f"{Path(res['model']).name}: {res['dofs']} DoF; {res['poses']} random poses against OpenSim")
    exact = [m for m in ms if not any(m in a["markers"] for a in res["approximations"])]
    if exact:
        print(f"  markers not below an approximation: largest {max(ms[m]['max'] for m in exact):.3g} mm")
    t = res.get("together")
    if t:
        below: dict[str, int] = {}
        for a in res["approximations"]:
            for m in a["markers"]:
                below[m] = below.get(m, 0) + 1
        stacked = [m for m, k in below.items() if k >= 2]
        print(f"  all approximations together: reported {t['max_marker_mm']:.1f} mm ({t['marker']}, {t['poses']} "
              f"poses); against OpenSim, markers below two or more: largest "
              f"{max(ms[m]['max'] for m in stacked):.1f} mm")
    for a in res["approximations"]:
        rows = a["markers"]
        one = f", one coordinate at a time {a['one_coordinate_mm']:.1f}" if a["one_coordinate_mm"] is not None else ""
        ratios = (" (ratios " + ", ".join(f"{c} {g:.3g}" for c, g in a["ratios"].items()) + ")") if a["ratios"] else ""
        print(f"  {a['joint']}: {a['kind']}{ratios}; reported {a['max_marker_mm']:.1f} mm{one}, bound "
              f"{a['bound_mm']:.1f}; against OpenSim: mean {min(ms[m]['mean'] for m in rows):.1f}-"
              f"{max(ms[m]['mean'] for m in rows):.1f} mm, largest {max(ms[m]['max'] for m in rows):.1f} mm")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=Path, help="an OpenSim model (.osim)")
    ap.add_argument("--marker-set", type=Path, default=None, help="an OpenSim MarkerSet file for it")
    ap.add_argument("--poses", type=int, default=POSES, help=f"random poses (default {POSES})")
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    a = ap.parse_args()
    res = import_check(a.model, lambda m: print(m, file=sys.stderr), a.marker_set, a.poses)
    report(res)
    if a.json is not None:
        a.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
