"""A rotation coupled to another joint's coordinate, about the axis the next joint turns about (MoBL-ARMS's shoulder:
shoulder0 turns by elv_angle, shoulder1 by shoulder_elv and by shoulder1_r2 = -elv_angle about shoulder0's axis, and
shoulder2 by shoulder_rot about that same axis).  Imported, the coupled turn moves onto the next joint's revolute
exactly (calibrate.io.osim.FOLDED), whose URDF angle is then shoulder_rot - elv_angle; checked against OpenSim itself
(the `opensim` package in a child process, as tests/test_osim_import.py does), and back through the .osim export and
its .mot.  Before, shoulder1 was a fixed hinge with shoulder1_r2 held: 120 mm at this model's hand, 608 mm at
MoBL-ARMS's.  The three hinges turn about one centre through two light bodies without markers: one ball written as
an angle convention (OsimInfo.gimbals), whose axes the calibration holds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.errors import ModelError
from calibrate.io.osim import FOLDED
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
    _lin,
    _pin_markers,
    _ta,
    _task,
    ground_free,
)

A = "0.0048 0.99908918 0.04240001"  # MoBL-ARMS's axes (shoulder0's and shoulder2's, then shoulder1's own)
B = "-0.99826136 0.0023 0.05889802"
RANGES = {"elv_angle": (-1.5, 2.0), "shoulder_elv": (0.0, 2.5), "shoulder_rot": (-1.5, 0.5)}


def shoulder_osim(slope: float = -1.0, phantom: float = 1.0) -> str:
    """trunk -> upper (plane: elv_angle) -> mid (elevate: shoulder_elv, then elevate_r2 = slope · elv_angle about A)
    -> arm (rot: shoulder_rot about A); markers on the trunk and the arm only, the centre off the trunk's origin;
    `phantom`: the mass (kg) of upper and mid (MoBL-ARMS's humphant and humphant1: 1e-4)."""
    bodies = "".join(_BODY.format(name=n, mass=m) for n, m in [("trunk", 10), ("upper", phantom), ("mid", phantom),
                                                                ("arm", 2)])
    still = (_ta("translation1", "1 0 0", "", _c()) + _ta("translation2", "0 1 0", "", _c())
             + _ta("translation3", "0 0 1", "", _c()))
    joints = (
        ground_free("trunk", "0 0 0", prefix="t")
        + f"<CustomJoint name=\"plane\">{_frames('trunk', 'upper', '0 0.4 0.17', '0 0 0')}"
        f"{_coords(('elv_angle', *RANGES['elv_angle']))}<SpatialTransform>"
        + _ta("rotation1", A, "elv_angle", _lin()) + _ta("rotation2", "0 1 0", "", _c())
        + _ta("rotation3", "0.0424 0 -0.0048", "", _c()) + still + "</SpatialTransform></CustomJoint>"
        f"<CustomJoint name=\"elevate\">{_frames('upper', 'mid', '0 0 0', '0 0 0')}"
        f"{_coords(('shoulder_elv', *RANGES['shoulder_elv']), ('elevate_r2', -99, 99))}<SpatialTransform>"
        + _ta("rotation1", B, "shoulder_elv", _lin()) + _ta("rotation2", A, "elevate_r2", _lin())
        + _ta("rotation3", "-0.05874685 0.042609 -0.99736316", "", _c()) + still + "</SpatialTransform></CustomJoint>"
        f"<CustomJoint name=\"rot\">{_frames('mid', 'arm', '0 0 0', '0 0 0')}"
        f"{_coords(('shoulder_rot', *RANGES['shoulder_rot']))}<SpatialTransform>"
        + _ta("rotation1", A, "shoulder_rot", _lin()) + _ta("rotation2", "0 1 0", "", _c())
        + _ta("rotation3", "0.0424 0 -0.0048", "", _c()) + still + "</SpatialTransform></CustomJoint>")
    markers = "".join(
        f"<Marker name=\"{n}\"><socket_parent_frame>/bodyset/{b}</socket_parent_frame><location>{loc}</location>"
        f"</Marker>" for n, b, loc in [("T1", "trunk", "0.1 0 0"), ("T2", "trunk", "0 0.2 0"),
                                      ("T3", "trunk", "0 0 0.1"), ("ELB", "arm", "0.02 -0.3 0.04"),
                                      ("HAND", "arm", "-0.03 -0.55 0.05")])
    # MoBL-ARMS writes its couplers as SimmSplines of two points: a straight line the fold reads as one
    spline = (f"<SimmSpline><x> -1.5708 3.14159</x><y> {-1.5708 * slope:.6g} {3.14159 * slope:.6g}</y></SimmSpline>")
    coupler = ("<CoordinateCouplerConstraint name=\"elevate_con\"><isEnforced>true</isEnforced>"
               f"<coupled_coordinates_function>{spline}</coupled_coordinates_function>"
               "<independent_coordinate_names>elv_angle</independent_coordinate_names>"
               "<dependent_coordinate_name>elevate_r2</dependent_coordinate_name><scale_factor>1</scale_factor>"
               "</CoordinateCouplerConstraint>")
    return ("<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40000\">"
            "<Model name=\"shoulder\"><Ground name=\"ground\"/><gravity>0 -9.80665 0</gravity>"
            f"<BodySet name=\"bodyset\"><objects>{bodies}</objects></BodySet>"
            f"<JointSet name=\"jointset\"><objects>{joints}</objects></JointSet>"
            f"<ConstraintSet name=\"constraintset\"><objects>{coupler}</objects></ConstraintSet>"
            f"<MarkerSet name=\"markerset\"><objects>{markers}</objects></MarkerSet></Model></OpenSimDocument>\n")


def test_the_fold_is_recorded_and_read_back_in_opensims_coordinates(tmp_path):
    """The import folds elevate_r2 onto shoulder_rot's revolute (no other approximation), says so, keeps the mix in
    the URDF's <opensim> element, widens the URDF limit by the coupled turn's range, converts the motion's angles
    to OpenSim's coordinates in the .mot (with the coupled coordinate's column), and refuses an IK setup's task on
    shoulder_rot while elv_angle moves."""
    from calibrate.io.motion import Motion
    from calibrate.io.osim_export import mot_columns
    from calibrate.io.osim_setup import ik_setup_locks

    path = tmp_path / "shoulder.osim"
    path.write_text(shoulder_osim(slope=-0.8))
    model = load_model(path)
    info = osim_info(model)
    (fold,) = [a for a in info.approximations if a.markers or a.kind == FOLDED]
    assert fold.joint == "elevate" and fold.kind == FOLDED and "shoulder_rot - 0.8 × elv_angle" in fold.detail
    assert set(model.dof_names) == set(RANGES) and "elevate_r2" in info.dropped
    mix = info.mixes["shoulder_rot"]
    assert (mix.independent, mix.dependent) == ("elv_angle", "elevate_r2")
    assert mix.mix == pytest.approx(-0.8) and (mix.lo, mix.hi) == RANGES["shoulder_rot"]
    rot = next(d for d in model.dofs if d.name == "shoulder_rot")
    assert (rot.lower, rot.upper) == pytest.approx((-1.5 - 0.8 * 2.0, 0.5 + 0.8 * 1.5))
    # the motion's URDF angles -> OpenSim's coordinates
    rng = np.random.default_rng(2)
    angles = rng.uniform(-1, 1, (6, 3))
    motion = Motion(np.arange(6) / 100, rng.normal(0, 0.3, (6, 3)), Rotation.random(6, random_state=1).as_quat(),
                    angles, model.dof_names)
    names, values = mot_columns(model, motion)
    col = {n: values[:, k] for k, n in enumerate(names)}
    theta = dict(zip(model.dof_names, angles.T, strict=True))
    assert np.allclose(col["shoulder_rot"], theta["shoulder_rot"] + 0.8 * theta["elv_angle"], atol=1e-12)
    assert np.allclose(col["elevate_r2"], -0.8 * theta["elv_angle"], atol=1e-12)
    assert np.allclose(col["elv_angle"], theta["elv_angle"]) and np.allclose(col["shoulder_elv"],
                                                                             theta["shoulder_elv"])
    setup = tmp_path / "ik.xml"
    setup.write_text(_ik_setup(_task("shoulder_rot", "manual_value", 0.3)))
    with pytest.raises(ModelError, match="shoulder_rot.*elv_angle"):
        ik_setup_locks(setup, model)


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed")
def test_the_fold_against_opensim_and_back(tmp_path):
    """At random poses within the ranges (OpenSim following the coupler), every marker is where OpenSim puts it
    (1e-6 m); a calibrated-like subject (scales, centres, axes and markers moved) exported as .osim with a .mot of its
    own random poses puts every marker where calibrate does, and keeps the source's bodies, joints and coordinates."""
    from calibrate.io.motion import Motion
    from calibrate.io.osim_export import export_osim, write_mot
    from calibrate.model.model import Parameters, write_model

    path = tmp_path / "shoulder.osim"
    path.write_text(shoulder_osim())
    model = load_model(path)
    info = osim_info(model)
    rng = np.random.default_rng(7)
    poses, ours = [], []
    for k in range(40):
        coords = {n: float(rng.uniform(lo, hi)) for n, (lo, hi) in RANGES.items()}
        t, quat = rng.normal(0, 0.5, 3), Rotation.random(random_state=k).as_quat()
        angles = np.array([info.urdf_angle(d, coords) for d in model.dof_names])  # the URDF's angle
        poses.append({**coords, **{n: float(v[0]) for n, v in root_coordinates(info, t[None], quat[None]).items()}})
        ours.append(_pin_markers(model, t, quat, angles))
    theirs = _run_worker(tmp_path, [{"osim": str(path), "marker_set": None, "poses": poses, "bodies": []}],
                         _WORKER, 300)[0]
    off = max(np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(theirs, ours, strict=True)
              for m in model.marker_names)
    assert off < TOL, off
    p0 = model.parameters()
    p = Parameters(1 + rng.uniform(-0.1, 0.1, p0.scale.shape), p0.centre + rng.uniform(-0.01, 0.01, p0.centre.shape),
                   p0.axis + rng.uniform(-0.05, 0.05, p0.axis.shape),
                   p0.marker + rng.uniform(-0.01, 0.01, p0.marker.shape))
    subject = load_model(write_model(model, tmp_path / "s.urdf", p))
    n = 15
    angles = np.array([[rng.uniform(d.lower, d.upper) for d in subject.dofs] for _ in range(n)])
    motion = Motion(np.arange(n) / 100, rng.normal(0, 0.5, (n, 3)), Rotation.random(n, random_state=9).as_quat(),
                    angles, subject.dof_names)
    export = {"osim": str(export_osim(subject, tmp_path / "s.osim")),
              "mot": str(write_mot(tmp_path / "s.mot", subject, motion))}
    exported = _run_worker(tmp_path, [export], _EXPORT_WORKER, 300)[0]
    refs = [_pin_markers(subject, motion.root_translation[f], motion.root_quaternion[f], angles[f]) for f in range(n)]
    off = max(np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(exported["frames"], refs, strict=True)
              for m in subject.marker_names)
    assert off < TOL, off
    assert {"trunk", "upper", "mid", "arm"} <= set(exported["bodies"])
    assert {"plane", "elevate", "rot"} <= set(exported["joints"])
    assert {*RANGES, "elevate_r2"} <= set(exported["coordinates"])


def _swept_arm(model, n: int = 300, seed: int = 4):
    """A trial of `model` itself (the imported arm): every coordinate swept over most of its range, the trunk turning,
    1 mm noise; and OpenSim's coordinates frame by frame."""
    import pinocchio as pin

    from calibrate.io.trial import Trial

    info = osim_info(model)
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 100
    coords = {c: 0.5 * (lo + hi) + 0.4 * (hi - lo) * np.sin(2 * np.pi * (0.3 + 0.2 * k) * t + k)
              for k, (c, (lo, hi)) in enumerate(RANGES.items())}
    pm, data = model.pin, model.pin.createData()
    X = np.empty((n, len(model.marker_names), 3))
    for f in range(n):
        angles = np.array([info.urdf_angle(d, {c: v[f] for c, v in coords.items()}) for d in model.dof_names])
        q = model.pin_configuration(np.array([0.1, 0.2, 1.0]), Rotation.from_euler("z", 0.2 * t[f]).as_quat(), angles)
        pin.framesForwardKinematics(pm, data, q)
        X[f] = [data.oMf[pm.getFrameId(m, pin.FrameType.BODY)].translation for m in model.marker_names]
    return Trial(tuple(model.marker_names), X + rng.normal(0, 0.001, X.shape), 100.0), coords


def test_hinges_about_one_centre_through_light_markerless_bodies_are_a_gimbal_whose_axes_are_held(tmp_path, capsys):
    """With upper and mid as light as MoBL-ARMS's phantom bodies the import names the three hinges a gimbal (not with
    bodies of 1 kg; `inspect` says so); the calibration holds their axes at the model's (said on the `axes held`
    line; --no-auto-hold or a calibration that frees no axis leaves them), and on a simulated arm of the model itself
    (every coordinate swept, 1 mm noise) finds the shoulder's angles and fits the markers to the noise: holding costs
    nothing there.  The trade it prevents is MoBL-ARMS's, with its ten markers (a simulated arm's elv_angle axis
    carried 81 deg, the shoulder angles 50-73 deg RMS off; held 3.6-13.5: docs/benchmarks.md)."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.cli import main
    from calibrate.io.osim_info import with_gimbals
    from calibrate.problem.settings import Settings

    heavy = tmp_path / "heavy.osim"
    heavy.write_text(shoulder_osim())
    assert osim_info(load_model(heavy)).gimbals == ()
    path = tmp_path / "light.osim"
    path.write_text(shoulder_osim(phantom=1e-4))
    model = load_model(path)
    info = osim_info(model)
    assert info.gimbals == ((("elv_angle", "shoulder_elv", "shoulder_rot"), ("upper", "mid")),)
    assert set(with_gimbals(model, Settings()).hold_axes) == set(RANGES)
    assert with_gimbals(model, Settings(auto_hold=False)).hold_axes == ()
    assert with_gimbals(model, Settings(free=("scale", "centre", "marker"))).hold_axes == ()
    assert main(["inspect", str(path)]) == 0
    assert "gimbal: elv_angle, shoulder_elv, shoulder_rot turn about one centre through upper, mid" in \
        capsys.readouterr().out
    trial, coords = _swept_arm(model)
    cal = calibrate(model, trial)
    assert set(RANGES) <= set(cal.settings.hold_axes)
    assert "turn about one centre through upper, mid" in cal.text()
    from calibrate.calibration.html import report_html
    from calibrate.calibration.report import calibration_report

    report = calibration_report(cal)
    assert report["gimbal_axes"] == [{"coordinates": list(RANGES), "bodies": ["upper", "mid"]}]
    assert "turn about one centre through upper, mid (light, no markers)" in report_html(report)
    assert cal.marker_rms < 0.0015
    motion = cal.motions[0]
    theirs = info.coordinates({d: motion.angles[:, k] for k, d in enumerate(motion.dof_names)})
    rms = {c: float(np.degrees(np.sqrt(np.mean((theirs[c] - coords[c]) ** 2)))) for c in RANGES}
    print(f"gimbal held: marker RMS {1000 * cal.marker_rms:.2f} mm; shoulder angles from the truth (deg RMS) {rms}")
    assert max(rms.values()) < 3.0, rms
