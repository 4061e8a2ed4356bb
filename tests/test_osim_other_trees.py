"""OpenSim models with more than the subject on ground and with contact forces, as opensim-models' ToyLanding,
SoccerKick and WalkerModel are: a landing platform welded to ground, a ball on a FreeJoint, and
HuntCrossleyForces whose nested classes OpenSim writes with C++ scope (`<HuntCrossleyForce::ContactParametersSet>`,
well-formed XML but not namespace-well-formed).  Read (they were refused as 'not valid XML', then as '3 joints
connect a body to ground'); the other trees left out and named; the subject's markers where OpenSim puts them
(OpenSim in a child process); calibrated end to end, a welded segment's markers included (the frame-wise start
crashed on a weld whose child carries markers); markers on two trees refused in one line.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.cli import main
from calibrate.errors import ModelError
from calibrate.io.osim_info import osim_info
from calibrate.model.model import load_model
from tests.test_osim_import import (
    _WORKER,
    HAVE_OPENSIM,
    TOL,
    _cases,
    _pin_markers,
    _ranges,
    hand_made_osim,
)

_TREE_BODIES = ('<Body name="platform"><mass>50</mass><mass_center>0 0 0</mass_center>'
                '<inertia>1 1 1 0 0 0</inertia></Body>'
                '<Body name="ball"><mass>0.4</mass><mass_center>0 0 0</mass_center>'
                '<inertia>0.001 0.001 0.001 0 0 0</inertia></Body>')
_TREE_JOINTS = (
    '<WeldJoint name="ground_platform"><socket_parent_frame>ground_offset</socket_parent_frame>'
    '<socket_child_frame>platform_offset</socket_child_frame><frames>'
    '<PhysicalOffsetFrame name="ground_offset"><socket_parent>/ground</socket_parent>'
    '<translation>0 -0.05 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame>'
    '<PhysicalOffsetFrame name="platform_offset"><socket_parent>/bodyset/platform</socket_parent>'
    '<translation>0 0 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame></frames></WeldJoint>'
    '<FreeJoint name="ball_free"><socket_parent_frame>ground_offset</socket_parent_frame>'
    '<socket_child_frame>ball_offset</socket_child_frame><coordinates>'
    + "".join(f'<Coordinate name="ball_{c}"><default_value>0</default_value><range>-5 5</range></Coordinate>'
              for c in ("rx", "ry", "rz", "tx", "ty", "tz"))
    + '</coordinates><frames><PhysicalOffsetFrame name="ground_offset"><socket_parent>/ground</socket_parent>'
    '<translation>1 0.1 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame>'
    '<PhysicalOffsetFrame name="ball_offset"><socket_parent>/bodyset/ball</socket_parent>'
    '<translation>0 0 0</translation><orientation>0 0 0</orientation></PhysicalOffsetFrame></frames></FreeJoint>')
_CONTACT = (
    '<ForceSet name="forceset"><objects><HuntCrossleyForce name="foot_platform"><appliesForce>true</appliesForce>'
    '<HuntCrossleyForce::ContactParametersSet name="contact_parameters"><objects>'
    '<HuntCrossleyForce::ContactParameters><geometry>platform_surface heel</geometry>'
    '<stiffness>100000000</stiffness><dissipation>0.5</dissipation><static_friction>0.9</static_friction>'
    '<dynamic_friction>0.9</dynamic_friction><viscous_friction>0.6</viscous_friction>'
    '</HuntCrossleyForce::ContactParameters></objects><groups /></HuntCrossleyForce::ContactParametersSet>'
    '<transition_velocity>0.1</transition_velocity></HuntCrossleyForce></objects></ForceSet>'
    '<ContactGeometrySet name="contactgeometryset"><objects>'
    '<ContactHalfSpace name="platform_surface"><socket_frame>/bodyset/platform</socket_frame>'
    '<location>0 0 0</location><orientation>0 0 -1.5707963</orientation></ContactHalfSpace>'
    '<ContactSphere name="heel"><socket_frame>/bodyset/foot</socket_frame><location>0 0 0</location>'
    '<orientation>0 0 0</orientation><radius>0.03</radius></ContactSphere></objects></ContactGeometrySet>')


def other_trees_osim(hand: str | None = None) -> str:
    """The hand-made model (tests/test_osim_import.py) with a platform welded to ground, a ball on a FreeJoint and
    a HuntCrossleyForce between the platform and the foot, written as OpenSim writes them."""
    text = hand or hand_made_osim()
    text = text.replace("</objects></BodySet>", _TREE_BODIES + "</objects></BodySet>", 1)
    text = text.replace("</objects></JointSet>", _TREE_JOINTS + "</objects></JointSet>", 1)
    return text.replace("<MarkerSet", _CONTACT + "<MarkerSet", 1)


def test_other_trees_are_left_out_and_named(tmp_path, capsys):
    path = tmp_path / "landing.osim"
    path.write_text(other_trees_osim())
    plain = tmp_path / "handmade.osim"
    plain.write_text(hand_made_osim())
    model, base = load_model(path), load_model(plain)
    assert {s.name for s in model.segments} == {s.name for s in base.segments}  # neither platform nor ball
    assert model.dof_names == base.dof_names and model.marker_names == base.marker_names
    info = osim_info(model)
    left = {a.joint: a for a in info.approximations if a.kind == "left out"}
    assert set(left) == {"ground_platform", "ball_free"}
    assert "platform" in left["ground_platform"].detail and left["ball_free"].coordinates == tuple(
        f"ball_{c}" for c in ("rx", "ry", "rz", "tx", "ty", "tz"))
    assert set(left["ball_free"].coordinates) <= set(info.dropped)
    # the subject is the plain model: its markers where the plain model's are (which OpenSim's are, test_osim_import)
    rng = np.random.default_rng(0)
    for _ in range(5):
        angles = np.array([rng.uniform(max(d.lower, -1), min(d.upper, 1)) for d in model.dofs])
        t, q = rng.normal(0, 0.3, 3), Rotation.random(random_state=int(rng.integers(1000))).as_quat()
        a, b = _pin_markers(model, t, q, angles), _pin_markers(base, t, q, angles)
        assert max(np.abs(a[m] - b[m]).max() for m in model.marker_names) < 1e-12
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "ground_platform: left out (a second tree on ground, no marker on it: platform" in out
    assert "ball_free: left out" in out and "ball_rx" in out


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed (pip install -e '.[opensim]')")
def test_markers_equal_opensim_with_other_trees(tmp_path):
    """OpenSim reads the document (platform, ball, scoped contact classes) and puts the subject's markers where
    our kinematics do, to 1e-6 m on every marker whose joints are exact."""
    path = tmp_path / "landing.osim"
    path.write_text(other_trees_osim())
    model = load_model(path)
    info = osim_info(model)
    plain = tmp_path / "handmade.osim"  # the same subject's ranges (ElementTree alone cannot read the scoped tags)
    plain.write_text(hand_made_osim())
    ranges = {k: v for k, v in _ranges(plain).items() if k not in info.dropped}
    poses, refs = _cases(model, 20, 7, ranges)
    spec, result = tmp_path / "jobs.json", tmp_path / "result.json"
    spec.write_text(json.dumps({"jobs": [{"osim": str(path), "marker_set": None, "poses": poses, "bodies": []}]}))
    proc = subprocess.run([sys.executable, "-c", _WORKER, str(spec), str(result)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"OpenSim worker failed:\n{proc.stderr[-3000:]}"
    theirs = json.loads(result.read_text())[0]
    approximated = {m for a in info.approximations for m in a.markers}
    exact = [m for m in model.marker_names if m not in approximated]
    assert len(exact) >= 10
    worst = max(np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(theirs, refs, strict=True) for m in exact)
    assert worst < TOL


def test_markers_on_two_trees_one_line_exit_2(tmp_path, capsys):
    text = other_trees_osim().replace(
        "</objects></MarkerSet>", '<Marker name="BALL"><socket_parent_frame>/bodyset/ball</socket_parent_frame>'
        "<location>0 0.1 0</location></Marker></objects></MarkerSet>", 1)
    path = tmp_path / "two.osim"
    path.write_text(text)
    with pytest.raises(ModelError) as e:
        load_model(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg and "ball_free: 1" in msg and "remove the other trees' markers" in msg
    assert main(["import-osim", str(path), "-o", str(tmp_path / "out.urdf")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["two.osim"]


def test_calibrates_a_model_with_other_trees_and_a_welded_marker_segment(tmp_path, capsys):
    """End to end from the command line: a trial made from the model's own markers (every free coordinate
    swaying; the welded 'cap' carries two markers) is fitted to under 1 mm, and the subject goes back to
    OpenSim with the contact force named as left out."""
    from calibrate.io.trc import write_trc
    from calibrate.io.trial import Trial

    path = tmp_path / "landing.osim"
    path.write_text(other_trees_osim())
    model = load_model(path)
    cap = model.segments[model.segment_index("cap")]
    assert len(cap.markers) == 2 and model.joints[model.joint_index("cap_weld")].kind == "fixed"
    n, rng = 60, np.random.default_rng(5)
    t = np.arange(n) / 60
    amp = np.radians(rng.uniform(10, 25, model.n_dofs))
    mid = np.array([0.5 * (d.lower + d.upper) for d in model.dofs])
    angles = mid + amp * np.sin(2 * np.pi * t[:, None] + rng.uniform(0, 6, model.n_dofs))
    angles = np.clip(angles, [d.lower for d in model.dofs], [d.upper for d in model.dofs])
    quat = Rotation.from_euler("y", 0.3 * np.sin(np.pi * t)[:, None]).as_quat()
    root = np.column_stack([0.8 * t, np.full(n, 0.9), 0.02 * np.sin(2 * np.pi * t)])
    frames = [_pin_markers(model, root[f], quat[f], angles[f]) for f in range(n)]
    trc = tmp_path / "landing.trc"
    write_trc(trc, Trial(list(model.marker_names), np.array([[fr[m] for m in model.marker_names] for fr in frames]),
                         60.0, 0, str(trc)))
    code = main([str(trc), str(path), "-o", str(tmp_path / "subject.osim"), "--no-new-markers"])
    said = capsys.readouterr()
    assert code == 0, said.err
    printed = said.err + said.out
    assert "landing.osim: 6 joints approximated (" in printed
    assert "; other trees on ground left out (ground_platform, ball_free); see 'calibrate inspect" in printed
    report = json.loads((tmp_path / "landing_report.json").read_text())
    assert report["trials"][0]["rms_mm"] < 1.0
    assert "HuntCrossleyForce foot_platform (a contact force: the export does not carry contact geometry)" in printed
    text = (tmp_path / "subject.osim").read_text()
    assert '<WeldJoint name="cap_weld">' in text and 'name="platform"' not in text and 'name="ball"' not in text


def test_a_welded_or_pinned_root_floats_and_keeps_its_name(tmp_path, capsys):
    """A ground joint of fewer than six coordinates (arm26's WeldJoint 'offset', SoccerKick's PinJoint
    'ground_pelvis'): calibrate's root floats, which inspect and the calibration's note say, its coordinate is
    not a coordinate here, and the .osim export writes the floating root under the source joint's name (it had
    written ground_<root>, which SoccerKick's weld 'ground_swivel' already had: two joints of one name).  OpenSim
    loads the export, and its markers at random coordinates are where Pinocchio puts them."""
    from tests.test_opensim_export import _coordinates, _random_poses, _run_worker

    hand = hand_made_osim()
    start = hand.index('<FreeJoint name="ground_pelvis">')
    end = hand.index("</FreeJoint>") + len("</FreeJoint>")
    pin_root = (hand[start:end].replace('<FreeJoint name="ground_pelvis">', '<PinJoint name="offset">')
                .replace("</FreeJoint>", "</PinJoint>"))
    c0 = pin_root.index("<coordinates>")
    c1 = pin_root.index("</coordinates>") + len("</coordinates>")
    pin_root = (pin_root[:c0] + '<coordinates><Coordinate name="base_rot"><default_value>0</default_value>'
                '<range>-3 3</range></Coordinate></coordinates>' + pin_root[c1:])
    text = hand[:start] + pin_root + hand[end:]
    text = text.replace('<WeldJoint name="cap_weld">', '<WeldJoint name="ground_pelvis">')
    path = tmp_path / "pinned.osim"
    path.write_text(text)
    model = load_model(path)
    info = osim_info(model)
    floating = [a for a in info.approximations if a.kind == "floating base"]
    assert [a.joint for a in floating] == ["offset"] and floating[0].coordinates == ("base_rot",)
    assert "base_rot" in info.dropped and info.root is None
    assert main(["inspect", str(path)]) == 0
    assert "offset: floating base (its PinJoint from ground to pelvis gives 1 of 6 coordinates" in \
        capsys.readouterr().out
    urdf = tmp_path / "pinned.urdf"
    assert main(["import-osim", str(path), "-o", str(urdf)]) == 0
    out = tmp_path / "back.osim"
    assert main(["export-osim", str(urdf), "-o", str(out)]) == 0
    capsys.readouterr()
    import xml.etree.ElementTree as ET

    names = [j.get("name") for j in ET.parse(out).getroot().find("Model/JointSet/objects")]
    assert names.count("offset") == 1 and names.count("ground_pelvis") == 1 and len(names) == len(set(names))
    poses = _random_poses(model, 5, 3)
    theirs = _run_worker(tmp_path, [{"osim": str(out), "poses": [_coordinates(model, p) for p in poses]}])[0]
    ours = [_pin_markers(model, t, q, a) for t, q, a in poses]
    worst = max(np.linalg.norm(np.array(o[m]) - r[m]) for o, r in zip(theirs["poses"], ours, strict=True)
                for m in model.marker_names)
    assert worst < TOL


@pytest.mark.skipif(not HAVE_OPENSIM, reason="opensim is not installed (pip install -e '.[opensim]')")
def test_a_planar_root_keeps_its_coordinates_names_in_the_export(tmp_path):
    """Gait10dof18musc's pelvis: a CustomJoint of pelvis_tilt (about ground z) and pelvis_tx, pelvis_ty.  calibrate's
    root floats; the export's root turns about z, y', x'' and slides along the ground axes, so its z turn and x, y
    slides are the source's coordinates and carry their names (the lab's RRA / CMC setups name them), the three
    others calibrate's.  OpenSim reads the .mot by those names and puts every marker where Pinocchio does.  With the
    source's frames turned, the names are not the export's and stay root_*."""
    from calibrate.io.motion import Motion
    from calibrate.io.osim_export import export_osim, write_mot
    from tests.test_osim_import import _EXPORT_WORKER, _c, _coords, _frames, _lin, _ta

    def planar(orientation: str) -> str:
        return (f"<CustomJoint name=\"ground_pelvis\">{_frames('ground', 'pelvis', '0 0.9 0', orientation)}"
                + _coords(("pelvis_tilt", -1.5, 1.5), ("pelvis_tx", -5, 5), ("pelvis_ty", -1, 2))
                + "<SpatialTransform>" + _ta("rotation1", "0 0 1", "pelvis_tilt", _lin())
                + _ta("rotation2", "0 1 0", "", _c()) + _ta("rotation3", "1 0 0", "", _c())
                + _ta("translation1", "1 0 0", "pelvis_tx", _lin()) + _ta("translation2", "0 1 0", "pelvis_ty", _lin())
                + _ta("translation3", "0 0 1", "", _c()) + "</SpatialTransform></CustomJoint>")

    hand = hand_made_osim()
    start = hand.index('<FreeJoint name="ground_pelvis">')
    end = hand.index("</FreeJoint>") + len("</FreeJoint>")
    turned = tmp_path / "turned.osim"
    turned.write_text(hand[:start] + planar("0.1 0 0.2") + hand[end:])
    assert osim_info(load_model(turned)).root_names == {}
    path = tmp_path / "planar.osim"
    path.write_text(hand[:start] + planar("0 0 0") + hand[end:])
    model = load_model(path)
    assert osim_info(model).root_names == {"root_rz": "pelvis_tilt", "root_x": "pelvis_tx", "root_y": "pelvis_ty"}
    rng = np.random.default_rng(8)
    n = 8
    angles = np.array([[rng.uniform(max(d.lower, -np.pi), min(d.upper, np.pi)) for d in model.dofs] for _ in range(n)])
    motion = Motion(np.arange(n) / 100, rng.normal(0, 0.5, (n, 3)), Rotation.random(n, random_state=2).as_quat(),
                    angles, model.dof_names)
    out = export_osim(model, tmp_path / "back.osim")
    mot = write_mot(tmp_path / "back.mot", model, motion)
    spec, result = tmp_path / "jobs.json", tmp_path / "result.json"
    spec.write_text(json.dumps({"jobs": [{"osim": str(out), "mot": str(mot)}]}))
    proc = subprocess.run([sys.executable, "-c", _EXPORT_WORKER, str(spec), str(result)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads(result.read_text())[0]
    assert res["labels"][:6] == ["pelvis_tilt", "root_ry", "root_rx", "pelvis_tx", "pelvis_ty", "root_z"]
    assert {"pelvis_tilt", "pelvis_tx", "pelvis_ty"} <= set(res["coordinates"])
    worst = max(np.linalg.norm(np.array(o[m]) - _pin_markers(model, motion.root_translation[f],
                                                             motion.root_quaternion[f], angles[f])[m])
                for f, o in enumerate(res["frames"]) for m in model.marker_names)
    assert worst < TOL
