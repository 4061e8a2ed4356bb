"""The MuJoCo export (calibrate.io.mjcf) against MuJoCo itself.

MuJoCo loads the MJCF calibrate writes and computes its own kinematics and mass properties; each is compared with
Pinocchio's reading of the URDF calibrate writes for the same subject (the reference for kinematics): marker sites
against marker frames, body inertias, visual geoms, joint ranges, and a motion's qpos rows against the motion.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import HUMAN, ROOT
from scipy.spatial.transform import Rotation
from test_osim_import import hand_made_osim

from calibrate.errors import CalibrateError
from calibrate.io.mjcf import (
    CONNECTOR_INERTIA,
    CONNECTOR_MASS,
    add_export_mjcf_parser,
    cmd_export_mjcf,
    export_mjcf,
    mjcf_qpos,
    qpos_columns,
)
from calibrate.io.motion import write_motion_csv
from calibrate.io.osim_info import osim_info
from calibrate.model.model import Parameters, load_model, write_model
from calibrate.simulation.simulate import simulate_squats
from calibrate.simulation.subject import tilt

mujoco = pytest.importorskip("mujoco", reason="mujoco is not installed (pip install -e '.[test]')")

GAIT = ROOT.parent / "shared" / "data" / "real" / "gait2392"
# MuJoCo's kinematics against Pinocchio's: the same transforms composed in another order and in quaternions;
# 1.4e-15 m measured at worst (100 random poses of each case).  A modelling slip (an axis, a placement, a
# quaternion's order) is far larger.
TOL = 1e-12


def _perturbed(model, seed: int) -> Parameters:
    """A calibrated-like subject: scales != 1, moved centres and markers, every axis tilted."""
    rng = np.random.default_rng(seed)
    p = model.parameters()
    return Parameters(1 + rng.uniform(-0.15, 0.15, p.scale.shape), p.centre + rng.uniform(-0.02, 0.02, p.centre.shape),
                      np.array([tilt(a, np.radians(rng.uniform(1, 8)), rng) * rng.uniform(0.5, 2) for a in p.axis]),
                      p.marker + rng.uniform(-0.01, 0.01, p.marker.shape))


def _variant(path: Path) -> Path:
    """models/human.urdf with a welded segment (radioulnar_l fixed, turned: radius_l rides on ulna_l's body), a
    turned hinge origin (knee_r), a turned inertial (femur_r: an inertia with products) and a continuous joint
    (radioulnar_r: no limits)."""
    t = HUMAN.read_text()
    i = t.index('<joint name="radioulnar_l"')
    j = t.index("</joint>", i)
    block = re.sub(r"\s*<(axis|limit)[^>]*/>", "", t[i:j].replace('type="revolute"', 'type="fixed"'))
    t = t[:i] + block.replace('rpy="0 0 0"', 'rpy="0.2 -0.1 0.3"', 1) + t[j:]
    i = t.index('<link name="femur_r">')
    j = t.index("</inertial>", i)
    t = t[:i] + t[i:j].replace('rpy="0 0 0"', 'rpy="0.3 -0.2 0.5"', 1) + t[j:]
    i = t.index('<joint name="knee_r"')
    j = t.index("</joint>", i)
    t = t[:i] + re.sub(r'rpy="[^"]*"', 'rpy="0.1 -0.2 0.3"', t[i:j], count=1) + t[j:]
    i = t.index('<joint name="radioulnar_r"')
    j = t.index("</joint>", i)
    t = t[:i] + re.sub(r"\s*<limit[^>]*/>", "", t[i:j].replace('type="revolute"', 'type="continuous"')) + t[j:]
    path.write_text(t)
    return path


def _cases(tmp: Path) -> dict[str, tuple]:
    """name -> (model, the URDF calibrate writes for the subject, its MJCF as MuJoCo loads it)."""
    human = load_model(HUMAN)
    variant = load_model(_variant(tmp / "variant_base.urdf"))
    (tmp / "handmade.osim").write_text(hand_made_osim())  # every OpenSim joint type and function calibrate reads
    handmade = load_model(tmp / "handmade.osim")
    out = {"base": (human, None), "perturbed": (human, _perturbed(human, 3)), "variant": (variant, None),
           "handmade": (handmade, _perturbed(handmade, 5))}
    if GAIT.exists():  # another lab's model: y up, OpenSim's names, a knee hinge fit; mtp_angle_r locked at 0.2 rad
        text = (GAIT / "gait2392.osim").read_text()
        i = text.index('<Coordinate name="mtp_angle_r">')
        j = text.index("</Coordinate>", i)
        block = text[i:j].replace("<default_value>0</default_value>", "<default_value>0.2</default_value>", 1)
        (tmp / "gait2392.osim").write_text(text[:i] + block.replace("<locked>false", "<locked>true", 1) + text[j:])
        gait = load_model(tmp / "gait2392.osim", GAIT / "gait2392_Scale_MarkerSet.xml")
        out["gait2392"] = (gait, _perturbed(gait, 4))
    cases = {}
    for name, (model, params) in out.items():
        urdf = write_model(model, tmp / f"{name}.urdf", params)
        xml = export_mjcf(model, tmp / f"{name}.xml", params)
        cases[name] = (load_model(urdf), urdf, mujoco.MjModel.from_xml_path(str(xml)))
    return cases


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    return _cases(tmp_path_factory.mktemp("mjcf"))


def _random_q(model, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    angles = np.array([rng.uniform(max(d.lower, -np.pi), min(d.upper, np.pi)) for d in model.dofs])
    return rng.normal(0, 1, 3), Rotation.random(random_state=rng).as_quat(), angles


@pytest.mark.parametrize("name", ["base", "perturbed", "variant", "handmade", "gait2392"])
def test_marker_sites_where_pinocchio_puts_the_markers(cases, name):
    """At random poses, MuJoCo's marker sites sit where Pinocchio's reading of the written URDF puts the markers,
    the qpos being the motion's root position, quaternion (w, x, y, z) and angles (mjcf_qpos)."""
    if name not in cases:
        pytest.skip("../shared/data/real/gait2392 is not here")
    model, urdf, mj = cases[name]
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    pd, md = pm.createData(), mujoco.MjData(mj)
    rng = np.random.default_rng(1)
    assert mj.nq == 7 + model.n_dofs and mj.nsite == len(model.markers)
    worst = 0.0
    for _ in range(20):
        t, quat, angles = _random_q(model, rng)
        pin.framesForwardKinematics(pm, pd, model.pin_configuration(t, quat, angles))
        from calibrate.io.motion import Motion

        motion = Motion(np.zeros(1), t[None], quat[None], angles[None], model.dof_names)
        md.qpos[:] = mjcf_qpos(model, motion)[0]
        mujoco.mj_kinematics(mj, md)
        for m in model.markers:
            ref = pd.oMf[pm.getFrameId(m.name, pin.FrameType.BODY)].translation
            worst = max(worst, np.linalg.norm(md.site(m.name).xpos - ref))
    assert worst < TOL


@pytest.mark.parametrize("name", ["base", "perturbed", "variant", "handmade", "gait2392"])
def test_mass_properties_and_ranges(cases, name):
    """Each moving segment's mass, centre of mass and inertia in MuJoCo equal Pinocchio's (the connector bodies at
    export's point-like 1 µg at their origin); each hinge's range is the URDF's limits."""
    if name not in cases:
        pytest.skip("../shared/data/real/gait2392 is not here")
    model, urdf, mj = cases[name]
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    connectors = 0
    for j in range(1, pm.njoints):
        ref = pm.inertias[j]
        b = mj.body(mj.jnt_bodyid[mj.joint(pm.names[j] if j > 1 else "root").id])
        if ref.mass == 0:
            connectors += 1
            assert b.mass[0] == CONNECTOR_MASS
            np.testing.assert_array_equal(b.ipos, 0)
            np.testing.assert_array_equal(b.inertia, CONNECTOR_INERTIA)
            continue
        assert b.mass[0] == pytest.approx(ref.mass, rel=1e-12)
        np.testing.assert_allclose(b.ipos, ref.lever, atol=1e-12)
        R = Rotation.from_quat(np.roll(b.iquat, -1)).as_matrix()  # MuJoCo: principal axes (w, x, y, z)
        np.testing.assert_allclose(R @ np.diag(b.inertia) @ R.T, ref.inertia, atol=1e-12)
    assert mj.body_mass.sum() == pytest.approx(model.total_mass + connectors * CONNECTOR_MASS, rel=1e-12)
    for d in model.dofs:
        joint = mj.joint(d.name)
        if np.isfinite(d.lower) and np.isfinite(d.upper):
            assert joint.limited[0] and tuple(joint.range) == (pytest.approx(d.lower, abs=1e-12),
                                                               pytest.approx(d.upper, abs=1e-12))
        else:  # a continuous joint (the variant's radioulnar_r)
            assert not joint.limited[0] and name == "variant" and d.name == "radioulnar_r"
    up = np.array([0, -9.80665, 0] if name in ("gait2392", "handmade") else [0, 0, -9.80665])  # OpenSim: y up
    np.testing.assert_array_equal(mj.opt.gravity, up)
    # an OpenSim model's locked coordinates (the test's gait2392: mtp_angle_r at 0.2 rad) held by joint equalities
    info = osim_info(model)
    locked = {d: v for d, v in (info.locked.items() if info else ()) if d in model.dof_names}
    assert mj.neq == len(locked) and (name != "gait2392" or locked == {"mtp_angle_r": 0.2})
    for d, value in locked.items():
        eq = mj.equality(f"{d}_locked")
        assert (eq.type[0], eq.obj1id[0]) == (mujoco.mjtEq.mjEQ_JOINT, mj.joint(d).id)
        np.testing.assert_allclose(eq.data[:5], [value, 0, 0, 0, 0], atol=1e-12)  # URDF angles (OsimInfo.locked)


@pytest.mark.parametrize("name", ["base", "perturbed", "variant", "handmade", "gait2392"])
def test_visual_geoms_where_pinocchio_draws_them(cases, name):
    """Each segment's URDF visual is a MuJoCo geom of the same kind, size, place, axis and colour as in Pinocchio's
    visual model of the written URDF, at random poses; visual only (no contacts, no mass).  Gait2392's: the rods
    and boxes its import draws (calibrate.io.osim.bone_visuals)."""
    if name not in cases:
        pytest.skip("../shared/data/real/gait2392 is not here")
    model, urdf, mj = cases[name]
    pm, _, vm = pin.buildModelsFromUrdf(str(urdf), root_joint=pin.JointModelFreeFlyer())
    pd, vd, md = pm.createData(), pin.GeometryData(vm), mujoco.MjData(mj)
    segments = {sg.name for sg in model.segments}
    ref = [g for g in vm.geometryObjects if pm.frames[g.parentFrame].name in segments]
    assert mj.ngeom == len(ref) >= len(model.segments)
    rng = np.random.default_rng(2)
    from calibrate.io.motion import Motion

    kinds = {"Sphere": mujoco.mjtGeom.mjGEOM_SPHERE, "Box": mujoco.mjtGeom.mjGEOM_BOX,
             "Cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER}
    for _ in range(5):
        t, quat, angles = _random_q(model, rng)
        q = model.pin_configuration(t, quat, angles)
        pin.forwardKinematics(pm, pd, q)
        pin.updateGeometryPlacements(pm, pd, vm, vd)
        md.qpos[:] = mjcf_qpos(model, Motion(np.zeros(1), t[None], quat[None], angles[None], model.dof_names))[0]
        mujoco.mj_kinematics(mj, md)
        for g in ref:
            X = vd.oMg[vm.getGeometryId(g.name)]
            geom = md.geom(g.name)
            shape = g.geometry
            kind = type(shape).__name__
            assert mj.geom(g.name).type[0] == kinds[kind]
            assert (mj.geom(g.name).contype[0], mj.geom(g.name).conaffinity[0]) == (0, 0)
            np.testing.assert_allclose(geom.xpos, X.translation, atol=TOL)
            R = geom.xmat.reshape(3, 3)
            size = mj.geom(g.name).size
            if kind == "Sphere":
                assert size[0] == pytest.approx(shape.radius, abs=1e-12)
            elif kind == "Box":
                np.testing.assert_allclose(R, X.rotation, atol=TOL)
                np.testing.assert_allclose(size, shape.halfSide, atol=1e-12)
            else:
                np.testing.assert_allclose(R[:, 2], X.rotation[:, 2], atol=TOL)
                np.testing.assert_allclose(size[:2], [shape.radius, shape.halfLength], atol=1e-12)
            np.testing.assert_allclose(mj.geom(g.name).rgba, g.meshColor, atol=1e-7)  # MuJoCo keeps floats


# ---------------------------------------------------------------------- the command line
def _args(model: Path, **kw) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="calibrate")
    add_export_mjcf_parser(ap.add_subparsers(dest="command"))
    argv = ["export-mjcf", str(model)]
    for key, value in kw.items():
        flag = "--" + key.replace("_", "-") if key != "output" else "-o"
        argv += [flag] if value is True else [flag, str(value)]
    return ap.parse_args(argv)


def test_cli_writes_the_model_and_a_motion_as_qpos(tmp_path, human, capsys):
    """`calibrate export-mjcf subject.urdf --motion motion.csv`: the MJCF MuJoCo loads and the qpos CSV whose rows,
    put in MuJoCo, put every marker site where the motion puts the markers (Pinocchio)."""
    sim = simulate_squats(human, frames=12, seed=5)
    urdf = write_model(human, tmp_path / "subject.urdf", sim.truth)
    csv = write_motion_csv(tmp_path / "motion.csv", sim.motion)
    assert cmd_export_mjcf(_args(urdf, motion=csv)) == 0
    out = capsys.readouterr().out
    xml, qpos = tmp_path / "subject_mujoco.xml", tmp_path / "motion_qpos.csv"
    assert f"wrote {xml}" in out and str(qpos) in out
    mj = mujoco.MjModel.from_xml_path(str(xml))
    header = qpos.read_text().splitlines()[0].split(",")
    assert header == qpos_columns(human)
    rows = np.loadtxt(qpos, delimiter=",", skiprows=1)
    np.testing.assert_allclose(rows[:, 0], sim.motion.times, atol=1e-12)
    subject = load_model(urdf)
    pm = subject.pin
    pd, md = pm.createData(), mujoco.MjData(mj)
    m = sim.motion
    for f in range(m.n_frames):
        md.qpos[:] = rows[f, 1:]
        mujoco.mj_kinematics(mj, md)
        pin.framesForwardKinematics(pm, pd, subject.pin_configuration(m.root_translation[f], m.root_quaternion[f],
                                                                      m.angles[f]))
        for mk in subject.markers:
            ref = pd.oMf[pm.getFrameId(mk.name, pin.FrameType.BODY)].translation
            assert np.linalg.norm(md.site(mk.name).xpos - ref) < TOL
    # kept unless --overwrite; nothing written when one output cannot be
    before = xml.read_text()
    with pytest.raises(CalibrateError, match="exists"):
        cmd_export_mjcf(_args(urdf, motion=csv))
    assert cmd_export_mjcf(_args(urdf, motion=csv, overwrite=True)) == 0
    assert xml.read_text() == before


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_bad_arguments_one_line_nothing_written(tmp_path, human):
    urdf = write_model(human, tmp_path / "subject.urdf")
    other = tmp_path / "other.csv"
    other.write_text("time,root_x,root_y,root_z,root_qx,root_qy,root_qz,root_qw,knee\n0,0,0,0,0,0,0,1,0\n")
    ms = tmp_path / "markers.xml"
    ms.write_text("<OpenSimDocument Version=\"40000\"><MarkerSet><objects/></MarkerSet></OpenSimDocument>\n")
    for kw, needle in [({"qpos": tmp_path / "q.csv"}, "--qpos needs --motion"),
                       ({"output": tmp_path / "m.mjcf"}, "should end in .xml"),
                       ({"output": urdf.with_suffix(".xml"), "motion": other, "qpos": tmp_path / "q.txt"},
                        "should end in .csv"),
                       ({"motion": other}, "the motion has no angle of subject.urdf's joint"),
                       ({"output": tmp_path / "no" / "m.xml"}, "does not exist"),
                       ({"marker_set": ms}, "goes with an OpenSim model")]:
        with pytest.raises(CalibrateError) as exc:
            cmd_export_mjcf(_args(urdf, **kw))
        assert needle in _one_line(exc), (kw, str(exc.value))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["markers.xml", "other.csv", "subject.urdf"]


def _sites_where_pinocchio_puts_the_markers(xml: Path, qpos: Path, urdf: Path, motion_csv: Path) -> None:
    """Every seventh qpos row in MuJoCo puts each marker site where Pinocchio puts the URDF's markers at the motion
    CSV's frame (both CSVs hold every digit)."""
    from calibrate.io.motion import read_motion_csv

    subject, motion = load_model(urdf), read_motion_csv(motion_csv)
    mj = mujoco.MjModel.from_xml_path(str(xml))
    md, pm = mujoco.MjData(mj), subject.pin
    pd = pm.createData()
    rows = np.loadtxt(qpos, delimiter=",", skiprows=1)
    assert rows.shape == (motion.n_frames, 1 + mj.nq)
    np.testing.assert_allclose(rows[:, 0], motion.times, atol=1e-12)
    for f in range(0, motion.n_frames, 7):
        md.qpos[:] = rows[f, 1:]
        mujoco.mj_kinematics(mj, md)
        pin.framesForwardKinematics(pm, pd, subject.pin_configuration(motion.root_translation[f],
                                                                      motion.root_quaternion[f], motion.angles[f]))
        for mk in subject.markers:
            ref = pd.oMf[pm.getFrameId(mk.name, pin.FrameType.BODY)].translation
            assert np.linalg.norm(md.site(mk.name).xpos - ref) < TOL


def test_calibrate_mjcf_writes_the_subject_and_its_motion_for_mujoco(human, tmp_path, capsys):
    """`calibrate TRIAL MODEL --mjcf`: beside the subject URDF its MJCF (TRIAL_mujoco.xml) and beside the motion CSV
    its qpos rows (TRIAL_motion_qpos.csv), which put MuJoCo's sites where Pinocchio puts the subject URDF's markers
    at the motion CSV's frames; `calibrate ik ... --mjcf` likewise; refused before the work where one exists (no
    --overwrite)."""
    from calibrate.cli.main import main
    from calibrate.io.c3d import write_c3d

    sim = simulate_squats(human, frames=60, noise_mm=1.0, seed=5)
    write_c3d(tmp_path / "squat.c3d", sim.trial)
    assert main([str(tmp_path / "squat.c3d"), str(human.path), "--mjcf", "-q"]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    xml, qpos = tmp_path / "squat_mujoco.xml", tmp_path / "squat_motion_qpos.csv"
    assert str(xml) in out and str(qpos) in out
    import json

    report = json.loads((tmp_path / "squat_report.json").read_text())  # the report lists them with the rest
    assert report["outputs"]["mjcf"] == str(xml) and report["outputs"]["qpos"] == [str(qpos)]
    _sites_where_pinocchio_puts_the_markers(xml, qpos, tmp_path / "squat.urdf", tmp_path / "squat_motion.csv")
    # calibrate ik on the subject: its motion's qpos rows for the same MJCF
    (tmp_path / "ik").mkdir()
    assert main(["ik", str(tmp_path / "squat.c3d"), str(tmp_path / "squat.urdf"), "--out", str(tmp_path / "ik"),
                 "--mjcf", "-q"]) == 0, capsys.readouterr().err
    _sites_where_pinocchio_puts_the_markers(xml, tmp_path / "ik" / "squat_motion_qpos.csv", tmp_path / "squat.urdf",
                                            tmp_path / "ik" / "squat_motion.csv")
    for name in ("squat.urdf", "squat_motion.csv", "squat_report.json", "squat_mujoco.xml"):
        (tmp_path / name).unlink()
    qpos.write_text("mine\n")
    assert main([str(tmp_path / "squat.c3d"), str(human.path), "--mjcf", "-q"]) == 2
    err = capsys.readouterr().err
    assert "squat_motion_qpos.csv: exists" in err and err.count("\n") == 1, err
    assert qpos.read_text() == "mine\n" and not xml.exists() and not (tmp_path / "squat.urdf").exists()


def test_a_model_from_opensim_keeps_its_source_gravity(tmp_path, human):
    """Gravity comes from the source .osim, not from a guess: models/human.urdf exported as .osim (z up) and read
    back keeps -z in the MJCF and in the .osim written again; gait2392 (y up) keeps -y."""
    from calibrate.io.osim_export import export_osim, osim_text

    zup = load_model(export_osim(human, tmp_path / "human.osim"))
    want = {zup: (0.0, 0.0, -9.80665)}
    if GAIT.exists():
        want[load_model(GAIT / "gait2392.osim", GAIT / "gait2392_Scale_MarkerSet.xml")] = (0.0, -9.80665, 0.0)
    for model, g in want.items():
        assert tuple(osim_info(load_model(write_model(model, tmp_path / "m.urdf"))).gravity) == g  # kept in the URDF
        np.testing.assert_array_equal(mujoco.MjModel.from_xml_path(str(export_mjcf(model, tmp_path / "m.xml")))
                                      .opt.gravity, g)
        again = re.search(r"<gravity>([^<]*)</gravity>", osim_text(model)).group(1)
        assert tuple(float(v) for v in again.split()) == g


@pytest.mark.parametrize("name", ["base", "perturbed", "variant", "handmade", "gait2392"])
def test_joint_space_dynamics_match_pinocchio(cases, name):
    """MuJoCo's joint-space inertia over the hinges and their gravity torques equal Pinocchio's (CRBA, generalized
    gravity) at random poses: the inertias, centres of mass and the tree carry over to a simulation, not only the
    kinematics.  The root's block differs by each engine's free-joint velocity convention and is not compared;
    the connector bodies get the export's point mass in Pinocchio too (CONNECTOR_MASS at their origin), so the two
    agree to rounding (3e-15 of the largest entry measured at 50 poses; tested to 1e-12)."""
    if name not in cases:
        pytest.skip("../shared/data/real/gait2392 is not here")
    from calibrate.io.motion import Motion

    model, urdf, mj = cases[name]
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    pm.gravity.linear = mj.opt.gravity.copy()
    for j in range(1, pm.njoints):
        if pm.inertias[j].mass == 0:  # the export's connector body (calibrate.io.mjcf)
            pm.inertias[j] = pin.Inertia(CONNECTOR_MASS, np.zeros(3), CONNECTOR_INERTIA * np.eye(3))
    pd, md = pm.createData(), mujoco.MjData(mj)
    rng = np.random.default_rng(4)
    for _ in range(5):
        t, quat, angles = _random_q(model, rng)
        q = model.pin_configuration(t, quat, angles)
        md.qpos[:] = mjcf_qpos(model, Motion(np.zeros(1), t[None], quat[None], angles[None], model.dof_names))[0]
        md.qvel[:] = 0
        mujoco.mj_forward(mj, md)
        M = np.zeros((mj.nv, mj.nv))
        try:
            mujoco.mj_fullM(mj, md, M)  # MuJoCo 4
        except TypeError:
            mujoco.mj_fullM(mj, M, md.qM)  # MuJoCo 3
        ref = pin.crba(pm, pd, q)
        ref = np.triu(ref) + np.triu(ref, 1).T
        scale = np.abs(ref[6:, 6:]).max()
        np.testing.assert_allclose(M[6:, 6:], ref[6:, 6:], atol=1e-12 * scale)
        g = pin.computeGeneralizedGravity(pm, pd, q)
        np.testing.assert_allclose(md.qfrc_bias[6:], g[6:], atol=1e-12 * np.abs(g).max())
