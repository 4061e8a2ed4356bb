"""A model's URDF document with a subject's geometry: joint and marker origins and axes from the
parameters, links (inertia, visuals, meshes) scaled with their segment, masses scaled to the body mass.
calibrate.model.model.write_model writes it."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ModelError
from ..io.text import fmt_float, fmt_vec
from .rotations import euler_matrices

if TYPE_CHECKING:
    from .model import Model, Parameters


def urdf_text(model: Model, params: Parameters | None = None, mass: float | None = None) -> str:
    """The URDF document (text) that write_model writes: `model` with geometric parameters `params`
    (default: its own) and segment masses scaled to the body `mass` (kg; None: kept).
    ``Model(path, text=urdf_text(...))`` is the model that loading the written file gives."""
    p = model.parameters() if params is None else params
    check_sizes(model, p)
    k_mass = mass_factor(model, mass)
    tree = ET.ElementTree(ET.fromstring(model.text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))))
    robot = tree.getroot()
    seg_scale = {s.name: float(p.scale[i]) for i, s in enumerate(model.segments)}
    joint_el = {el.get("name"): el for el in robot.findall("joint")}
    for u in model.urdf_joints:
        el = joint_el[u.name]
        s = seg_scale[u.owner]
        if u.role == "centre":
            xyz = s * p.centre[u.index]
        elif u.role == "marker":
            xyz = s * p.marker[u.index]
        else:
            xyz = s * u.xyz
        _set_origin_xyz(el, xyz)
        if u.dof >= 0:
            ax = el.find("axis")
            if ax is None:
                ax = ET.SubElement(el, "axis")
            a = p.axis[u.dof]
            ax.set("xyz", fmt_vec(a / np.linalg.norm(a)))
    for link in robot.findall("link"):
        s = seg_scale.get(link.get("name", ""))
        if s is None or (s == 1.0 and k_mass == 1.0):
            continue
        _scale_link(link, s, k_mass)
    # A model imported from OpenSim keeps each source body's scale (calibrate.io.osim_forces: where the source
    # model's muscle points go): the written segment's scale times the one it had.
    for body in robot.findall("opensim/body"):
        s = seg_scale.get(body.get("name", ""))
        if s is not None and s != 1.0:
            body.set("scale", fmt_float(float(body.get("scale", "1")) * s))
    data = ET.tostring(robot, encoding="unicode")
    start = model.text.find("<robot")
    head = model.text[:start] if start > 0 else '<?xml version="1.0"?>\n'  # declaration and comments
    return head + data + "\n"


def with_comment(text: str, comment: str) -> str:
    """The XML document `text` with `comment` (no '--' in it) as a comment right after its XML declaration, before
    the comments it carries (a subject URDF's provenance ahead of its base model's header)."""
    line = f"<!-- {comment.replace('--', '- -')} -->\n"
    if text.startswith("<?xml"):
        end = text.index("?>") + 2
        return text[:end] + "\n" + line + text[end:].lstrip("\n")
    return line + text


def check_sizes(model: Model, p: Parameters) -> None:
    want = {"scale": (len(model.segments),), "centre": (len(model.joints), 3),
            "axis": (model.n_dofs, 3), "marker": (len(model.markers), 3)}
    for b, shape in want.items():
        got = np.shape(getattr(p, b))
        if got != shape:
            raise ValueError(f"Parameters.{b}: expected shape {shape}, got {got}")
    if np.any(~np.isfinite(p.vector())):
        raise ValueError("Parameters: non-finite entries")
    if np.any(p.scale <= 0):
        raise ValueError("Parameters.scale: scale factors must be positive")
    if np.any(np.linalg.norm(p.axis, axis=1) < 1e-12):
        raise ValueError("Parameters.axis: zero-length axis")


def mass_factor(model: Model, mass: float | None) -> float:
    """The factor on every segment mass that makes the model weigh `mass` kg (1 if None)."""
    if mass is None:
        return 1.0
    if isinstance(mass, bool) or not isinstance(mass, (int, float)) or not (math.isfinite(mass) and mass > 0):
        raise ModelError(f"mass: must be the subject's body mass in kg (a positive number), got {mass!r}")
    total = model.total_mass
    if total <= 0:
        raise ModelError(f"{model.path}: the model's segments have no mass, so none can be scaled to {mass:g} kg")
    return float(mass) / total


def _scale_link(link: ET.Element, s: float, k_mass: float = 1.0) -> None:
    """Scale one segment's inertial (origin s*, mass k_mass*, inertia k_mass*s**2*) and visuals (s*)."""
    inertial = link.find("inertial")
    if inertial is not None:
        o = inertial.find("origin")
        if o is not None:
            _scale_attr(o, "xyz", s)
        m = inertial.find("mass")
        if m is not None and k_mass != 1.0:
            m.set("value", fmt_float(float(m.get("value", "0")) * k_mass))
        i = inertial.find("inertia")
        if i is not None:
            for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                if k in i.attrib:
                    i.set(k, fmt_float(float(i.get(k, "0")) * k_mass * s * s))
    for tag in ("visual", "collision"):
        for v in link.findall(tag):
            o = v.find("origin")
            if o is not None:
                _scale_attr(o, "xyz", s)
            g = v.find("geometry")
            if g is None:
                continue
            for shape, attrs in (("box", ("size",)), ("cylinder", ("radius", "length")),
                                 ("sphere", ("radius",)), ("capsule", ("radius", "length"))):
                e = g.find(shape)
                if e is not None:
                    for a in attrs:
                        _scale_attr(e, a, s)
            mesh = g.find("mesh")
            if mesh is not None:
                old = np.array([float(x) for x in mesh.get("scale", "1 1 1").split()])
                mesh.set("scale", fmt_vec(np.broadcast_to(old, (3,)) * s))


def _scale_attr(el: ET.Element, attr: str, s: float) -> None:
    if attr in el.attrib:
        el.set(attr, fmt_vec(np.array([float(x) for x in el.get(attr, "").split()]) * s))


def _set_origin_xyz(joint: ET.Element, xyz: np.ndarray) -> None:
    o = joint.find("origin")
    if o is None:
        o = ET.Element("origin")
        joint.insert(0, o)
    o.set("xyz", fmt_vec(xyz))


def origin_of(el: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    """(R, xyz) of a URDF element's <origin> (the identity where it has none): R = Rz(y) Ry(p) Rx(r)."""
    o = el.find("origin")
    xyz = np.array([float(x) for x in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()])
    rpy = np.array([float(x) for x in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()])
    return (euler_matrices("xyz", rpy) if np.any(rpy) else np.eye(3)), xyz


def urdf_visuals(model: Model) -> dict[str, list[tuple[str, tuple[np.ndarray, np.ndarray], dict[str, str],
                                                       np.ndarray | None]]]:
    """segment -> its URDF visuals, as `model`'s document has them: (shape tag, origin (R, xyz) in the segment frame,
    the shape's attributes as written — sphere radius; cylinder or capsule radius and length; box size; mesh filename
    and scale —, colour rgba or None).  Markers' and connectors' visuals are not read.  What the .osim and MJCF exports
    draw the segments with (calibrate.io.osim_export, calibrate.io.mjcf)."""
    robot = ET.fromstring(model.text)
    colours = {m.get("name"): m.find("color").get("rgba") for m in robot.findall("material")
               if m.find("color") is not None}
    segments = {sg.name for sg in model.segments}
    out: dict[str, list] = {}
    for link in robot.findall("link"):
        if link.get("name") not in segments:
            continue
        for v in link.findall("visual"):
            g = v.find("geometry")
            shape = next(iter(g), None) if g is not None else None
            if shape is None:
                continue
            sizes = {k: shape.get(k, "") for k in ("radius", "length", "size", "filename", "scale")}
            m = v.find("material")
            rgba = None
            if m is not None:
                c = m.find("color")
                text = c.get("rgba") if c is not None else colours.get(m.get("name"))
                rgba = np.array([float(x) for x in text.split()]) if text else None
            out.setdefault(link.get("name", ""), []).append((shape.tag, origin_of(v), sizes, rgba))
    return out
