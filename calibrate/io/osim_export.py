"""OpenSim export: a calibrate model as an OpenSim model (``.osim``), a motion as an OpenSim
motion (``.mot``), a trial as ``.trc`` — ``calibrate export-osim``.

Pure Python (xml.etree): writing needs no ``opensim`` package; loading the files in OpenSim
is what the tests check (``pip install calibrate[opensim]``).

How the URDF becomes an OpenSim model (OpenSim 4 format, ``Version 40000``):

* **bodies** — one ``Body`` per segment, named after its link, its frame the URDF link frame;
  mass, centre of mass (the URDF ``<inertial><origin xyz>`` × segment scale) and inertia
  about the centre of mass in the body frame (R I Rᵀ with R from the inertial origin's
  ``rpy``, × scale²).  Connectors and markers are not bodies (but see the chain case below).
* **root** — ``CustomJoint`` ``ground_<root>`` (from a .osim whose ground joint had fewer than six
  coordinates, a weld or a pin: that joint's name) from ground: three rotations about the body-fixed
  z, y', x'' axes (coordinates ``root_rz``, ``root_ry``, ``root_rx``: R = Rz Ry Rx, as
  ``scipy`` ``as_euler("ZYX")``) then three translations along the ground axes (``root_x``,
  ``root_y``, ``root_z``: the root origin in the lab, as in the motion CSV).  The Euler angles
  are singular only at ``root_ry`` = ±90° (the root's x axis vertical: a pelvis lying on its
  back or front).
* **anatomical joints** — one ``CustomJoint`` per joint, named like calibrate's joint (``hip_r``,
  ``knee_r``), one coordinate per moving URDF joint, named after it (the motion CSV's columns),
  range = the URDF limits (clamped as the source .osim clamps it, OsimInfo.clamped; a model of calibrate's own:
  clamped; continuous joints unbounded, unclamped).  A URDF chain is
  ``O0 · Rot(a1, q1) · O1 · Rot(a2, q2) · O2 ...`` (O = origin xyz/rpy; the rotations about
  the unit axes in the joint frames).  When the origins between rotations have no translation
  (ball and universal joints; any rpy allowed) this equals
  ``O0 · Rot(b1, q1) Rot(b2, q2) Rot(b3, q3) · O_end`` with b1 = a1, b2 = R(O1) a2,
  b3 = R(O1) R(O2) a3 and O_end the product of the rotations O1 O2 ... with the last origin:
  O0 is the joint's parent ``PhysicalOffsetFrame`` (on the parent body), the b's the
  ``SpatialTransform``'s rotation axes (successive, body-fixed), O_end⁻¹ the child offset frame.
  A chain whose later origins do translate cannot be one ``SpatialTransform`` and is exported
  as one single-rotation ``CustomJoint`` per URDF joint (named after it) through massless
  bodies named after the connector links; so is a chain whose axes are linearly dependent.
  A 0-DoF chain (a welded segment) becomes a ``WeldJoint``.
* **markers** — ``Marker`` on its segment's body at the URDF offset (× scale).
* gravity ``0 0 -9.80665`` (z up, as in models/human.urdf); a model imported from OpenSim keeps its source's.
* **visuals** — a model of calibrate's own: each segment's URDF visuals as OpenSim geometry (Sphere, Brick,
  Cylinder, Mesh) on offset frames of its body, sizes × scale (``_Builder.visuals``), so that OpenSim's GUI draws
  the subject as a URDF viewer does.  A model imported from OpenSim gets its source bodies' geometry back instead
  (the bone meshes, moved and scaled with their segments as OpenSim's Scale tool scales them:
  calibrate.io.osim_forces.carried_geometry) and its ground's.
* **forces** — for a model imported from OpenSim, the source model's muscles (path points moved and scaled
  with their segments, fibre and tendon slack lengths scaled with the path, as OpenSim's Scale tool does),
  the bodies' wrap objects, and the forces on coordinates the subject has: calibrate.io.osim_forces.
* **a model imported from an OpenSim model** (calibrate.io.osim; its URDF keeps an ``<opensim>`` element,
  also after calibration) gets OpenSim's names back: the ground joint's name, frames and six
  coordinates (e.g. ``ground_pelvis``: ``pelvis_tilt``, ``pelvis_list``, ``pelvis_rotation``,
  ``pelvis_tx``...), the coordinates' default values and locked flags, and gravity along the
  original's -y; bodies, joints and coordinates already carry the original names.  The .mot then has
  those root columns (OpenSim's coordinate values of the root pose).

With ``params`` (a calibrated or perturbed :class:`calibrate.model.model.Parameters`) positions are
placed exactly as calibrate.model.kinematics and :func:`calibrate.model.model.write_model` place them
(scale × centre, scale × marker, scale × later chain origins, axis/|axis|, inertia × scale²).

Motion (``.mot``, OpenSim Storage, ``inDegrees=yes``): ``time``, the root's Euler angles
(degrees) and translation (m), every joint angle (degrees; a lumped chain's coordinate in radians, as
OpenSim writes a Coupled coordinate), one row per frame.

Do not ``import opensim`` in a process that uses calibrate: the opensim 4.6 wheel bundles a
libcasadi with the same soname as (but another ABI than) the casadi wheel calibrate needs, and
whichever is imported second fails to load.  Run OpenSim in its own process on the written files
(as tests/test_opensim_export.py and scripts/bench_peers.py do).
"""

from __future__ import annotations

import argparse
import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import CalibrateError, ModelError
from ..model.model import Model, Parameters, UrdfJoint
from ..model.rotations import euler_matrices, matrix_eulers, quat_eulers
from ..model.urdf import origin_of, urdf_visuals
from ..seed.geometry import Transform, compose, identity_transform, invert
from .labels import OSIM_INVALID_CHARS, osim_name
from .motion import Motion
from .osim import FLOATING_ROOT
from .osim_forces import NOTE_MARK, CarriedForces, carried_forces, forces_lines
from .outputs import check_targets, write_all
from .text import atomic_write_text, fmt_float, fmt_vec
from .trial import Trial

ROOT_ROTATIONS = FLOATING_ROOT[:3]  # body-fixed z, y', x'' (scipy "ZYX"): root_rz, root_ry, root_rx
ROOT_TRANSLATIONS = FLOATING_ROOT[3:]  # ground axes, as the motion CSV's columns: root_x, root_y, root_z
GRAVITY = (0.0, 0.0, -9.80665)
UNBOUNDED_ROTATION = 4 * np.pi  # range written for continuous joints and the root's angles (unclamped)
UNBOUNDED_TRANSLATION = 100.0  # m, range written for the root's translations (unclamped)
_ZERO_OFFSET = 1e-12  # m: a chain origin translating less than this counts as none


def floating_root_names(info) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The floating root's rotation and translation coordinates as the export writes them: ROOT_ROTATIONS and
    ROOT_TRANSLATIONS, those the source .osim names under its names (OsimInfo.root_names: a planar pelvis's
    pelvis_tilt, pelvis_tx, pelvis_ty)."""
    named = info.root_names if info is not None else {}
    return tuple(named.get(n, n) for n in ROOT_ROTATIONS), tuple(named.get(n, n) for n in ROOT_TRANSLATIONS)


# ---------------------------------------------------------------------- geometry



def _euler_xyz(R: np.ndarray) -> np.ndarray:
    """OpenSim frame orientation: body-fixed x-y-z angles (R = Rx Ry Rz); exactly 0 for R = I."""
    if np.array_equal(R, np.eye(3)):
        return np.zeros(3)
    return matrix_eulers(R, "XYZ")


def _completion(axes: list[np.ndarray]) -> list[np.ndarray]:
    """Unit vectors that, appended to `axes` (1 to 3 independent unit vectors), give 3 independent axes."""
    out = list(axes)
    for e in np.eye(3):
        if len(out) == 3:
            break
        M = np.array(out + [e])
        if np.linalg.matrix_rank(M, tol=1e-6) == len(M):
            out.append(e)
    return out[len(axes):]


def _independent(axes: list[np.ndarray]) -> bool:
    return np.linalg.svd(np.array(axes), compute_uv=False).min() > 1e-6


def _inertia_vec6(I: np.ndarray) -> np.ndarray:
    """OpenSim's [Ixx Iyy Izz Ixy Ixz Iyz]."""
    return np.array([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])


def _urdf_inertials(model: Model) -> dict[str, tuple[float, np.ndarray, np.ndarray]]:
    """link -> (mass, centre of mass (3,), inertia about it in the link frame (3, 3)), base model."""
    robot = ET.fromstring(model.text)
    out = {}
    for link in robot.findall("link"):
        el = link.find("inertial")
        if el is None:
            continue
        m = el.find("mass")
        mass = float(m.get("value", "0")) if m is not None else 0.0
        R, xyz = origin_of(el)
        att = el.find("inertia")
        v = {k: float(att.get(k, "0")) if att is not None else 0.0 for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
        inertia = np.array([[v["ixx"], v["ixy"], v["ixz"]], [v["ixy"], v["iyy"], v["iyz"]],
                            [v["ixz"], v["iyz"], v["izz"]]])
        out[link.get("name", "")] = (mass, xyz, R @ inertia @ R.T)
    return out


# ---------------------------------------------------------------------- the model
# OpenSim draws a Cylinder along its frame's y axis, URDF along z: the frame turned by Rx(90°) (y -> z)
_Y_TO_Z = euler_matrices("x", np.pi / 2)


def _shape(components: ET.Element, name: str, s: float, rgba: np.ndarray | None, kind: str, R: np.ndarray,
           at: np.ndarray, **props: str) -> None:
    """One OpenSim geometry ``kind`` with ``props`` on a PhysicalOffsetFrame ``name`` of the body whose
    ``components`` these are, at ``at`` (segment frame, unscaled; × ``s``) turned by ``R``; coloured by ``rgba``."""
    frame = ET.SubElement(components, "PhysicalOffsetFrame", name=name)
    _text(frame, "socket_parent", "..")
    _text(frame, "translation", fmt_vec(s * at))
    _text(frame, "orientation", fmt_vec(_euler_xyz(R)))
    g = ET.SubElement(ET.SubElement(frame, "attached_geometry"), kind, name=f"{name}_geom")
    _text(g, "socket_frame", "..")
    for key, value in props.items():
        _text(g, key, value)
    if rgba is not None:
        look = ET.SubElement(g, "Appearance")
        _text(look, "opacity", fmt_float(float(rgba[3])))
        _text(look, "color", fmt_vec(rgba[:3]))


class _Builder:
    """Collects the bodies, joints and markers of the .osim document."""

    def __init__(self, model: Model, p: Parameters):
        self.model = model
        self.p = p
        self.bodies: list[ET.Element] = []
        self.joints: list[ET.Element] = []
        self.couplers: list[ET.Element] = []  # CoordinateCouplerConstraints of folded turns (anatomical_joint)
        self.scale = {s.name: float(p.scale[i]) for i, s in enumerate(model.segments)}
        self.urdf = {u.name: u for u in model.urdf_joints}
        self.limits = {d.name: (d.lower, d.upper, d.continuous) for d in model.dofs}
        from .osim_info import osim_info

        self.info = osim_info(model)

    def origin(self, u: UrdfJoint) -> Transform:
        """A URDF joint's origin with the parameters applied (as calibrate.model.kinematics does)."""
        s = self.scale[u.owner]
        if u.role == "centre":
            xyz = s * self.p.centre[u.index]
        elif u.role == "marker":
            xyz = s * self.p.marker[u.index]
        else:
            xyz = s * u.xyz
        return np.array(u.rotation, dtype=float), np.asarray(xyz, dtype=float)

    def axis(self, u: UrdfJoint) -> np.ndarray:
        a = np.asarray(self.p.axis[u.dof], dtype=float)
        return a / np.linalg.norm(a)

    # -------------------------------------------------------------- elements
    def body(self, name: str, mass: float, com: np.ndarray, inertia: np.ndarray) -> None:
        b = ET.Element("Body", name=name)
        _text(b, "mass", fmt_float(mass))
        _text(b, "mass_center", fmt_vec(com))
        _text(b, "inertia", fmt_vec(_inertia_vec6(inertia)))
        self.bodies.append(b)

    def joint(self, kind: str, name: str, parent: str, parent_offset: Transform, child: str,
              child_offset: Transform, coords: Sequence[tuple[str, np.ndarray, str]] = ()) -> None:
        """A joint between two bodies ('ground' or a body name) through two offset frames.

        coords: (coordinate name, unit axis, 'rotation' | 'translation'), rotations first.
        """
        j = ET.Element(kind, name=name)
        pf, cf = f"{parent}_offset_{name}", f"{child}_offset_{name}"
        _text(j, "socket_parent_frame", pf)
        _text(j, "socket_child_frame", cf)
        if coords:
            cs = ET.SubElement(j, "coordinates")
            for cname, _, motion in coords:
                cs.append(self.coordinate(cname, motion))
        frames = ET.SubElement(j, "frames")
        for fname, owner, (R, t) in ((pf, parent, parent_offset), (cf, child, child_offset)):
            f = ET.SubElement(frames, "PhysicalOffsetFrame", name=fname)
            _text(f, "socket_parent", "/ground" if owner == "ground" else f"/bodyset/{owner}")
            _text(f, "translation", fmt_vec(t))
            _text(f, "orientation", fmt_vec(_euler_xyz(R)))
        if kind == "CustomJoint":
            j.append(_spatial_transform(coords, {n: self.ratio(n) for n, _, _ in coords}))
        self.joints.append(j)

    def ratio(self, name: str) -> float:
        """The URDF angle per unit of OpenSim's coordinate `name` (a lumped chain's whole turn; else 1)."""
        return self.info.ratio(name) if self.info is not None else 1.0

    def coordinate(self, name: str, motion: str) -> ET.Element:
        c = ET.Element("Coordinate", name=name)
        info = self.info
        g = self.ratio(name)
        default = info.defaults.get(name, 0.0) / g if info is not None else 0.0
        mix = info.mixes.get(name) if info is not None else None
        dependent = next((m for m in info.mixes.values() if m.dependent == name), None) if info is not None else None
        if mix is not None:  # a fold's coordinate: OpenSim's range and default, not its URDF angle's
            default = float(info.coordinates(info.defaults)[name])  # type: ignore[union-attr]
            c = ET.Element("Coordinate", name=name)
            _text(c, "default_value", fmt_float(default))
            _text(c, "range", f"{fmt_float(mix.lo)} {fmt_float(mix.hi)}")
            _text(c, "clamped", "true" if name in info.clamped else "false")  # type: ignore[union-attr]
            _text(c, "locked", "true" if name in info.locked else "false")  # type: ignore[union-attr]
            return c
        if dependent is not None:  # its coupled turn, followed by OpenSim through the constraint
            default = dependent.mix * float(info.coordinates(info.defaults).get(dependent.independent, 0.0))  # type: ignore[union-attr]
        if name in self.limits:
            lo, hi, cont = self.limits[name]
            bounded = not cont and np.isfinite(lo) and np.isfinite(hi)
            # clamped as the source model (OsimInfo.clamped); a model of calibrate's own: wherever it has limits
            clamped = bounded and (info is None or name in info.clamped)
            if not bounded:
                lo, hi = -UNBOUNDED_ROTATION, UNBOUNDED_ROTATION
            else:
                lo, hi = lo / g, hi / g
        else:  # the root
            big = UNBOUNDED_ROTATION if motion == "rotation" else UNBOUNDED_TRANSLATION
            lo, hi, clamped = -big, big, False
        if clamped:  # OpenSim refuses a clamped coordinate whose default lies outside its range
            default = min(max(default, lo), hi)
        _text(c, "default_value", fmt_float(default))
        _text(c, "range", f"{fmt_float(lo)} {fmt_float(hi)}")
        _text(c, "clamped", "true" if clamped else "false")
        _text(c, "locked", "true" if self.info is not None and name in self.info.locked else "false")
        return c

    # -------------------------------------------------------------- structure
    def build(self) -> None:
        model = self.model
        inertials = _urdf_inertials(model)
        for seg in model.segments:
            s = self.scale[seg.name]
            mass, com, inertia = inertials.get(seg.name, (0.0, np.zeros(3), np.zeros((3, 3))))
            self.body(seg.name, mass, s * com, s * s * inertia)
        if self.info is None:  # a model of calibrate's own: its primitives drawn in OpenSim (an .osim's: its meshes)
            self.visuals()
        ez = np.eye(3)
        root = self.info.root if self.info is not None else None
        if root is not None:  # the original ground joint: name, frames, coordinates
            root_coords = [(n, a, "rotation") for n, a in root.rotations]
            root_coords += [(n, a, "translation") for n, a in root.translations]
            child = (root.child_offset[0], self.scale[model.root] * root.child_offset[1])
            self.joint("CustomJoint", root.joint, "ground", root.parent_offset, model.root, child, root_coords)
        else:
            rot_names, trans_names = floating_root_names(self.info)
            root_coords = [(n, ez[k], "rotation") for n, k in zip(rot_names, (2, 1, 0), strict=True)]
            root_coords += [(n, ez[k], "translation") for k, n in enumerate(trans_names)]
            self.joint("CustomJoint", self._root_name(), "ground", identity_transform(), model.root,
                       identity_transform(), root_coords)
        for j in model.joints:
            self.anatomical_joint(j.name, j.parent, j.child, [self.urdf[n] for n in j.urdf_joints])

    def visuals(self) -> None:
        """The segments' URDF visuals as OpenSim geometry, each on a PhysicalOffsetFrame among its body's components
        at the visual's origin (× scale): sphere -> Sphere, box -> Brick, cylinder -> Cylinder (its axis, OpenSim's y,
        turned onto the URDF's z), capsule -> a Cylinder and a Sphere at each end, mesh -> Mesh (its scale × the
        segment's); sizes × the segment's scale, colours from the URDF materials."""
        bodies = {b.get("name"): b for b in self.bodies}
        for seg, visuals in urdf_visuals(self.model).items():
            s = self.scale[seg]
            components = ET.SubElement(bodies[seg], "components")
            for k, (tag, (R, xyz), sizes, rgba) in enumerate(visuals):
                name = f"{seg}_visual_{k}"
                if tag == "sphere":
                    _shape(components, name, s, rgba, "Sphere", R, xyz, radius=fmt_float(s * float(sizes["radius"])))
                elif tag == "box":
                    half = s * np.array([float(x) for x in sizes["size"].split()]) / 2
                    _shape(components, name, s, rgba, "Brick", R, xyz, half_lengths=fmt_vec(half))
                elif tag in ("cylinder", "capsule"):
                    radius, length = s * float(sizes["radius"]), float(sizes["length"])
                    _shape(components, name, s, rgba, "Cylinder", R @ _Y_TO_Z, xyz, radius=fmt_float(radius),
                           half_height=fmt_float(s * length / 2))
                    if tag == "capsule":
                        for end, sign in (("_top", 1.0), ("_bottom", -1.0)):
                            _shape(components, name + end, s, rgba, "Sphere", R, xyz + sign * R[:, 2] * length / 2,
                                   radius=fmt_float(radius))
                elif tag == "mesh" and sizes["filename"]:
                    scale = np.array([float(x) for x in sizes["scale"].split()]) if sizes["scale"] else np.ones(3)
                    _shape(components, name, s, rgba, "Mesh", R, xyz, mesh_file=sizes["filename"],
                           scale_factors=fmt_vec(s * scale))
            if not len(components):
                bodies[seg].remove(components)

    def _root_name(self) -> str:
        """The floating root's joint: the source model's ground joint's name (a weld or pin made a floating base,
        calibrate.io.osim.FLOATING), else ground_<root>; either with '_free' added while another joint has it."""
        from .osim import FLOATING

        info, model = self.info, self.model
        source = [a.joint for a in info.approximations if a.kind == FLOATING] if info is not None else []
        name = source[0] if source else f"ground_{model.root}"
        while name in {j.name for j in model.joints}:
            name += "_free"
        return name

    def anatomical_joint(self, name: str, parent: str, child: str, chain: list[UrdfJoint]) -> None:
        # Split the chain into O0 · Rot(a1) · O1 · Rot(a2) · ... · On.
        offsets: list[Transform] = [identity_transform()]
        rotations: list[tuple[UrdfJoint, np.ndarray]] = []
        for u in chain:
            offsets[-1] = compose(offsets[-1], self.origin(u))
            if u.dof >= 0:
                rotations.append((u, self.axis(u)))
                offsets.append(identity_transform())
        mix = self.info.mixes.get(rotations[0][0].name) if self.info is not None and rotations else None
        if mix is not None:
            # A fold (calibrate.io.osim.FOLDED): the first angle is OpenSim's coordinate plus the coupled turn
            # mix · independent.  The coupled turn, about the same axis, goes on a joint of its own before this one
            # (OpenSim refuses two collinear axes in one CustomJoint), through a massless body, its coordinate the
            # source's coupled one under a CoordinateCouplerConstraint; the joint's own angle is the coordinate's.
            body = f"{child}_{mix.dependent}"
            self.body(body, 0.0, np.zeros(3), np.zeros((3, 3)))
            self.joint("CustomJoint", f"{name}_{mix.dependent}", parent, offsets[0], body, identity_transform(),
                       [(mix.dependent, rotations[0][1], "rotation")])
            self.couplers.append(_coupler(mix.dependent, mix.independent, mix.mix))
            parent, offsets[0] = body, identity_transform()
        if not rotations:
            self.joint("WeldJoint", name, parent, offsets[0], child, identity_transform())
            return
        inner = offsets[1:-1]
        if len(rotations) <= 3 and all(np.linalg.norm(t) < _ZERO_OFFSET for _, t in inner):
            # One CustomJoint: Rot(a1) O1 Rot(a2) O2 Rot(a3) O3 = Rot(b1) Rot(b2) Rot(b3) · (R1 R2 R3, t3).
            R_acc = np.eye(3)
            axes = []
            for k, (_, a) in enumerate(rotations):
                if k > 0:
                    R_acc = R_acc @ inner[k - 1][0]
                axes.append(R_acc @ a)
            if _independent(axes):
                end = (R_acc @ offsets[-1][0], R_acc @ offsets[-1][1])
                coords = [(u.name, b, "rotation") for (u, _), b in zip(rotations, axes, strict=True)]
                self.joint("CustomJoint", name, parent, offsets[0], child, invert(end), coords)
                return
        # General chain: one single-rotation joint per URDF joint, through massless connector bodies.
        prev = parent
        for k, (u, a) in enumerate(rotations):
            last = k == len(rotations) - 1
            body = child if last else u.child_link
            if not last:
                self.body(body, 0.0, np.zeros(3), np.zeros((3, 3)))
            child_offset = invert(offsets[-1]) if last else identity_transform()
            self.joint("CustomJoint", u.name, prev, offsets[k], body, child_offset, [(u.name, a, "rotation")])
            prev = body

    def document(self) -> str:
        model = self.model
        doc = ET.Element("OpenSimDocument", Version="40000")
        m = ET.SubElement(doc, "Model", name=model.name)
        _text(m, "credits", f"exported by calibrate {__version__} from {model.path.name}")
        _text(m, "length_units", "meters")
        _text(m, "force_units", "N")
        _text(m, "gravity", fmt_vec(self.info.gravity if self.info is not None else GRAVITY))
        ground = ET.SubElement(m, "Ground", name="ground")
        self.carried = None
        if self.info is not None:  # the source model's muscles and other forces (calibrate.io.osim_forces)
            coordinates = {c.get("name", ""): f"/jointset/{j.get('name')}/{c.get('name')}"
                           for j in self.joints for c in j.iter("Coordinate")}
            self.carried = carried_forces(model, self.p, self.info, coordinates)
            for b in self.bodies:
                wraps = self.carried.wraps.get(b.get("name", ""))
                if wraps is not None:
                    b.append(wraps)
                b.extend(self.carried.geometry.get(b.get("name", ""), ()))
            if self.carried.ground_geometry is not None:
                ground.append(self.carried.ground_geometry)
        for set_name, tag, items in (("bodyset", "BodySet", self.bodies), ("jointset", "JointSet", self.joints)):
            objs = ET.SubElement(ET.SubElement(m, tag, name=set_name), "objects")
            objs.extend(items)
        if self.couplers:
            ET.SubElement(ET.SubElement(m, "ConstraintSet", name="constraintset"), "objects").extend(self.couplers)
        if self.carried is not None and self.carried.forces:
            ET.SubElement(ET.SubElement(m, "ForceSet", name="forceset"), "objects").extend(self.carried.forces)
        objs = ET.SubElement(ET.SubElement(m, "MarkerSet", name="markerset"), "objects")
        for i, mk in enumerate(model.markers):
            el = ET.SubElement(objs, "Marker", name=osim_name(mk.name))
            _text(el, "socket_parent_frame", f"/bodyset/{mk.segment}")
            _text(el, "location", fmt_vec(self.scale[mk.segment] * np.asarray(self.p.marker[i], dtype=float)))
            _text(el, "fixed", "false")
        ET.indent(doc, space="\t")
        return '<?xml version="1.0" encoding="UTF-8" ?>\n' + ET.tostring(doc, encoding="unicode") + "\n"


def _text(parent: ET.Element, tag: str, text: str) -> ET.Element:
    el = ET.SubElement(parent, tag)
    el.text = text
    return el


def _coupler(dependent: str, independent: str, slope: float) -> ET.Element:
    """OpenSim's CoordinateCouplerConstraint dependent = slope · independent."""
    c = ET.Element("CoordinateCouplerConstraint", name=f"{dependent}_con")
    _text(c, "isEnforced", "true")
    f = ET.SubElement(ET.SubElement(c, "coupled_coordinates_function"), "LinearFunction")
    _text(f, "coefficients", f"{fmt_float(slope)} 0")
    _text(c, "independent_coordinate_names", independent)
    _text(c, "dependent_coordinate_name", dependent)
    _text(c, "scale_factor", "1")
    return c


def _spatial_transform(coords: Sequence[tuple[str, np.ndarray, str]],
                       ratios: Mapping[str, float] | None = None) -> ET.Element:
    """The six TransformAxis of a CustomJoint: the coordinates' (linear functions, slope 1 but a lumped chain's
    ratio), the rest constant 0."""
    st = ET.Element("SpatialTransform")
    for motion in ("rotation", "translation"):
        used = [(n, a) for n, a, m in coords if m == motion]
        spare = _completion([a for _, a in used]) if used else list(np.eye(3))
        for k, (cname, a) in enumerate(used + [(None, e) for e in spare]):
            ta = ET.SubElement(st, "TransformAxis", name=f"{motion}{k + 1}")
            _text(ta, "coordinates", cname or "")
            _text(ta, "axis", fmt_vec(a))
            if cname:
                f = ET.SubElement(ta, "LinearFunction", name="function")
                _text(f, "coefficients", f"{fmt_float((ratios or {}).get(cname, 1.0))} 0")
            else:
                f = ET.SubElement(ta, "Constant", name="function")
                _text(f, "value", "0")
    return st


def _check_params(model: Model, p: Parameters) -> None:
    want = {"scale": (len(model.segments),), "centre": (len(model.joints), 3), "axis": (model.n_dofs, 3),
            "marker": (len(model.markers), 3)}
    for block, shape in want.items():
        got = np.shape(getattr(p, block))
        if got != shape:
            raise CalibrateError(f"{model.path}: Parameters.{block} has shape {got}, the model needs {shape}; "
                                 f"give parameters of this model")
    v = p.vector()
    if not np.all(np.isfinite(v)) or np.any(np.asarray(p.scale) <= 0) \
            or np.any(np.linalg.norm(p.axis, axis=1) < 1e-12):
        raise CalibrateError(f"{model.path}: parameters with non-finite values, scales <= 0 or zero axes; "
                             f"give a valid calibration's parameters")


def _check_names(model: Model) -> None:
    """The model's names as OpenSim takes them: its segments', joints' and coordinates' without the characters OpenSim
    does not allow in names; its markers' written as osim_name writes them (a trial's new label 'r bar 1' as
    'r_bar_1'), each still its own."""
    names = [("segment", s.name) for s in model.segments] + [("joint", j.name) for j in model.joints]
    names += [("URDF joint", d.name) for d in model.dofs]
    for what, n in names:
        bad = [c for c in n if c in OSIM_INVALID_CHARS]
        if bad:
            raise ModelError(f"{model.path}: {what} name {n!r} contains {bad[0]!r}, which OpenSim does not allow "
                             f"in names; rename it in the URDF")
    written: dict[str, str] = {}
    for m in model.markers:
        other = written.setdefault(osim_name(m.name), m.name)
        if other != m.name:
            raise ModelError(f"{model.path}: markers {other!r} and {m.name!r} would both be named "
                             f"{osim_name(m.name)!r} in OpenSim, which does not allow some of their characters; "
                             "rename one in the URDF")
    from .osim_info import osim_info

    info = osim_info(model)
    root = info.root if info is not None else None
    coords = set(sum(floating_root_names(info), ())) if root is None else \
        {n for n, _ in root.rotations + root.translations}
    clash = [d.name for d in model.dofs if d.name in coords]
    if clash:
        raise ModelError(f"{model.path}: URDF joint '{clash[0]}' has the name of an exported root coordinate; "
                         f"rename it in the URDF")


def osim_text(model: Model, params: Parameters | None = None) -> str:
    """The .osim document (text) of `model` with geometric parameters `params` (default: the model's)."""
    return osim_document(model, params)[0]


def marker_set_text(osim: str) -> str:
    """The MarkerSet of the .osim document `osim` as an OpenSim MarkerSet file (what the Scale tool's MarkerPlacer
    writes as its output_marker_file: each marker's body and location on it), which `--marker-set` and OpenSim read."""
    markers = ET.fromstring(osim.split("\n", 1)[1] if osim.startswith("<?xml") else osim).find("Model/MarkerSet")
    doc = ET.Element("OpenSimDocument", Version="40000")
    doc.append(markers if markers is not None else ET.Element("MarkerSet", name="markerset"))
    ET.indent(doc, space="\t")
    return '<?xml version="1.0" encoding="UTF-8" ?>\n' + ET.tostring(doc, encoding="unicode") + "\n"


def scale_set_text(osim: str, scales: Mapping[str, float]) -> str:
    """The scale factors of the .osim document `osim` as an OpenSim ScaleSet file (what the Scale tool's ModelScaler
    writes as its output_scale_file): one uniform Scale per physical frame, as OpenSim lists them (ground, each body,
    each offset frame at the scale of the body it is fixed to), `scales` giving each body's (a segment's scale
    factor, × the base model's; ground and a body it lacks: 1).  OpenSim reads it (ScaleSet) and its Scale tool
    applies it to the generic model (ModelScaler's manualScale): the bodies sized as calibrate sized the segments,
    without calibrate's joint centres, axes and marker positions, which the subject .osim carries."""
    root = ET.fromstring(osim.split("\n", 1)[1] if osim.startswith("<?xml") else osim).find("Model")
    parent = {child: el for el in root.iter() for child in el}
    named = {el.get("name"): el for el in root.iter() if el.tag in ("Body", "PhysicalOffsetFrame", "Ground")}
    ground = root.find("Ground")
    frames: list[tuple[str, str]] = [] if ground is None else [(ground.get("name", "ground"), "")]
    frames += [(b.get("name", ""), b.get("name", "")) for b in root.iter("Body")]

    def body_of(frame: ET.Element | None) -> str:
        """The body (or '' for ground) an offset frame is fixed to: through its parent socket, or ('..') the
        component holding it (a body's own geometry frame)."""
        for _ in range(len(named) + 1):  # (a chain of offset frames is at most that long)
            if frame is None or frame.tag != "PhysicalOffsetFrame":
                break
            socket = (frame.findtext("socket_parent") or "").strip()
            if socket.startswith(".."):
                frame = parent.get(frame)
                while frame is not None and frame.tag not in ("Body", "Ground", "PhysicalOffsetFrame"):
                    frame = parent.get(frame)
            else:
                frame = named.get(socket.rstrip("/").rsplit("/", 1)[-1])
        return frame.get("name", "") if frame is not None and frame.tag == "Body" else ""

    frames += [(f.get("name", ""), body_of(f)) for f in root.iter("PhysicalOffsetFrame")]
    doc = ET.Element("OpenSimDocument", Version="40000")
    objects = ET.SubElement(ET.SubElement(doc, "ScaleSet", name="ScaleSet"), "objects")
    for name, body in frames:
        s = float(scales.get(body, 1.0)) if body else 1.0
        scale = ET.SubElement(objects, "Scale")
        _text(scale, "scales", fmt_vec(np.full(3, s)))
        _text(scale, "segment", name)
        _text(scale, "apply", "true")
    ET.SubElement(doc.find("ScaleSet"), "groups")
    ET.indent(doc, space="\t")
    return '<?xml version="1.0" encoding="UTF-8" ?>\n' + ET.tostring(doc, encoding="unicode") + "\n"


def osim_document(model: Model, params: Parameters | None = None) -> tuple[str, CarriedForces | None]:
    """osim_text, and for a model imported from OpenSim what came of its source's forces (muscles carried and
    scaled, forces left out; calibrate.io.osim_forces), else None."""
    p = model.parameters() if params is None else params
    _check_params(model, p)
    _check_names(model)
    b = _Builder(model, p)
    b.build()
    text = b.document()
    notes = forces_lines(b.carried)
    if notes:  # said in the file too: whoever opens it in OpenSim sees what came of the source's forces
        head, rest = text.split("\n", 1)
        text = head + "\n" + "".join(f"<!-- {NOTE_MARK} {_comment(line)} -->\n" for line in notes) + rest
    return text, b.carried


def _comment(text: str) -> str:
    """Text safe inside an XML comment (no '--')."""
    return text.replace("--", "- -")


def _check_target(path: Path, overwrite: bool = True) -> None:
    check_targets([path], overwrite)


def _write(path: Path, text: str) -> None:
    try:
        atomic_write_text(path, text)
    except OSError as e:
        raise CalibrateError(f"{path}: cannot write ({e.strerror}); choose a writable place") from None


def export_osim(model: Model, path: str | os.PathLike[str], params: Parameters | None = None,
                overwrite: bool = True) -> Path:
    """Write `model` (with `params`, default the model's own) as an OpenSim model at `path` (atomically)."""
    path = Path(path)
    if path.suffix.lower() == ".urdf" or path.resolve() == model.path.resolve():
        raise CalibrateError(f"{path}: the OpenSim model would replace a URDF; give an .osim name")
    _check_target(path, overwrite)
    _write(path, osim_text(model, params))
    return path


# ---------------------------------------------------------------------- motion
def mot_columns(model: Model, motion: Motion, params: Parameters | None = None) -> tuple[list[str], np.ndarray]:
    """Column names and values (n_frames, 1 + 6 + n_dofs) of the .mot: time, root angles (rad),
    root translation (m), joint angles (rad), for the model exported by :func:`export_osim` (with
    `params`; they matter only for an OpenSim ground joint whose child frame is offset in the root)."""
    missing = [d for d in model.dof_names if d not in motion.dof_names]
    extra = [d for d in motion.dof_names if d not in model.dof_names]
    if missing or extra:
        what = f"has no column for joint '{missing[0]}'" if missing else f"has a column '{extra[0]}' the model lacks"
        raise CalibrateError(f"motion: {what}; give a motion of {model.path.name} (e.g. its calibration's "
                             f"_motion.csv)")
    data = [motion.times[:, None], motion.root_translation, motion.root_quaternion, motion.angles]
    if not all(np.all(np.isfinite(x)) for x in data):
        raise CalibrateError("motion: has non-finite values (NaN or inf); fill or drop those frames first")
    norms = np.linalg.norm(motion.root_quaternion, axis=1)
    if np.any(norms < 1e-9):
        raise CalibrateError("motion: has a zero root quaternion; give unit quaternions (x, y, z, w)")
    order = [motion.dof_names.index(d) for d in model.dof_names]
    from .osim_info import osim_info, root_coordinates

    info = osim_info(model)
    angles = motion.angles[:, order]
    extra: list[str] = []
    if info is not None and (info.ratios or info.mixes):  # a lumped chain's whole turn, a fold -> OpenSim's coordinate
        coords = info.coordinates({d: angles[:, k] for k, d in enumerate(model.dof_names)})
        # a fold's coupled coordinate too, as OpenSim's IK writes every coordinate (tools that set a .mot's values
        # without assembling the constraints then turn it as OpenSim would)
        extra = [m.dependent for m in info.mixes.values() if m.independent in coords]
        coords.update({m.dependent: m.mix * coords[m.independent] for m in info.mixes.values() if m.dependent in extra})
        angles = np.stack([coords[d] for d in [*model.dof_names, *extra]], axis=1) if coords else angles
    if info is not None and info.root is not None:  # OpenSim's own ground-joint coordinates
        s = 1.0 if params is None else float(params.scale[0])
        root = root_coordinates(info, motion.root_translation, motion.root_quaternion / norms[:, None], s)
        names = [n for n, _ in info.root.rotations + info.root.translations]
        values = np.hstack([motion.times[:, None], np.array([root[n] for n in names]).T, angles])
        return ["time", *names, *model.dof_names, *extra], values
    euler = quat_eulers(motion.root_quaternion / norms[:, None], "ZYX")
    euler = np.unwrap(euler, axis=0)  # continuous angles; the same rotations
    values = np.hstack([motion.times[:, None], euler, motion.root_translation, angles])
    rot_names, trans_names = floating_root_names(info)
    return ["time", *rot_names, *trans_names, *model.dof_names, *extra], values


def mot_text(model: Model, motion: Motion, name: str = "motion", params: Parameters | None = None) -> str:
    """The .mot document (OpenSim Storage, angles in degrees) of `motion`."""
    from .osim_info import osim_info

    names, values = mot_columns(model, motion, params)
    info = osim_info(model)
    root_rot = set(floating_root_names(info)[0]) if info is None or info.root is None else \
        {n for n, _ in info.root.rotations}
    # A lumped chain's coordinate turns its axis by a LinearFunction of slope ≠ 1: OpenSim calls it Coupled and
    # reads (and writes) it in radians in a file in degrees.
    dependents = {m.dependent for m in info.mixes.values()} if info is not None else set()
    rotational = np.array([n in root_rot or n in dependents or (n in model.dof_names and (info is None or
                                                                                        info.ratio(n) == 1.0))
                           for n in names])
    values = np.where(rotational, np.degrees(values), values)
    head = [name, "version=1", f"nRows={values.shape[0]}", f"nColumns={values.shape[1]}", "inDegrees=yes",
            "endheader", "\t".join(names)]
    rows = ["\t".join(repr(float(x)) for x in row) for row in values]
    return "\n".join(head + rows) + "\n"


#: The columns of OpenSim's IK marker errors (InverseKinematicsTool's <name>_ik_marker_errors.sto), metres.
MARKER_ERROR_COLUMNS = ("total_squared_error", "marker_error_RMS", "marker_error_max")


def _posed_markers(model: Model, params: Parameters, trial: Trial, motion: Motion) -> np.ndarray:
    """(n_frames, n_markers, 3) the markers of `model` at `params` posed by `motion`, the motion of `trial` (m)."""
    from ..model.blocks import FrameLayout
    from ..model.kinematics import build_kinematics

    if motion.n_frames != trial.n_frames:
        raise ValueError(f"{trial.source or 'trial'}: motion of {motion.n_frames} frames for a trial of "
                         f"{trial.n_frames}")
    return build_kinematics(model).batch(FrameLayout.coordinates(motion.root_translation, motion.angles),
                                         motion.root_quaternion, params)[0]


def ik_model_marker_locations(model: Model, params: Parameters, trial: Trial, motion: Motion,
                              markers: Sequence[str] | None = None) -> tuple[list[str], np.ndarray]:
    """(names, (n_frames, n, 3)) where the model's markers are in every frame of `trial` (its labels the model's),
    `model` at `params` posed by `motion`, as OpenSim's IK tool reports them (_ik_model_marker_locations.sto, where
    the IK setup asks, report_marker_locations): the markers of `markers` (default: every marker of `model`) that
    the trial labels, in the trial's column order, in the ground frame (m)."""
    wanted = set(model.marker_names if markers is None else markers)
    index = {name: k for k, name in enumerate(model.marker_names)}
    names = [lab for lab in trial.labels if lab in index and lab in wanted]
    return names, _posed_markers(model, params, trial, motion)[:, [index[n] for n in names]]


def marker_locations_text(times: np.ndarray, names: Sequence[str], positions: np.ndarray) -> str:
    """The .sto document of OpenSim's IK model marker locations (`names`, `positions` (n_frames, n, 3), m: those of
    ik_model_marker_locations) at `times` (s), as InverseKinematicsTool writes it: a column per marker and axis,
    <marker>_tx, _ty, _tz."""
    head = ["Model Marker Locations from IK", "version=1", f"nRows={len(times)}", f"nColumns={1 + 3 * len(names)}",
            "inDegrees=no", "endheader",
            "\t".join(("time", *(f"{osim_name(n)}_{a}" for n in names for a in ("tx", "ty", "tz"))))]
    rows = ["\t".join(repr(float(x)) for x in (t, *np.ravel(p))) for t, p in zip(times, positions, strict=True)]
    return "\n".join(head + rows) + "\n"


def ik_marker_errors(model: Model, params: Parameters, trial: Trial, motion: Motion,
                     markers: Sequence[str] | None = None) -> np.ndarray:
    """(n_frames, 3) per frame of `trial` (its labels the model's): the total squared error (m²), the RMS error and
    the largest error (m) of the recorded positions of `markers` (default: every marker of `model`) against the
    model's markers at `params` posed by `motion`, as OpenSim's IK tool reports them (_ik_marker_errors.sto): the
    sum over the markers the frame records, unweighted, and the root of its mean over them; NaN in a frame that
    records none.  Every recorded position counts, those a fit left out as damaged too, as OpenSim's are."""
    from ..solve.ik import marker_columns

    posed = _posed_markers(model, params, trial, motion)
    wanted = set(model.marker_names if markers is None else markers)
    keep = [k for k, name in enumerate(model.marker_names) if name in wanted]
    d2 = np.sum((posed[:, keep] - marker_columns(model, trial)[:, keep]) ** 2, axis=2)
    seen = np.isfinite(d2)
    count = seen.sum(axis=1)
    total = np.where(seen, d2, 0.0).sum(axis=1)
    out = np.full((trial.n_frames, 3), np.nan)
    some = count > 0
    out[some, 0] = total[some]
    out[some, 1] = np.sqrt(total[some] / count[some])
    out[some, 2] = np.sqrt(np.max(np.where(seen, d2, -np.inf), axis=1)[some])
    return out


def marker_errors_text(times: np.ndarray, errors: np.ndarray) -> str:
    """The .sto document of OpenSim's IK marker errors (`errors`: ik_marker_errors' (n_frames, 3), m) at `times`
    (s), as InverseKinematicsTool writes it."""
    head = ["Model Marker Errors from IK", "version=1", f"nRows={len(times)}", f"nColumns={1 + errors.shape[1]}",
            "inDegrees=no", "endheader", "\t".join(("time", *MARKER_ERROR_COLUMNS))]
    rows = ["\t".join(repr(float(x)) for x in (t, *e)) for t, e in zip(times, errors, strict=True)]
    return "\n".join(head + rows) + "\n"


def write_mot(path: str | os.PathLike[str], model: Model, motion: Motion, overwrite: bool = True,
              params: Parameters | None = None) -> Path:
    """Write `motion` (of `model`) as an OpenSim .mot at `path` (atomically)."""
    path = Path(path)
    _check_target(path, overwrite)
    _write(path, mot_text(model, motion, path.stem, params))
    return path


# ---------------------------------------------------------------------- command line
def add_export_osim_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``export-osim`` to the CLI's subparsers."""
    p = subparsers.add_parser(
        "export-osim", prog="calibrate export-osim",
        help="write a model as an OpenSim model (.osim), a motion as .mot, a trial as .trc",
        description="Write MODEL (a calibrate URDF) as an OpenSim model: one body per segment (mass, centre of "
                    "mass, inertia), one joint per anatomical joint with the URDF's centres, axes and limits, "
                    "the markers.  Optionally also a motion CSV of the model as an OpenSim .mot (degrees) and a "
                    "trial as a .trc (mm).  Existing files are kept unless --overwrite.")
    p.add_argument("model", type=Path, metavar="MODEL", help="the model (.urdf), e.g. a calibrated subject.urdf")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="OSIM",
                   help="the OpenSim model to write (default: MODEL's name + .osim)")
    p.add_argument("--motion", type=Path, default=None, metavar="CSV", help="a motion CSV of MODEL to write as .mot")
    p.add_argument("--mot", type=Path, default=None, metavar="MOT",
                   help="the .mot to write (default: CSV's name + .mot)")
    p.add_argument("--trial", type=Path, default=None, metavar="TRIAL",
                   help="a trial (.c3d, .trc, .tsv or .csv) to write as .trc")
    p.add_argument("--trc", type=Path, default=None, metavar="TRC",
                   help="the .trc to write (default: TRIAL's name + .trc)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    return p


def cmd_export_osim(args: argparse.Namespace) -> int:
    """``calibrate export-osim``: check every destination, build every file, then write them all."""
    from ..model.model import load_model
    from .motion import read_motion_csv
    from .read import read_trial
    from .trc import write_trc

    model_path: Path = args.model
    if args.mot is not None and args.motion is None:
        raise CalibrateError(f"{args.mot}: --mot needs --motion (the motion CSV to convert)")
    if args.trc is not None and args.trial is None:
        raise CalibrateError(f"{args.trc}: --trc needs --trial (the trial to convert)")
    out = args.output or model_path.with_suffix(".osim")
    targets: dict[str, Path] = {"osim": out}
    if args.motion is not None:
        targets["mot"] = args.mot or args.motion.with_suffix(".mot")
    if args.trial is not None:
        targets["trc"] = args.trc or args.trial.with_suffix(".trc")
    sources = [model_path] + [s for s in (args.motion, args.trial) if s is not None]
    for kind, path in targets.items():
        if path.suffix.lower() != f".{kind}":
            raise CalibrateError(f"{path}: the {kind} output should end in .{kind}; rename it")
    check_targets(list(targets.values()), args.overwrite,
                  inputs={s: "that is an input file; refusing to overwrite it (choose another name)" for s in sources},
                  same="the .osim, .mot and .trc outputs must be different files")
    model = load_model(model_path)
    osim, carried = osim_document(model)
    texts = {"osim": osim}
    if args.motion is not None:
        texts["mot"] = mot_text(model, read_motion_csv(args.motion), targets["mot"].stem)
    trial = read_trial(args.trial) if args.trial is not None else None
    if trial is not None:
        unknown = [lab for lab in trial.labels if lab not in set(model.marker_names)]
        if len(unknown) == trial.n_markers:
            raise CalibrateError(f"{args.trial}: none of its labels is a marker of {model_path} (e.g. "
                                 f"'{unknown[0]}'); is it a trial of this model?")
    writers = {path: (lambda p: write_trc(p, trial)) if kind == "trc"  # type: ignore[arg-type]
               else (lambda p, kind=kind: _write(p, texts[kind])) for kind, path in targets.items()}
    try:
        write_all(writers, keep_names=True)
    except OSError as e:
        raise CalibrateError(f"{targets['osim'].parent}: cannot write ({e.strerror}); choose a writable place") \
            from None
    print(f"{model.summary()}")
    doc = ET.fromstring(osim.split("\n", 1)[1])  # (bodies and joints as written: connectors, folds included)
    n_bodies, n_joints = (len(doc.findall(f"./Model/{tag}/objects/*")) for tag in ("BodySet", "JointSet"))
    print(f"wrote {targets['osim']}  ({n_bodies} bodies, {n_joints} joints, {len(model.markers)} markers)")
    for line in forces_lines(carried):
        print(f"      {line}")
    if "mot" in targets:
        print(f"      {targets['mot']}  (OpenSim motion, angles in degrees)")
    if "trc" in targets:
        print(f"      {targets['trc']}  ({trial.n_frames} frames, mm)")  # type: ignore[union-attr]
    return 0


__all__ = ["ROOT_ROTATIONS", "ROOT_TRANSLATIONS", "add_export_osim_parser", "cmd_export_osim", "export_osim",
           "floating_root_names", "mot_columns", "mot_text", "osim_document", "osim_text", "write_mot"]
