"""The human model: a URDF read into segments, markers, joints, degrees of freedom and
the geometric parameters that calibration may change.

Conventions (docs/model-format.md):

* a **segment** is the root link or any link with positive mass;
* a **marker** is a leaf link, without mass, attached to its parent link by a ``fixed``
  joint; its name is the marker label and its position the joint's origin xyz;
* a **connector** is any other (massless) link: it chains the revolute joints of a
  multi-DoF joint (a ball joint is three revolute joints with coincident origins);
* an **anatomical joint** is the chain of URDF joints from a segment to a child segment;
  its **centre** is the origin of the chain's first URDF joint, in the parent segment
  frame; its degrees of freedom are the chain's revolute/continuous joints;
* the root segment floats: a free-flyer is added at load time.

A :class:`Model` is immutable.  Geometry that calibration may change lives in a
:class:`Parameters` object (scale factors, joint centres, axes, marker offsets);
:func:`write_model` writes a URDF with new parameters, editing only those numbers
(and the inertials/visuals they scale) in the original XML.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin

from ..errors import ModelError, read_text_file
from ..io.text import atomic_write_text, finite_numbers, fmt_vec
from .blocks import GROUPS, ParameterLayout
from .urdf import urdf_text

MOVING = ("revolute", "continuous")


@dataclass(frozen=True)
class Segment:
    """A rigid body segment (a link with mass, or the root)."""

    name: str
    parent_joint: str | None  # anatomical joint into this segment; None for the root
    mass: float  # kg
    markers: tuple[str, ...]  # labels of the markers on this segment


@dataclass(frozen=True)
class Marker:
    """A skin marker rigidly attached to a segment."""

    name: str  # label, as in the trial
    segment: str
    offset: np.ndarray  # (3,) position in the segment frame, metres (base model)


@dataclass(frozen=True)
class Dof:
    """One rotational degree of freedom: a revolute or continuous URDF joint."""

    name: str  # URDF joint name (a column of the motion CSV)
    joint: str  # anatomical joint it belongs to
    axis: np.ndarray  # (3,) unit axis in the URDF joint frame (base model)
    lower: float  # rad; -inf for continuous joints
    upper: float  # rad; +inf for continuous joints
    continuous: bool


@dataclass(frozen=True)
class Joint:
    """An anatomical joint: the chain of URDF joints from one segment to the next."""

    name: str
    parent: str  # parent segment
    child: str  # child segment
    urdf_joints: tuple[str, ...]  # chain, proximal first
    dofs: tuple[str, ...]  # moving URDF joints of the chain
    centre: np.ndarray  # (3,) origin of the first URDF joint in the parent segment frame (m)

    @property
    def kind(self) -> str:
        """'fixed', 'hinge' (1 DoF), 'universal' (2 DoF) or 'ball' (3 DoF)."""
        return {0: "fixed", 1: "hinge", 2: "universal", 3: "ball"}.get(len(self.dofs), f"{len(self.dofs)}-dof")


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint as the kinematics use it (walked from Pinocchio's frame tree)."""

    name: str
    type: str  # 'revolute', 'continuous' or 'fixed'
    parent_link: str
    child_link: str
    xyz: np.ndarray  # origin translation in the parent link frame (base model)
    rotation: np.ndarray  # (3, 3) origin rotation (from rpy); never calibrated
    owner: str  # segment whose scale factor multiplies `xyz`
    role: str  # 'centre' (first of an anatomical joint), 'chain' (later in one), 'marker'
    index: int  # index into Parameters.centre / .marker for those roles, else -1
    dof: int  # index into the DoF vector for moving joints, else -1


@dataclass(frozen=True)
class Parameters:
    """The geometric parameters p shared by all frames of a trial.

    Positions are *unscaled*: the kinematics place a joint centre at
    ``scale[parent segment] * centre`` and a marker at ``scale[segment] * marker``.
    A model read from a URDF has scale 1 and the URDF's numbers.
    """

    scale: np.ndarray  # (n_segments,) isotropic scale factor per segment
    centre: np.ndarray  # (n_joints, 3) joint centres, parent segment frame (m)
    axis: np.ndarray  # (n_dofs, 3) revolute axes in the URDF joint frame (unit)
    marker: np.ndarray  # (n_markers, 3) marker offsets, segment frame (m)

    BLOCKS = GROUPS  # their order in vector() (calibrate.model.blocks)

    def vector(self) -> np.ndarray:
        """Flat p = [scale, centre.ravel(), axis.ravel(), marker.ravel()]."""
        return np.concatenate([np.ravel(getattr(self, b)) for b in self.BLOCKS])

    def copy(self) -> Parameters:
        return Parameters(*(np.array(getattr(self, b), dtype=float) for b in self.BLOCKS))


#: The URDF's number attributes: (element path from a <link> or <joint>, attribute, how many numbers; 0: one if given).
_URDF_NUMBERS = (("origin", "xyz", 3), ("origin", "rpy", 3), ("inertial/origin", "xyz", 3),
                 ("inertial/origin", "rpy", 3), ("inertial/mass", "value", 1), ("axis", "xyz", 3),
                 *(("inertial/inertia", a, 1) for a in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")),
                 *(("limit", a, 0) for a in ("lower", "upper", "effort", "velocity")),
                 *((f"{part}/{sub}", a, n) for part in ("visual", "collision")
                   for sub, a, n in (("origin", "xyz", 3), ("origin", "rpy", 3), ("geometry/box", "size", 3),
                                     ("geometry/cylinder", "radius", 1), ("geometry/cylinder", "length", 1),
                                     ("geometry/sphere", "radius", 1), ("geometry/mesh", "scale", 3))))


def _check_urdf(robot: ET.Element, where: str) -> None:
    """One ModelError line for what the URDF parser would refuse or this module misread: a joint type calibrate does
    not take, a joint without its parent or child link or naming a link the file lacks, a number attribute that is
    not as many finite numbers as it should be.  (urdfdom prints its own complaints on the terminal and Pinocchio
    then says only that the URDF is not valid; a mass it could not read passed on to a Python error.)"""
    links = {el.get("name", "") for el in robot.findall("link")}
    for tag in ("link", "joint"):
        names = [el.get("name", "") for el in robot.findall(tag)]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ModelError(f"{where}: {tag} name '{twice[0]}' is used {names.count(twice[0])} times; rename all "
                             f"but one")
    children = {e.get("link") for e in robot.findall("joint/child")}
    roots = sorted(links - children)
    if len(roots) != 1:
        raise ModelError(f"{where}: expected one root link, found {len(roots)} ({', '.join(roots[:5])}); every "
                         f"other link needs a joint to its parent")
    for el in robot.findall("joint"):
        name = el.get("name", "")
        kind = el.get("type", "")
        if kind not in (*MOVING, "fixed"):
            hint = " (the free-flyer is added at load time; remove it)" if kind == "floating" else ""
            raise ModelError(f"{where}: joint '{name}' is of type '{kind}'; calibrate models use revolute, continuous "
                             f"and fixed joints only{hint}")
        for end in ("parent", "child"):
            e = el.find(end)
            link = e.get("link") if e is not None else None
            if link not in links:
                said = f"link '{link}', which the file does not have" if link else "no link"
                raise ModelError(f"{where}: joint '{name}' has {said} as its {end}; name one of its links")
        if kind == "revolute" and el.find("limit") is None:
            raise ModelError(f"{where}: revolute joint '{name}' has no <limit>; give it one (lower, upper) or make "
                             f"it continuous")
    for el in robot.findall("link"):
        for part in el.findall("inertial"):
            for need in ("mass", "inertia"):
                if part.find(need) is None:
                    raise ModelError(f"{where}: link '{el.get('name', '')}': <inertial> has no <{need}>; give it "
                                     f"one or remove the <inertial>")
        for part in (*el.findall("visual"), *el.findall("collision")):
            g = part.find("geometry")
            if g is None or len(g) == 0:
                raise ModelError(f"{where}: link '{el.get('name', '')}': a <{part.tag}> without a shape in its "
                                 f"<geometry>; give it one (box, cylinder, sphere, mesh) or remove the <{part.tag}>")
    for e in robot.iter("color"):
        values = finite_numbers(e.get("rgba"))
        if values is None or len(values) != 4:
            raise ModelError(f"{where}: <color rgba='{e.get('rgba')}'> is not 4 finite numbers; fix the file or "
                             f"regenerate it")
    for el in (*robot.findall("link"), *robot.findall("joint")):
        for sub, attr, count in _URDF_NUMBERS:
            for e in el.findall(sub):
                if e.get(attr) is None and count != 1:  # (an optional one: urdfdom's default)
                    continue
                text = e.get(attr, "")
                values = finite_numbers(text)
                if values is not None and len(values) == max(count, 1):
                    continue
                want = "a finite number" if count <= 1 else f"{count} finite numbers"
                raise ModelError(f"{where}: {el.tag} '{el.get('name', '')}': <{sub.split('/')[-1]} {attr}="
                                 f"'{text}'> is not {want}; fix the file or regenerate it")


class Model:
    """A calibrate model loaded from a URDF file.

    Attributes (read-only by convention):
      path, name, pin (pinocchio.Model with the free-flyer root), segments, markers,
      joints, dofs (in Pinocchio's configuration order), urdf_joints (tree order),
      root (root segment name).
    """

    def __init__(self, path: str | os.PathLike[str], text: str | None = None):
        """Load the URDF at `path`; with `text`, build from that URDF text instead (and `path` is only
        where it came from, e.g. the base model a model with added markers was made from)."""
        self.path = Path(path)
        if text is None:
            text = read_text_file(self.path, "the model's .urdf file")
        try:
            root_el = ET.fromstring(text)
        except ET.ParseError as e:
            raise ModelError(f"{self.path}: not valid XML ({e}); fix the file or regenerate it") from None
        if root_el.tag != "robot":
            raise ModelError(f"{self.path}: top element is <{root_el.tag}>, expected <robot>; is this a URDF?")
        self._text = text
        self.name = root_el.get("name", self.path.stem)
        _check_urdf(root_el, str(self.path))  # before urdfdom, which prints its complaints on the terminal
        try:
            self.pin = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        except Exception as e:  # pinocchio raises plain RuntimeError/ValueError
            msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise ModelError(f"{self.path}: Pinocchio cannot load this URDF ({msg})") from None
        self._build(root_el)

    # ------------------------------------------------------------------ structure

    @property
    def text(self) -> str:
        """The model's URDF text, as read (or as generated from an OpenSim model)."""
        return self._text

    def _build(self, robot: ET.Element) -> None:
        where = str(self.path)
        links: dict[str, ET.Element] = {}
        for el in robot.findall("link"):
            links[el.get("name", "")] = el
        joints_el = {el.get("name", ""): el for el in robot.findall("joint")}
        children: dict[str, list[str]] = {n: [] for n in links}
        parent_of: dict[str, str] = {}
        for jn, el in joints_el.items():  # (types and links checked: _check_urdf)
            p = el.find("parent").get("link")  # type: ignore[union-attr]
            c = el.find("child").get("link")  # type: ignore[union-attr]
            children[p].append(jn)
            parent_of[c] = jn

        def mass(link: str) -> float:
            m = links[link].find("inertial/mass")
            return float(m.get("value", "0")) if m is not None else 0.0

        def jtype(jn: str) -> str:
            return joints_el[jn].get("type", "")

        def child(jn: str) -> str:
            return joints_el[jn].find("child").get("link")  # type: ignore[union-attr]

        self.root = next(n for n in links if n not in parent_of)  # the one root (_check_urdf)

        def is_marker(link: str) -> bool:
            return (
                link != self.root and not children[link] and jtype(parent_of[link]) == "fixed" and mass(link) <= 0.0
            )

        def is_segment(link: str) -> bool:
            return link == self.root or mass(link) > 0.0

        for ln in links:
            if not is_segment(ln) and not is_marker(ln):
                kids = children[ln]
                if len(kids) != 1 or jtype(kids[0]) not in MOVING:
                    raise ModelError(
                        f"{where}: link '{ln}' has no mass and is neither a marker (massless leaf on a fixed "
                        f"joint) nor a connector (exactly one revolute child joint); give it a mass or "
                        f"restructure the chain"
                    )

        # Walk Pinocchio's frame tree: links are BODY frames, URDF joints JOINT/FIXED_JOINT frames.
        pm = self.pin
        frames = list(pm.frames)
        urdf_joints: list[UrdfJoint] = []
        seg_order: list[str] = [self.root]
        joint_chain: dict[str, list[str]] = {}  # child segment -> URDF joints from parent segment
        owner: dict[str, str] = {self.root: self.root}  # link -> segment that owns its frame contents
        marker_list: list[Marker] = []
        dof_index: dict[str, int] = {}
        for i in range(2, pm.njoints):  # 0 universe, 1 root free-flyer
            dof_index[pm.names[i]] = len(dof_index)
        for f in frames:
            if f.type not in (pin.FrameType.JOINT, pin.FrameType.FIXED_JOINT) or f.name in ("universe", "root_joint"):
                continue
            jn = f.name
            parent_fid = f.parentFrame
            parent_link = frames[parent_fid].name
            child_link = child(jn)
            if f.type == pin.FrameType.JOINT:
                placement = frames[parent_fid].placement.inverse() * pm.jointPlacements[f.parentJoint]
            else:
                placement = frames[parent_fid].placement.inverse() * f.placement
            t = jtype(jn)
            own = owner[parent_link]
            if is_marker(child_link):
                role, index = "marker", len(marker_list)
                marker_list.append(Marker(child_link, own, np.array(placement.translation)))
                if parent_link != own:
                    raise ModelError(f"{where}: marker '{child_link}' hangs on connector '{parent_link}'; "
                                     f"attach it to a segment")
            elif is_segment(parent_link):
                role, index = "centre", -1  # index set below once the joints are numbered
                joint_chain[child_link] = [jn]
            else:
                role, index = "chain", -1
                joint_chain[child_link] = joint_chain.pop(parent_link) + [jn]
            if not is_marker(child_link):
                if is_segment(child_link):
                    owner[child_link] = child_link
                    seg_order.append(child_link)
                else:
                    owner[child_link] = own
            urdf_joints.append(UrdfJoint(
                name=jn, type=t, parent_link=parent_link, child_link=child_link,
                xyz=np.array(placement.translation), rotation=np.array(placement.rotation),
                owner=own, role=role, index=index, dof=dof_index.get(jn, -1) if t in MOVING else -1,
            ))

        # Anatomical joints, in segment order.
        joints: list[Joint] = []
        seg_parent_joint: dict[str, str | None] = {self.root: None}
        first_index: dict[str, int] = {}
        for seg in seg_order[1:]:
            chain = joint_chain[seg]
            name = joints_el[chain[0]].get("anatomical") or _joint_name(chain)  # named, as from a .osim
            first = next(u for u in urdf_joints if u.name == chain[0])
            dofs = tuple(jn for jn in chain if jtype(jn) in MOVING)
            joints.append(Joint(name, owner[first.parent_link], seg, tuple(chain), dofs, first.xyz.copy()))
            seg_parent_joint[seg] = name
            first_index[chain[0]] = len(joints) - 1
        names = [j.name for j in joints]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise ModelError(f"{where}: two anatomical joints are both named '{dup[0]}'; rename the URDF joints")
        self.urdf_joints = tuple(
            UrdfJoint(**{**u.__dict__, "index": first_index[u.name]}) if u.role == "centre" else u
            for u in urdf_joints
        )

        # DoFs in Pinocchio's configuration order.
        dofs: list[Dof] = []
        chain_of = {jn: j.name for j in joints for jn in j.urdf_joints}
        for i, axis in zip(range(2, pm.njoints), _pin_axes(pm, where), strict=True):
            jn = pm.names[i]
            el = joints_el[jn]
            cont = jtype(jn) == "continuous"
            lim = el.find("limit")
            lo = -np.inf if cont or lim is None else float(lim.get("lower", "-inf"))
            hi = np.inf if cont or lim is None else float(lim.get("upper", "inf"))
            dofs.append(Dof(jn, chain_of[jn], axis, lo, hi, cont))

        self.markers = tuple(marker_list)
        mk_by_seg: dict[str, list[str]] = {s: [] for s in seg_order}
        for mk in marker_list:
            mk_by_seg[mk.segment].append(mk.name)
        self.segments = tuple(
            Segment(s, seg_parent_joint[s], mass(s), tuple(mk_by_seg[s])) for s in seg_order
        )
        self.joints = tuple(joints)
        self.dofs = tuple(dofs)
        self._segment_index = {s.name: i for i, s in enumerate(self.segments)}
        self._marker_index = {m.name: i for i, m in enumerate(self.markers)}
        self._joint_index = {j.name: i for i, j in enumerate(self.joints)}
        self._dof_index = {d.name: i for i, d in enumerate(self.dofs)}
        if not self.markers:
            raise ModelError(f"{where}: the model has no markers (massless leaf links on fixed joints)")

    # ------------------------------------------------------------------ queries
    @property
    def n_dofs(self) -> int:
        """Joint angles (excluding the 6 of the floating root)."""
        return len(self.dofs)

    @property
    def nz(self) -> int:
        """Coordinates per frame: root translation (3) + root rotation (3) + joint angles."""
        return self.layout.frame.nz

    @property
    def total_mass(self) -> float:
        """Sum of the segment masses (kg)."""
        return float(sum(sg.mass for sg in self.segments))

    @property
    def marker_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.markers)

    @property
    def dof_names(self) -> tuple[str, ...]:
        return tuple(d.name for d in self.dofs)

    def segment_index(self, name: str) -> int:
        return self._lookup(self._segment_index, name, "segment")

    def marker_index(self, name: str) -> int:
        return self._lookup(self._marker_index, name, "marker")

    def joint_index(self, name: str) -> int:
        return self._lookup(self._joint_index, name, "joint")

    def dof_index(self, name: str) -> int:
        return self._lookup(self._dof_index, name, "degree of freedom")

    def _lookup(self, table: dict[str, int], name: str, what: str) -> int:
        try:
            return table[name]
        except KeyError:
            known = ", ".join(list(table)[:8])
            raise ModelError(f"{self.path}: no {what} named '{name}' (known: {known}, ...)") from None

    def parameters(self) -> Parameters:
        """The base model's geometric parameters (all scales 1)."""
        return Parameters(
            scale=np.ones(len(self.segments)),
            centre=np.array([j.centre for j in self.joints]).reshape(-1, 3),
            axis=np.array([d.axis for d in self.dofs]).reshape(-1, 3),
            marker=np.array([m.offset for m in self.markers]).reshape(-1, 3),
        )

    @cached_property
    def layout(self) -> ParameterLayout:
        """The named blocks of Parameters.vector() (calibrate.model.blocks), every block free."""
        return ParameterLayout(self)

    def parameter_names(self) -> list[str]:
        """One name per entry of Parameters.vector(), e.g. 'centre[knee_r].y'."""
        return self.layout.names()

    def unpack(self, p: np.ndarray) -> Parameters:
        """Inverse of Parameters.vector() for this model's sizes."""
        return Parameters(**self.layout.split(p))

    def pin_configuration(self, root_translation, root_quaternion, angles) -> np.ndarray:
        """Pinocchio q from root translation (3), unit quaternion (x, y, z, w) and joint angles."""
        angles = np.asarray(angles, dtype=float).ravel()
        if angles.size != self.n_dofs:
            raise ValueError(f"joint angles: expected {self.n_dofs}, got {angles.size}")
        q = [np.asarray(root_translation, float).ravel(), np.asarray(root_quaternion, float).ravel()]
        for d, a in zip(self.dofs, angles, strict=True):
            q.append(np.array([np.cos(a), np.sin(a)]) if d.continuous else np.array([a]))
        return np.concatenate(q)

    def neutral_positions(self, names: Sequence[str]) -> np.ndarray:
        """(n, 3) world positions (m) of the named frames (markers, segments) in the base model's neutral pose: root
        at the origin, every angle 0 (Pinocchio)."""
        data = self.pin.createData()
        pin.framesForwardKinematics(self.pin, data, self.pin_configuration(np.zeros(3), [0, 0, 0, 1],
                                                                           np.zeros(self.n_dofs)))
        return np.array([data.oMf[self.pin.getFrameId(n)].translation for n in names]).reshape(-1, 3)

    def summary(self) -> str:
        """A short human-readable description (segments, joints, DoF, markers)."""
        kinds: dict[str, int] = {}
        for j in self.joints:
            kinds[j.kind] = kinds.get(j.kind, 0) + 1
        kind_txt = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items()))
        return (
            f"{self.name}: {len(self.segments)} segments, {len(self.joints)} joints ({kind_txt}), "
            f"{self.nz} DoF ({self.layout.frame.n_root} root + {self.n_dofs}), {len(self.markers)} markers"
        )

    def __repr__(self) -> str:
        return f"Model({str(self.path)!r}: {self.summary()})"


def load_model(path: str | os.PathLike[str], marker_set: str | os.PathLike[str] | None = None) -> Model:
    """Load a calibrate model (URDF), or an OpenSim model (.osim, with an optional OpenSim MarkerSet
    file, calibrate.io.osim); raises ModelError with one line on bad input."""
    if Path(path).suffix.lower() == ".osim":
        from ..io.osim import osim_to_urdf  # (only for OpenSim models: its readers cost every command 0.1 s of imports)

        text, info = osim_to_urdf(path, marker_set)
        model = Model(Path(path), text=text)
        model.osim = info  # what the URDF keeps of its OpenSim origin (calibrate.io.osim_info)
        return model
    if marker_set is not None:
        raise ModelError(f"{marker_set}: a marker-set file goes with an OpenSim model (.osim), not {path}")
    return Model(path)


# ---------------------------------------------------------------------- writing
def write_model(model: Model, path: str | os.PathLike[str], params: Parameters | None = None,
                overwrite: bool = True, mass: float | None = None) -> Path:
    """Write `model` with geometric parameters `params` as a URDF at `path`.

    Changes, per segment with scale s: origins of joints in its frame (s * centre, and
    s * xyz for the later joints of a chain), marker origins (s * offset), revolute axes,
    inertial origin (s *) and inertia tensor (s**2 *), visual/collision origins, mesh scales
    and primitive sizes (s *).  Segment masses are kept, or, given the subject's body `mass`
    (kg), all multiplied by mass / the model's total mass (the base model's mass distribution,
    as OpenSim's Scale tool keeps it), the inertia tensors with them.  Everything else in the
    file is kept.  Written to a temporary file and renamed, so a failure leaves nothing
    half-written.
    """
    path = Path(path)
    if not overwrite and path.exists():
        raise ModelError(f"{path}: exists; choose another output name or allow overwriting")
    if path.resolve() == model.path.resolve() and params is not None:
        raise ModelError(f"{path}: refusing to overwrite the base model; choose another output name")
    if not path.parent.is_dir():
        raise ModelError(f"{path}: directory '{path.parent}' does not exist; create it first")
    atomic_write_text(path, urdf_text(model, params, mass))
    return path


def add_markers(model: Model, markers: Mapping[str, tuple[str, np.ndarray]]) -> Model:
    """A copy of `model` with new markers: label -> (segment, position in the segment frame, m).

    Each becomes a massless link on a fixed joint ``<label>_marker``, as in docs/model-format.md, so
    a model written from the result carries them.  Labels clashing with a link or joint name of the
    model raise ModelError."""
    if not markers:
        return model
    tree = ET.ElementTree(ET.fromstring(model.text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))))
    robot = tree.getroot()
    names = {el.get("name") for el in robot.findall("link")} | {el.get("name") for el in robot.findall("joint")}
    segments = {s.name for s in model.segments}
    if len(robot):
        robot[-1].tail = "\n  "
    for label, (segment, xyz) in markers.items():
        if segment not in segments:
            raise ModelError(f"{model.path}: cannot add marker '{label}' to '{segment}', which is not a segment")
        if label in names or f"{label}_marker" in names:
            raise ModelError(f"{model.path}: a new marker is labelled '{label}', which the model already uses as a "
                             f"link or joint name; rename the trial label")
        link = ET.SubElement(robot, "link", name=label)
        visual = ET.SubElement(ET.SubElement(link, "visual"), "geometry")
        ET.SubElement(visual, "sphere", radius="0.007")
        joint = ET.SubElement(robot, "joint", name=f"{label}_marker", type="fixed")
        ET.SubElement(joint, "parent", link=segment)
        ET.SubElement(joint, "child", link=label)
        ET.SubElement(joint, "origin", xyz=fmt_vec(np.asarray(xyz, dtype=float)), rpy="0 0 0")
        for el in (link, joint):  # indent the new elements only: the rest of the file is kept as it was
            ET.indent(el, space="  ", level=1)
            el.tail = "\n  "
    robot[-1].tail = "\n"
    start = model.text.find("<robot")
    head = model.text[:start] if start > 0 else '<?xml version="1.0"?>\n'
    return Model(model.path, text=head + ET.tostring(robot, encoding="unicode") + "\n")


def hinge_axis(model: Model, params: Parameters, dof: int) -> np.ndarray:
    """Hinge DoF `dof`'s unit axis in its parent segment's frame in geometry `params` (the URDF joint's rotation
    applied to the calibrated axis): where a hinge's lateral and medial markers are measured along it."""
    joint = model.joints[model.joint_index(model.dofs[dof].joint)]
    rotation = next(u.rotation for u in model.urdf_joints if u.name == joint.urdf_joints[0])
    return rotation @ (params.axis[dof] / np.linalg.norm(params.axis[dof]))


def _joint_name(chain: list[str]) -> str:
    """Anatomical joint name: the URDF joint's name, or the chain's common prefix ('hip_r')."""
    if len(chain) == 1:
        return chain[0]
    prefix = os.path.commonprefix(chain).rstrip("_")
    return prefix if prefix else chain[0]


def _pin_axes(pm: pin.Model, where: str) -> list[np.ndarray]:
    """Rotation axis of every joint after the free-flyer, from its motion subspace S (angular part).

    Works for every revolute flavour Pinocchio builds from a URDF (RX/RY/RZ, unaligned,
    unbounded) without depending on which attributes each Python binding exposes.
    """
    data = pm.createData()
    pin.forwardKinematics(pm, data, pin.neutral(pm))
    axes = []
    for i in range(2, pm.njoints):
        S = np.asarray(data.joints[i].S).reshape(6, -1)
        if S.shape[1] != 1 or np.abs(S[:3, 0]).max() > 1e-12:
            raise ModelError(f"{where}: joint '{pm.names[i]}' became a Pinocchio {pm.joints[i].shortname()}, "
                             f"not a single rotation; use revolute or continuous joints")
        axes.append(S[3:, 0].copy())
    return axes




__all__ = ["Dof", "Joint", "Marker", "Model", "Parameters", "Segment", "UrdfJoint", "add_markers", "hinge_axis",
           "load_model", "write_model"]

