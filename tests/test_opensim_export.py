"""OpenSim round trip: `calibrate export-osim` models and .mot motions, loaded in the real `opensim`
package, put every marker where Pinocchio puts it (to 1e-14 m: rounding only); masses, centres of mass, inertia,
joints; bad input.

OpenSim runs in a child process: the opensim 4.6 wheel bundles its own libcasadi with the same
soname (libcasadi.so.3.7) as the casadi wheel calibrate uses, but another ABI, so whichever is
imported second fails to load.  Each test run starts one child (the _WORKER source below, which
imports opensim and nothing of calibrate) for every OpenSim evaluation at once.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import HUMAN
from scipy.spatial.transform import Rotation

from calibrate.errors import CalibrateError
from calibrate.io.c3d import write_c3d
from calibrate.io.motion import Motion, write_motion_csv
from calibrate.io.osim_export import add_export_osim_parser, cmd_export_osim, export_osim, write_mot
from calibrate.io.trc import read_trc
from calibrate.model.model import Parameters, load_model, write_model
from calibrate.simulation.simulate import simulate_squats
from calibrate.simulation.subject import tilt

HAVE_OPENSIM = importlib.util.find_spec("opensim") is not None
needs_opensim = pytest.mark.skipif(
    not HAVE_OPENSIM, reason="opensim is not installed (pip install -e '.[opensim]'; .ci/run installs it)")
# m.  OpenSim's markers differ from Pinocchio's by rounding only: 8.1e-16 m at worst over the four cases
# (6 random poses of 3 models, a 30-frame .mot) on this machine; 1e-14 leaves ten times that for other
# BLAS/compilers, while a modelling slip (an origin or axis off by 1e-9, a Euler convention) is far larger.
# docs/commands.md (calibrate export-osim) states this figure.
TOL = 1e-14

# The child process: {"jobs": [{"osim", "poses": [{coordinate: value (rad, m)}], "mot"}]} -> per job the
# markers at each pose and each .mot frame, bodies (mass, centre of mass, inertia), joints, coordinates.
_WORKER = r"""
import json, sys
import numpy as np
import opensim as osim
osim.Logger.removeFileSink()  # no opensim.log in the working directory
osim.Logger.setLevelString("warn")

def markers(model, state):
    model.realizePosition(state)
    ms = model.getMarkerSet()
    return {ms.get(i).getName(): ms.get(i).getLocationInGround(state).to_numpy().tolist()
            for i in range(ms.getSize())}

def geometry(model, state):  # each drawn shape: its class, frame in ground (R, p), sizes, colour
    model.realizePosition(state)
    out = {}
    for c in model.getComponentsList():
        kind = c.getConcreteClassName()
        if kind not in ("Sphere", "Brick", "Cylinder", "Mesh"):
            continue
        g = getattr(osim, kind).safeDownCast(c)
        X = g.getFrame().getTransformInGround(state)
        sizes = {"Sphere": lambda: [g.get_radius()], "Brick": lambda: g.get_half_lengths().to_numpy().tolist(),
                 "Cylinder": lambda: [g.get_radius(), g.get_half_height()],
                 "Mesh": lambda: [g.get_mesh_file()]}[kind]()
        out[g.getName()] = {"kind": kind, "R": [[X.R().get(i, j) for j in range(3)] for i in range(3)],
                            "p": X.p().to_numpy().tolist(), "sizes": sizes,
                            "scale": g.get_scale_factors().to_numpy().tolist(),
                            "color": g.get_Appearance().get_color().to_numpy().tolist()}
    return out

out = []
for job in json.load(open(sys.argv[1]))["jobs"]:
    model = osim.Model(job["osim"])
    state = model.initSystem()
    cs = model.getCoordinateSet()
    res = {"n_bodies": model.getNumBodies(), "n_joints": model.getNumJoints(),
           "joints": [model.getJointSet().get(i).getConcreteClassName() for i in range(model.getNumJoints())],
           "coordinates": [cs.get(i).getName() for i in range(cs.getSize())],
           "ranges": {cs.get(i).getName(): [cs.get(i).getRangeMin(), cs.get(i).getRangeMax(),
                                             cs.get(i).getDefaultClamped()] for i in range(cs.getSize())},
           "bodies": {}, "poses": [], "mot": None}
    bs = model.getBodySet()
    for i in range(bs.getSize()):
        b = bs.get(i)
        I = b.getInertia()
        res["bodies"][b.getName()] = {"mass": b.getMass(), "com": b.getMassCenter().to_numpy().tolist(),
                                      "moments": I.getMoments().to_numpy().tolist(),
                                      "products": I.getProducts().to_numpy().tolist()}
    for pose in job["poses"]:
        for name, value in pose.items():
            cs.get(name).setValue(state, value, False)
        res["poses"].append(markers(model, state))
        if job.get("geometry"):
            res.setdefault("geometry", []).append(geometry(model, state))
    if job.get("mot"):
        table = osim.TimeSeriesTable(job["mot"])
        storage = osim.Storage(job["mot"])
        model.getSimbodyEngine().convertDegreesToRadians(storage)  # as OpenSim's tools read a .mot
        cols = storage.getColumnLabels()
        labels = [cols.get(i) for i in range(1, cols.getSize())]
        frames = []
        for f in range(storage.getSize()):
            row = storage.getStateVector(f).getData()
            for k, name in enumerate(labels):
                cs.get(name).setValue(state, row.get(k), False)
            frames.append(markers(model, state))
        res["mot"] = {"frames": frames, "table_shape": [table.getNumRows(), table.getNumColumns()],
                      "in_degrees": table.getTableMetaDataString("inDegrees"),
                      "time": [storage.getStateVector(f).getTime() for f in range(storage.getSize())]}
    out.append(res)
json.dump(out, open(sys.argv[2], "w"))
"""


def _run_worker(tmp: Path, jobs: list[dict], worker: str = _WORKER, timeout: float = 120) -> list[dict]:
    """Run an OpenSim `worker` script in a child process on `jobs`; its JSON result."""
    spec, result = tmp / "jobs.json", tmp / "result.json"
    spec.write_text(json.dumps({"jobs": jobs}))
    proc = subprocess.run([sys.executable, "-c", worker, str(spec), str(result)], capture_output=True, text=True,
                          timeout=timeout)
    assert proc.returncode == 0, f"OpenSim worker failed:\n{proc.stderr[-3000:]}"
    return json.loads(result.read_text())


# ---------------------------------------------------------------------- independent references
def _pin_markers(urdf: Path, root_t, root_q, angles) -> dict[str, np.ndarray]:
    """Markers by Pinocchio straight from a URDF file (free-flyer root); angles in the file's DoF order."""
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    d = pm.createData()
    q = [np.asarray(root_t, float), np.asarray(root_q, float)]
    q += [np.atleast_1d(a) for a in angles]
    pin.framesForwardKinematics(pm, d, np.concatenate(q))
    model = load_model(urdf)
    return {m.name: d.oMf[pm.getFrameId(m.name, pin.FrameType.BODY)].translation.copy() for m in model.markers}


def _random_poses(model, n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        angles = np.array([rng.uniform(max(d.lower, -np.pi), min(d.upper, np.pi)) for d in model.dofs])
        out.append((rng.normal(0, 1, 3), Rotation.random(random_state=seed * 100 + k).as_quat(), angles))
    return out


def _coordinates(model, pose) -> dict[str, float]:
    """OpenSim coordinate values of a pose: root Z-Y'-X'' angles, translations, joint angles (a URDF angle over its
    coordinate's ratio where an imported OpenSim model has one: calibrate.io.osim.OsimInfo.ratios)."""
    from calibrate.io.osim_info import osim_info

    t, quat, angles = pose
    rz, ry, rx = Rotation.from_quat(quat).as_euler("ZYX")
    out = {"root_rz": rz, "root_ry": ry, "root_rx": rx, "root_x": t[0], "root_y": t[1], "root_z": t[2]}
    info = osim_info(model)
    out.update((d, a / (info.ratio(d) if info is not None else 1.0)) for d, a in zip(model.dof_names, angles,
                                                                                      strict=True))
    return {k: float(v) for k, v in out.items()}


def _set_origin(text: str, joint: str, xyz: str | None = None, rpy: str | None = None) -> str:
    i = text.index(f'<joint name="{joint}"')
    j = text.index("</joint>", i)
    block = text[i:j]
    if xyz:
        block = re.sub(r'xyz="[^"]*"', f'xyz="{xyz}"', block, count=1)
    if rpy:
        block = re.sub(r'rpy="[^"]*"', f'rpy="{rpy}"', block, count=1)
    return text[:i] + block + text[j:]


def _variant_urdf(path: Path) -> Path:
    """models/human.urdf with origin rotations in chains and hinges, a ball joint whose second axis is
    offset from the first (not one SpatialTransform) and a rotated inertial."""
    t = HUMAN.read_text()
    t = _set_origin(t, "knee_r", rpy="0.1 -0.2 0.3")
    t = _set_origin(t, "hip_r_adduction", rpy="0.2 0.1 -0.1")
    t = _set_origin(t, "hip_r_rotation", rpy="-0.3 0.05 0.2")
    t = _set_origin(t, "wrist_r_deviation", rpy="0 0.4 0")
    t = _set_origin(t, "shoulder_l_adduction", xyz="0.01 0 -0.02", rpy="0.1 0 0")
    i = t.index('<link name="femur_r">')
    j = t.index("</inertial>", i)
    t = t[:i] + re.sub(r'rpy="[^"]*"', 'rpy="0.3 -0.2 0.5"', t[i:j], count=1) + t[j:]
    path.write_text(t)
    return path


def _perturbed(model, seed: int) -> Parameters:
    """A calibrated-like subject: scales != 1, moved centres and markers, every axis (ball joints too) tilted."""
    rng = np.random.default_rng(seed)
    p = model.parameters()
    p = Parameters(1 + rng.uniform(-0.15, 0.15, p.scale.shape), p.centre + rng.uniform(-0.02, 0.02, p.centre.shape),
                   np.array([tilt(a, np.radians(rng.uniform(1, 8)), rng) * rng.uniform(0.5, 2) for a in p.axis]),
                   p.marker + rng.uniform(-0.01, 0.01, p.marker.shape))
    return p


# ---------------------------------------------------------------------- the round trip
@pytest.fixture(scope="module")
def roundtrip(tmp_path_factory):
    """Exports (base, perturbed, variant URDF, a squat .mot), one OpenSim run for all; with the references."""
    if not HAVE_OPENSIM:
        pytest.skip("opensim is not installed (pip install -e '.[opensim]'; .ci/run installs it)")
    tmp = tmp_path_factory.mktemp("osim")
    human = load_model(HUMAN)
    cases: dict[str, dict] = {}

    def add(name: str, urdf: Path, params: Parameters | None, n_poses: int, seed: int) -> None:
        model = load_model(urdf)
        osim = export_osim(model, tmp / f"{name}.osim", params)
        ref_urdf = urdf
        if params is not None:  # the reference: the URDF calibrate writes with these parameters
            ref_urdf = write_model(model, tmp / f"{name}_ref.urdf", params)
        poses = _random_poses(model, n_poses, seed)
        cases[name] = {"model": model, "urdf": ref_urdf, "osim": osim, "poses": poses,
                       "ref": [_pin_markers(ref_urdf, *pose) for pose in poses],
                       "job": {"osim": str(osim), "poses": [_coordinates(model, p) for p in poses],
                               "geometry": True}}

    add("base", HUMAN, None, 6, 1)
    add("perturbed", HUMAN, _perturbed(human, 7), 6, 2)
    add("variant", _variant_urdf(tmp / "variant.urdf"), None, 6, 3)
    girdle = HUMAN.with_name("human_girdle.urdf")  # the clavicles' universal joints, the acromions on them
    add("girdle", girdle, _perturbed(load_model(girdle), 9), 6, 4)
    # A squat trial's true motion as .mot, with the true subject's model.
    sim = simulate_squats(human, frames=30, seed=5)
    truth_osim = export_osim(human, tmp / "truth.osim", sim.truth)
    mot = write_mot(tmp / "truth.mot", human, sim.motion)
    truth_urdf = write_model(human, tmp / "truth.urdf", sim.truth)
    m = sim.motion
    cases["mot"] = {"model": human, "urdf": truth_urdf, "osim": truth_osim, "motion": m,
                    "ref": [_pin_markers(truth_urdf, m.root_translation[f], m.root_quaternion[f], m.angles[f])
                            for f in range(m.n_frames)],
                    "job": {"osim": str(truth_osim), "poses": [], "mot": str(mot)}}
    results = _run_worker(tmp, [c["job"] for c in cases.values()])
    for c, r in zip(cases.values(), results, strict=True):
        c["osim_result"] = r
    return cases


def _worst(osim_markers: list[dict], ref: list[dict]) -> float:
    return max(np.linalg.norm(np.array(o[name]) - x) for o, r in zip(osim_markers, ref, strict=True)
               for name, x in r.items())


@needs_opensim
@pytest.mark.parametrize("case", ["base", "perturbed", "variant", "girdle"])
def test_markers_match_pinocchio(roundtrip, case):
    c = roundtrip[case]
    r = c["osim_result"]
    assert set(r["poses"][0]) == set(c["model"].marker_names)
    assert _worst(r["poses"], c["ref"]) < TOL


@needs_opensim
def test_structure(roundtrip):
    human = roundtrip["base"]["model"]
    r = roundtrip["base"]["osim_result"]
    assert r["n_bodies"] == len(human.segments) == 19
    assert r["n_joints"] == len(human.joints) + 1 == 19  # + the root's joint to ground
    assert set(r["joints"]) == {"CustomJoint"}
    assert r["coordinates"][:6] == ["root_rz", "root_ry", "root_rx", "root_x", "root_y", "root_z"]
    assert r["coordinates"][6:] == list(human.dof_names)  # 38 coordinates, named as the motion CSV's columns
    for d in human.dofs:  # joint limits from the URDF, clamped
        lo, hi, clamped = r["ranges"][d.name]
        assert (lo, hi, clamped) == (pytest.approx(d.lower, abs=1e-12), pytest.approx(d.upper, abs=1e-12), True)
    # the variant's offset shoulder chain: one joint per URDF joint through two massless connector bodies
    v = roundtrip["variant"]["osim_result"]
    assert v["n_joints"] == 19 + 2 and v["n_bodies"] == 19 + 2
    assert sum(b["mass"] == 0 for b in v["bodies"].values()) == 2


def _pin_inertias(urdf: Path) -> dict[str, pin.Inertia]:
    """Each segment's inertia (mass, centre of mass, inertia about it) in its frame, as Pinocchio reads it."""
    pm = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
    out = {}
    for f in pm.frames:
        if f.type == pin.FrameType.BODY and f.inertia.mass > 0:
            out[f.name] = f.inertia
    return out


@needs_opensim
@pytest.mark.parametrize("case", ["base", "perturbed", "variant", "girdle"])
def test_mass_properties_match(roundtrip, case):
    c = roundtrip[case]
    bodies = c["osim_result"]["bodies"]
    ref = _pin_inertias(c["urdf"])
    assert set(ref) <= set(bodies)
    for name, inertia in ref.items():
        b = bodies[name]
        assert b["mass"] == pytest.approx(inertia.mass, rel=1e-12)
        np.testing.assert_allclose(b["com"], inertia.lever, atol=1e-12)
        I = inertia.inertia  # about the centre of mass, segment frame
        np.testing.assert_allclose(b["moments"], np.diag(I), atol=1e-12)
        np.testing.assert_allclose(b["products"], [I[0, 1], I[0, 2], I[1, 2]], atol=1e-12)
    total = sum(b["mass"] for b in bodies.values())
    assert total == pytest.approx(75.0, rel=1e-9)


def _pin_visuals(urdf: Path, segments: set[str], root_t, root_q, angles) -> dict[str, tuple]:
    """The segments' visual shapes as Pinocchio reads them from a URDF (free-flyer root), placed at a pose:
    name '<link>_<k>' -> (hpp-fcl shape, placement in the world, colour rgba)."""
    pm, _, vm = pin.buildModelsFromUrdf(str(urdf), root_joint=pin.JointModelFreeFlyer())
    d, vd = pm.createData(), pin.GeometryData(vm)
    q = np.concatenate([np.asarray(root_t, float), np.asarray(root_q, float), *(np.atleast_1d(a) for a in angles)])
    pin.forwardKinematics(pm, d, q)
    pin.updateGeometryPlacements(pm, d, vm, vd)
    return {g.name: (g.geometry, vd.oMg[i].copy(), np.array(g.meshColor)) for i, g in enumerate(vm.geometryObjects)
            if pm.frames[g.parentFrame].name in segments}


@needs_opensim
@pytest.mark.parametrize("case", ["base", "perturbed", "variant"])
def test_visuals_drawn_in_opensim_as_in_a_urdf_viewer(roundtrip, case):
    """Each segment's URDF visual is an OpenSim shape of the same kind, size, place and colour as Pinocchio's
    visual model (from the URDF calibrate writes) has it, at every random pose; a cylinder's axis is OpenSim's y."""
    c = roundtrip[case]
    segments = {sg.name for sg in c["model"].segments}
    cylinders = spheres = bricks = 0
    for pose, drawn in zip(c["poses"], c["osim_result"]["geometry"], strict=True):
        ref = _pin_visuals(c["urdf"], segments, *pose)
        assert len(ref) == 19 and set(drawn) == {"{}_visual_{}_geom".format(*n.rsplit("_", 1)) for n in ref}
        for name, (shape, X, rgba) in ref.items():
            seg, k = name.rsplit("_", 1)
            o = drawn[f"{seg}_visual_{k}_geom"]
            R, p = np.array(o["R"]), np.array(o["p"])
            np.testing.assert_allclose(p, X.translation, atol=1e-12)
            np.testing.assert_allclose(o["color"], rgba[:3], atol=1e-12)
            kind = type(shape).__name__  # coal's (hpp-fcl's) shape classes
            if kind == "Sphere":
                assert o["kind"] == "Sphere" and o["sizes"][0] == pytest.approx(shape.radius, abs=1e-12)
                spheres += 1
            elif kind == "Box":
                assert o["kind"] == "Brick"
                np.testing.assert_allclose(R, X.rotation, atol=1e-12)
                np.testing.assert_allclose(o["sizes"], shape.halfSide, atol=1e-12)
                bricks += 1
            else:
                assert kind == "Cylinder" and o["kind"] == "Cylinder"
                np.testing.assert_allclose(R[:, 1], X.rotation[:, 2], atol=1e-12)  # OpenSim's y = the URDF's z
                np.testing.assert_allclose(o["sizes"], [shape.radius, shape.halfLength], atol=1e-12)
                cylinders += 1
    assert (cylinders, spheres, bricks) == (12 * len(c["poses"]), 3 * len(c["poses"]), 4 * len(c["poses"]))


@needs_opensim
def test_mot_motion_matches_pinocchio(roundtrip):
    c = roundtrip["mot"]
    r = c["osim_result"]["mot"]
    m: Motion = c["motion"]
    assert r["in_degrees"] == "yes"
    assert r["table_shape"] == [m.n_frames, 6 + m.angles.shape[1]]
    np.testing.assert_allclose(r["time"], m.times, atol=1e-12)
    assert _worst(r["frames"], c["ref"]) < TOL


# ---------------------------------------------------------------------- the command line and bad input
def _args(model: Path, **kw) -> argparse.Namespace:
    """Arguments as `calibrate export-osim` parses them (the subcommand's own parser)."""
    ap = argparse.ArgumentParser(prog="calibrate")
    add_export_osim_parser(ap.add_subparsers(dest="command"))
    argv = ["export-osim", str(model)]
    for key, value in kw.items():
        if key == "overwrite":
            argv += ["--overwrite"] if value else []
        else:
            argv += ["-o" if key == "output" else f"--{key}", str(value)]
    return ap.parse_args(argv)


def test_cli_writes_osim_mot_trc(tmp_path, human, capsys):
    sim = simulate_squats(human, frames=12, seed=2)
    write_motion_csv(tmp_path / "s_motion.csv", sim.motion)
    write_c3d(tmp_path / "s.c3d", sim.trial)
    urdf = write_model(human, tmp_path / "s.urdf", sim.truth)
    assert cmd_export_osim(_args(urdf, motion=tmp_path / "s_motion.csv", trial=tmp_path / "s.c3d")) == 0
    out = capsys.readouterr().out
    for name in ("s.osim", "s_motion.mot", "s.trc"):
        assert (tmp_path / name).is_file() and name in out
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging leftovers
    import xml.etree.ElementTree as ET

    import calibrate  # the model's credits: what wrote it, from what

    credits = ET.parse(tmp_path / "s.osim").getroot().find("Model/credits").text
    assert credits == f"exported by calibrate {calibrate.__version__} from s.urdf"
    trc = read_trc(tmp_path / "s.trc")
    assert trc.labels == sim.trial.labels and trc.n_frames == 12
    np.testing.assert_allclose(trc.markers, sim.trial.markers, atol=2e-6)  # C3D float32, TRC nm resolution
    lines = (tmp_path / "s_motion.mot").read_text().splitlines()
    assert lines[:6] == ["s_motion", "version=1", "nRows=12", f"nColumns={7 + human.n_dofs}", "inDegrees=yes",
                         "endheader"]
    row = np.array(lines[7].split("\t"), dtype=float)
    knee = lines[6].split("\t").index("knee_r")
    assert row[knee] == pytest.approx(np.degrees(sim.motion.angles[0, human.dof_index("knee_r")]), abs=1e-12)
    # existing outputs are kept unless --overwrite
    before = (tmp_path / "s.osim").read_text()
    with pytest.raises(CalibrateError, match="exists; pass --overwrite"):
        cmd_export_osim(_args(urdf, motion=tmp_path / "s_motion.csv"))
    assert cmd_export_osim(_args(urdf, output=tmp_path / "t.osim", overwrite=True)) == 0
    assert (tmp_path / "s.osim").read_text() == before


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and ";" in msg
    return msg


@pytest.mark.parametrize("content, needle", [
    ("hello, not xml", "not valid XML"),
    ("<?xml version='1.0'?><sdf/>", "expected <robot>"),
])
def test_bad_model_one_line_nothing_written(tmp_path, content, needle):
    bad = tmp_path / "bad.urdf"
    bad.write_text(content)
    with pytest.raises(CalibrateError) as e:
        cmd_export_osim(_args(bad))
    assert needle in _one_line(e) and str(bad) in str(e.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.urdf"]


@pytest.mark.skipif(os.geteuid() == 0, reason="running as root: directory permissions do not stop root")
def test_unwritable_directory(tmp_path, human):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(CalibrateError) as e:
            export_osim(human, ro / "x.osim")
        assert "not writable" in _one_line(e)
        with pytest.raises(CalibrateError) as e:
            cmd_export_osim(_args(HUMAN, output=ro / "x.osim"))
        assert "not writable" in _one_line(e)
    finally:
        ro.chmod(0o700)
    assert list(ro.iterdir()) == []


def test_bad_destinations_and_inputs(tmp_path, human):
    (tmp_path / "adir.osim").mkdir()
    with pytest.raises(CalibrateError) as e:
        export_osim(human, tmp_path / "adir.osim")
    assert "is a directory" in _one_line(e)
    with pytest.raises(CalibrateError) as e:
        export_osim(human, tmp_path / "missing" / "x.osim")
    assert "does not exist" in _one_line(e)
    with pytest.raises(CalibrateError) as e:
        export_osim(human, tmp_path / "x.urdf")
    assert ".osim" in _one_line(e)
    with pytest.raises(CalibrateError) as e:
        export_osim(human, tmp_path / "x.osim", Parameters(np.ones(3), np.zeros((1, 3)), np.zeros((1, 3)),
                                                           np.zeros((1, 3))))
    assert "Parameters.scale has shape" in _one_line(e)
    # a motion of another model, --mot without --motion, wrong output suffix
    sim = simulate_squats(human, frames=3, seed=0)
    other = Motion(sim.motion.times, sim.motion.root_translation, sim.motion.root_quaternion,
                   sim.motion.angles[:, 1:], sim.motion.dof_names[1:])
    with pytest.raises(CalibrateError) as e:
        write_mot(tmp_path / "m.mot", human, other)
    assert human.dof_names[0] in _one_line(e)
    write_motion_csv(tmp_path / "other.csv", other)
    with pytest.raises(CalibrateError):
        cmd_export_osim(_args(HUMAN, output=tmp_path / "h.osim", motion=tmp_path / "other.csv"))
    with pytest.raises(CalibrateError) as e:
        cmd_export_osim(_args(HUMAN, output=tmp_path / "h.osim", mot=tmp_path / "m.mot"))
    assert "--mot needs --motion" in str(e.value)
    with pytest.raises(CalibrateError) as e:
        cmd_export_osim(_args(HUMAN, output=tmp_path / "h.txt"))
    assert ".osim" in _one_line(e)
    with pytest.raises(CalibrateError) as e:  # an unreadable trial, found before anything is written
        cmd_export_osim(_args(HUMAN, output=tmp_path / "h.osim", trial=tmp_path / "none.c3d"))
    assert "none.c3d" in _one_line(e)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir.osim", "other.csv"]  # nothing written
