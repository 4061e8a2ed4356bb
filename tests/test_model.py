"""The model format, models/human.urdf, and the model API (load, parameters, write)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy
from conftest import HUMAN

from calibrate.errors import ModelError
from calibrate.model.human import build_human_urdf
from calibrate.model.model import load_model, write_model

PLUG_IN_GAIT = set(
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LASI RASI LPSI RPSI".split()
    + [s + m for s in "LR" for m in "SHO UPA ELB FRM WRA WRB FIN THI KNE TIB ANK HEE TOE".split()]
)


def _fk(pm: pin.Model, q: np.ndarray) -> dict[str, np.ndarray]:
    d = pm.createData()
    pin.forwardKinematics(pm, d, q)
    pin.updateFramePlacements(pm, d)
    return {f.name: d.oMf[i].translation.copy() for i, f in enumerate(pm.frames)}


def test_human_loads_unchanged_in_pinocchio_and_yourdfpy():
    pm = pin.buildModelFromUrdf(str(HUMAN), pin.JointModelFreeFlyer())
    assert pm.nv == 38 and pm.nv >= 36  # 6 (free-flyer) + 32 joint DoF
    u = yourdfpy.URDF.load(str(HUMAN), build_scene_graph=False, load_meshes=False)
    links = {ln.name: ln for ln in u.robot.links}
    total = sum(ln.inertial.mass for ln in links.values() if ln.inertial is not None)
    assert total == pytest.approx(75.0, rel=1e-9)
    # markers per the format: leaf links on fixed joints, massless, named by Plug-in Gait labels
    parents = {j.parent for j in u.robot.joints}
    markers = {j.child for j in u.robot.joints if j.type == "fixed"}
    assert markers == PLUG_IN_GAIT
    for mk in markers:
        assert mk not in parents and links[mk].inertial is None


def test_committed_model_is_the_generators_output():
    from conftest import assert_same_text_and_numbers

    assert_same_text_and_numbers(build_human_urdf(), HUMAN.read_text())


def test_model_structure(human):
    kinds = {j.name: j.kind for j in human.joints}
    for side in "rl":
        assert kinds[f"hip_{side}"] == "ball" and kinds[f"shoulder_{side}"] == "ball"
        assert kinds[f"knee_{side}"] == "hinge" and kinds[f"elbow_{side}"] == "hinge"
        assert kinds[f"radioulnar_{side}"] == "hinge" and kinds[f"wrist_{side}"] == "universal"
        assert kinds[f"ankle_{side}"] == "hinge" and kinds[f"subtalar_{side}"] == "hinge"
    assert kinds["lumbar"] == "ball" and kinds["neck"] == "ball"
    assert set(human.marker_names) == PLUG_IN_GAIT
    seg_of = {m.name: m.segment for m in human.markers}
    assert seg_of["RKNE"] == "femur_r" and seg_of["LHEE"] == "calcn_l" and seg_of["C7"] == "torso"
    # ankle axes are tilted (not a lab axis) and mirror left/right
    ar = human.dofs[human.dof_index("ankle_r")].axis
    al = human.dofs[human.dof_index("ankle_l")].axis
    assert np.degrees(np.arccos(abs(ar[1]))) > 5
    np.testing.assert_allclose(al, [-ar[0], ar[1], -ar[2]], atol=1e-12)
    # ball joints: three revolute joints with coincident origins through massless links
    hip = human.joints[human.joint_index("hip_r")]
    chain = [u for u in human.urdf_joints if u.name in hip.urdf_joints]
    assert len(chain) == 3 and all(np.all(u.xyz == 0) for u in chain[1:])


def test_other_sizes_scale_lengths_and_masses():
    small = build_human_urdf(height=1.60, mass=55.0)
    pm0 = pin.buildModelFromUrdf(str(HUMAN))
    pm1 = pin.buildModelFromXML(small)
    f0, f1 = _fk(pm0, pin.neutral(pm0)), _fk(pm1, pin.neutral(pm1))
    thigh0 = np.linalg.norm(f0["knee_r"] - f0["hip_r_flexion"])
    thigh1 = np.linalg.norm(f1["knee_r"] - f1["hip_r_flexion"])
    assert thigh1 / thigh0 == pytest.approx(1.60 / 1.75, rel=1e-12)
    assert sum(i.mass for i in pm1.inertias) == pytest.approx(55.0, rel=1e-9)
    with pytest.raises(ValueError):
        build_human_urdf(height=3.0)


def test_round_trip_load_write_load(human, tmp_path):
    out = write_model(human, tmp_path / "copy.urdf")
    again = load_model(out)
    for a, b in zip(human.parameters().__dict__.values(), again.parameters().__dict__.values(), strict=True):
        np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(1)
    for _ in range(5):  # seeded configurations: root anywhere, every joint angle in [-pi, pi]
        q = pin.normalize(human.pin, rng.uniform(-np.pi, np.pi, human.pin.nq))  # unit quaternions
        fa, fb = _fk(human.pin, q), _fk(again.pin, q)
        assert max(np.abs(fa[k] - fb[k]).max() for k in fa) < 1e-12


def test_write_with_parameters_scales_inertials_and_visuals(human, tmp_path):
    p = human.parameters()
    i = human.segment_index("femur_r")
    p.scale[i] = 1.1
    out = write_model(human, tmp_path / "scaled.urdf", p)
    u0 = yourdfpy.URDF.load(str(HUMAN), build_scene_graph=False, load_meshes=False)
    u1 = yourdfpy.URDF.load(str(out), build_scene_graph=False, load_meshes=False)
    l0, l1 = u0.link_map["femur_r"], u1.link_map["femur_r"]
    assert l1.inertial.mass == l0.inertial.mass
    np.testing.assert_allclose(l1.inertial.inertia, 1.21 * l0.inertial.inertia, rtol=1e-12)
    np.testing.assert_allclose(l1.inertial.origin[:3, 3], 1.1 * l0.inertial.origin[:3, 3], rtol=1e-12)
    assert l1.visuals[0].geometry.cylinder.length == pytest.approx(1.1 * l0.visuals[0].geometry.cylinder.length)
    np.testing.assert_allclose(u1.joint_map["knee_r"].origin[:3, 3], 1.1 * u0.joint_map["knee_r"].origin[:3, 3])
    np.testing.assert_allclose(u1.joint_map["RKNE_marker"].origin[:3, 3],
                               1.1 * u0.joint_map["RKNE_marker"].origin[:3, 3])
    # other segments untouched
    np.testing.assert_array_equal(u1.link_map["tibia_r"].inertial.inertia, u0.link_map["tibia_r"].inertial.inertia)


def test_write_with_subject_mass_keeps_the_mass_distribution(human, tmp_path):
    """--mass: every segment mass times mass/base total (OpenSim Scale's 'preserve mass distribution'),
    inertias with it (and with s**2); checked in Pinocchio's total mass and yourdfpy's numbers."""
    p = human.parameters()
    i = human.segment_index("tibia_l")
    p.scale[i] = 0.95
    out = write_model(human, tmp_path / "m60.urdf", p, mass=60.0)
    pm = pin.buildModelFromUrdf(str(out), pin.JointModelFreeFlyer())
    assert pin.computeTotalMass(pm) == pytest.approx(60.0, rel=1e-9)
    k = 60.0 / pin.computeTotalMass(pin.buildModelFromUrdf(str(HUMAN), pin.JointModelFreeFlyer()))
    u0 = yourdfpy.URDF.load(str(HUMAN), build_scene_graph=False, load_meshes=False)
    u1 = yourdfpy.URDF.load(str(out), build_scene_graph=False, load_meshes=False)
    for name, s in (("tibia_l", 0.95), ("pelvis", 1.0), ("hand_r", 1.0)):
        l0, l1 = u0.link_map[name], u1.link_map[name]
        assert l1.inertial.mass == pytest.approx(k * l0.inertial.mass, rel=1e-9)
        np.testing.assert_allclose(l1.inertial.inertia, k * s * s * l0.inertial.inertia, rtol=1e-9)
    for bad in (0.0, -70.0, float("nan")):
        with pytest.raises(ModelError, match="body mass"):
            write_model(human, tmp_path / "bad.urdf", p, mass=bad)
    assert not (tmp_path / "bad.urdf").exists()


def test_write_keeps_elements_it_does_not_know(tmp_path):
    text = HUMAN.read_text().replace("</robot>", '<gazebo reference="pelvis"><mu1>0.5</mu1></gazebo>\n</robot>')
    src = tmp_path / "with_gazebo.urdf"
    src.write_text(text)
    m = load_model(src)
    p = m.parameters()
    p.scale[:] = 0.9
    out = write_model(m, tmp_path / "out.urdf", p)
    written = out.read_text()
    assert '<gazebo reference="pelvis"><mu1>0.5</mu1></gazebo>' in written
    assert "de Leva" in written  # the comment survives


def test_write_refuses_base_model_and_missing_directory(human, tmp_path):
    with pytest.raises(ModelError, match="base model"):
        write_model(human, HUMAN, human.parameters())
    with pytest.raises(ModelError, match="does not exist"):
        write_model(human, tmp_path / "nope" / "x.urdf")
    target = tmp_path / "exists.urdf"
    target.write_text("keep me")
    with pytest.raises(ModelError, match="exists"):
        write_model(human, target, overwrite=False)
    assert target.read_text() == "keep me"


@pytest.mark.parametrize("text, needle", [
    ("", "empty"),
    ("<robot name='x'><link name='a'>", "not valid XML"),
    ("<sdf/>", "expected <robot>"),
    ("""<robot name="x"><link name="a"><inertial><mass value="1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1"
        iyz="0" izz="1"/></inertial></link><link name="b"><inertial><mass value="1"/><inertia ixx="1" ixy="0"
        ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link><joint name="j" type="prismatic"><parent link="a"/>
        <child link="b"/><axis xyz="1 0 0"/><limit lower="0" upper="1" effort="1" velocity="1"/></joint></robot>""",
     "prismatic"),
])
def test_bad_model_files_give_one_line(tmp_path, text, needle):
    f = tmp_path / "bad.urdf"
    f.write_text(text)
    with pytest.raises(ModelError) as e:
        load_model(f)
    msg = str(e.value)
    assert needle in msg and "bad.urdf" in msg and "\n" not in msg


def test_missing_model_file(tmp_path):
    with pytest.raises(ModelError, match="no such file"):
        load_model(tmp_path / "missing.urdf")


def test_parameter_vector_names_and_unpack(human):
    p = human.parameters()
    v = p.vector()
    names = human.parameter_names()
    assert len(names) == v.size == len(human.segments) + 3 * (len(human.joints) + human.n_dofs + len(human.markers))
    knee = human.joints[human.joint_index("knee_r")]
    assert v[names.index("centre[knee_r].z")] == knee.centre[2]
    assert v[names.index("marker[RKNE].y")] == human.markers[human.marker_index("RKNE")].offset[1]
    assert v[names.index("axis[knee_r].y")] == human.dofs[human.dof_index("knee_r")].axis[1]
    back = human.unpack(v)
    for b in p.BLOCKS:
        np.testing.assert_array_equal(getattr(back, b), getattr(p, b))
    q = p.copy()
    q.scale[0] = 2.0
    assert p.scale[0] == 1.0  # copies do not share memory
    with pytest.raises(ValueError, match="expected"):
        human.unpack(v[:-1])


def _nth(text: str, old: str, new: str, after: str = "") -> str:
    """`text` with the first `old` after `after` replaced by `new`."""
    start = text.index(after) if after else 0
    at = text.index(old, start)
    return text[:at] + new + text[at + len(old):]


@pytest.mark.parametrize("mutate, needle", [
    # numbers as URDF parsers read them (C++: no '1_0', no nan, no inf)
    (lambda t: _nth(t, '<axis xyz="0 0 1.0"', '<axis xyz="0 0 1.0_2"'),
     "<axis xyz='0 0 1.0_2'> is not 3 finite numbers"),
    (lambda t: _nth(t, '<mass value="', '<mass value="nan" x="'), "<mass value='nan'> is not a finite number"),
    (lambda t: _nth(t, 'radius="', 'radius="1e999" r="', "<cylinder"), "<cylinder radius='1e999'>"),
    (lambda t: _nth(t, 'rgba="', 'rgba="1 0 x 1" c="'), "<color rgba='1 0 x 1'> is not 4 finite numbers"),
    # structure urdfdom refuses after printing its own complaints
    (lambda t: _nth(t, 'type="fixed"', 'type="revolute"', '_marker"'), "has no <limit>"),
    (lambda t: _nth(t, '<joint name="knee_r"', '<joint name="knee_l"'), "joint name 'knee_l' is used 2 times"),
    (lambda t: _nth(t, '<child link="femur_r"/>', '<child link="femur_l"/>'), "expected one root link, found 2"),
    (lambda t: _nth(t, '<parent link="pelvis"/>', '<parent link="hips"/>'), "has link 'hips', which the file"),
    (lambda t: _nth(t, '<sphere radius="0.007"/>', ''), "a <visual> without a shape in its <geometry>"),
    (lambda t: _nth(t, 'type="revolute"', 'type="prismatic"'), "is of type 'prismatic'"),
])
def test_a_broken_urdf_is_one_line_without_the_parsers_complaints(tmp_path, capfd, mutate, needle):
    """A URDF the parsers would refuse or misread: one line naming the file and what to fix, before urdfdom prints
    its complaints on the terminal (and Pinocchio then says only that the URDF is not valid) or Python's float() takes
    a number C++ would not; found by fuzzing models/human.urdf."""
    from calibrate.cli.main import main

    bad = tmp_path / "bad.urdf"
    bad.write_text(mutate(HUMAN.read_text()))
    with pytest.raises(ModelError) as e:
        load_model(bad)
    assert needle in str(e.value) and str(bad) in str(e.value) and "\n" not in str(e.value)
    assert main(["inspect", str(bad)]) == 2
    err = capfd.readouterr().err
    assert err.startswith("calibrate: error: ") and err.count("\n") == 1 and needle in err  # nothing from urdfdom
