"""The source OpenSim model's muscles and other forces, carried into the exported subject
(calibrate.io.osim_export) and scaled as OpenSim's Scale tool scales them.

A lab that calibrates its own .osim wants the subject back with the model's muscles, for static
optimisation and CMC.  The muscles' path points, moving path points and the bodies' wrap objects sit in
the source bodies' frames; the exported subject's body is the calibrated segment, whose frame is the
source body's frame moved to its segment frame (OsimInfo.bodies: a translation where the child offset
frame translates) and scaled by the segment's scale.  Each point goes where the segment's centre of mass
goes (calibrate.io.osim_export: scale × the point in the segment frame), so that with scales alone (no
moved centre, axis or marker) the subject's muscle points are where OpenSim's Scale tool puts them with
the same scale factor on every axis of each body.  Wrap objects move and scale the same way (their
radii and lengths × scale), and so does each body's attached geometry, its bone meshes (their scale
factors × scale: carried_geometry), so that the subject opens in OpenSim's GUI with its skeleton.

Each muscle's optimal fibre length and tendon slack length are scaled, as OpenSim's Muscle::postScale
does, by the ratio of its path length after calibration to before, in the model's default pose.  The
path lengths here are the straight lines through the active path points (wrap objects not wrapped):
where a path wraps, the ratio is that of the path without its wrapping (exact when every body along
the path has one scale).  Both lengths are measured on calibrate's kinematics of the model (its
approximated knees, calibrate.io.osim), so an approximation changes neither.

Forces that are not paths (CoordinateActuator, CoordinateLimitForce, SpringGeneralizedForce,
ExpressionBasedCoordinateForce...) are kept when every coordinate they name is one of the subject's;
a force on a body or frame (point actuators, bushings, contact), or on a coordinate the import dropped
(a coupled patella's), is left out and named.  The ForceSet is read from the source .osim again at
export time (the URDF keeps its path); if it is gone, no force is carried, and the export says so.
"""

from __future__ import annotations

import copy
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from ..errors import ModelError
from ..model.rotations import euler_matrices, matrix_eulers
from ..seed.geometry import Transform, apply
from .osim_read import body_name, osim_function, parse_xml, xml_floats
from .text import fmt_float, fmt_vec

if TYPE_CHECKING:
    from ..model.model import Model, Parameters
    from .osim import OsimInfo

PATH_POINTS = ("PathPoint", "ConditionalPathPoint", "MovingPathPoint")
WRAP_SIZES = ("radius", "length", "dimensions", "inner_radius", "outer_radius")  # lengths of a wrap object (m)
SPLINES = ("SimmSpline", "NaturalCubicSpline", "PiecewiseLinearFunction")
PATH_CHANGE = 1.25  # a path longer or shorter than this times its segments' scale is named in the export's note
MUSCLE_LENGTHS = ("optimal_fiber_length", "tendon_slack_length")  # scaled with the path, as Muscle::postScale


@dataclass
class CarriedForces:
    """What the export adds from the source model: the ForceSet's kept forces, each body's WrapObjectSet and
    attached geometry (its bone meshes), and the forces left out (name and why), with a note when nothing could be
    read."""

    forces: list[ET.Element] = field(default_factory=list)
    wraps: dict[str, ET.Element] = field(default_factory=dict)
    # body -> the elements that carry its bones' geometry (carried_geometry); the ground's geometry as in the source
    geometry: dict[str, list[ET.Element]] = field(default_factory=dict)
    ground_geometry: ET.Element | None = None
    left_out: list[str] = field(default_factory=list)  # 'name (reason)'
    note: str = ""  # why no force was carried at all ('' when the source was read)
    source: str = ""  # the source model's file name
    total: int = 0  # forces in the source model's ForceSet
    scaled: dict[str, float] = field(default_factory=dict)  # muscle -> path length ratio (after / before)
    # muscle -> (path length ratio, its segments' scale): the paths changed by more than PATH_CHANGE beyond the scale
    # of the segments they span (a joint centre moved against the bones the muscle attaches to)
    changed: dict[str, tuple[float, float]] = field(default_factory=dict)


class _Skip(Exception):
    """A force that cannot be carried (its message says why)."""


def carried_forces(model: Model, p: Parameters, info: OsimInfo, coordinates: dict[str, str]) -> CarriedForces:
    """The source model's forces for the subject `model` with parameters `p`; `coordinates`: the exported
    model's coordinates and their component paths (a socket naming a coordinate is pointed there: the
    joint that holds it may have another name than in the source).  See the module docstring."""
    src = Path(info.source)
    if not info.source or not src.is_file():
        return CarriedForces(note=f"muscles and other forces not carried: the source model {src} is not found")
    if not info.bodies:
        return CarriedForces(note="muscles and other forces not carried: this model was written before calibrate kept "
                                  "its OpenSim bodies' frames and scales; import the .osim again and calibrate it")
    try:
        root = parse_xml(src.read_text(encoding="utf-8", errors="replace"))
    except (ET.ParseError, OSError) as e:
        return CarriedForces(note=f"muscles and other forces not carried: {src} cannot be read ({e})")
    m = root.find("Model")
    if m is None:
        return CarriedForces(note=f"muscles and other forces not carried: {src} has no <Model>")
    # the subject's body = the source body's scaled by the scales written into the model so far and by `p`'s
    scale = {s.name: info.body_scale.get(s.name, 1.0) * float(p.scale[i]) for i, s in enumerate(model.segments)}
    frames = {b: info.bodies.get(b, (np.eye(3), np.zeros(3))) for b in scale}
    out = CarriedForces()
    for body in m.findall("BodySet/objects/Body"):
        name = body.get("name", "")
        ws = body.find("WrapObjectSet")
        if name in scale and ws is not None and len(ws.findall("objects/*")):
            out.wraps[name] = _moved_wraps(copy.deepcopy(ws), frames[name], scale[name])
        if name in scale:
            carried = carried_geometry(body, frames[name], scale[name])
            if carried:
                out.geometry[name] = carried
    ground = m.find("Ground/attached_geometry")
    if ground is not None and len(ground):
        out.ground_geometry = copy.deepcopy(ground)
    forces = m.findall("ForceSet/objects/*")
    out.source, out.total = src.name, len(forces)
    if not forces:
        return out
    try:
        lengths = _PathLengths(model, p, info)
    except ModelError as e:  # the source changed since it was imported
        return CarriedForces(geometry=out.geometry, ground_geometry=out.ground_geometry,
                             note=f"muscles and other forces not carried: {e}")
    for f in forces:
        name = f"{f.tag} {f.get('name', '')}"
        try:
            el = copy.deepcopy(f)
            for sock in el.iter():  # every socket naming a coordinate (conditional and moving points' too)
                if sock.tag.startswith("socket_") and sock.tag.endswith("coordinate") and sock.text:
                    c = body_name(sock.text)
                    if c not in coordinates:
                        raise _Skip(f"follows '{c}', which the subject does not have")
                    sock.text = coordinates[c]
            path = el.find("GeometryPath")
            if path is None:
                _check_coordinates(el, coordinates)
            else:
                before, after, spanned = _move_path(path, frames, scale, lengths)
                ratio = after / before if before > 0 else 1.0
                if abs(np.log(ratio / spanned)) > np.log(PATH_CHANGE):
                    out.changed[f.get("name", "")] = (ratio, spanned)
                for tag in MUSCLE_LENGTHS:
                    v = el.find(tag)
                    if v is not None and v.text:
                        v.text = fmt_float(float(v.text) * ratio)
                out.scaled[f.get("name", "")] = ratio
            out.forces.append(el)
        except _Skip as e:
            out.left_out.append(f"{name} ({e})")
    return out


# ---------------------------------------------------------------------- moving points into the subject
def _moved(X: Transform, s: float, x: np.ndarray) -> np.ndarray:
    """A point of a source body in the exported subject's body: scale × the point in the segment frame."""
    return s * apply(X, x)


def _moved_wraps(ws: ET.Element, X: Transform, s: float) -> ET.Element:
    for w in ws.findall("objects/*"):
        t = w.find("translation")
        if t is not None:
            t.text = fmt_vec(_moved(X, s, xml_floats(t.text)))
        r = w.find("xyz_body_rotation")
        if r is not None and not np.array_equal(X[0], np.eye(3)):
            R = euler_matrices("XYZ", xml_floats(r.text))
            r.text = fmt_vec(matrix_eulers(X[0] @ R, "XYZ"))
        for tag in WRAP_SIZES:
            d = w.find(tag)
            if d is not None and d.text:
                d.text = fmt_vec(s * xml_floats(d.text))
    return ws


def carried_geometry(body: ET.Element, X: Transform, s: float) -> list[ET.Element]:
    """A source body's attached geometry (its bone meshes, or bricks, cylinders...) for the exported subject's body,
    moved and scaled as its wrap objects are: every geometry's scale_factors times the segment's scale `s`, as
    OpenSim's Body::scale scales a body's attached geometry.  Where the segment frame is the source body's (`X` the
    identity) the geometry is the body's own `attached_geometry`; else it hangs on a PhysicalOffsetFrame among the
    body's components, at the source body's origin and orientation in the segment frame (`X`, its translation × `s`).
    Only geometry on the body itself (socket_frame '..') is carried; none: []."""
    src = body.find("attached_geometry")
    kept = [g for g in (src if src is not None else []) if g.findtext("socket_frame", "..").strip() == ".."]
    if not kept:
        return []
    geometry = ET.Element("attached_geometry")
    for g in kept:
        g = copy.deepcopy(g)
        sf = g.find("scale_factors")
        if sf is None:
            sf = ET.SubElement(g, "scale_factors")
            sf.text = "1 1 1"
        sf.text = fmt_vec(s * xml_floats(sf.text))
        geometry.append(g)
    R, t = X
    if np.array_equal(R, np.eye(3)) and not np.any(t):
        return [geometry]
    components = ET.Element("components")
    frame = ET.SubElement(components, "PhysicalOffsetFrame", name=f"{body.get('name', '')}_geometry")
    for tag, text in (("socket_parent", ".."), ("translation", fmt_vec(s * np.asarray(t, dtype=float))),
                      ("orientation", fmt_vec(matrix_eulers(R, "XYZ")))):
        ET.SubElement(frame, tag).text = text
    frame.append(geometry)
    return [components]


def _coordinate(el: ET.Element, tag: str) -> str:
    """The coordinate a socket names: its last path element."""
    return body_name(el.findtext(tag, ""))


def _check_coordinates(el: ET.Element, coordinates: dict[str, str]) -> None:
    """A force that is not a path is kept if it names coordinates only, each one the subject has."""
    named = []
    for child in el.iter():
        tag = child.tag.lower()
        if child is el or child.text is None or not child.text.strip():
            continue
        if "body" in tag or tag.startswith("socket_") and "coordinate" not in tag or tag == "frame":
            raise _Skip("acts on a body or frame, which the export does not carry")
        if tag == "geometry":  # HuntCrossleyForce, ElasticFoundationForce: between the model's contact geometry
            raise _Skip("a contact force: the export does not carry contact geometry")
        if tag in ("coordinate", "socket_coordinate") or tag.endswith("_coordinate"):
            named.append(body_name(child.text))
    if not named:
        raise _Skip("names no coordinate of the model")
    missing = [c for c in named if c not in coordinates]
    if missing:
        raise _Skip(f"on {', '.join(missing)}, which the subject does not have")


def _move_path(path: ET.Element, frames: dict[str, Transform], scale: dict[str, float],
               lengths: _PathLengths) -> tuple[float, float, float]:
    """The path's points moved into the subject's bodies (in place); its length before and after, in the
    default pose, and the geometric mean scale of the segments its active points are on."""
    before, after, scales = [], [], []
    for pt in path.findall("PathPointSet/objects/*"):
        if pt.tag not in PATH_POINTS:
            raise _Skip(f"path point type {pt.tag} is not read")
        body = body_name(pt.findtext("socket_parent_frame") or pt.findtext("body") or "")
        if body not in scale:
            raise _Skip(f"a path point is on '{body}', which is not a body of the subject")
        X, s = frames[body], scale[body]
        if pt.tag == "MovingPathPoint":
            loc = _move_functions(pt, X, s, lengths.coordinates)
        else:
            loc = xml_floats(pt.findtext("location", "0 0 0"))
            pt.find("location").text = fmt_vec(_moved(X, s, loc))  # type: ignore[union-attr]
        active = True
        if pt.tag == "ConditionalPathPoint":
            c = _coordinate(pt, "socket_coordinate")
            lo, hi = xml_floats(pt.findtext("range", "0 0"))[:2]
            active = bool(lo <= lengths.coordinates.get(c, 0.0) <= hi)
        if active:
            scales.append(s)
            before.append(lengths.before(body, apply(X, loc)))
            after.append(lengths.after(body, _moved(X, s, loc)))
    if len(before) < 2:
        raise _Skip("fewer than two path points are active in the default pose")
    length = lambda pts: float(np.sum(np.linalg.norm(np.diff(np.array(pts), axis=0), axis=1)))  # noqa: E731
    return length(before), length(after), float(np.exp(np.mean(np.log(scales))))


def _move_functions(pt: ET.Element, X: Transform, s: float, defaults: dict[str, float]) -> np.ndarray:
    """A moving path point's location functions (x, y, z of one coordinate each) turned into the subject's
    body: each value v becomes s (v + t) for the segment frame's translation t (its rotation must be the
    identity, as the import makes it).  Returns the source location in the default pose."""
    if not np.allclose(X[0], np.eye(3)):
        raise _Skip("a moving path point on a body whose frame the import turned")
    loc = np.zeros(3)
    for k, axis in enumerate("xyz"):
        holder = pt.find(f"{axis}_location")
        if holder is None or not len(holder):
            raise _Skip(f"a moving path point without its {axis}_location function")
        fn = holder[0]
        c = _coordinate(pt, f"socket_{axis}_coordinate")
        try:
            loc[k] = float(osim_function(fn, "moving path point")(defaults.get(c, 0.0)))
        except ModelError as e:
            raise _Skip(str(e)) from None
        t = float(X[1][k])
        if fn.tag in SPLINES:
            fn.find("y").text = fmt_vec(s * (xml_floats(fn.findtext("y")) + t))  # type: ignore[union-attr]
        elif fn.tag == "Constant":
            fn.find("value").text = fmt_float(s * (float(fn.findtext("value", "0")) + t))  # type: ignore[union-attr]
        elif fn.tag in ("LinearFunction", "PolynomialFunction"):
            co = s * xml_floats(fn.findtext("coefficients"))
            co[-1] += s * t  # the constant term is last in both
            fn.find("coefficients").text = fmt_vec(co)  # type: ignore[union-attr]
        else:
            raise _Skip(f"a moving path point's {fn.tag} is not scaled by the export")
    return loc


# ---------------------------------------------------------------------- path lengths in the default pose
class _PathLengths:
    """Where a point of a body lies in the default pose, on the source model (before) and on the subject
    (after), by calibrate's kinematics of each (Pinocchio)."""

    def __init__(self, model: Model, p: Parameters, info: OsimInfo):
        from ..model.model import Model as _Model
        from .osim import osim_to_urdf

        self.defaults = dict(info.defaults)  # the URDF's angles
        # OpenSim's coordinates (a lumped chain's over its ratio): what path points' functions and ranges read
        self.coordinates = {n: float(v) for n, v in info.coordinates(info.defaults).items()}
        # (a source model whose markers come in a marker-set file has none: read with one at the root's origin)
        text, _ = osim_to_urdf(info.source, need_markers=False)
        self._before = self._placements(_Model(Path(info.source), text=text), None)
        self._after = self._placements(model, p)

    def _placements(self, model: Model, p: Parameters | None) -> dict[str, pin.SE3]:
        """Each segment's placement in the default pose (root at the origin, unturned)."""
        if p is not None:  # the model as the URDF written with `p` loads (calibrate.model.urdf.urdf_text)
            from ..model.model import Model as _Model
            from ..model.urdf import urdf_text

            model = _Model(model.path, text=urdf_text(model, p))
        angles = [self.defaults.get(d.name, 0.0) for d in model.dofs]
        q = model.pin_configuration(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), angles)
        pm = model.pin
        data = pm.createData()
        pin.forwardKinematics(pm, data, q)
        pin.updateFramePlacements(pm, data)
        return {s.name: data.oMf[pm.getFrameId(s.name, pin.FrameType.BODY)].copy() for s in model.segments}

    def before(self, body: str, x: np.ndarray) -> np.ndarray:
        """A source point (in the source segment's frame) in ground, on the source model."""
        X = self._before[body]
        return X.rotation @ x + X.translation

    def after(self, body: str, x: np.ndarray) -> np.ndarray:
        """A subject point (in the exported body's coordinates) in ground, on the subject."""
        X = self._after[body]
        return X.rotation @ x + X.translation


NOTE_MARK = "calibrate:"  # the comment lines of an exported .osim that say what came of the source's forces


def forces_lines(carried: CarriedForces | None) -> list[str]:
    """What the export did with the source model's forces, in a few lines for the user."""
    if carried is None:
        return []
    shapes = [g for els in carried.geometry.values() for el in els for g in el.iter()
              if g.find("scale_factors") is not None]
    names = _few([g.findtext("mesh_file", g.tag) for g in shapes])
    geometry = [f"geometry: its bodies' {len(shapes)} shapes carried ({names}), each scaled with its segment as "
                "OpenSim's Scale tool scales it (OpenSim looks for the mesh files beside the model and in its Geometry "
                "folders)"] if shapes else []
    if carried.note:
        return [carried.note, *geometry]
    if not carried.total:
        return [f"{carried.source} has no muscles or other forces to carry", *geometry]
    lines = [f"forces: {len(carried.forces)} of {carried.source}'s {carried.total} carried; each muscle path moved "
             f"with its segments, its fibre and tendon slack lengths scaled with the path's length in the default "
             f"pose (as OpenSim's Scale tool does)", *geometry]
    if carried.left_out:
        lines.append(f"forces left out: {'; '.join(carried.left_out)}")
    if carried.changed:
        worst = sorted(carried.changed.items(), key=lambda kv: -abs(np.log(kv[1][0] / kv[1][1])))
        shown = ", ".join(f"{n} x{r:.2f} (segments x{g:.2f})" for n, (r, g) in worst[:6])
        more = f" and {len(worst) - 6} more" if len(worst) > 6 else ""
        lines.append(f"muscle paths changed by over {100 * (PATH_CHANGE - 1):.0f} % beyond their segments' scale: "
                     f"{shown}{more}: a joint centre moved against the bones they attach to; check them before a "
                     f"muscle-driven simulation")
    return lines


def _few(names: list[str], shown: int = 3) -> str:
    """The first `shown` of `names` and how many more."""
    more = f" and {len(names) - shown} more" if len(names) > shown else ""
    return ", ".join(n.strip() for n in names[:shown]) + more


def forces_written(written: Path) -> list[str]:
    """The lines forces_lines wrote into an exported .osim (as comments), for the command line's summary."""
    try:
        head = written.read_text(encoding="utf-8")[:20000]
    except OSError:
        return []
    return [line.strip()[len("<!-- " + NOTE_MARK):-len("-->")].strip() for line in head.splitlines()
            if line.strip().startswith("<!-- " + NOTE_MARK)]


__all__ = ["CarriedForces", "carried_forces", "forces_lines", "forces_written"]
