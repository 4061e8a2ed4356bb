"""OpenSim models as base models (calibrate.io.osim): marker positions of the imported model, by Pinocchio,
equal OpenSim's own (the `opensim` package in a child process) to 1e-6 m where the import is exact, and
stay within the reported bound where it approximates; Gait2392, Rajagopal 2016 and a hand-made model
with every joint and function type; bad input; the CLI.

OpenSim runs in a child process (see tests/test_opensim_export.py): one child for every model at once.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from calibrate.cli import main
from calibrate.errors import ModelError
from calibrate.io.osim_info import osim_info, root_coordinates
from calibrate.model.model import load_model

HAVE_OPENSIM = importlib.util.find_spec("opensim") is not None
REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
GAIT = REAL / "gait2392" / "gait2392.osim"
GAIT_MARKERS = REAL / "gait2392" / "gait2392_Scale_MarkerSet.xml"
RAJAGOPAL = REAL / "rajagopal_walk" / "Rajagopal2016.osim"
TOL = 1e-6  # m
N_POSES = 100

# OpenSim's markers (and bodies) at poses, in a child process: scripts/bench_import.py's worker.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from bench_import import MARKERS_WORKER as _WORKER  # noqa: E402

# A hand-made model: a FreeJoint root, Ball, Gimbal, Pin, Universal, Weld and CustomJoints with every function
# type read (Constant, LinearFunction with slope -1 and an intercept, PolynomialFunction (linear: exact; quadratic),
# SimmSpline, NaturalCubicSpline, PiecewiseLinearFunction, MultiplierFunction), offset frames that turn and
# translate (child side too), a coupled body and a coordinate-driven translation.
_BODY = """<Body name="{name}"><mass>{mass}</mass><mass_center>0.01 -0.1 0.02</mass_center>
<inertia>0.1 0.12 0.05 0.001 -0.002 0.003</inertia></Body>"""


def _frames(parent: str, child: str, pt: str, po: str, ct: str = "0 0 0", co: str = "0 0 0") -> str:
    return (f"<frames><PhysicalOffsetFrame name=\"{parent}_off\"><socket_parent>/bodyset/{parent}</socket_parent>"
            f"<translation>{pt}</translation><orientation>{po}</orientation></PhysicalOffsetFrame>"
            f"<PhysicalOffsetFrame name=\"{child}_off\"><socket_parent>/bodyset/{child}</socket_parent>"
            f"<translation>{ct}</translation><orientation>{co}</orientation></PhysicalOffsetFrame></frames>"
            f"<socket_parent_frame>{parent}_off</socket_parent_frame><socket_child_frame>{child}_off"
            f"</socket_child_frame>").replace("/bodyset/ground", "/ground")


def _coords(*items: tuple[str, float, float]) -> str:
    return "<coordinates>" + "".join(
        f"<Coordinate name=\"{n}\"><default_value>0</default_value><range>{lo} {hi}</range><clamped>true</clamped>"
        f"<locked>false</locked></Coordinate>" for n, lo, hi in items) + "</coordinates>"


def ground_free(child: str, translation: str = "0 0.9 0", orientation: str = "0 0 0", prefix: str = "p") -> str:
    """A FreeJoint from ground to `child`, its six coordinates `prefix`_rx ... `prefix`_tz."""
    return (f"<FreeJoint name=\"ground_{child}\">{_frames('ground', child, translation, orientation)}"
            + _coords((f"{prefix}_rx", -3, 3), (f"{prefix}_ry", -1.4, 1.4), (f"{prefix}_rz", -3, 3),
                      (f"{prefix}_tx", -2, 2), (f"{prefix}_ty", -2, 2), (f"{prefix}_tz", -2, 2)) + "</FreeJoint>")


def _ta(name: str, axis: str, coord: str, func: str) -> str:
    return (f"<TransformAxis name=\"{name}\"><coordinates>{coord}</coordinates><axis>{axis}</axis>{func}"
            f"</TransformAxis>")


def _c(v: float = 0) -> str:
    return f"<Constant name=\"function\"><value>{v}</value></Constant>"


def _lin(a: float = 1, b: float = 0) -> str:
    return f"<LinearFunction name=\"function\"><coefficients>{a} {b}</coefficients></LinearFunction>"


def _xy(tag: str, x: str, y: str) -> str:
    return f"<{tag} name=\"function\"><x>{x}</x><y>{y}</y></{tag}>"


def hand_made_osim() -> str:
    bodies = "".join(_BODY.format(name=n, mass=m) for n, m in
                     [("pelvis", 10), ("thigh", 7), ("shank", 3), ("foot", 1), ("toes", 0.3), ("arm", 2),
                      ("hand", 0.5), ("cap", 0.1), ("patella", 0.05), ("slider", 0.2), ("wrist", 0.3),
                      ("sled", 0.2), ("flap", 0.2)])
    site = ("<components><PhysicalOffsetFrame name=\"cap_site\"><socket_parent>/bodyset/cap</socket_parent>"
            "<translation>0.02 -0.03 0.04</translation><orientation>0.4 -0.2 0.9</orientation>"
            "</PhysicalOffsetFrame></components></Body>")
    bodies = bodies.replace("</Body>", site, 8).replace(site, "</Body>", 7)  # the 8th body, cap, has a frame
    joints = [
        ground_free("pelvis", "0.1 0.2 0.3", "0.1 0 0.2"),
        "<BallJoint name=\"hip\">"
        + _frames('pelvis', 'thigh', '-0.05 -0.08 0.09', '0.2 -0.1 0.3', '0.01 0.02 -0.03', '0.1 0.2 0') +
        f"{_coords(('hip_x', -1, 1), ('hip_y', -1, 1), ('hip_z', -1, 1))}</BallJoint>",
        # the knee: rotation -q + 0.1 about a tilted axis, a constant rotation, spline translations (approximated)
        f"<CustomJoint name=\"knee\">{_frames('thigh', 'shank', '0 -0.4 0', '0 0 0.1')}{_coords(('knee_q', -2, 0.2))}"
        "<SpatialTransform>"
        + _ta("rotation1", "0.1 0 1", "knee_q", _lin(-1, 0.1))
        + _ta("rotation2", "0 1 0", "knee_q", "<PolynomialFunction name=\"function\"><coefficients>0.03 -0.02 0.2"
              "</coefficients></PolynomialFunction>")
        + _ta("rotation3", "1 0 0", "", _c())
        + _ta("translation1", "1 0 0", "knee_q",
              _xy("SimmSpline", "-2 -1.2 -0.5 0 0.2", "-0.003 0.002 0.004 -0.003 -0.005"))
        + _ta("translation2", "0 1 0", "knee_q",
              "<MultiplierFunction name=\"function\"><function>"
              + _xy("NaturalCubicSpline", "-2 -1 0 0.2", "-0.42 -0.40 -0.396 -0.396")
              + "</function><scale>1.1</scale></MultiplierFunction>")
        + _ta("translation3", "0 0 1", "", _c(0.002)) + "</SpatialTransform></CustomJoint>",
        "<PinJoint name=\"ankle\">"
        + _frames('shank', 'foot', '-0.01 -0.4 0', '0.17 -0.1 0.02', '0 0.01 0', '0.17 -0.1 0.02') +
        f"{_coords(('ankle_q', -0.7, 0.5))}</PinJoint>",
        f"<UniversalJoint name=\"mtp\">{_frames('foot', 'toes', '0.18 -0.002 0.001', '-0.3 0.6 0')}"
        f"{_coords(('mtp_x', -0.5, 0.5), ('mtp_y', -0.5, 0.5))}</UniversalJoint>",
        f"<GimbalJoint name=\"shoulder\">{_frames('pelvis', 'arm', '0 0.4 0.17', '0 0 0.3')}"
        f"{_coords(('sh_x', -1.5, 1.5), ('sh_y', -1.5, 1.5), ('sh_z', -1.5, 1.5))}</GimbalJoint>",
        # an exact CustomJoint of two coordinates: slope -1 with an intercept, a Multiplier of a linear function
        f"<CustomJoint name=\"elbow\">{_frames('arm', 'hand', '0.01 -0.29 -0.01', '-0.02 0.23 0.005')}"
        f"{_coords(('el_flex', 0, 2.6), ('el_pro', -1, 1))}<SpatialTransform>"
        + _ta("rotation1", "0 0 1", "el_flex", "<PolynomialFunction name=\"function\"><coefficients>0 -1 0.05"
              "</coefficients></PolynomialFunction>") + _ta("rotation2", "0 1 0", "", _c(0.1))
        + _ta("rotation3", "0.2 1 0", "el_pro",
              "<MultiplierFunction name=\"function\"><function>" + _lin(-1, 0).replace(' name="function"', "")
              + "</function><scale>1</scale></MultiplierFunction>")
        + _ta("translation1", "1 0 0", "", _c(0.01)) + _ta("translation2", "0 1 0", "", _c())
        + _ta("translation3", "0 0 1", "", _c()) + "</SpatialTransform></CustomJoint>",
        f"<WeldJoint name=\"cap_weld\">{_frames('pelvis', 'cap', '0.1 0.1 0', '0.3 0.2 0.1')}</WeldJoint>",
        # a body whose coordinate is coupled to the knee's (welded at mid-range)
        f"<CustomJoint name=\"patfem\">{_frames('thigh', 'patella', '0.02 -0.38 0', '0 0 0')}"
        f"{_coords(('knee_beta', -99999, 99999))}<SpatialTransform>"
        + _ta("rotation1", "0 0 1", "knee_beta", _lin(0.5, 0)) + _ta("rotation2", "0 1 0", "", _c())
        + _ta("rotation3", "1 0 0", "", _c())
        + _ta("translation1", "1 0 0", "knee_beta", _xy("SimmSpline", "-2 -1 0 0.2", "0.05 0.04 0.03 0.03"))
        + _ta("translation2", "0 1 0", "", _c()) + _ta("translation3", "0 0 1", "", _c())
        + "</SpatialTransform></CustomJoint>",
        # a coordinate that translates (frozen at mid-range)
        f"<CustomJoint name=\"slide\">{_frames('pelvis', 'slider', '0 0 -0.1', '0 0 0')}"
        f"{_coords(('slide_t', -0.02, 0.02))}<SpatialTransform>"
        + _ta("rotation1", "0 0 1", "", _c()) + _ta("rotation2", "0 1 0", "", _c())
        + _ta("rotation3", "1 0 0", "", _c())
        + _ta("translation1", "1 0 0", "slide_t", _lin()) + _ta("translation2", "0 1 0", "", _c())
        + _ta("translation3", "0 0 1", "", _c()) + "</SpatialTransform></CustomJoint>",
        # a SliderJoint (frozen) and a PlanarJoint (its rotation exact, its translations frozen)
        f"<SliderJoint name=\"sledj\">{_frames('pelvis', 'sled', '0.05 0 -0.1', '0.3 0.2 0.1')}"
        f"{_coords(('sled_t', -0.03, 0.01))}</SliderJoint>",
        f"<PlanarJoint name=\"flapj\">{_frames('pelvis', 'flap', '-0.1 0.1 0', '0 0.4 0')}"
        f"{_coords(('flap_r', -1, 1), ('flap_x', -0.02, 0.02), ('flap_y', -0.01, 0.03))}</PlanarJoint>",
        # two coordinates, one through a piecewise-linear function (frozen), one exact
        f"<CustomJoint name=\"wristj\">{_frames('hand', 'wrist', '0 -0.08 0', '0 0 0')}"
        f"{_coords(('wr_a', -1, 1), ('wr_b', -0.3, 0.3))}<SpatialTransform>"
        + _ta("rotation1", "0 0 1", "wr_a", _lin()) + _ta("rotation2", "1 0 0", "wr_b",
                                                          _xy("PiecewiseLinearFunction", "-0.3 0 0.3", "-0.1 0 0.2"))
        + _ta("rotation3", "0 1 0", "", _c()) + _ta("translation1", "1 0 0", "", _c())
        + _ta("translation2", "0 1 0", "", _c()) + _ta("translation3", "0 0 1", "", _c())
        + "</SpatialTransform></CustomJoint>",
    ]
    marker_bodies = ["pelvis", "pelvis", "pelvis", "thigh", "thigh", "shank", "shank", "foot", "foot", "toes", "arm",
                     "hand", "hand", "cap", "slider", "wrist", "patella", "sled", "flap", "flap"]
    rng = np.random.default_rng(3)
    markers = "".join(
        f"<Marker name=\"M{k}_{b}\"><socket_parent_frame>/bodyset/{b}</socket_parent_frame>"
        f"<location>{' '.join(f'{v:.4f}' for v in rng.uniform(-0.1, 0.1, 3))}</location><fixed>false</fixed></Marker>"
        for k, b in enumerate(marker_bodies))
    markers += ("<Marker name=\"SITE\"><socket_parent_frame>/bodyset/cap/cap_site</socket_parent_frame>"
                "<location>0.01 0.05 -0.02</location></Marker>")  # on an offset frame of a body
    coupler = ("<CoordinateCouplerConstraint name=\"pat_con\"><isEnforced>true</isEnforced>"
               "<coupled_coordinates_function>" + _lin(1, 0).replace(' name="function"', "")
               + "</coupled_coordinates_function><independent_coordinate_names>knee_q</independent_coordinate_names>"
               "<dependent_coordinate_name>knee_beta</dependent_coordinate_name><scale_factor>1</scale_factor>"
               "</CoordinateCouplerConstraint>")
    return ("<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40000\"><Model name=\"handmade\">"
            "<Ground name=\"ground\"/><gravity>0 -9.80665 0</gravity>"
            f"<BodySet name=\"bodyset\"><objects>{bodies}</objects></BodySet>"
            f"<JointSet name=\"jointset\"><objects>{''.join(joints)}</objects></JointSet>"
            f"<ConstraintSet name=\"constraintset\"><objects>{coupler}</objects></ConstraintSet>"
            f"<MarkerSet name=\"markerset\"><objects>{markers}</objects></MarkerSet></Model></OpenSimDocument>\n")


# ---------------------------------------------------------------------- the references
def _pin_markers(model, root_t, root_q, angles) -> dict[str, np.ndarray]:
    """Markers in the lab by Pinocchio, and ('body S') every segment frame's pose (R row-major, p)."""
    pm = model.pin
    d = pm.createData()
    pin.framesForwardKinematics(pm, d, model.pin_configuration(root_t, root_q, angles))
    out = {m: d.oMf[pm.getFrameId(m, pin.FrameType.BODY)].translation.copy() for m in model.marker_names}
    for s in model.segments:
        X = d.oMf[pm.getFrameId(s.name, pin.FrameType.BODY)]
        out["body " + s.name] = np.concatenate([X.rotation.ravel(), X.translation])
    return out


def _cases(model, n: int, seed: int, ranges: dict[str, tuple[float, float]]) -> tuple[list[dict], list[dict]]:
    """n random poses: OpenSim coordinates (every coordinate, within its range) and Pinocchio's markers."""
    rng = np.random.default_rng(seed)
    info = osim_info(model)
    jobs, refs = [], []
    for k in range(n):
        t = rng.normal(0, 0.5, 3)
        quat = Rotation.random(random_state=seed * 1000 + k).as_quat()
        coords = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in ranges.items()}
        angles = np.array([info.ratio(d) * coords[d] for d in model.dof_names])  # the URDF's angle
        root = root_coordinates(info, t[None], quat[None])
        coords.update({name: float(v[0]) for name, v in root.items()})
        jobs.append(coords)
        refs.append(_pin_markers(model, t, quat, angles))
    return jobs, refs


def _ranges(path: Path) -> dict[str, tuple[float, float]]:
    """Every non-root coordinate's range, from the .osim (independent of calibrate.io.osim), within one turn."""
    import xml.etree.ElementTree as ET

    out = {}
    for j in ET.parse(path).getroot().iter():
        if j.tag.endswith("Joint") and j.find("coordinates") is not None:
            parent = j.findtext("socket_parent_frame", "")
            frames = {f.get("name"): f.findtext("socket_parent", "") for f in j.iter("PhysicalOffsetFrame")}
            if frames.get(parent, parent).strip().endswith("ground"):
                continue
            for c in j.iter("Coordinate"):
                lo, hi = (float(v) for v in c.findtext("range").split())
                out[c.get("name")] = (max(lo, -np.pi), min(hi, np.pi))
    return out


@pytest.fixture(scope="module")
def equivalence(tmp_path_factory):
    """One OpenSim child for the three models; per model: the Model, Pinocchio's markers, OpenSim's."""
    if not HAVE_OPENSIM:
        pytest.skip("opensim is not installed (pip install -e '.[opensim]'; .ci/run installs it)")
    tmp = tmp_path_factory.mktemp("osim_import")
    hand = tmp / "handmade.osim"
    hand.write_text(hand_made_osim())
    cases = {"handmade": (hand, None)}
    if GAIT.exists():
        cases["gait2392"] = (GAIT, GAIT_MARKERS)
    if RAJAGOPAL.exists():
        cases["rajagopal"] = (RAJAGOPAL, None)
    out, jobs = {}, []
    for seed, (name, (path, ms)) in enumerate(cases.items()):
        model = load_model(path, ms)
        coupled = {c for a in osim_info(model).approximations if a.kind == "welded (coupled)" for c in a.coordinates}
        poses, refs = _cases(model, N_POSES, seed + 1, {k: v for k, v in _ranges(path).items() if k not in coupled})
        out[name] = {"model": model, "refs": refs}
        children = sorted({model.joints[model.joint_index(a.joint)].child for a in osim_info(model).approximations})
        jobs.append({"osim": str(path), "marker_set": str(ms) if ms else None, "poses": poses, "bodies": children})
    spec, result = tmp / "jobs.json", tmp / "result.json"
    spec.write_text(json.dumps({"jobs": jobs}))
    proc = subprocess.run([sys.executable, "-c", _WORKER, str(spec), str(result)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"OpenSim worker failed:\n{proc.stderr[-3000:]}"
    for name, poses in zip(out, json.loads(result.read_text()), strict=True):
        out[name]["osim"] = poses
    return out


def _kabsch_residual(a: np.ndarray, b: np.ndarray) -> float:
    """Largest distance left after the best rigid motion taking points a (n, 3) onto b."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((a - ca).T @ (b - cb))
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return float(np.linalg.norm((a - ca) @ R.T + cb - b, axis=1).max())


def _local(pose: list[float] | np.ndarray, x) -> np.ndarray:
    R, p = np.asarray(pose[:9]).reshape(3, 3), np.asarray(pose[9:])
    return R.T @ (np.asarray(x) - p)


def _errors(case: dict) -> dict[str, np.ndarray]:
    """marker -> |Pinocchio - OpenSim| (m) over the poses."""
    names = case["model"].marker_names
    return {m: np.array([np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(case["osim"], case["refs"],
                                                                                  strict=True)]) for m in names}


@pytest.mark.parametrize("name", ["handmade", "gait2392", "rajagopal"])
def test_markers_equal_opensim(equivalence, name):
    if name not in equivalence:
        pytest.skip(f"{name}: the real model is not in ../shared/data/real")
    case = equivalence[name]
    model = case["model"]
    info = osim_info(model)
    err = _errors(case)
    assert {k for k in case["osim"][0] if not k.startswith("body ")} == set(model.marker_names)
    approximated = {m for a in info.approximations for m in a.markers}
    exact = [m for m in model.marker_names if m not in approximated]
    assert exact, "some markers are exact"
    worst_exact = max(err[m].max() for m in exact)
    assert worst_exact < TOL, f"{name}: exact markers off by {worst_exact:.3g} m"
    for m in approximated:  # within the sum of the bounds of the approximated joints above the marker
        bound = sum(a.bound_mm for a in info.approximations if m in a.markers) / 1000
        assert err[m].max() <= bound + TOL, f"{name}: {m} off by {err[m].max():.4g} m > bound {bound:.4g} m"
    # Below an approximated joint the rest is exact: in its child body's frame (OpenSim) and child segment's
    # frame (calibrate), the markers below differ by one rigid motion, the same in every pose.
    for a in info.approximations:
        deepest = [m for m in a.markers if min((len(b.markers), b.joint) for b in info.approximations
                                               if m in b.markers) == (len(a.markers), a.joint)]
        if not deepest:
            continue
        child = model.joints[model.joint_index(a.joint)].child
        ours = np.array([_local(r["body " + child], r[m]) for r in case["refs"] for m in deepest])
        theirs = np.array([_local(o["body " + child], o[m]) for o in case["osim"] for m in deepest])
        assert _kabsch_residual(ours, theirs) < TOL, f"{name}: markers below {a.joint} are not exact relative to it"
    print(f"{name}: exact markers within {worst_exact:.2g} m; approximated: " + ", ".join(
        f"{a.joint} {1000 * max(err[m].max() for m in a.markers) if a.markers else 0:.2f} mm (bound {a.bound_mm:.2f})"
        for a in info.approximations))
    if name == "handmade":
        kinds = {a.joint: a.kind for a in info.approximations}
        assert kinds == {"knee": "hinge fit", "patfem": "welded (coupled)", "slide": "frozen", "wristj": "joint fit",
                         "sledj": "frozen", "flapj": "frozen"}
        assert max(err[m].max() for m in approximated) > 1e-4  # the approximations do change markers


def test_structure_and_names():
    if not GAIT.exists():
        pytest.skip("gait2392 is not in ../shared/data/real")
    m = load_model(GAIT, GAIT_MARKERS)
    assert m.n_dofs == 17 and m.root == "pelvis" and len(m.markers) == 39
    assert {j.name for j in m.joints} == {"hip_r", "knee_r", "ankle_r", "subtalar_r", "mtp_r", "hip_l", "knee_l",
                                          "ankle_l", "subtalar_l", "mtp_l", "back"}
    assert m.joints[m.joint_index("hip_r")].dofs == ("hip_flexion_r", "hip_adduction_r", "hip_rotation_r")
    knee = m.dofs[m.dof_index("knee_angle_r")]
    assert (knee.lower, knee.upper) == (pytest.approx(-2.0943951), pytest.approx(0.17453293))
    info = osim_info(m)
    assert [a.joint for a in info.approximations] == ["knee_l", "knee_r"] or \
        sorted(a.joint for a in info.approximations) == ["knee_l", "knee_r"]
    assert all(0.5 < a.max_marker_mm < 10 for a in info.approximations)
    assert info.root is not None and [c for c, _ in info.root.rotations] == ["pelvis_tilt", "pelvis_list",
                                                                            "pelvis_rotation"]


@pytest.mark.skipif(not RAJAGOPAL.exists(), reason="Rajagopal2016 is not in ../shared/data/real")
def test_rajagopal_locked_and_coupled():
    m = load_model(RAJAGOPAL)
    info = osim_info(m)
    assert set(info.locked) == {"subtalar_angle_r", "subtalar_angle_l", "mtp_angle_r", "mtp_angle_l", "wrist_flex_r",
                                "wrist_flex_l", "wrist_dev_r", "wrist_dev_l"}
    assert set(info.dropped) == {"knee_angle_r_beta", "knee_angle_l_beta"}
    assert {a.joint: a.kind for a in info.approximations} == {
        "walker_knee_r": "hinge fit", "walker_knee_l": "hinge fit", "patellofemoral_r": "welded (coupled)",
        "patellofemoral_l": "welded (coupled)"}
    # segment frames are the bodies' frames where the child offset frame does not translate: the markers
    # keep the .osim's numbers (the Rajagopal knee's child offset translates: the tibia's shift)
    import xml.etree.ElementTree as ET

    doc = ET.parse(RAJAGOPAL).getroot()
    shifted = set()
    for j in doc.find("Model/JointSet/objects"):
        child = j.findtext("socket_child_frame")
        for f in j.iter("PhysicalOffsetFrame"):
            if f.get("name") == child and np.any(np.array(f.findtext("translation").split(), float) != 0):
                shifted.add(f.findtext("socket_parent").split("/")[-1])
    assert shifted == {"tibia_r", "tibia_l"}
    same = 0
    for mk in doc.iter("Marker"):
        body = mk.findtext("socket_parent_frame").split("/")[-1]
        seg = m.markers[m.marker_index(mk.get("name"))]
        assert seg.segment == body
        if body not in shifted:
            np.testing.assert_allclose(seg.offset, np.array(mk.findtext("location").split(), float), atol=1e-12)
            same += 1
    assert same > 40
    from calibrate.io.osim_info import with_locked
    from calibrate.problem.settings import Settings

    s = with_locked(m, Settings(lock={"mtp_angle_r": 0.1}))
    assert dict(s.lock)["mtp_angle_r"] == 0.1 and dict(s.lock)["subtalar_angle_l"] == 0.0


# ---------------------------------------------------------------------- bad input and the CLI
def _bad(tmp_path: Path, text: str, name: str = "bad.osim") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("mutate, needle", [
    (lambda t: "hello, not xml", "not valid XML"),
    (lambda t: "<?xml version='1.0'?><robot name='x'/>", "not an OpenSimDocument"),
    (lambda t: t.replace('Version="40000"', 'Version="20302"'), "OpenSim 3.x model (Version 20302); open it in "
     "OpenSim 4 and save it (File > Save Model) to convert it to the 4.x format, or with OpenSim's Python package: "
     "python -c \"import opensim; opensim.Model('OLD.osim').printToXML('NEW.osim')\""),
    # OpenSim 4.0's pre-release format: a joint's parent named by a connector (opensim-models' double_pendulum)
    (lambda t: re.sub(r"<socket_parent_frame>([^<]*)</socket_parent_frame>",
                      r'<connectors><Connector_PhysicalFrame_ name="parent_body"><connectee_name>\1</connectee_name>'
                      r"</Connector_PhysicalFrame_></connectors>", t.replace('Version="40000"', 'Version="30501"'),
                      count=1), "OpenSim 4.0 pre-release model (Version 30501"),
    (lambda t: t.replace("<PinJoint name=\"ankle\">", "<EllipsoidJoint name=\"ankle\">").replace(
        "</PinJoint>", "</EllipsoidJoint>"), "joint type EllipsoidJoint is not read"),
    (lambda t: t.replace("PiecewiseLinearFunction", "StepFunction"), "function type StepFunction is not read"),
    (lambda t: t.replace("<socket_parent_frame>/bodyset/cap</socket_parent_frame>",
                         "<socket_parent_frame>/bodyset/nobody</socket_parent_frame>"), "which handmade.osim does not"),
    # a number field that holds no finite numbers, or too few: named, not a Python traceback (found by fuzzing)
    (lambda t: t.replace("<range>-1.4 1.4</range>", "<range>1.4</range>", 1), "<range> is '1.4', not 2 finite"),
    (lambda t: t.replace("<range>-1.4 1.4</range>", "<range>1e999 1.4</range>", 1), "<range> is '1e999 1.4'"),
    (lambda t: t.replace("<translation>0.1 0.2 0.3</translation>", "<translation>0.1 x 0.3</translation>", 1),
     "<translation> is '0.1 x 0.3', not finite numbers"),
    (lambda t: t.replace("<axis>0 1 0</axis>", "<axis>false</axis>", 1), "<axis> is 'false'"),
    (lambda t: t.replace("<mass>7</mass>", "<mass>seven</mass>", 1), "<mass> is 'seven', not a finite number"),
    (lambda t: re.sub(r"<gravity>[^<]*</gravity>", "<gravity>0 -9.8</gravity>", t, count=1),
     "<gravity> is '0 -9.8', not 3 finite numbers"),
    (lambda t: t.replace("<mass>7</mass>", "<mass>7_0</mass>", 1), "<mass> is '7_0'"),  # Python's float() takes it
    (lambda t: t.replace("<coefficients>-1 0.1</coefficients>", "<coefficients>-1 nan</coefficients>", 1),
     "<coefficients> is '-1 nan'"),
])
def test_bad_model_one_line_exit_2_nothing_written(tmp_path, capsys, mutate, needle):
    good = hand_made_osim()
    bad = _bad(tmp_path, mutate(good), "handmade.osim")
    with pytest.raises(ModelError) as e:
        load_model(bad)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg and ";" in msg and str(bad) in msg
    assert main(["import-osim", str(bad), "-o", str(tmp_path / "out.urdf")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("calibrate: error: ") and err.count("\n") == 1
    for argv in (["inspect", str(bad)], [str(tmp_path / "walk.trc"), str(bad), "-q"]):  # the same one line
        assert main(argv) == 2
        assert capsys.readouterr().err == err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["handmade.osim"]  # nothing written


def test_marker_set_unknown_body(tmp_path, capsys):
    osim = _bad(tmp_path, hand_made_osim(), "m.osim")
    ms = _bad(tmp_path, "<?xml version='1.0'?><OpenSimDocument Version='20302'><MarkerSet><objects>"
                        "<Marker name='X'><body> femur </body><location>0 0 0</location></Marker>"
                        "</objects></MarkerSet></OpenSimDocument>", "ms.xml")
    with pytest.raises(ModelError, match="ms.xml: marker 'X' is on body 'femur'"):
        load_model(osim, ms)
    assert main(["import-osim", str(osim), "--marker-set", str(ms), "-o", str(tmp_path / "o.urdf")]) == 2
    assert "femur" in capsys.readouterr().err and not (tmp_path / "o.urdf").exists()


def test_marker_set_bad_number(tmp_path, capsys):
    osim = _bad(tmp_path, hand_made_osim(), "m.osim")
    ms = _bad(tmp_path, "<?xml version='1.0'?><OpenSimDocument Version='40000'><MarkerSet><objects>"
                        "<Marker name='X'><socket_parent_frame>/bodyset/cap</socket_parent_frame>"
                        "<location>0 0,1 0</location></Marker></objects></MarkerSet></OpenSimDocument>", "ms.xml")
    with pytest.raises(ModelError, match=r"ms.xml: <Marker name='X'>'s <location> is '0 0,1 0', not finite numbers; "
                                         "fix the number in the marker set file"):
        load_model(osim, ms)
    assert main(["import-osim", str(osim), "--marker-set", str(ms), "-o", str(tmp_path / "o.urdf")]) == 2
    assert capsys.readouterr().err.count("\n") == 1 and not (tmp_path / "o.urdf").exists()


def test_labels_an_osim_model_leaves_out_point_to_its_marker_set(tmp_path, capsys):
    """A trial label that rides on no segment of an OpenSim base model given without --marker-set: the warning names
    the lab's MarkerSet file as the way to place such labels (gait2392's walk on Rajagopal2016.osim left its 17
    thigh, shank and sacrum labels out, the hips 351 mm apart); with a marker set given, it does not."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.osim_export import export_osim
    from calibrate.io.trial import Trial
    from calibrate.simulation.simulate import simulate_squats

    human = load_model(Path(__file__).resolve().parent.parent / "models" / "human.urdf")
    sim = simulate_squats(human, frames=80, noise_mm=1.0, seed=4)
    # a random walk of its own beside the pelvis: on no segment
    walk = np.cumsum(np.random.default_rng(0).normal(0.0, 0.01, (sim.trial.n_frames, 3)), axis=0)
    loose = sim.clean_markers[:, sim.trial.labels.index("RASI")] + [0.0, 0.3, 0.0] + walk
    write_c3d(tmp_path / "squat.c3d", Trial(sim.trial.labels + ("LOOSE",),
                                            np.concatenate([sim.trial.markers, loose[:, None]], axis=1),
                                            sim.trial.rate))
    osim = export_osim(human, tmp_path / "human.osim")
    ms = _bad(tmp_path, "<?xml version='1.0'?><OpenSimDocument Version='40000'><MarkerSet><objects>"
                        "<Marker name='UNSEEN'><socket_parent_frame>/bodyset/pelvis</socket_parent_frame>"
                        "<location>0 0.1 0</location></Marker></objects></MarkerSet></OpenSimDocument>", "ms.xml")
    for k, extra in enumerate(([], ["--marker-set", str(ms)])):
        (tmp_path / f"o{k}").mkdir()
        assert main([str(tmp_path / "squat.c3d"), str(osim), "-o", str(tmp_path / f"o{k}"), *extra]) == 0
        (line,) = [x for x in capsys.readouterr().err.splitlines() if "LOOSE" in x]
        assert line.startswith("warning: 1 trial label rides on no segment of human.osim and is ignored: LOOSE")
        assert ("--marker-set FILE.xml" in line) == (not extra), line
        assert "the marker map's [segments] table" in line  # (a label one knows the segment of)


def test_marker_set_replaces_and_adds(tmp_path):
    osim = _bad(tmp_path, hand_made_osim(), "m.osim")
    ms = _bad(tmp_path, "<?xml version='1.0'?><OpenSimDocument Version='40000'><MarkerSet><objects>"
                        "<Marker name='M0_pelvis'><socket_parent_frame>/bodyset/thigh</socket_parent_frame>"
                        "<location>0.01 0.02 0.03</location></Marker>"
                        "<Marker name='NEW'><body>toes</body><location>0.1 0 0</location></Marker>"
                        "</objects></MarkerSet></OpenSimDocument>", "ms.xml")
    base, m = load_model(osim), load_model(osim, ms)
    assert set(m.marker_names) == set(base.marker_names) | {"NEW"}
    assert m.markers[m.marker_index("M0_pelvis")].segment == "thigh"


def test_cli_import_osim_and_inspect(tmp_path, capsys):
    osim = _bad(tmp_path, hand_made_osim(), "h.osim")
    out = tmp_path / "h.urdf"
    assert main(["import-osim", str(osim), "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "knee: hinge fit" in text and str(out) in text
    a, b = load_model(osim), load_model(out)  # the written URDF is the same model
    assert a.dof_names == b.dof_names and a.marker_names == b.marker_names
    pose = (np.zeros(3), np.array([0, 0, 0, 1.0]), np.linspace(-0.3, 0.3, a.n_dofs))
    pa, pb = _pin_markers(a, *pose), _pin_markers(b, *pose)
    assert max(np.linalg.norm(pa[k] - pb[k]) for k in pa) < TOL  # two imports agree to the hinge fit's precision
    for x, y in zip(osim_info(b).approximations, osim_info(a).approximations, strict=True):
        assert (x.joint, x.kind, x.markers, x.marker) == (y.joint, y.kind, y.markers, y.marker)
        assert (x.max_marker_mm, x.bound_mm) == (pytest.approx(y.max_marker_mm, abs=1e-3),
                                                 pytest.approx(y.bound_mm, abs=1e-3))
    assert main(["import-osim", str(osim), "-o", str(out)]) == 2  # exists: kept unless --overwrite
    assert "--overwrite" in capsys.readouterr().err
    assert main(["inspect", str(osim)]) == 0
    text = capsys.readouterr().out
    assert "approximated" in text and "patfem: welded (coupled)" in text


# ---------------------------------------------------------------------- back to OpenSim
_EXPORT_WORKER = r"""
import json, sys
import opensim as osim
osim.Logger.removeFileSink()
osim.Logger.setLevelString("error")
out = []
for job in json.load(open(sys.argv[1]))["jobs"]:
    model = osim.Model(job["osim"])
    state = model.initSystem()
    cs = model.getCoordinateSet()
    storage = osim.Storage(job["mot"])
    model.getSimbodyEngine().convertDegreesToRadians(storage)  # as OpenSim's tools read a .mot
    cols = storage.getColumnLabels()
    labels = [cols.get(i) for i in range(1, cols.getSize())]
    for i in range(cs.getSize()):  # a locked coordinate keeps its value in setValue
        cs.get(i).setLocked(state, False)
    frames = []
    for f in range(storage.getSize()):
        row = storage.getStateVector(f).getData()
        for k, name in enumerate(labels):
            cs.get(name).setValue(state, row.get(k), False)
        model.realizePosition(state)
        ms = model.getMarkerSet()
        frames.append({ms.get(i).getName(): ms.get(i).getLocationInGround(state).to_numpy().tolist()
                       for i in range(ms.getSize())})
    out.append({"frames": frames, "labels": labels,
                "bodies": [model.getBodySet().get(i).getName() for i in range(model.getBodySet().getSize())],
                "joints": [model.getJointSet().get(i).getName() for i in range(model.getJointSet().getSize())],
                "coordinates": [cs.get(i).getName() for i in range(cs.getSize())],
                "locked": [cs.get(i).getName() for i in range(cs.getSize()) if cs.get(i).getDefaultLocked()],
                "clamped": [cs.get(i).getName() for i in range(cs.getSize()) if cs.get(i).getDefaultClamped()]})
json.dump(out, open(sys.argv[2], "w"))
"""


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed")
def test_export_keeps_names_and_kinematics(tmp_path):
    """A calibrated-like subject of each imported model, exported as .osim with a .mot of random poses:
    OpenSim puts every marker where Pinocchio puts it on the written subject URDF (1e-6 m), and the
    bodies, joints and coordinates have the original model's names."""
    from calibrate.io.motion import Motion
    from calibrate.io.osim_export import export_osim, write_mot
    from calibrate.model.model import Parameters, write_model

    hand = tmp_path / "handmade.osim"
    hand.write_text(hand_made_osim())
    sources = [(hand, None)] + ([(GAIT, GAIT_MARKERS)] if GAIT.exists() else []) + \
        ([(RAJAGOPAL, None)] if RAJAGOPAL.exists() else [])
    jobs, refs, models = [], [], []
    for k, (path, ms) in enumerate(sources):
        model = load_model(path, ms)
        rng = np.random.default_rng(10 + k)
        p0 = model.parameters()
        p = Parameters(1 + rng.uniform(-0.15, 0.15, p0.scale.shape),
                       p0.centre + rng.uniform(-0.02, 0.02, p0.centre.shape),
                       p0.axis + rng.uniform(-0.1, 0.1, p0.axis.shape),
                       p0.marker + rng.uniform(-0.01, 0.01, p0.marker.shape))
        subject = load_model(write_model(model, tmp_path / f"s{k}.urdf", p))  # what `calibrate` writes
        n = 20
        angles = np.array([[rng.uniform(max(d.lower, -np.pi), min(d.upper, np.pi)) for d in subject.dofs]
                           for _ in range(n)])
        motion = Motion(np.arange(n) / 100, rng.normal(0, 0.5, (n, 3)), Rotation.random(n, random_state=k).as_quat(),
                        angles, subject.dof_names)
        osim_path = export_osim(subject, tmp_path / f"s{k}.osim")
        mot = write_mot(tmp_path / f"s{k}.mot", subject, motion)
        jobs.append({"osim": str(osim_path), "mot": str(mot)})
        refs.append([{m: x for m, x in _pin_markers(subject, motion.root_translation[f], motion.root_quaternion[f],
                                                     angles[f]).items() if not m.startswith("body ")}
                     for f in range(n)])
        models.append((path, model))
    spec, result = tmp_path / "jobs.json", tmp_path / "result.json"
    spec.write_text(json.dumps({"jobs": jobs}))
    proc = subprocess.run([sys.executable, "-c", _EXPORT_WORKER, str(spec), str(result)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, f"OpenSim worker failed:\n{proc.stderr[-3000:]}"
    import xml.etree.ElementTree as ET

    for (path, model), res, ref in zip(models, json.loads(result.read_text()), refs, strict=True):
        worst = max(np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(res["frames"], ref, strict=True) for m in r)
        bad = sorted({m for o, r in zip(res["frames"], ref, strict=True) for m in r
                      if np.linalg.norm(np.array(o[m]) - r[m]) > TOL})
        assert worst < TOL, f"{path.name}: exported markers off by {worst:.3g} m ({bad[:12]})"
        doc = ET.parse(path).getroot()
        bodies = {b.get("name") for b in doc.iter("Body")}
        joints = {j.get("name") for j in doc.find("Model/JointSet/objects")}
        coords = {c.get("name") for c in doc.iter("Coordinate")} - set(osim_info(model).dropped)
        assert set(res["bodies"]) == bodies and set(res["joints"]) == joints and set(res["coordinates"]) == coords
        assert set(res["labels"]) == coords  # the .mot's columns: OpenSim's coordinate names
        assert set(res["locked"]) == {c.get("name") for c in doc.iter("Coordinate")
                                      if c.findtext("locked", "").strip() == "true"}
        # clamped as the source (gait2392 clamps none of its coordinates, Rajagopal 37 of 39; the export clamped
        # every one with a range, and OpenSim then refused MoBL-ARMS's elbow_flexion, default -2e-8 below its 0)
        info = osim_info(model)
        root = {n for n, _ in (info.root.rotations + info.root.translations)} if info.root is not None else set()
        assert set(res["clamped"]) == {c.get("name") for c in doc.iter("Coordinate")  # (the root's float: unclamped)
                                       if c.findtext("clamped", "").strip() == "true"} - set(info.dropped) - root


@pytest.mark.skipif(not GAIT.exists(), reason="gait2392 is not in ../shared/data/real")
def test_cli_calibrates_from_osim(tmp_path, capsys):
    """`calibrate TRIAL MODEL.osim --marker-set XML -o subject.osim` end to end on a trial made from the model's own
    markers (a walking-like sway of every coordinate): the subject URDF keeps the OpenSim facts, the motion CSV's
    columns are OpenSim's coordinate names, and it recovers the motion's marker positions."""
    from calibrate.io.motion import read_motion_csv
    from calibrate.io.trc import write_trc
    from calibrate.io.trial import Trial

    model = load_model(GAIT, GAIT_MARKERS)
    n, rng = 40, np.random.default_rng(4)
    t = np.arange(n) / 60
    amp = np.radians(rng.uniform(5, 25, model.n_dofs))
    mid = np.array([0.5 * (d.lower + d.upper) * 0.1 for d in model.dofs])
    angles = mid + amp * np.sin(2 * np.pi * 1.0 * t[:, None] + rng.uniform(0, 6, model.n_dofs))
    quat = Rotation.from_euler("y", 0.3 * np.sin(2 * np.pi * 0.5 * t)[:, None]).as_quat()
    root = np.column_stack([1.2 * t, np.full(n, 0.95), 0.02 * np.sin(2 * np.pi * t)])
    frames = [_pin_markers(model, root[f], quat[f], angles[f]) for f in range(n)]
    markers = np.array([[frames[f][m] for m in model.marker_names] for f in range(n)])
    trc = tmp_path / "walk.trc"
    write_trc(trc, Trial(list(model.marker_names), markers, 60.0, 0, str(trc)))
    out = tmp_path / "subject.urdf"  # -o names the subject .osim, as an OpenSim user would: the URDF beside it
    code = main([str(trc), str(GAIT), "--marker-set", str(GAIT_MARKERS), "-o", str(tmp_path / "subject.osim"),
                 "--no-new-markers", "-q"])
    said = capsys.readouterr()
    assert code == 0, said.err
    assert "subject.osim: forces: 92 of gait2392.osim's 92 carried" in said.out  # its 92 muscles
    subject = load_model(out)
    info = osim_info(subject)
    assert info is not None and info.root is not None and info.root.joint == "ground_pelvis"
    head = (tmp_path / "walk_motion.csv").read_text().splitlines()[0].split(",")
    assert set(model.dof_names) <= set(head)
    report = json.loads((tmp_path / "walk_report.json").read_text())
    assert report["trials"][0]["rms_mm"] < 1.0  # noise-free markers of the model itself
    assert report["settings"]["segment_frames"] == "markers"  # an OpenSim model's default: its frames by its markers
    # back to OpenSim: the subject and its motion in OpenSim's names, written with them and by export-osim
    assert (tmp_path / "subject.osim").is_file() and (tmp_path / "walk_motion.mot").is_file()
    assert main(["export-osim", str(out), "--motion", str(tmp_path / "walk_motion.csv"), "-o",
                 str(tmp_path / "again.osim"), "--mot", str(tmp_path / "again.mot")]) == 0
    assert (tmp_path / "again.mot").read_text().splitlines()[1:] == \
        (tmp_path / "walk_motion.mot").read_text().splitlines()[1:]
    mot = (tmp_path / "walk_motion.mot").read_text().splitlines()
    cols = mot[mot.index("endheader") + 1].split("\t")
    assert cols[:7] == ["time", "pelvis_tilt", "pelvis_list", "pelvis_rotation", "pelvis_tx", "pelvis_ty", "pelvis_tz"]
    assert set(cols[7:]) == set(model.dof_names)
    text = (tmp_path / "subject.osim").read_text()
    assert '<CustomJoint name="ground_pelvis">' in text and '<CustomJoint name="knee_r">' in text
    assert text.count("<Thelen2003Muscle ") == 92
    assert text == (tmp_path / "again.osim").read_text()  # written with the others = exported from the URDF
    # the marker errors as OpenSim's IK tool writes them (_ik_marker_errors.sto): the subject URDF posed by the motion
    # in Pinocchio against the trial's markers, each frame's sum of squares, RMS and largest error
    sto = (tmp_path / "walk_ik_marker_errors.sto").read_text().splitlines()
    assert sto[:7] == ["Model Marker Errors from IK", "version=1", f"nRows={n}", "nColumns=4", "inDegrees=no",
                       "endheader", "time\ttotal_squared_error\tmarker_error_RMS\tmarker_error_max"]
    errors = np.array([[float(v) for v in line.split("\t")] for line in sto[7:]])
    motion = read_motion_csv(tmp_path / "walk_motion.csv")
    used = [m for m in subject.marker_names if m not in report["marker_set"]["unused_model_markers"]]
    for f in (0, 17, n - 1):
        at = _pin_markers(subject, motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        d2 = np.array([np.sum((at[m] - markers[f, model.marker_names.index(m)]) ** 2) for m in used])
        # (the URDF's text rounds the subject's offsets: the errors, ~1e-5 m on these noise-free markers, agree to
        # 2e-10 m; another sum, weights or set of markers would change them by a tenth or more)
        assert errors[f, 0] == pytest.approx(t[f], abs=1e-12) and errors[f, 1] == pytest.approx(d2.sum(), abs=1e-12)
        assert errors[f, 2:] == pytest.approx([np.sqrt(d2.mean()), np.sqrt(d2.max())], abs=1e-9)
        assert errors[f, 2] > 1e-6


def test_marker_set_needs_an_osim(tmp_path):
    from conftest import HUMAN

    ms = _bad(tmp_path, "<OpenSimDocument Version='40000'><MarkerSet><objects/></MarkerSet></OpenSimDocument>",
              "ms.xml")
    with pytest.raises(ModelError, match="goes with an OpenSim model"):
        load_model(HUMAN, ms)
    with pytest.raises(ModelError, match="no such file"):
        load_model(tmp_path / "missing.osim")


@pytest.mark.skipif(not GAIT.exists(), reason="gait2392 is not in ../shared/data/real")
def test_commands_on_an_opensim_model_import_no_scipy(tmp_path):
    # Importing scipy (its optimize and Rotation) took every command on an .osim a quarter of a second of its
    # start, more than calibrate ik's fit of a 121-frame walk: the import's fits, Euler angles and splines are
    # numpy's (a NaturalCubicSpline, which no model here has, still takes scipy's).
    code = (f"import sys; from calibrate.cli.main import main; o = r'{tmp_path}'; "
            f"assert main(['import-osim', r'{GAIT}', '--marker-set', r'{GAIT_MARKERS}', '-o', o + '/g.urdf']) == 0; "
            "assert main(['inspect', o + '/g.urdf']) == 0; "
            "assert main(['export-osim', o + '/g.urdf', '-o', o + '/g.osim']) == 0; "
            "assert main(['export-mjcf', o + '/g.urdf', '-o', o + '/g.xml']) == 0; "
            "assert main(['inspect', o + '/g.osim']) == 0; "
            "print(sorted(m for m in sys.modules if m.startswith('scipy')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"
    assert {"g.urdf", "g.osim", "g.xml"} <= {f.name for f in tmp_path.iterdir()}


@pytest.mark.skipif(not GAIT.exists(), reason="gait2392 is not in ../shared/data/real")
def test_hinge_fit_is_the_same_in_every_process():
    # The knee's fixed-hinge fit came out 1e-13 apart from process to process under MINPACK's Levenberg-
    # Marquardt (with the string-hash seed), and the calibration on it 1e-6 apart; the same model is the same
    # bits wherever it is loaded.
    code = (f"import hashlib, calibrate; m = calibrate.load_model(r'{GAIT}', r'{GAIT_MARKERS}'); "
            "print(hashlib.sha1(m.parameters().vector().tobytes()).hexdigest())")
    seen = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                           env={**os.environ, "PYTHONHASHSEED": str(seed)}).stdout for seed in range(5)}
    assert len(seen) == 1, seen


# ---------------------------------------------------------------------- the source model's muscles
def muscle_osim() -> str:
    """A leg with muscles: translating child offset frames (the thigh's and shank's segment frames are not their
    body frames), non-zero default angles, a path over a wrap cylinder, a conditional and a moving path point
    (spline, linear and constant location functions), a CoordinateActuator (carried) and a PointActuator (left
    out)."""
    body = ("<Body name=\"{n}\"><mass>{m}</mass><mass_center>0.01 -0.1 0.02</mass_center>"
            "<inertia>0.1 0.12 0.05 0 0 0</inertia>{w}</Body>")
    cyl = ("<WrapObjectSet name=\"wrapobjectset\"><objects><WrapCylinder name=\"thigh_cyl\">"
           "<xyz_body_rotation>0.1 0 0.2</xyz_body_rotation><translation>0.04 -0.36 0.0</translation>"
           "<quadrant>all</quadrant><radius>0.03</radius><length>0.12</length></WrapCylinder></objects>"
           "</WrapObjectSet>")
    bodies = "".join(body.format(n=n, m=m, w=cyl if n == "thigh" else "")
                     for n, m in (("pelvis", 10), ("thigh", 7), ("shank", 3)))

    def coords(name: str, lo: float, hi: float, default: float) -> str:
        return (f"<coordinates><Coordinate name=\"{name}\"><default_value>{default}</default_value><range>{lo} {hi}"
                f"</range><clamped>true</clamped><locked>false</locked></Coordinate></coordinates>")

    joints = (
        ground_free("pelvis") +
        f"<PinJoint name=\"hip\">{_frames('pelvis', 'thigh', '-0.07 -0.08 0.08', '0 0 0', '0.01 0.03 -0.02', '0 0 0')}"
        f"{coords('hip_q', -1.5, 1.5, 0.2)}</PinJoint>"
        f"<PinJoint name=\"knee\">{_frames('thigh', 'shank', '0 -0.4 0', '0 0 0', '0.005 0.01 0', '0 0 0')}"
        f"{coords('knee_q', -2, 0.2, -0.3)}"
        "</PinJoint>")

    def point(name: str, bodyname: str, loc: str) -> str:
        return (f"<PathPoint name=\"{name}\"><socket_parent_frame>/bodyset/{bodyname}</socket_parent_frame>"
                f"<location>{loc}</location></PathPoint>")

    def muscle(name: str, points: str, wrap: str = "") -> str:
        wraps = (f"<PathWrapSet><objects><PathWrap name=\"{name}_wrap\"><wrap_object>{wrap}</wrap_object>"
                 "<method>hybrid</method><range>-1 -1</range></PathWrap></objects></PathWrapSet>") if wrap else ""
        return (f"<Thelen2003Muscle name=\"{name}\"><GeometryPath name=\"geometrypath\"><PathPointSet><objects>"
                f"{points}</objects></PathPointSet>{wraps}</GeometryPath><max_isometric_force>500"
                "</max_isometric_force><optimal_fiber_length>0.1</optimal_fiber_length><tendon_slack_length>0.12"
                "</tendon_slack_length><pennation_angle_at_optimal>0</pennation_angle_at_optimal></Thelen2003Muscle>")

    conditional = ("<ConditionalPathPoint name=\"hipm-P2\"><socket_parent_frame>/bodyset/thigh</socket_parent_frame>"
                   "<location>-0.01 -0.1 0.03</location><socket_coordinate>/jointset/hip/hip_q</socket_coordinate>"
                   "<range>-1 1</range></ConditionalPathPoint>")
    moving = ("<MovingPathPoint name=\"kneem-P3\"><socket_parent_frame>/bodyset/shank</socket_parent_frame>"
              "<socket_x_coordinate>/jointset/knee/knee_q</socket_x_coordinate>"
              "<socket_y_coordinate>/jointset/knee/knee_q</socket_y_coordinate>"
              "<socket_z_coordinate>/jointset/knee/knee_q</socket_z_coordinate>"
              "<x_location><SimmSpline><x>-2 -1 0 0.2</x><y>0.02 0.025 0.03 0.031</y></SimmSpline></x_location>"
              "<y_location><LinearFunction><coefficients>0.01 -0.05</coefficients></LinearFunction></y_location>"
              "<z_location><Constant><value>0.01</value></Constant></z_location></MovingPathPoint>")
    forces = (muscle("hipm", point("hipm-P1", "pelvis", "0.02 0.01 0.05") + conditional
                     + point("hipm-P3", "thigh", "0.01 -0.3 0.03"))
              + muscle("kneem", point("kneem-P1", "pelvis", "0.0 -0.05 0.06") + point("kneem-P2", "thigh",
                                                                                     "0.05 -0.3 0.01") + moving,
                       wrap="thigh_cyl")
              + "<CoordinateActuator name=\"knee_act\"><coordinate>knee_q</coordinate><optimal_force>100"
                "</optimal_force></CoordinateActuator>"
              + "<PointActuator name=\"push\"><body>shank</body><point>0 -0.2 0</point><direction>1 0 0</direction>"
                "<optimal_force>10</optimal_force></PointActuator>")
    markers = "".join(f"<Marker name=\"M{k}\"><socket_parent_frame>/bodyset/{b}</socket_parent_frame>"
                      f"<location>{loc}</location></Marker>"
                      for k, (b, loc) in enumerate((("pelvis", "0.1 0 0.1"), ("pelvis", "-0.1 0 0.1"),
                                                    ("pelvis", "0 0.05 -0.1"), ("thigh", "0.05 -0.2 0.05"),
                                                    ("thigh", "0.05 -0.3 -0.05"), ("shank", "0.04 -0.2 0.05"),
                                                    ("shank", "0.04 -0.3 -0.04"))))
    return ("<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40000\"><Model name=\"muscled\">"
            "<Ground name=\"ground\"/><gravity>0 -9.80665 0</gravity>"
            f"<BodySet name=\"bodyset\"><objects>{bodies}</objects></BodySet>"
            f"<JointSet name=\"jointset\"><objects>{joints}</objects></JointSet>"
            f"<ForceSet name=\"forceset\"><objects>{forces}</objects></ForceSet>"
            f"<MarkerSet name=\"markerset\"><objects>{markers}</objects></MarkerSet></Model></OpenSimDocument>\n")


# The start of both workers below: each job's "source" model scaled by OpenSim's own Model::scale (job["scales"]:
# the same factor on every axis of a body) and its "exported" subject, each loaded and posed in its default pose.
_SCALED_PAIR = r"""
import json, sys
import opensim as osim
osim.Logger.removeFileSink()
osim.Logger.setLevelString("error")

def loaded(job, key):
    model = osim.Model(job[key])
    state = model.initSystem()
    if key == "source":
        scales = osim.ScaleSet()
        for body, f in job["scales"].items():
            sc = osim.Scale()
            sc.setSegmentName(body)
            sc.setScaleFactors(osim.Vec3(f, f, f))
            sc.setApply(True)
            scales.cloneAndAppend(sc)
        model.scale(state, scales, True)
        state = model.initSystem()
    model.realizePosition(state)
    return model, state
"""


# {"jobs": [{"source", "exported", "scales": {body: factor}}]} -> per job: per muscle of the source scaled by
# OpenSim's own Model::scale (the same factor on every axis of a body) and of the exported subject: its length
# in the default pose (wrapping included), optimal fibre and tendon slack length; and the forces' names.
_MUSCLE_WORKER = _SCALED_PAIR + r"""
out = []
for job in json.load(open(sys.argv[1]))["jobs"]:
    res = {}
    for key in ("source", "exported"):
        model, state = loaded(job, key)
        muscles = model.getMuscles()
        res[key] = {muscles.get(i).getName(): [muscles.get(i).getLength(state), muscles.get(i).getOptimalFiberLength(),
                                               muscles.get(i).getTendonSlackLength()] for i in range(muscles.getSize())}
        fs = model.getForceSet()
        res[key + " forces"] = [fs.get(i).getName() for i in range(fs.getSize())]
    out.append(res)
json.dump(out, open(sys.argv[2], "w"))
"""


def _scaled_exports(tmp_path: Path, own: Path, prefix: str) -> list[tuple]:
    """The hand-made model `own`, Gait2392 and Rajagopal (where the files are), each with its segments scaled by
    random factors (seed: its place in the list) and exported as .osim: (source path, model, subject, the
    exported path and the OpenSim worker's job for it: source, exported, scales) each."""
    from calibrate.io.osim_export import export_osim
    from calibrate.model.model import Parameters, write_model

    sources = [(own, None)] + ([(GAIT, GAIT_MARKERS)] if GAIT.exists() else []) + \
        ([(RAJAGOPAL, None)] if RAJAGOPAL.exists() else [])
    out = []
    for k, (path, ms) in enumerate(sources):
        model = load_model(path, ms)
        p0 = model.parameters()
        scale = 1 + np.random.default_rng(k).uniform(-0.15, 0.15, p0.scale.shape)
        subject = load_model(write_model(model, tmp_path / f"{prefix}{k}.urdf",
                                         Parameters(scale, p0.centre, p0.axis, p0.marker)))
        exported = export_osim(subject, tmp_path / f"{prefix}{k}.osim")
        job = {"source": str(path), "exported": str(exported),
               "scales": {s.name: float(scale[i]) for i, s in enumerate(model.segments)}}
        out.append((path, model, subject, exported, job))
    return out


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed")
def test_export_carries_the_source_muscles_scaled_as_opensim_scales_them(tmp_path):
    """A subject whose segments are the source model's scaled (each by its own factor), exported as .osim: its
    muscles, in OpenSim, have the lengths OpenSim's own Model::scale gives the source with the same factors (1e-6
    m, wrapping included), and the same optimal fibre and tendon slack lengths (1e-9 where the path does not wrap;
    within 1 % over the wrap cylinder, whose path calibrate measures straight); a force on a body is left out and
    said so.  Gait2392 and Rajagopal too, where the files are: every muscle whose path does not cross the
    approximated knee has OpenSim's length to 1e-6 m."""
    from calibrate.io.osim_export import osim_document
    from calibrate.io.osim_forces import forces_lines, forces_written

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    exports = _scaled_exports(tmp_path, src, "m")
    jobs = [e[-1] for e in exports]
    for _, _, subject, out, _ in exports[:1]:
            _, carried = osim_document(subject)
            assert [f.get("name") for f in carried.forces] == ["hipm", "kneem", "knee_act"]
            assert len(carried.left_out) == 1 and carried.left_out[0].startswith("PointActuator push (acts on a body")
            assert any("left out: PointActuator push" in line for line in forces_lines(carried))
            assert forces_written(out) == forces_lines(carried)  # said in the file too
    spec, result = tmp_path / "jobs.json", tmp_path / "result.json"
    spec.write_text(json.dumps({"jobs": jobs}))
    proc = subprocess.run([sys.executable, "-c", _MUSCLE_WORKER, str(spec), str(result)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, f"OpenSim worker failed:\n{proc.stderr[-3000:]}"
    knee = ("bflh", "bfsh", "gaslat", "gasmed", "grac", "recfem", "sart", "semimem", "semiten", "tfl", "vasint",
            "vaslat", "vasmed", "bifemlh", "bifemsh", "lat_gas", "med_gas", "rect_fem", "sar", "vas_int", "vas_lat",
            "vas_med")
    for (path, *_), res in zip(exports, json.loads(result.read_text()), strict=True):
        ref, got = res["source"], res["exported"]
        assert set(got) == set(ref), path.name
        if path == src:
            assert res["exported forces"] == ["hipm", "kneem", "knee_act"]
            for name in got:
                assert abs(got[name][0] - ref[name][0]) < TOL, (name, got[name], ref[name])
            assert np.allclose(got["hipm"][1:], ref["hipm"][1:], rtol=1e-9, atol=0)
            assert np.allclose(got["kneem"][1:], ref["kneem"][1:], rtol=0.01, atol=0)
            assert not np.allclose(got["kneem"][1:], [0.1, 0.12], rtol=0.01)  # scaled, not kept
            continue
        assert len(res["exported forces"]) == len(res["source forces"]), path.name
        straight = [m for m in got if m.rsplit("_", 1)[0] not in knee]
        assert len(straight) > 40
        worst = max(abs(got[m][0] - ref[m][0]) for m in straight)
        assert worst < TOL, f"{path.name}: muscle lengths off by {worst:.3g} m"


# {"jobs": [{"source", "exported", "root", "scales": {body: factor}}]} -> per job, for the source scaled by OpenSim's
# own Model::scale (the same factor on every axis of a body) and for the exported subject: every attached geometry (not
# the frames' axes) with its body, mesh file and four points of its own frame (its origin and 0.1 along each axis,
# times its scale factors) in the root body's frame, in the default pose.
_GEOMETRY_WORKER = _SCALED_PAIR + r"""
out = []
for job in json.load(open(sys.argv[1]))["jobs"]:
    res = {}
    for key in ("source", "exported"):
        model, state = loaded(job, key)
        root = model.getBodySet().get(job["root"]).getTransformInGround(state)
        geometry = {}
        for comp in model.getComponentsList():
            g = osim.Geometry.safeDownCast(comp)
            if g is None or g.getConcreteClassName() == "FrameGeometry":
                continue
            T, sf = g.getFrame().getTransformInGround(state), g.get_scale_factors()
            points = []
            for v in ((0, 0, 0), (0.1, 0, 0), (0, 0.1, 0), (0, 0, 0.1)):
                w = T.shiftFrameStationToBase(osim.Vec3(*(sf.get(k) * v[k] for k in range(3))))
                w = root.shiftBaseStationToFrame(w)
                points.append([w.get(0), w.get(1), w.get(2)])
            mesh = osim.Mesh.safeDownCast(comp)
            geometry[g.getName()] = {"body": g.getFrame().findBaseFrame().getName(), "points": points,
                                     "file": mesh.get_mesh_file() if mesh is not None else g.getConcreteClassName()}
        res[key] = geometry
    out.append(res)
json.dump(out, open(sys.argv[2], "w"))
"""


def _geometry_osim() -> str:
    """muscle_osim with bones: meshes (one with scale factors of its own), a brick without scale factors and a
    cylinder on the bodies (the thigh's and shank's body frames translated from their segment frames), a mesh on
    the ground, and a shape on another frame (not carried)."""
    shapes = {"pelvis": "<Mesh name=\"pelvis_bone\"><socket_frame>..</socket_frame><scale_factors>1 1 1</scale_factors>"
                        "<mesh_file>pelvis.vtp</mesh_file></Mesh>",
              "thigh": "<Mesh name=\"thigh_bone\"><socket_frame>..</socket_frame><scale_factors>0.5 1 2</scale_factors>"
                       "<mesh_file>femur.vtp</mesh_file></Mesh><Brick name=\"thigh_box\">"
                       "<socket_frame>..</socket_frame><half_lengths>0.02 0.2 0.02</half_lengths></Brick>",
              "shank": "<Cylinder name=\"shank_rod\"><socket_frame>..</socket_frame>"
                       "<scale_factors>1 1 1</scale_factors><radius>0.03</radius>"
                       "<half_height>0.2</half_height></Cylinder>"
                       "<Sphere name=\"elsewhere\"><socket_frame>/ground</socket_frame><radius>0.05</radius></Sphere>"}
    text = muscle_osim()
    for body, shape in shapes.items():
        text = text.replace(f"<Body name=\"{body}\">", f"<Body name=\"{body}\"><attached_geometry>{shape}"
                                                       "</attached_geometry>", 1)
    return text.replace("<Ground name=\"ground\"/>", "<Ground name=\"ground\"><attached_geometry><Mesh name=\"floor\">"
                        "<socket_frame>..</socket_frame><mesh_file>floor.vtp</mesh_file></Mesh></attached_geometry>"
                        "</Ground>", 1)


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed")
def test_export_carries_the_source_bones_scaled_as_opensim_scales_them(tmp_path):
    """A subject whose segments are the source model's scaled (each by its own factor), exported as .osim, opens in
    OpenSim with the source's bones: every mesh (and brick, cylinder) of its bodies, in OpenSim, where OpenSim's own
    Model::scale puts the source's with the same factors (1e-6 m, in the root body's frame), the ground's kept, a
    shape on another frame left out; the export says how many were carried.  Gait2392 and Rajagopal too, where the
    files are: every shape carried with its mesh file, those not below an approximated joint (the knees, the
    patellae) where OpenSim's scaling puts them to 1e-6 m."""
    from calibrate.io.osim import FLOATING, LEFT_OUT
    from calibrate.io.osim_export import osim_document
    from calibrate.io.osim_forces import forces_lines

    src = tmp_path / "bones.osim"
    src.write_text(_geometry_osim())
    exports = _scaled_exports(tmp_path, src, "g")
    jobs, below = [], []
    for k, (_, model, subject, _, job) in enumerate(exports):
        jobs.append({**job, "root": model.root})
        # the bodies below a joint the import approximates: placed as calibrate's kinematics place them
        approximated = {a.joint for a in osim_info(model).approximations if a.kind not in (FLOATING, LEFT_OUT)}
        seen = {j.child for j in model.joints if j.name in approximated}
        while True:
            more = {j.child for j in model.joints if j.parent in seen} - seen
            if not more:
                break
            seen |= more
        below.append(seen)
        if k == 0:
            lines = forces_lines(osim_document(subject)[1])
            assert any(line.startswith("geometry: its bodies' 4 shapes carried (pelvis.vtp, femur.vtp, Brick and "
                                       "1 more)") for line in lines), lines
    spec, result = tmp_path / "jobs.json", tmp_path / "result.json"
    spec.write_text(json.dumps({"jobs": jobs}))
    proc = subprocess.run([sys.executable, "-c", _GEOMETRY_WORKER, str(spec), str(result)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, f"OpenSim worker failed:\n{proc.stderr[-3000:]}"
    for (path, *_), res, out_below in zip(exports, json.loads(result.read_text()), below, strict=True):
        ref, got = res["source"], res["exported"]
        expected = set(ref) - ({"elsewhere"} if path == src else set())
        assert set(got) == expected, (path.name, set(got) ^ expected)
        exact = set()  # the bodies whose shapes were compared
        for name in expected:
            assert (got[name]["body"], got[name]["file"]) == (ref[name]["body"], ref[name]["file"]), name
            if ref[name]["body"] in out_below or ref[name]["body"] == "ground":
                continue
            worst = np.abs(np.array(got[name]["points"]) - np.array(ref[name]["points"])).max()
            assert worst < TOL, f"{path.name}: {name} on {ref[name]['body']} off by {worst:.3g} m"
            exact.add(ref[name]["body"])
        if path == src:
            assert exact == {"pelvis", "thigh", "shank"} and not out_below
        else:
            assert {"pelvis", "femur_r", "femur_l", "torso"} <= exact, (path.name, exact)


def test_imported_model_draws_its_segments_in_a_urdf_viewer(tmp_path):
    """An imported model, and a subject written from it, open in a URDF viewer (yourdfpy) with every segment drawn:
    a rod from its origin that ends at one of its child joints (read back from the written URDF, scaled with the
    segment), or for a leaf the box whose uniform density gives the segment's mass and inertia; a sphere on every
    marker; and no warning on the way (the rods' and boxes' Euler angles kept off gimbal lock)."""
    import warnings

    import yourdfpy

    from calibrate.io.osim import BOX_SIDES
    from calibrate.model.model import Parameters, write_model

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    cases = [(src, None, 3)] + ([(GAIT, GAIT_MARKERS, 12)] if GAIT.exists() else [])
    for k, (path, ms, drawn) in enumerate(cases):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            model = load_model(path, ms)
            p0 = model.parameters()
            scale = 1 + np.random.default_rng(k).uniform(-0.15, 0.15, p0.scale.shape)
            out = write_model(model, tmp_path / f"v{k}.urdf", Parameters(scale, p0.centre, p0.axis, p0.marker))
        imported = tmp_path / f"i{k}.urdf"
        imported.write_text(model.text)
        boxes = 0
        for urdf in (imported, out):
            robot = yourdfpy.URDF.load(str(urdf), load_meshes=False).robot
            links = {lk.name: lk for lk in robot.links}
            segments = {sg.name for sg in model.segments}
            assert all(len(links[m].visuals) == 1 and links[m].visuals[0].geometry.sphere is not None
                       for m in model.marker_names)
            assert sum(1 for n in segments if links[n].visuals) >= drawn
            for name in segments:
                joints = [j.origin[:3, 3] for j in robot.joints
                          if j.parent == name and j.child not in model.marker_names]
                for v in links[name].visuals:
                    g = v.geometry
                    if g.cylinder is not None:  # a rod: from the origin to a child joint
                        assert np.allclose(v.origin[:3, 3], v.origin[:3, :3] @ [0, 0, g.cylinder.length / 2])
                        end = 2 * v.origin[:3, 3]
                        assert min(np.linalg.norm(end - o) for o in joints) < 1e-9, (urdf.name, name)
                    else:  # a leaf's box: its inertia about its centre is the segment's
                        assert g.box is not None and not joints, (urdf.name, name)
                        inertial = links[name].inertial
                        a, b, c = g.box.size
                        I_box = v.origin[:3, :3] @ np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) \
                            @ v.origin[:3, :3].T * inertial.mass / 12
                        R = inertial.origin[:3, :3]
                        assert np.allclose(v.origin[:3, 3], inertial.origin[:3, 3], atol=1e-12)
                        s_ = 1.0 if urdf == imported else scale[[sg.name for sg in model.segments].index(name)]
                        if np.all((g.box.size > s_ * BOX_SIDES[0] + 1e-12) & (g.box.size < s_ * BOX_SIDES[1] - 1e-12)):
                            assert np.allclose(I_box, R @ inertial.inertia @ R.T, atol=1e-9), (urdf.name, name)
                            boxes += 1
                        else:  # a plate drawn at the least thickness (gait2392's toes)
                            assert np.isclose(g.box.size.min(), s_ * BOX_SIDES[0]), (urdf.name, name, g.box.size)
        assert boxes >= (2 if path == GAIT else 0)


def test_export_without_its_source_model_says_so(tmp_path):
    """The source .osim moved away after the import: the subject is still exported, without forces, and the
    file and the export say why."""
    from calibrate.io.osim_export import osim_document
    from calibrate.model.model import write_model

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    subject = load_model(write_model(load_model(src), tmp_path / "s.urdf"))
    text, carried = osim_document(subject)
    assert "<ForceSet" in text and len(carried.forces) == 3
    src.rename(tmp_path / "moved.osim")
    text, carried = osim_document(subject)
    assert "<ForceSet" not in text and "<Marker " in text
    assert "not carried: the source model" in carried.note and str(src) in carried.note
    assert f"<!-- calibrate: {carried.note} -->" in text


# ---------------------------------------------------------------------- the lab's IK setup
def _ik_setup(tasks: str, tool: str = "InverseKinematicsTool") -> str:
    return (f"<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40000\"><{tool} name=\"ik\">"
            f"<IKTaskSet><objects><IKMarkerTask name=\"M0\"><apply>true</apply><weight>10</weight></IKMarkerTask>"
            f"{tasks}</objects></IKTaskSet></{tool}></OpenSimDocument>\n")


def _task(name: str, kind: str = "default_value", value: float = 0.0, apply: str = "true", weight: float = 1000) -> str:
    return (f"<IKCoordinateTask name=\"{name}\"><apply>{apply}</apply><weight>{weight:g}</weight>"
            f"<value_type>{kind}</value_type><value>{value}</value></IKCoordinateTask>")


def _muscled_trial(tmp_path, model) -> Path:
    """trial.trc in `tmp_path`: 30 frames of `model`'s own markers (muscle_osim), the hip and knee moving."""
    from calibrate.io.trc import write_trc
    from calibrate.io.trial import Trial

    n, rng = 30, np.random.default_rng(5)
    t = np.arange(n) / 60
    angles = np.column_stack([0.4 * np.sin(2 * np.pi * t), -0.6 + 0.5 * np.sin(2 * np.pi * t + 1)])
    quat = Rotation.from_euler("y", 0.2 * np.sin(2 * np.pi * t)[:, None]).as_quat()
    root = np.column_stack([t, np.full(n, 0.9), np.zeros(n)])
    frames = [_pin_markers(model, root[f], quat[f], angles[f]) for f in range(n)]
    markers = np.array([[frames[f][m] for m in model.marker_names] for f in range(n)])
    trc = tmp_path / "trial.trc"
    write_trc(trc, Trial(list(model.marker_names), markers + rng.normal(0, 2e-4, markers.shape), 60.0, 0, str(trc)))
    return trc


def test_ik_setup_locks_the_coordinates_its_tasks_hold(tmp_path, capsys):
    """`calibrate TRIAL MODEL.osim --ik-setup FILE.xml`: each applied coordinate task of the lab's IK setup locks its
    coordinate, at the model's default (default_value) or at the task's value (manual_value); a task not applied
    locks nothing, nor one on the ground joint's coordinate (a note says so); the motion then holds those coordinates
    there in every frame.  The setup's task on a coordinate
    the model lacks, a value from a file, a file that is not an IK setup: one line each, exit 2, nothing written."""
    from calibrate.io.osim_setup import ik_setup_locks

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    model = load_model(src)
    setup = tmp_path / "setup_IK.xml"
    setup.write_text(_ik_setup(_task("hip_q") + _task("knee_q", "manual_value", -0.25)
                               + _task("p_rx", apply="false") + _task("p_ry")))
    assert dict(ik_setup_locks(setup, model)) == {"hip_q": 0.2, "knee_q": -0.25}  # hip_q's default in the model
    trc = _muscled_trial(tmp_path, model)
    out = tmp_path / "subject.urdf"
    code = main([str(trc), str(src), "--ik-setup", str(setup), "-o", str(out), "--no-new-markers"])
    err = capsys.readouterr().err
    assert code == 0, err
    # A task on the ground joint's coordinate (p_ry) holds nothing, and says so.
    assert "note: setup_IK.xml: its tasks on p_ry (the ground joint's) are not held" in err, err
    report = json.loads((tmp_path / "trial_report.json").read_text())
    assert report["settings"]["lock_deg"] == pytest.approx({"hip_q": np.degrees(0.2), "knee_q": np.degrees(-0.25)})
    rows = (tmp_path / "trial_motion.csv").read_text().splitlines()
    head = rows[0].split(",")
    values = np.array([[float(v) for v in r.split(",")] for r in rows[1:]])
    assert np.allclose(values[:, head.index("hip_q")], 0.2, atol=1e-6)
    assert np.allclose(values[:, head.index("knee_q")], -0.25, atol=1e-6)
    # bad setups: one line, exit 2, nothing written
    for k, (text, needle) in enumerate([
            (_ik_setup(_task("ankle_q")), "coordinate task 'ankle_q' names no coordinate of"),
            (_ik_setup(_task("hip_q", "from_file")), "takes its value 'from_file'"),
            (_ik_setup(_task("hip_q"), tool="ScaleTool"), "no <InverseKinematicsTool>"),
            ("not xml", "not valid XML")]):
        bad = tmp_path / f"bad{k}.xml"
        bad.write_text(text)
        _assert_refused(capsys, tmp_path / f"out{k}", trc, src, "--ik-setup", bad, needle)


def test_a_light_ik_coordinate_task_is_held_and_said(tmp_path, capsys):
    """An IK setup's coordinate task lighter than POSE_TASK_WEIGHT (a preference OpenSim's IK weighs against the
    markers) is held as a lock as the heavy ones are, and the note and `calibrate inspect` say so with its weight and
    the marker tasks' weights."""
    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    model = load_model(src)
    setup = tmp_path / "setup_IK.xml"
    setup.write_text(_ik_setup(_task("hip_q", weight=5) + _task("knee_q", "manual_value", -0.25)))
    trc = _muscled_trial(tmp_path, model)
    code = main([str(trc), str(src), "--ik-setup", str(setup), "-o", str(tmp_path / "s.urdf"), "--no-new-markers"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert ("note: setup_IK.xml: its tasks on hip_q (weight 5) weigh less than 100 (its marker tasks weigh 10): "
            "OpenSim's IK lets the markers pull that coordinate a little off the value; calibrate holds it there in "
            "every frame (remove the task to leave it free)") in err, err
    assert "knee_q (weight" not in err
    report = json.loads((tmp_path / "trial_report.json").read_text())
    assert report["settings"]["lock_deg"] == pytest.approx({"hip_q": np.degrees(0.2), "knee_q": np.degrees(-0.25)})
    assert main(["inspect", str(setup)]) == 0
    out = capsys.readouterr().out
    assert ("locks 2 coordinates its tasks hold: hip_q (the model's default, weight 5: OpenSim weighs it against "
            "the markers), knee_q (-0.25)") in out, out


def _assert_refused(capsys, out: Path, trc: Path, base: Path, flag: str, bad: Path, needle: str) -> None:
    """`calibrate TRIAL BASE FLAG BAD -o out/s.urdf`: one line naming BAD and saying `needle`, exit 2, nothing in
    `out` (made here)."""
    out.mkdir()
    code = main([str(trc), str(base), flag, str(bad), "-o", str(out / "s.urdf"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and needle in err[0] and str(bad) in err[0], err
    assert not any(out.iterdir())


def _scale_setup(mass: str, marker_set: str, tool: str = "ScaleTool") -> str:
    return (f"<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40000\"><{tool} name=\"s\">"
            f"<mass>{mass}</mass><height>1700</height><GenericModelMaker><model_file>generic.osim</model_file>"
            f"<marker_set_file>{marker_set}</marker_set_file></GenericModelMaker></{tool}></OpenSimDocument>\n")


def test_scale_setup_gives_the_mass_and_the_marker_set(tmp_path, capsys):
    """`calibrate TRIAL MODEL.osim --scale-setup FILE.xml`: the lab's Scale setup gives the subject's body mass (the
    subject .osim's bodies then weigh it in all, the report names the file) and the marker set it names (read
    against the setup's folder: its markers in the subject); --mass and --marker-set win.  A file that is not a
    Scale setup, a mass that is not a number, a marker set that is not there, a URDF base model: one line each,
    exit 2, nothing written."""
    from calibrate.io.osim_setup import scale_setup

    src = tmp_path / "muscled.osim"
    src.write_text(muscle_osim())
    model = load_model(src)
    trc = _muscled_trial(tmp_path, model)
    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "ms.xml").write_text(
        "<?xml version='1.0'?><OpenSimDocument Version='40000'><MarkerSet><objects><Marker name='NEW'>"
        "<socket_parent_frame>/bodyset/shank</socket_parent_frame><location>0.05 -0.25 0</location></Marker>"
        "</objects></MarkerSet></OpenSimDocument>")
    setup = tmp_path / "lab" / "setup_Scale.xml"
    setup.write_text(_scale_setup("61.5", "ms.xml"))
    assert scale_setup(setup).mass == 61.5 and scale_setup(setup).marker_set == tmp_path / "lab" / "ms.xml"
    for k, (extra, kg, source) in enumerate([([], 61.5, str(setup)), (["--mass", "70"], 70.0, "given")]):
        out = tmp_path / f"run{k}"
        out.mkdir()
        code = main([str(trc), str(src), "--scale-setup", str(setup), "-o", str(out / "s.osim"), *extra])
        captured = capsys.readouterr()
        assert code == 0, captured.err
        report = json.loads((out / "trial_report.json").read_text())
        assert report["mass"]["subject_kg"] == pytest.approx(kg) and report["mass"]["from"] == source
        bodies = ET.parse(out / "s.osim").getroot().iter("Body")
        assert sum(float(b.findtext("mass")) for b in bodies) == pytest.approx(kg, rel=1e-6)
        assert "NEW" in load_model(out / "s.urdf").marker_names  # the setup's marker set, on the shank
        taken = "mass 61.5 kg, marker set ms.xml taken" if k == 0 else "marker set ms.xml taken"  # --mass: given
        assert f"note: {setup.name}: {taken}" in captured.err, captured.err
    # bad input: one line, exit 2, nothing written
    from calibrate.model.model import write_model

    urdf = write_model(model, tmp_path / "base.urdf")
    cases = [(src, _scale_setup("61.5", "ms.xml", tool="InverseKinematicsTool"), "no <ScaleTool>"),
             (src, _scale_setup("heavy", "ms.xml"), "<mass> 'heavy' is not a number"),
             (src, _scale_setup("61.5", "nothere.xml"), "its marker set file 'nothere.xml' is not at"),
             (urdf, _scale_setup("61.5", "ms.xml"), "is not one; give --mass")]
    for k, (base, text, needle) in enumerate(cases):
        bad = tmp_path / "lab" / f"bad{k}.xml"
        bad.write_text(text)
        _assert_refused(capsys, tmp_path / f"out{k}", trc, base, "--scale-setup", bad, needle)


def test_inspect_a_setup_says_what_calibrate_takes(tmp_path, capsys):
    """`calibrate inspect FILE.xml`: a Scale setup's mass and marker set, an IK setup's applied coordinate tasks (what
    --scale-setup and --ik-setup take) and what neither uses; a MarkerSet or other XML: one line, exit 2."""
    (tmp_path / "ms.xml").write_text("<?xml version='1.0'?><OpenSimDocument Version='40000'><MarkerSet><objects/>"
                                     "</MarkerSet></OpenSimDocument>")
    scale = tmp_path / "setup_Scale.xml"
    scale.write_text(_scale_setup("61.5", "ms.xml"))
    assert main(["inspect", str(scale)]) == 0
    out = capsys.readouterr().out
    assert "an OpenSim Scale setup" in out and f"body mass 61.5 kg, marker set {tmp_path / 'ms.xml'}" in out
    ik = tmp_path / "setup_IK.xml"
    ik.write_text(_ik_setup(_task("hip_q") + _task("knee_q", "manual_value", -0.25) + _task("p_rx", apply="false")))
    assert main(["inspect", str(ik)]) == 0
    out = capsys.readouterr().out
    assert "locks 2 coordinates its tasks hold: hip_q (the model's default), knee_q (-0.25)" in out
    assert "its 1 applied marker tasks" in out
    assert main(["inspect", str(tmp_path / "ms.xml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calibrate inspect MODEL.osim --marker-set ms.xml" in err[0]


@pytest.mark.skipif(not (REAL / "rajagopal_walk").exists(), reason="needs ../shared/data/real/rajagopal_walk")
def test_inspect_names_the_marker_sets_fixed_markers(tmp_path, capsys):
    """OpenSim's `<fixed>` flags (its marker placer keeps those markers where the model puts them; calibrate places
    every marker alike): `calibrate inspect MODEL.osim --marker-set FILE.xml` counts and names them, the marker set's
    flag replacing the model's for a marker of the same name, as its markers do; a marker set without any fixed
    (gait2392's) says nothing."""
    from calibrate.io.osim_info import fixed_flags

    raj = REAL / "rajagopal_walk"
    ms = ET.parse(raj / "markerset_walk_preScale.xml").getroot()
    want = [m.get("name") for m in ms.iter("Marker") if (m.findtext("fixed") or "").strip() == "true"]
    ms_file = raj / "markerset_walk_preScale.xml"
    assert main(["inspect", str(raj / "Rajagopal2016.osim"), "--marker-set", str(ms_file)]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("  fixed markers:"))
    assert line.startswith(f"  fixed markers: {len(want)} of its ") and len(want) == 37
    assert set(out.splitlines()[out.splitlines().index(line) + 1].strip().split(", ")) == set(want)
    # the marker set's flag over the model's: R.ASIS fixed in the set, unfixed in a copy of it
    loose = tmp_path / "loose.xml"
    text = (raj / "markerset_walk_preScale.xml").read_text()
    at = text.index('<Marker name="R.ASIS">')
    end = text.index("</Marker>", at)
    assert "<fixed>true</fixed>" in text[at:end]
    loose.write_text(text[:at] + text[at:end].replace("<fixed>true</fixed>", "<fixed>false</fixed>") + text[end:])
    assert fixed_flags(raj / "Rajagopal2016.osim", raj / "markerset_walk_preScale.xml")["R.ASIS"]
    assert not fixed_flags(raj / "Rajagopal2016.osim", loose)["R.ASIS"]
    assert main(["inspect", str(GAIT), "--marker-set", str(GAIT_MARKERS)]) == 0
    assert "fixed markers" not in capsys.readouterr().out


_SCALE_AND_IK = r"""
import os, sys
import opensim as osim
osim.Logger.removeFileSink()  # no opensim.log in the working directory
osim.Logger.setLevelString("warn")
folder, scale, ik = sys.argv[1:4]
os.chdir(folder)
before = set(os.listdir("."))
assert osim.ScaleTool(scale).run() and osim.InverseKinematicsTool(ik).run()
print("\n".join(sorted(set(os.listdir(".")) - before)))
"""


@pytest.mark.skipif(importlib.util.find_spec("opensim") is None or not GAIT.exists(),
                    reason="needs the opensim package (pip install -e '.[opensim]') and ../shared/data/real/gait2392")
def test_setup_names_are_where_opensims_own_tools_write(tmp_path, capsys):
    """gait2392's pipeline as the lab runs it: OpenSim's Scale and IK tools from subject01_Setup_Scale.xml and
    subject01_Setup_IK.xml (a child process) write the subject, its marker set (the marker placer's output_marker_file,
    set here), its scale factors, the static's and the walk's motions, the walk's marker errors and its model marker
    locations (report_marker_locations, set here) under names of their own; `calibrate ... --setup-names` writes
    its own at exactly those paths (what the lab's ID, SO and CMC setups read), and OpenSim loads them: the .mot's
    coordinates are the model's, the marker set every marker, the scale set an entry per frame, which applied to the
    generic model scales its meshes as the subject's; the marker locations are OpenSim's columns, and OpenSim's own
    markers at our motion; read back as --marker-set, the subject's markers again.  The setups alone (no trial, no
    model: those they name) give the same calibration; `calibrate ik --ik-setup` alone the same motion."""
    files = ("gait2392_Scale_MarkerSet.xml", "subject01_static.trc", "subject01_walk1.trc",
             "subject01_Setup_Scale.xml", "subject01_Setup_IK.xml")
    lab, ours = tmp_path / "opensim", tmp_path / "calibrate"
    for d in (lab, ours):
        d.mkdir()
        for f in files:
            (d / f).write_bytes((REAL / "gait2392" / f).read_bytes())
        # the marker placer's marker set file too (gait2392's setup leaves it Unassigned; Rajagopal's names one)
        scale = (d / files[3]).read_text()
        assert scale.count("<output_marker_file> Unassigned </output_marker_file>") == 1
        (d / files[3]).write_text(scale.replace("<output_marker_file> Unassigned </output_marker_file>",
                                                "<output_marker_file> subject01_markers.xml </output_marker_file>"))
        # and the IK's model marker locations (OpenSim's default leaves them out)
        ik = (d / files[4]).read_text()
        assert ik.count("<report_errors>true</report_errors>") == 1 and "report_marker_locations" not in ik
        (d / files[4]).write_text(ik.replace("<report_errors>true</report_errors>", "<report_errors>true"
                                             "</report_errors><report_marker_locations>true</report_marker_locations>"))
    # the Scale setup's generic model is gait2392_simbody.osim (../shared/data/real/README.md)
    (lab / "gait2392_simbody.osim").write_bytes(GAIT.read_bytes())
    child = subprocess.run([sys.executable, "-c", _SCALE_AND_IK, str(lab), files[3], files[4]], capture_output=True,
                           text=True, timeout=600)
    assert child.returncode == 0, child.stderr[-2000:]
    written = set(child.stdout.split())
    assert {"subject01_simbody.osim", "subject01_walk1_ik.mot", "subject01_ik_marker_errors.sto",
            "subject01_static_output.mot", "subject01_markers.xml", "subject01_ik_model_marker_locations.sto",
            "subject01_scaleSet_applied.xml"} <= written  # the lab's tools' names
    (ours / "out").mkdir()
    argv = [str(ours / files[1]), str(ours / files[2]), str(GAIT), "--marker-set", str(ours / files[0]),
            "--scale-setup", str(ours / files[3]), "--ik-setup", str(ours / files[4]), "--setup-names", "-o",
            str(ours / "out") + os.sep, "-q"]
    assert main(argv) == 0, capsys.readouterr().err
    capsys.readouterr()
    # run again: the files the setups name are there (as an OpenSim run's would be): one line saying so, exit 2
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists; the lab's setup names it" in err and "--overwrite" in err, err
    # the walk's marker errors count the markers OpenSim's counts, frame by frame: those its IK setup's marker tasks
    # track (sum of squares over RMS squared; the frames OpenSim wrote from the same setup)
    def counts(path: Path) -> np.ndarray:
        lines = path.read_text().splitlines()
        rows = np.array([[float(v) for v in line.split("\t")] for line in lines[lines.index("endheader") + 2:]])
        return np.round(rows[:, 1] / rows[:, 2] ** 2)

    sto = "subject01_ik_marker_errors.sto"
    assert np.array_equal(counts(ours / sto), counts(lab / sto)) and counts(lab / sto).max() == 31
    mine = {p.name for p in ours.iterdir() if p.suffix in (".osim", ".mot", ".sto")
            or p.name.endswith(("markers.xml", "scaleSet_applied.xml"))}
    assert mine == {"subject01_simbody.osim", "subject01_static_output.mot", "subject01_walk1_ik.mot",
                    "subject01_ik_marker_errors.sto", "subject01_markers.xml", "subject01_scaleSet_applied.xml",
                    "subject01_ik_model_marker_locations.sto"} and mine <= written
    # the model marker locations: OpenSim's columns (the tracked markers, in the trial's order) and frames
    def sto(path: Path) -> tuple[list[str], np.ndarray]:
        lines = path.read_text().splitlines()
        at = lines.index("endheader")
        return lines[at + 1].split("\t"), np.array([[float(v) for v in line.split("\t")] for line in lines[at + 2:]])

    locations = "subject01_ik_model_marker_locations.sto"
    (cols, ours_at), (lab_cols, lab_at) = sto(ours / locations), sto(lab / locations)
    # (the TRC prints its times to the millisecond; calibrate's are the frames' at the trial's rate)
    assert cols == lab_cols and len(cols) == 1 + 3 * 31 and np.allclose(ours_at[:, 0], lab_at[:, 0], atol=5e-4)
    # the marker set file carries the subject's markers: the subject with it read as --marker-set is the same
    subject = load_model(ours / "subject01_simbody.osim")
    again = load_model(ours / "subject01_simbody.osim", ours / "subject01_markers.xml")
    assert again.marker_names == subject.marker_names
    assert np.array_equal(again.parameters().marker, subject.parameters().marker)
    assert not any(p.suffix in (".osim", ".mot") for p in (ours / "out").iterdir())  # the rest where -o says
    check = subprocess.run([sys.executable, "-c", r"""
import json, sys
import opensim as osim
osim.Logger.removeFileSink()
osim.Logger.setLevelString("error")  # (not a warning for each mesh file, which the test has not copied)
model = osim.Model(sys.argv[1])
cs = model.getCoordinateSet()
names = {cs.get(i).getName() for i in range(cs.getSize())}
table = osim.TimeSeriesTable(sys.argv[2])
print(table.getNumRows(), int(set(table.getColumnLabels()) <= names), osim.MarkerSet(sys.argv[3]).getSize())

def meshes(m):  # (frame, mesh file) -> its scale factors, every frame's meshes
    out = {}
    for f in m.getFrameList():
        for i in range(f.getPropertyByName("attached_geometry").size()):
            mesh = osim.Mesh.safeDownCast(f.get_attached_geometry(i))
            if mesh is not None:
                out[mesh.get_mesh_file()] = mesh.get_scale_factors().to_numpy().tolist()
    return out

# the scale factors applied to the generic model by OpenSim: every bone mesh scaled as in the subject
scales = osim.ScaleSet(sys.argv[4])
generic = osim.Model(sys.argv[5])
generic.scale(generic.initSystem(), scales, True, -1.0)
print(json.dumps([scales.getSize(), meshes(generic), meshes(model)]))

# the subject posed by the walk's .mot (degrees for the rotations): its markers where the tracked ones go in ours
state = model.initSystem()
names = [label[:-3] for label in osim.TimeSeriesTable(sys.argv[6]).getColumnLabels()[::3]]
at = []
for i in range(table.getNumRows()):
    for name, v in zip(table.getColumnLabels(), table.getRowAtIndex(i).to_numpy()):
        c = cs.get(name)
        c.setValue(state, v * 3.141592653589793 / 180 if c.getMotionType() == 1 else v, False)
    model.realizePosition(state)
    at.append([x for n in names for x in model.getMarkerSet().get(n).getLocationInGround(state).to_numpy().tolist()])
print(json.dumps(at))
""", str(ours / "subject01_simbody.osim"), str(ours / "subject01_walk1_ik.mot"), str(ours / "subject01_markers.xml"),
        str(ours / "subject01_scaleSet_applied.xml"), str(GAIT), str(ours / locations)], capture_output=True,
        text=True, timeout=600)
    assert check.returncode == 0, check.stderr[-2000:]
    # the IK setup's frames, every column a coordinate of the model; OpenSim reads the marker set, every marker
    assert check.stdout.splitlines()[-3].split() == ["121", "1", str(len(subject.marker_names))]
    # OpenSim's markers on the subject at our walk's coordinates are our model marker locations (to rounding)
    assert np.abs(np.array(json.loads(check.stdout.splitlines()[-1])) - ours_at[:, 1:]).max() < 1e-9
    # the scale set: OpenSim reads an entry per physical frame of the subject (ground, 12 bodies, 26 offset
    # frames), and applied by OpenSim to the generic model it scales each of its 20 meshes as the subject's
    size, scaled, own = json.loads(check.stdout.splitlines()[-2])
    tree = ET.parse(ours / "subject01_simbody.osim").getroot()
    assert size == 1 + len(list(tree.iter("Body"))) + len(list(tree.iter("PhysicalOffsetFrame"))) == 39
    assert len(scaled) == len(own) == 20 and scaled.keys() == own.keys()
    assert max(abs(a - b) for k in own for a, b in zip(scaled[k], own[k], strict=True)) < 1e-12
    # the factors are the calibration's segment scales (its report's), which the report names the file of
    report = json.loads((ours / "out" / "subject01_static_report.json").read_text())
    factors = {sc.findtext("segment"): [float(x) for x in sc.findtext("scales").split()]
               for sc in ET.parse(ours / "subject01_scaleSet_applied.xml").getroot().iter("Scale")}
    segments = {p["name"][6:-1]: p["value"][0] for p in report["parameters"] if p["group"] == "scale"}
    assert len(segments) == 12 and all(np.allclose(factors[k], v, atol=1e-8) for k, v in segments.items())
    assert factors["ground"] == [1.0] * 3 and factors["femur_l_offset_knee_l"] == factors["femur_l"]
    assert Path(report["outputs"]["scale_set"]) == ours / "subject01_scaleSet_applied.xml"
    # calibrate ik with the lab's IK setup writes its .mot and marker errors there too (replacing them: --overwrite)
    before = {n: (ours / n).stat().st_mtime_ns for n in ("subject01_walk1_ik.mot", "subject01_ik_marker_errors.sto",
                                                         locations)}
    assert main(["ik", str(ours / files[2]), str(ours / "subject01_simbody.osim"), "--ik-setup", str(ours / files[4]),
                 "--setup-names", "-o", str(ours / "out"), "--overwrite", "-q"]) == 0
    assert all((ours / n).stat().st_mtime_ns > t for n, t in before.items())
    assert sto(ours / locations)[0] == lab_cols  # the same markers (those the IK setup tracks) from calibrate ik
    assert (ours / "out" / "subject01_walk1_motion.csv").is_file()
    # calibrate ik with the IK setup alone runs it as OpenSim's IK tool does: its model_file and marker_file, its
    # outputs where it names them (the motion CSV beside its .mot): the same fit, the same .mot to the byte
    mot = (ours / "subject01_walk1_ik.mot").read_text()
    assert main(["ik", "--ik-setup", str(ours / files[4]), "--overwrite", "-q"]) == 0
    assert (ours / "subject01_walk1_ik.mot").read_text() == mot
    csv = (ours / "out" / "subject01_walk1_motion.csv").read_text()
    assert (ours / "subject01_walk1_motion.csv").read_text() == csv
    # the setups alone, as OpenSim's Scale and IK tools run them: the generic model and the static the Scale setup
    # names (gait2392_simbody.osim, as its setup calls gait2392.osim), the walk the IK setup names: the same calibration
    drop = tmp_path / "dropin"
    (drop / "out").mkdir(parents=True)
    for f in files:
        (drop / f).write_bytes((ours / f).read_bytes())
    (drop / "gait2392_simbody.osim").write_bytes(GAIT.read_bytes())
    assert main(["--scale-setup", str(drop / files[3]), "--ik-setup", str(drop / files[4]), "-o",
                 str(drop / "out") + os.sep, "-q"]) == 0
    assert {p.name for p in drop.iterdir() if p.suffix in (".osim", ".mot", ".sto") or p.name.endswith(
        ("markers.xml", "scaleSet_applied.xml"))} >= mine
    static = "subject01_static_motion.csv"
    assert (drop / "out" / static).read_text() == (ours / "out" / static).read_text()
    # without the setups' names to take, refused in one line
    capsys.readouterr()
    assert main([str(ours / files[1]), str(GAIT), "--setup-names", "-o", str(ours / "out") + os.sep]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--setup-names" in err and "--scale-setup" in err


def test_the_setups_alone_write_beside_the_subject_not_among_the_data(tmp_path, capsys):
    """`calibrate --scale-setup Scale/Setup_Scale.xml` alone, a lab's folders (Scale/, data/): the generic model and
    static trial the setup names (read against its folder), the subject .osim where it names it, and calibrate's own
    outputs (URDF, motion CSV, report) beside that .osim: nothing written among the lab's data."""
    from calibrate.io.osim_export import export_osim
    from calibrate.simulation.simulate import simulate_squats, write_simulation

    human = load_model(Path(__file__).resolve().parent.parent / "models" / "human.urdf")
    export_osim(human, tmp_path / "human.osim")
    write_simulation(simulate_squats(human, frames=60, noise_mm=1.0, seed=14), tmp_path / "data")
    (tmp_path / "Scale").mkdir()
    (tmp_path / "Scale" / "Setup_Scale.xml").write_text(
        "<?xml version='1.0'?><OpenSimDocument Version='40000'><ScaleTool name='S1'><mass>70</mass>"
        "<GenericModelMaker><model_file>../human.osim</model_file></GenericModelMaker><MarkerPlacer><apply>true</apply>"
        "<marker_file>../data/trial.c3d</marker_file><output_model_file>S1.osim</output_model_file></MarkerPlacer>"
        "</ScaleTool></OpenSimDocument>")
    data = sorted(p.name for p in (tmp_path / "data").iterdir())
    assert main(["--scale-setup", str(tmp_path / "Scale" / "Setup_Scale.xml"), "-q"]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == data
    assert {"S1.osim", "S1.urdf", "trial_motion.csv", "trial_report.json", "trial_motion.mot"} <= \
        {p.name for p in (tmp_path / "Scale").iterdir()}
