"""A chain of joints coupled to one joint's coordinates (a lumbar spine whose vertebrae follow L5/S1's
coordinates through CoordinateCouplerConstraints, as in Pose2Sim's and the lifting models): imported as one
lumped joint that turns the chain's last body by the chain's whole turn (calibrate.io.osim.LUMPED), checked
against OpenSim itself (the `opensim` package in a child process, as tests/test_osim_import.py does).

Before the lumped joint the chain's coupled joints were welded, so the trunk turned by L5/S1's share alone.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.io.osim import IN_CHAIN, LUMPED
from calibrate.io.osim_info import osim_info, root_coordinates
from calibrate.model.model import load_model
from tests.test_opensim_export import _run_worker
from tests.test_osim_import import (
    _BODY,
    _EXPORT_WORKER,
    _WORKER,
    HAVE_OPENSIM,
    TOL,
    _c,
    _coords,
    _frames,
    _ik_setup,
    _kabsch_residual,
    _lin,
    _local,
    _pin_markers,
    _ta,
    _task,
    ground_free,
)

# (coordinate, range) of the driving joint, and each coupled joint's slopes on them (flexion, bending, rotation)
DRIVER = (("lum_flex", -0.25, 0.08), ("lum_bend", -0.05, 0.05), ("lum_rot", -0.12, 0.12))
SLOPES = {"v2": (1.6, 1.3, 1.0), "v3": (1.2, 2.0, 0.9), "chest": (0.7, 1.5, 0.8)}
RATIOS = tuple(1 + sum(s[k] for s in SLOPES.values()) for k in range(3))  # the chain's whole turn per unit


def _custom(name: str, parent: str, child: str, coords: tuple[str, str, str], funcs: tuple[str, str, str],
            offset: str, tilt: str, ranges: str = "") -> str:
    return (f"<CustomJoint name=\"{name}\">{_frames(parent, child, offset, tilt)}{ranges}<SpatialTransform>"
            + _ta("rotation1", "0 0 1", coords[0], funcs[0]) + _ta("rotation2", "1 0 0", coords[1], funcs[1])
            + _ta("rotation3", "0 1 0", coords[2], funcs[2]) + _ta("translation1", "1 0 0", "", _c())
            + _ta("translation2", "0 1 0", "", _c()) + _ta("translation3", "0 0 1", "", _c())
            + "</SpatialTransform></CustomJoint>")


def spine_osim(share: float = 1.0, christophy: bool = False) -> str:
    """pelvis -> v1 (the driving joint, three coordinates) -> v2 -> v3 -> chest (each coupled) -> head (a pin, exact);
    an abdomen coupled beside the chain, without markers; vertebrae 3-4 cm apart, each tilted (a lordosis).
    `share`: the driving joint turns by this share of its coordinates (LinearFunction slope; Christophy's lumbar
    spine: each joint a share of the whole turn); `christophy`: also a marker on a vertebra the chain passes (v2),
    ribs welded to the chest with a marker, and the neck a CustomJoint turning by half its coordinate."""
    bodies = "".join(_BODY.format(name=n, mass=m) for n, m in
                     [("pelvis", 10), ("v1", 1), ("v2", 1), ("v3", 1), ("chest", 20), ("head", 5), ("abdomen", 1)]
                     + ([("ribs", 2)] if christophy else []))
    joints = [
        ground_free("pelvis"),
        _custom("lumbar", "pelvis", "v1", tuple(n for n, _, _ in DRIVER), (_lin(share), _lin(share), _lin(share)),
                "-0.09 0.07 0", "0 0 0.15", _coords(*DRIVER)),
    ]
    parent = "v1"
    for k, (child, _) in enumerate(SLOPES.items()):
        names = tuple(f"{child}_{a}" for a in ("flex", "bend", "rot"))
        offset = ("0.008 0.032 0.001", "-0.004 0.034 0", "0.01 0.05 0.002")[k]
        joints.append(_custom(f"{parent}_{child}", parent, child, names, (_lin(), _lin(), _lin()), offset,
                              f"0 0 {(-0.08, -0.1, 0.05)[k]}", _coords(*[(n, -99999, 99999) for n in names])))
        parent = child
    if christophy:
        joints.append(_custom("neck", "chest", "head", ("neck_q", "", ""), (_lin(0.5, 0.1), _c(), _c(0.2)), "0 0.45 0",
                              "0 0 0", _coords(('neck_q', -0.6, 0.6))))
        joints.append(f"<WeldJoint name=\"ribcage\">{_frames('chest', 'ribs', '0.02 0.2 0', '0.1 0 0')}</WeldJoint>")
    else:
        joints.append(f"<PinJoint name=\"neck\">{_frames('chest', 'head', '0 0.45 0', '0 0 0')}"
                      f"{_coords(('neck_q', -0.6, 0.6))}</PinJoint>")
    abd = ("abd_flex", "abd_bend", "abd_rot")
    joints.append(_custom("abdominal", "pelvis", "abdomen", abd, (_lin(), _lin(), _lin()), "0.05 0.1 0", "0 0 0",
                          _coords(*[(n, -99999, 99999) for n in abd])))
    couplers = []
    for child, slopes in [*SLOPES.items(), ("abd", (3.0, 2.0, 1.0))]:
        for (ind, _, _), a, s in zip(DRIVER, ("flex", "bend", "rot"), slopes, strict=True):
            couplers.append(
                f"<CoordinateCouplerConstraint name=\"{child}_{a}_con\"><isEnforced>true</isEnforced>"
                f"<coupled_coordinates_function>" + _lin(s, 0).replace(' name="function"', "")
                + f"</coupled_coordinates_function><independent_coordinate_names>{ind}</independent_coordinate_names>"
                f"<dependent_coordinate_name>{child}_{a}</dependent_coordinate_name><scale_factor>1</scale_factor>"
                f"</CoordinateCouplerConstraint>")
    places = {"pelvis": ["0.1 0 0.12", "0.1 0 -0.12", "-0.1 0.05 0"], "chest": ["0.1 0.35 0.15", "0.1 0.35 -0.15",
              "-0.08 0.4 0", "0.03 0.2 0.12"], "head": ["0.1 0.1 0", "0 0.2 0.07"]}
    if christophy:
        places.update({"v2": ["-0.06 0.01 0"], "ribs": ["0.12 0.05 0.1"]})
    markers = "".join(f"<Marker name=\"{b}{k}\"><socket_parent_frame>/bodyset/{b}</socket_parent_frame>"
                      f"<location>{x}</location><fixed>false</fixed></Marker>"
                      for b, xs in places.items() for k, x in enumerate(xs))
    return ("<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40000\"><Model name=\"spine\">"
            "<Ground name=\"ground\"/><gravity>0 -9.80665 0</gravity>"
            f"<BodySet name=\"bodyset\"><objects>{bodies}</objects></BodySet>"
            f"<JointSet name=\"jointset\"><objects>{''.join(joints)}</objects></JointSet>"
            f"<ConstraintSet name=\"constraintset\"><objects>{''.join(couplers)}</objects></ConstraintSet>"
            f"<MarkerSet name=\"markerset\"><objects>{markers}</objects></MarkerSet></Model></OpenSimDocument>\n")


def test_lumped_chain_structure(tmp_path):
    """One DoF per driving coordinate, turned by the chain's whole turn; the coupled joints welded and named."""
    path = tmp_path / "spine.osim"
    path.write_text(spine_osim())
    model = load_model(path)
    info = osim_info(model)
    kinds = {a.joint: a.kind for a in info.approximations}
    assert kinds == {"lumbar": LUMPED, "v1_v2": IN_CHAIN, "v2_v3": IN_CHAIN, "v3_chest": IN_CHAIN,
                     "abdominal": "welded (coupled)"}
    assert [d for d in model.dof_names if d.startswith(("lum", "v2_", "v3_", "chest_"))] == [n for n, _, _ in DRIVER]
    lumped = next(a for a in info.approximations if a.kind == LUMPED)
    assert set(lumped.markers) == {"chest0", "chest1", "chest2", "chest3", "head0", "head1"}
    # its axes orthonormal as the driving joint's are: a ball the solver keeps on SO(3), without limits
    from calibrate.model.kinematics import so3_balls

    assert "lumbar" in {b.name for b in so3_balls(model)}
    # each ratio near the couplers' sum (the vertebrae's axes are tilted, so not equal to it)
    for (name, lo, hi), total in zip(DRIVER, RATIOS, strict=True):
        assert info.ratio(name) == pytest.approx(total, rel=0.1)
        dof = model.dofs[model.dof_index(name)]
        assert (dof.lower, dof.upper) == pytest.approx((info.ratio(name) * lo, info.ratio(name) * hi))
    # written and read back (a calibrated subject keeps its ratios)
    from calibrate.model.model import write_model

    again = osim_info(load_model(write_model(model, tmp_path / "s.urdf")))
    assert again.ratios == pytest.approx(info.ratios)
    assert lumped.one_mm is not None and 0 < lumped.one_mm < lumped.max_marker_mm
    assert next(a for a in again.approximations if a.kind == LUMPED).one_mm == pytest.approx(lumped.one_mm)


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed (pip install -e '.[opensim]')")
def test_lumped_chain_against_opensim(tmp_path):
    """At random poses within the ranges (the couplers followed by OpenSim), the pelvis's markers are exact, the
    chain's within the reported bound and far nearer than the weld that came before (the chain's turn at the
    driving joint's share), the head's exact relative to the chest; and the exported subject with its .mot puts
    every marker where calibrate does (the ratio written as the coordinate's LinearFunction)."""
    path = tmp_path / "spine.osim"
    path.write_text(spine_osim())
    model = load_model(path)
    info = osim_info(model)
    rng = np.random.default_rng(5)
    poses, ours, welded = [], [], []
    share = np.array([1 / info.ratio(d) if d in info.ratios else 1.0 for d in model.dof_names])
    for k in range(75):
        coords = {n: float(rng.uniform(lo, hi)) for n, lo, hi in DRIVER}
        if k >= 60:  # one coordinate over its range, the others at mid-range (the import's one-coordinate figure)
            coords = {n: 0.5 * (lo + hi) for n, lo, hi in DRIVER}
            n, lo, hi = DRIVER[k % 3]
            coords[n] = lo + (hi - lo) * (k - 60) / 14
        coords["neck_q"] = float(rng.uniform(-0.6, 0.6))
        t, quat = rng.normal(0, 0.5, 3), Rotation.random(random_state=k).as_quat()
        angles = np.array([info.ratio(d) * coords[d] for d in model.dof_names])  # the URDF's angle
        root = root_coordinates(info, t[None], quat[None])
        poses.append({**coords, **{n: float(v[0]) for n, v in root.items()}})
        ours.append(_pin_markers(model, t, quat, angles))
        welded.append(_pin_markers(model, t, quat, angles * share))  # the chain turned by lumbar's own share
    # a calibrated-like subject, exported, with a .mot of its own random poses
    from calibrate.io.motion import Motion
    from calibrate.io.osim_export import export_osim, write_mot
    from calibrate.model.model import Parameters, write_model

    p0 = model.parameters()
    p = Parameters(1 + rng.uniform(-0.1, 0.1, p0.scale.shape), p0.centre + rng.uniform(-0.01, 0.01, p0.centre.shape),
                   p0.axis + rng.uniform(-0.05, 0.05, p0.axis.shape), p0.marker + rng.uniform(-0.01, 0.01,
                                                                                              p0.marker.shape))
    subject = load_model(write_model(model, tmp_path / "s.urdf", p))
    n = 15
    angles = np.array([[rng.uniform(d.lower, d.upper) for d in subject.dofs] for _ in range(n)])
    motion = Motion(np.arange(n) / 100, rng.normal(0, 0.5, (n, 3)), Rotation.random(n, random_state=9).as_quat(),
                    angles, subject.dof_names)
    export = {"osim": str(export_osim(subject, tmp_path / "s.osim")), "mot": str(write_mot(tmp_path / "s.mot",
                                                                                         subject, motion))}
    theirs = _run_worker(tmp_path, [{"osim": str(path), "marker_set": None, "poses": poses, "bodies": ["chest"]}],
                         _WORKER, 300)[0]
    exported = _run_worker(tmp_path, [export], _EXPORT_WORKER, 300)[0]

    def err(refs: list[dict], m: str) -> np.ndarray:
        return np.array([np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(theirs, refs, strict=True)])

    lumped = next(a for a in info.approximations if a.kind == LUMPED)
    assert max(err(ours, m).max() for m in ("pelvis0", "pelvis1", "pelvis2")) < TOL
    chain = [m for m in model.marker_names if m.startswith(("chest", "head"))]
    worst = max(err(ours, m).max() for m in chain)
    assert worst <= lumped.bound_mm / 1000 + TOL
    one = max(err(ours, m)[60:].max() for m in chain)
    assert one <= 1.05 * lumped.one_mm / 1000 + 5e-4, (one, lumped.one_mm)
    mean_ours = np.mean([err(ours, m).mean() for m in chain])
    mean_welded = np.mean([err(welded, m).mean() for m in chain])
    assert mean_ours < 0.2 * mean_welded, (mean_ours, mean_welded)
    print(f"chain markers: mean {1000 * mean_ours:.2f} mm, largest {1000 * worst:.2f} mm (reported "
          f"{lumped.max_marker_mm:.2f}, bound {lumped.bound_mm:.2f}); welded at the driver's share: mean "
          f"{1000 * mean_welded:.1f} mm")
    # the head rides on the chest exactly: one rigid motion between our chest frame and OpenSim's chest body
    a = np.array([_local(r["body chest"], r[m]) for r in ours for m in ("head0", "head1")])
    b = np.array([_local(o["body chest"], o[m]) for o in theirs for m in ("head0", "head1")])
    assert _kabsch_residual(a, b) < TOL
    # the exported subject and its .mot: OpenSim's coordinates (the URDF's angle over the ratio)
    refs = [_pin_markers(subject, motion.root_translation[f], motion.root_quaternion[f], angles[f]) for f in range(n)]
    off = max(np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(exported["frames"], refs, strict=True)
              for m in subject.marker_names)
    assert off < TOL
    assert {n for n, _, _ in DRIVER} <= set(exported["labels"])


def test_lumped_chain_said_and_setups_read_in_opensims_coordinate(tmp_path, capsys):
    """`calibrate inspect` names the lumped chain, its ratios and its one-coordinate figure; an IK setup's task
    value (OpenSim's coordinate) is held as the URDF's angle, its ratio times over."""
    from calibrate.cli import main
    from calibrate.io.osim_setup import ik_setup_locks

    path = tmp_path / "spine.osim"
    path.write_text(spine_osim())
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.strip().startswith("lumbar: lumped chain"))
    info = osim_info(load_model(path))
    assert f"{info.ratio('lum_flex'):.3g} × lum_flex" in line and "one coordinate at a time up to" in line
    assert "v1_v2: in a lumped chain" in out
    setup = tmp_path / "ik.xml"
    setup.write_text(_ik_setup(_task("lum_bend", "manual_value", 0.02) + _task("neck_q", "manual_value", 0.3)))
    locks = dict(ik_setup_locks(setup, load_model(path)))
    assert locks == pytest.approx({"lum_bend": 0.02 * info.ratio("lum_bend"), "neck_q": 0.3})


def test_inspect_an_osim_without_markers(tmp_path, capsys):
    """A model whose markers come in a MarkerSet file (OpenSense's, SoccerKick's): `inspect` describes its joints
    and approximations and says that calibrating needs the marker set; loading it to calibrate is still refused."""
    import re

    from calibrate.cli import main
    from calibrate.errors import NoMarkersError

    path = tmp_path / "bare.osim"
    path.write_text(re.sub(r"<MarkerSet name=\"markerset\">.*</MarkerSet>", "", spine_osim()))
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "no markers" in out.splitlines()[0] and "--marker-set FILE.xml" in out
    assert "v1_v2: welded (coupled)" in out  # no marker rides the chain: nothing to lump it for
    assert "calibrate_default_pose_probe" not in out
    with pytest.raises(NoMarkersError, match="no markers on its bodies"):
        load_model(path)


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed (pip install -e '.[opensim]')")
def test_a_share_driven_chain_and_its_passengers_against_opensim(tmp_path):
    """Christophy's lumbar spine: the driving joint turns by a share of its coordinates (LinearFunction slope 0.3),
    the vertebrae follow; a marker on a vertebra the chain passes, ribs welded to the chest, a neck turning by half
    its coordinate.  Against OpenSim at random poses: the neck exact with ratio 0.5 (the head exact relative to the
    chest), the ribs exact relative to the chest, every marker of the chain within the reported bound, the vertebra's
    among them.  (Before, the driving joint's rotations were frozen: no lumbar coordinate was a DoF.)"""
    path = tmp_path / "christophy.osim"
    path.write_text(spine_osim(share=0.3, christophy=True))
    model = load_model(path)
    info = osim_info(model)
    kinds = {a.joint: a.kind for a in info.approximations}
    assert kinds["lumbar"] == LUMPED and "neck" not in kinds and "ribcage" not in kinds
    assert info.ratio("neck_q") == pytest.approx(0.5)
    for (name, _, _), k in zip(DRIVER, range(3), strict=True):
        assert info.ratio(name) == pytest.approx(0.3 + sum(sl[k] for sl in SLOPES.values()), rel=0.1)
    lumped = next(a for a in info.approximations if a.kind == LUMPED)
    assert {"v20", "ribs0", "head0", "chest0"} <= set(lumped.markers)
    rng = np.random.default_rng(8)
    poses, ours = [], []
    for k in range(40):
        coords = {n: float(rng.uniform(lo, hi)) for n, lo, hi in DRIVER}
        coords["neck_q"] = float(rng.uniform(-0.6, 0.6))
        t, quat = rng.normal(0, 0.5, 3), Rotation.random(random_state=100 + k).as_quat()
        angles = np.array([info.ratio(d) * coords[d] for d in model.dof_names])
        root = root_coordinates(info, t[None], quat[None])
        poses.append({**coords, **{n: float(v[0]) for n, v in root.items()}})
        ours.append(_pin_markers(model, t, quat, angles))
    theirs = _run_worker(tmp_path, [{"osim": str(path), "marker_set": None, "poses": poses, "bodies": ["chest"]}],
                         _WORKER, 300)[0]
    err = {m: max(np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(theirs, ours, strict=True))
           for m in model.marker_names}
    assert max(err[m] for m in ("pelvis0", "pelvis1", "pelvis2")) < TOL
    assert all(err[m] <= lumped.bound_mm / 1000 + TOL for m in lumped.markers)
    for riders in (("head0", "head1"), ("ribs0", "chest0", "chest1")):  # exact relative to the chest
        a = np.array([_local(r["body chest"], r[m]) for r in ours for m in riders])
        b = np.array([_local(o["body chest"], o[m]) for o in theirs for m in riders])
        assert _kabsch_residual(a, b) < TOL, riders
