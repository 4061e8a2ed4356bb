"""OpenSim models as base models: an OpenSim 4 ``.osim`` file (and optionally a MarkerSet file) read
with ``xml.etree`` into calibrate's model format (docs/model-format.md, docs/opensim.md).

How the OpenSim model becomes a calibrate URDF:

* **bodies** become segments of the same name (mass, centre of mass, inertia about it).  A segment's
  frame is parallel to its body's, its origin at the joint centre (the child offset frame's origin): for
  the usual models (child offset frames without translation) it is the body's own frame, so markers,
  centres of mass and inertias keep OpenSim's numbers.
* **the ground joint** (``ground_pelvis``) becomes calibrate's free root: its child is the root segment.
* **joints**: the parent ``PhysicalOffsetFrame`` and the ``SpatialTransform`` give one revolute URDF
  joint per rotational coordinate, named by the coordinate (so motion columns are OpenSim's coordinate
  names), with coincident origins; constant rotations go into the origins' ``rpy``.  WeldJoint,
  PinJoint (about z), UniversalJoint (x then y'), BallJoint and GimbalJoint (x, y', z''),
  FreeJoint, PlanarJoint, SliderJoint and CustomJoint are read; functions: Constant, LinearFunction,
  PolynomialFunction, SimmSpline, NaturalCubicSpline, PiecewiseLinearFunction, MultiplierFunction.
  The chain's first URDF joint carries ``anatomical="<OpenSim joint>"``, so calibrate's joint is named
  as OpenSim's.
* **exact** where every rotation is a constant or ``±coordinate + constant`` and every translation is
  constant.  Otherwise the joint is **approximated**: a joint with one free coordinate (the knee of
  Gait2392 and Rajagopal: translations and small rotations that are splines of the knee angle) by the
  best fixed hinge over the coordinate's range (axis, centre and child pose fitted by least squares to
  the child's points); a joint whose coordinates are all coupled to others by a
  CoordinateCouplerConstraint (the patella) is welded at the independent coordinate's mid-range; any
  other non-linear axis is frozen at its coordinates' mid-range value.  Each approximation is recorded
  with its largest effect on a marker over the coordinate's range (other coordinates at their
  defaults) and a bound that holds in any pose (:class:`Approximation`).
* **coordinates**: ranges become joint limits; locked coordinates are listed (``locked``) for
  ``Settings.lock`` at their default values.
* **markers**: the model's MarkerSet, then a MarkerSet file's markers (replacing those of the same name,
  as OpenSim's ScaleTool does), on their bodies, in the segment frames.

The import's OpenSim facts (source file, the ground joint's coordinates and frames, locked coordinates,
approximations) are kept in the URDF in an ``<opensim>`` element (ignored by URDF readers, kept by
:func:`calibrate.model.model.write_model`), so a calibrated subject exported with ``calibrate export-osim``
gets OpenSim's names back (:func:`osim_info`).

Do not ``import opensim`` in a process that uses calibrate (see calibrate.io.osim_export).
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from ..errors import ModelError, read_text_file
from ..seed.geometry import Transform, apply, compose, identity_transform, invert
from .text import fmt_float, fmt_vec

JOINT_TYPES = ("CustomJoint", "WeldJoint", "PinJoint", "UniversalJoint", "BallJoint", "GimbalJoint", "FreeJoint",
               "PlanarJoint", "SliderJoint")
FUNCTION_TYPES = ("Constant", "LinearFunction", "PolynomialFunction", "SimmSpline", "NaturalCubicSpline",
                  "PiecewiseLinearFunction", "MultiplierFunction")
GRID = 401  # coordinate values over a range at which approximations are measured
MIN_MASS = 1e-6  # kg: a massless OpenSim body is kept as a segment with this mass


# ---------------------------------------------------------------------- records
@dataclass(frozen=True)
class Approximation:
    """One joint the model format cannot express exactly, and what the approximation costs.

    max_marker_mm: the largest displacement of a marker (on the child body or below) between OpenSim's
    kinematics and the imported model's, over the joint's coordinates' ranges (jointly, on a grid, when the
    joint has several), the other coordinates at their defaults.
    bound_mm: an upper bound on that displacement in any pose (|Δt| + |ΔR|·reach, the farthest a marker
    below the joint can be from it, over the range).  Both 0 when no marker rides below the joint.
    """

    joint: str  # OpenSim joint name
    kind: str  # 'hinge fit', 'welded (coupled)', 'frozen'
    coordinates: tuple[str, ...]  # the joint's OpenSim coordinates
    detail: str  # what was not expressible
    max_marker_mm: float
    marker: str  # the marker where max_marker_mm occurs ('' if none)
    bound_mm: float
    markers: tuple[str, ...]  # markers on the child body and below

    def text(self) -> str:
        where = f" at {self.marker}" if self.marker else " (no marker below)"
        return (f"{self.joint}: {self.kind} ({self.detail}); largest marker effect {self.max_marker_mm:.2f} mm"
                f"{where}, bound {self.bound_mm:.2f} mm in any pose")


@dataclass(frozen=True)
class RootInfo:
    """The OpenSim ground joint: its name, frames and six coordinates (for .osim/.mot export)."""

    joint: str
    parent_offset: Transform  # ground -> parent offset frame F
    child_offset: Transform  # root body -> child offset frame M (pose of M in the body)
    rotations: tuple[tuple[str, np.ndarray], ...]  # (coordinate, unit axis), body-fixed order
    translations: tuple[tuple[str, np.ndarray], ...]  # (coordinate, unit axis in F)


@dataclass(frozen=True)
class OsimInfo:
    """What an imported model keeps of its OpenSim origin (the URDF's <opensim> element)."""

    source: str
    root: RootInfo | None
    locked: dict[str, float]  # coordinate -> value (rad) held in every frame
    defaults: dict[str, float]  # coordinate -> default value (rad, m)
    approximations: tuple[Approximation, ...]
    dropped: tuple[str, ...] = field(default=())  # coordinates that are not DoFs (coupled, frozen)


# ---------------------------------------------------------------------- geometry
def _rot(axis: np.ndarray, angle) -> np.ndarray:
    """Rotation matrices about a unit axis, for an angle or an array of angles ((..., 3, 3))."""
    a = np.asarray(axis, dtype=float)
    th = np.asarray(angle, dtype=float)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    s, c = np.sin(th)[..., None, None], np.cos(th)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)






def _rpy(R: np.ndarray) -> np.ndarray:
    """URDF rpy (R = Rz(y) Ry(p) Rx(r)); exactly 0 for I."""
    if np.allclose(R, np.eye(3), atol=1e-15, rtol=0):
        return np.zeros(3)
    return Rotation.from_matrix(R).as_euler("xyz")


# ---------------------------------------------------------------------- functions
@dataclass(frozen=True)
class _Function:
    """An OpenSim function of one coordinate: kind, evaluation, and (a, b) when it is a*x + b."""

    kind: str
    f: Callable[[np.ndarray], np.ndarray]
    linear: tuple[float, float] | None = None  # (slope, intercept)
    constant: float | None = None

    def __call__(self, x) -> np.ndarray:
        return self.f(np.asarray(x, dtype=float))


def _floats(text: str | None) -> np.ndarray:
    return np.array([float(v) for v in (text or "").split()], dtype=float)


def _simm_spline(x: np.ndarray, y: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """OpenSim's SimmSpline: a cubic spline whose end third derivatives match the divided differences
    of the first/last four points (two points: a line); continued along the end tangents outside."""
    n = len(x)
    tiny = 1e-7
    b, c, d = np.zeros(n), np.zeros(n), np.zeros(n)
    if n == 2:
        b[:] = (y[1] - y[0]) / max(x[1] - x[0], tiny)
    else:
        d[0] = max(x[1] - x[0], tiny)
        c[1] = (y[1] - y[0]) / d[0]
        for i in range(1, n - 1):
            d[i] = max(x[i + 1] - x[i], tiny)
            b[i] = 2.0 * (d[i - 1] + d[i])
            c[i + 1] = (y[i + 1] - y[i]) / d[i]
            c[i] = c[i + 1] - c[i]
        b[0], b[-1] = -d[0], -d[n - 2]
        c[0] = c[-1] = 0.0
        if n > 3:
            c0 = c[2] / max(x[3] - x[1], tiny) - c[1] / max(x[2] - x[0], tiny)
            cn = c[n - 2] / max(x[-1] - x[n - 3], tiny) - c[n - 3] / max(x[n - 2] - x[n - 4], tiny)
            c[0] = c0 * d[0] * d[0] / max(x[3] - x[0], tiny)
            c[-1] = -cn * d[n - 2] * d[n - 2] / max(x[-1] - x[n - 4], tiny)
        for i in range(1, n):
            t = d[i - 1] / b[i - 1]
            b[i] -= t * d[i - 1]
            c[i] -= t * c[i - 1]
        c[-1] /= b[-1]
        for i in range(n - 2, -1, -1):
            c[i] = (c[i] - d[i] * c[i + 1]) / b[i]
        b[-1] = (y[-1] - y[n - 2]) / d[n - 2] + d[n - 2] * (c[n - 2] + 2.0 * c[-1])
        for i in range(n - 1):
            b[i] = (y[i + 1] - y[i]) / d[i] - d[i] * (c[i + 1] + 2.0 * c[i])
            d[i] = (c[i + 1] - c[i]) / d[i]
            c[i] *= 3.0
        c[-1] *= 3.0
        d[-1] = d[n - 2]

    def f(v: np.ndarray) -> np.ndarray:
        v = np.asarray(v, dtype=float)
        k = np.clip(np.searchsorted(x, v, side="right") - 1, 0, n - 2)
        dx = v - x[k]
        out = y[k] + dx * (b[k] + dx * (c[k] + dx * d[k]))
        out = np.where(v < x[0], y[0] + (v - x[0]) * b[0], out)
        return np.where(v > x[-1], y[-1] + (v - x[-1]) * b[-1], out)

    return f


def _function(el: ET.Element, where: str) -> _Function:
    tag = el.tag
    if tag == "Constant":
        v = float(el.findtext("value", "0"))
        return _Function(tag, lambda x: np.full(np.shape(x), v), linear=(0.0, v), constant=v)
    if tag == "LinearFunction":
        co = _floats(el.findtext("coefficients", "1 0"))
        if co.size != 2:
            raise ModelError(f"{where}: LinearFunction needs 2 coefficients, has {co.size}; fix the model")
        a, b = float(co[0]), float(co[1])
        return _Function(tag, lambda x: a * x + b, linear=(a, b), constant=b if a == 0 else None)
    if tag == "PolynomialFunction":  # coefficients from the highest order to the lowest
        co = _floats(el.findtext("coefficients", "0"))
        if co.size == 0:
            raise ModelError(f"{where}: PolynomialFunction without coefficients; fix the model")
        nz = np.flatnonzero(co)
        co = co[nz[0]:] if nz.size else np.zeros(1)
        if co.size <= 2:  # constant or linear: exact
            a, b = (0.0, float(co[0])) if co.size == 1 else (float(co[0]), float(co[1]))
            return _Function(tag, lambda x: a * x + b, linear=(a, b), constant=b if a == 0 else None)
        return _Function(tag, lambda x: np.polyval(co, x))
    if tag in ("SimmSpline", "NaturalCubicSpline", "PiecewiseLinearFunction"):
        x, y = _floats(el.findtext("x")), _floats(el.findtext("y"))
        if x.size < 2 or x.size != y.size or np.any(np.diff(x) <= 0):
            raise ModelError(f"{where}: {tag} needs at least 2 points with increasing x; fix the model")
        if tag == "SimmSpline":
            return _Function(tag, _simm_spline(x, y))
        if tag == "PiecewiseLinearFunction":
            def pl(v: np.ndarray) -> np.ndarray:
                k = np.clip(np.searchsorted(x, v, side="right") - 1, 0, x.size - 2)
                return y[k] + (v - x[k]) * (y[k + 1] - y[k]) / (x[k + 1] - x[k])
            return _Function(tag, pl)
        if x.size == 2:
            return _Function(tag, lambda v: y[0] + (v - x[0]) * (y[1] - y[0]) / (x[1] - x[0]))
        cs = CubicSpline(x, y, bc_type="natural", extrapolate=True)
        return _Function(tag, lambda v: cs(v))
    if tag == "MultiplierFunction":
        s = float(el.findtext("scale", "1"))
        inner = _inner_function(el, where)
        lin = None if inner.linear is None else (s * inner.linear[0], s * inner.linear[1])
        return _Function(tag, lambda x: s * inner(x), linear=lin,
                         constant=None if inner.constant is None else s * inner.constant)
    raise ModelError(f"{where}: function type {tag} is not read (calibrate reads {', '.join(FUNCTION_TYPES)}); "
                     f"replace it with one of those")


def _inner_function(el: ET.Element, where: str) -> _Function:
    """The function held by a TransformAxis, MultiplierFunction or coupler (directly or in <function>)."""
    for child in el:
        if child.tag == "function" and len(child) and not child.get("name"):
            return _function(child[0], where)
        if child.tag in ("function", "coupled_coordinates_function") and len(child):
            return _function(child[0], where)
        if child.get("name") == "function" or child.tag in FUNCTION_TYPES:
            return _function(child, where)
    raise ModelError(f"{where}: no function; give it one (e.g. <LinearFunction>)")


# ---------------------------------------------------------------------- the OpenSim model
@dataclass
class _Coord:
    name: str
    joint: str
    lo: float
    hi: float
    default: float
    locked: bool
    translational: bool = False

    def span(self) -> tuple[float, float]:
        """The range, limited to one turn for rotations (couplers declare +-99999)."""
        if self.translational:
            return self.lo, self.hi
        return max(self.lo, -np.pi), min(self.hi, np.pi)


@dataclass
class _Axis:
    motion: str  # 'rotation' | 'translation'
    axis: np.ndarray  # unit
    coord: str | None
    func: _Function


@dataclass
class _Joint:
    name: str
    type: str
    parent: str  # body name or 'ground'
    parent_offset: Transform  # pose of F in the parent body
    child: str
    child_offset: Transform  # pose of M in the child body
    coords: list[_Coord]
    axes: list[_Axis]  # rotations (body-fixed, in order) then translations (in F)

    def transform(self, values: Mapping[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
        """X_FM for n coordinate sets: (R (n, 3, 3), p (n, 3)), OpenSim's SpatialTransform."""
        R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        p = np.zeros((n, 3))
        for ax in self.axes:
            x = values[ax.coord] if ax.coord is not None else np.zeros(n)
            v = np.broadcast_to(ax.func(x), (n,))
            if ax.motion == "rotation":
                R = R @ _rot(ax.axis, v)
            else:
                p = p + v[:, None] * ax.axis
        return R, p


def _frame_of(el: ET.Element, where: str) -> Transform:
    t = _floats(el.findtext("translation", "0 0 0"))
    o = _floats(el.findtext("orientation", "0 0 0"))
    if t.size != 3 or o.size != 3:
        raise ModelError(f"{where}: frame '{el.get('name')}' needs 3 translation and 3 orientation values")
    R = np.eye(3) if not np.any(o) else Rotation.from_euler("XYZ", o).as_matrix()  # body-fixed x-y-z
    return R, t


def _body_name(path: str) -> str:
    """'/bodyset/femur_r', '../bodyset/femur_r', 'femur_r', '/ground' -> body name (or 'ground')."""
    return path.strip().rstrip("/").split("/")[-1]


class _Reader:
    """Parses the .osim document into bodies, joints, coordinates, couplers and markers."""

    def __init__(self, path: Path, text: str):
        self.path = path
        where = str(path)
        try:
            root = ET.fromstring(text)
        except ET.ParseError as e:
            raise ModelError(f"{where}: not valid XML ({e}); give an OpenSim model file (.osim)") from None
        if root.tag != "OpenSimDocument" or root.find("Model") is None:
            raise ModelError(f"{where}: top element is <{root.tag}>, not an OpenSimDocument with a <Model>; "
                             f"is this an OpenSim model (.osim)?")
        try:
            version = int(root.get("Version", "0"))
        except ValueError:
            version = 0
        if version < 30000 or version < 40000 and root.find("Model/BodySet/objects/Body/Joint") is not None:
            raise ModelError(f"{where}: an OpenSim 3.x model (Version {root.get('Version')}); open it in OpenSim 4 "
                             f"and save it (File > Save Model) to convert it to the 4.x format")
        m = root.find("Model")
        assert m is not None
        self.name = m.get("name", path.stem)
        self.bodies: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        for b in m.findall("BodySet/objects/Body"):
            name = b.get("name", "")
            mass = float(b.findtext("mass", "0"))
            com = _floats(b.findtext("mass_center", "0 0 0"))
            iv = _floats(b.findtext("inertia", "0 0 0 0 0 0"))
            if iv.size != 6 or com.size != 3:
                raise ModelError(f"{where}: body '{name}' needs 3 mass_center and 6 inertia values; fix the model")
            inertia = np.array([[iv[0], iv[3], iv[4]], [iv[3], iv[1], iv[5]], [iv[4], iv[5], iv[2]]])
            self.bodies[name] = (mass, com, inertia)
        # Offset frames anywhere in the model (joints' <frames>, bodies' <components>, the model's <components>),
        # for sockets that name them by path; a name used twice is not resolved by name alone.
        self.frames: dict[str, ET.Element | None] = {}
        for f in m.iter("PhysicalOffsetFrame"):
            name = f.get("name", "")
            self.frames[name] = None if name in self.frames else f
        self.coords: dict[str, _Coord] = {}
        self.joints: list[_Joint] = []
        for jel in m.findall("JointSet/objects/*"):
            self.joints.append(self._joint(jel, m))
        self.couplers: dict[str, tuple[str, _Function, float]] = {}  # dependent -> (independent, f, scale)
        for c in m.findall("ConstraintSet/objects/*"):
            cw = f"{where}: constraint '{c.get('name')}'"
            if c.tag != "CoordinateCouplerConstraint":
                continue  # other constraints (e.g. point on line) do not change the tree's kinematics here
            if c.findtext("isEnforced", "true").strip().lower() == "false":
                continue
            indep = (c.findtext("independent_coordinate_names") or "").split()
            dep = (c.findtext("dependent_coordinate_name") or "").strip()
            if len(indep) != 1 or dep not in self.coords or indep[0] not in self.coords:
                raise ModelError(f"{cw}: couples '{dep}' to {indep}, which are not one coordinate of the model; "
                                 f"fix its coordinate names")
            self.couplers[dep] = (indep[0], _inner_function(c, cw), float(c.findtext("scale_factor", "1")))
        self.markers: dict[str, tuple[str, np.ndarray]] = {}
        for mk in m.findall("MarkerSet/objects/Marker"):
            self._marker(mk, where)

    def frame(self, ref: str, local: dict[str, ET.Element], where: str) -> tuple[str, Transform]:
        """(body, pose of the frame in the body) of a socket path."""
        ref = ref.strip()
        name = _body_name(ref)
        el = local.get(name)
        if el is None and name not in self.bodies and name != "ground":
            el = self.frames.get(name)
        if el is not None:
            parent = el.findtext("socket_parent", "")
            if _body_name(parent) == name:
                raise ModelError(f"{where}: frame '{ref}' is its own parent; fix its socket_parent")
            body, X = self.frame(parent, {}, where)
            return body, compose(X, _frame_of(el, where))
        if name == "ground" or name in self.bodies:
            return name, identity_transform()
        raise ModelError(f"{where}: frame '{ref}' is not a body or an offset frame of the model; fix the path")

    def _joint(self, jel: ET.Element, m: ET.Element) -> _Joint:
        name = jel.get("name", "")
        where = f"{self.path}: joint '{name}'"
        if jel.tag not in JOINT_TYPES:
            raise ModelError(f"{where}: joint type {jel.tag} is not read (calibrate reads {', '.join(JOINT_TYPES)}); "
                             f"replace it with a CustomJoint")
        local = {f.get("name", ""): f for f in jel.findall("frames/PhysicalOffsetFrame")}
        parent, X_pf = self.frame(jel.findtext("socket_parent_frame", ""), local, where)
        child, X_bm = self.frame(jel.findtext("socket_child_frame", ""), local, where)
        if child == "ground":
            raise ModelError(f"{where}: has ground as its child; make ground the parent frame")
        coords: list[_Coord] = []
        for c in jel.findall("coordinates/Coordinate"):
            rng = _floats(c.findtext("range", "-3.14159 3.14159"))
            co = _Coord(c.get("name", ""), name, float(rng[0]), float(rng[1]), float(c.findtext("default_value", "0")),
                        c.findtext("locked", "false").strip().lower() == "true")
            if co.name in self.coords:
                raise ModelError(f"{where}: coordinate '{co.name}' is declared twice; rename one")
            self.coords[co.name] = co
            coords.append(co)
        cn = [c.name for c in coords]
        e = np.eye(3)
        lin = _Function("LinearFunction", lambda x: x, linear=(1.0, 0.0))
        zero = _Function("Constant", lambda x: np.zeros(np.shape(x)), linear=(0.0, 0.0), constant=0.0)
        axes: list[_Axis] = []
        want = {"WeldJoint": 0, "PinJoint": 1, "UniversalJoint": 2, "BallJoint": 3, "GimbalJoint": 3, "FreeJoint": 6,
                "PlanarJoint": 3, "SliderJoint": 1}
        if jel.tag in want and len(cn) != want[jel.tag]:
            raise ModelError(f"{where}: a {jel.tag} needs {want[jel.tag]} coordinates, has {len(cn)}; fix the model")
        if jel.tag == "PinJoint":
            axes = [_Axis("rotation", e[2], cn[0], lin)]
        elif jel.tag == "UniversalJoint":
            axes = [_Axis("rotation", e[0], cn[0], lin), _Axis("rotation", e[1], cn[1], lin)]
        elif jel.tag in ("BallJoint", "GimbalJoint"):
            axes = [_Axis("rotation", e[k], cn[k], lin) for k in range(3)]
        elif jel.tag == "PlanarJoint":  # rotation about z, translations along x and y of the parent frame
            axes = [_Axis("rotation", e[2], cn[0], lin), _Axis("translation", e[0], cn[1], lin),
                    _Axis("translation", e[1], cn[2], lin)]
            for c in coords[1:]:
                c.translational = True
        elif jel.tag == "SliderJoint":  # translation along x
            axes = [_Axis("translation", e[0], cn[0], lin)]
            coords[0].translational = True
        elif jel.tag == "FreeJoint":
            axes = [_Axis("rotation", e[k], cn[k], lin) for k in range(3)]
            axes += [_Axis("translation", e[k], cn[3 + k], lin) for k in range(3)]
            for c in coords[3:]:
                c.translational = True
        elif jel.tag == "CustomJoint":
            st = jel.find("SpatialTransform")
            if st is None:
                raise ModelError(f"{where}: CustomJoint without a SpatialTransform; fix the model")
            for motion in ("rotation", "translation"):
                for k in (1, 2, 3):
                    ta = st.find(f"TransformAxis[@name='{motion}{k}']")
                    if ta is None:
                        continue
                    aw = f"{where}, {motion}{k}"
                    a = _floats(ta.findtext("axis", "0 0 1"))
                    if a.size != 3 or np.linalg.norm(a) == 0:
                        raise ModelError(f"{aw}: axis must be 3 numbers, not all 0; fix the model")
                    names = (ta.findtext("coordinates") or "").split()
                    if len(names) > 1:
                        raise ModelError(f"{aw}: a function of {len(names)} coordinates is not read; use one")
                    if names and names[0] not in cn:
                        raise ModelError(f"{aw}: coordinate '{names[0]}' is not one of the joint's ({', '.join(cn)})")
                    has_f = any(ch.tag not in ("coordinates", "axis") for ch in ta)
                    f = _inner_function(ta, aw) if has_f else (lin if names else zero)
                    axes.append(_Axis(motion, a / np.linalg.norm(a), names[0] if names else None, f))
                    if motion == "translation" and names:
                        tr = [x for x in axes if x.coord == names[0]]
                        if all(x.motion == "translation" for x in tr):
                            self.coords[names[0]].translational = True
        return _Joint(name, jel.tag, parent, X_pf, child, X_bm, coords, axes)

    def _marker(self, mk: ET.Element, where: str, source: str | None = None) -> None:
        name = mk.get("name", "")
        ref = mk.findtext("socket_parent_frame") or mk.findtext("body") or ""
        loc = _floats(mk.findtext("location", "0 0 0"))
        src = source or where
        body = _body_name(ref)
        if loc.size != 3:
            raise ModelError(f"{src}: marker '{name}' needs 3 location values; fix the file")
        if body not in self.bodies and body != "ground" and self.frames.get(body) is None:
            raise ModelError(f"{src}: marker '{name}' is on body '{ref.strip()}', which {self.path.name} does not "
                             f"have; attach it to one of its bodies ({', '.join(list(self.bodies)[:6])}, ...)")
        body, X = self.frame(ref, {}, src)  # a marker on an offset frame: its location in the body
        self.markers[name] = (body, apply(X, loc))

    def add_marker_set(self, path: Path) -> None:
        text = read_text_file(path, "an OpenSim MarkerSet file (.xml)")
        try:
            root = ET.fromstring(text)
        except ET.ParseError as e:
            raise ModelError(f"{path}: not valid XML ({e}); give an OpenSim MarkerSet file") from None
        ms = root if root.tag == "MarkerSet" else root.find(".//MarkerSet")
        if ms is None:
            raise ModelError(f"{path}: no <MarkerSet>; give an OpenSim MarkerSet file (as the Scale tool reads)")
        for mk in ms.findall("objects/Marker"):
            self._marker(mk, str(path), source=str(path))


# ---------------------------------------------------------------------- the import
@dataclass
class _Op:
    """One factor of a joint's transform as calibrate builds it: fixed, or a revolute of a coordinate."""

    fixed: Transform | None = None
    coord: str | None = None
    axis: np.ndarray | None = None


def _ops_transform(ops: list[_Op], values: Mapping[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    p = np.zeros((n, 3))
    for op in ops:
        if op.fixed is not None:
            p = p + np.einsum("nij,j->ni", R, op.fixed[1])
            R = R @ op.fixed[0]
        else:
            R = R @ _rot(op.axis, values[op.coord])  # type: ignore[arg-type,index]
    return R, p


def _body_aligned(ops: list[_Op], child_offset: Transform) -> tuple[list[_Op], Transform]:
    """The same chain with the segment frame parallel to the child body: the rotation Q of what follows the
    last revolute (with the child offset) moves in front of the first revolute, and everything between is
    conjugated by it (Q⁻¹ Rot(a) Q = Rot(Qᵀ a)).  Returns the ops and the body's pose in the segment frame
    (a translation only)."""
    idx = [i for i, op in enumerate(ops) if op.coord is not None]
    first, last = idx[0], idx[-1]
    tail = identity_transform()
    for op in ops[last + 1:]:
        tail = compose(tail, op.fixed)  # type: ignore[arg-type]
    tail = compose(tail, invert(child_offset))
    R = tail[0]
    out = ops[:first] + [_Op(fixed=(R, np.zeros(3)))]
    for op in ops[first:last + 1]:
        if op.fixed is not None:
            out.append(_Op(fixed=(R.T @ op.fixed[0] @ R, R.T @ op.fixed[1])))
        else:
            out.append(_Op(coord=op.coord, axis=R.T @ op.axis))  # type: ignore[operator]
    return out, (np.eye(3), R.T @ tail[1])


class _Importer:
    def __init__(self, reader: _Reader):
        self.r = reader
        self.where = str(reader.path)
        by_child: dict[str, _Joint] = {}
        for j in reader.joints:
            if j.child in by_child:
                raise ModelError(f"{self.where}: body '{j.child}' is the child of two joints "
                                 f"('{by_child[j.child].name}',"
                                 f" '{j.name}'); closed loops are not read; remove one joint")
            by_child[j.child] = j
        self.by_child = by_child
        grounded = [j for j in reader.joints if j.parent == "ground"]
        if len(grounded) != 1:
            raise ModelError(f"{self.where}: {len(grounded)} joints connect a body to ground; calibrate needs exactly "
                             f"one (the root's, e.g. ground_pelvis)")
        self.root_joint = grounded[0]
        self.children: dict[str, list[_Joint]] = {b: [] for b in reader.bodies}
        for j in reader.joints:
            if j.parent != "ground":
                if j.parent not in reader.bodies:
                    raise ModelError(f"{self.where}: joint '{j.name}' has parent '{j.parent}', not a body; fix it")
                self.children[j.parent].append(j)
        orphans = [b for b in reader.bodies if b not in by_child]
        if orphans:
            raise ModelError(f"{self.where}: body '{orphans[0]}' has no joint; connect it with a joint")
        self.order: list[_Joint] = []  # depth-first from the root

        def walk(body: str) -> None:
            for j in self.children[body]:
                self.order.append(j)
                walk(j.child)
        walk(self.root_joint.child)
        if len(self.order) + 1 != len(reader.joints):
            raise ModelError(f"{self.where}: some joints are not connected to the root body; fix the tree")

    # -------------------------------------------------------------- values
    def ref_value(self, name: str) -> float:
        """A coordinate's value at which approximations freeze it: mid-range (of its independent one if coupled)."""
        if name in self.r.couplers:
            ind, f, s = self.r.couplers[name]
            return float(s * f(self.ref_value(ind)))
        c = self.r.coords[name]
        lo, hi = c.span()
        return 0.5 * (lo + hi)

    def default_values(self) -> dict[str, float]:
        out = {}
        for name, c in self.r.coords.items():
            out[name] = c.default
        for dep, (ind, f, s) in self.r.couplers.items():
            out[dep] = float(s * f(out[ind]))
        return out

    # -------------------------------------------------------------- per joint
    def joint_ops(self, j: _Joint) -> tuple[list[_Op], tuple[str, str] | None]:
        """Ops of the imported joint and, if approximated, (kind, detail)."""
        free = [c for c in j.coords if c.name not in self.r.couplers and not c.translational]
        used: set[str] = set()
        exact = all(c.name not in self.r.couplers for c in j.coords)
        why: list[str] = []
        for ax in j.axes:
            if ax.coord is None or ax.func.constant is not None:
                continue
            if ax.motion == "translation":
                exact = False
                why.append(f"translation along {fmt_vec(np.round(ax.axis, 3))} is a {ax.func.kind} of {ax.coord}")
            elif ax.func.linear is None or abs(abs(ax.func.linear[0]) - 1) > 1e-12 or ax.coord in used:
                exact = False
                why.append(f"rotation about {fmt_vec(np.round(ax.axis, 3))} is a {ax.func.kind} of {ax.coord}")
            used.add(ax.coord)
        if exact:
            return self._exact_ops(j, {}), None
        if not free:
            ref = {c.name: np.array([self.ref_value(c.name)]) for c in j.coords}
            R, p = j.transform(ref, 1)
            kind = "welded (coupled)" if any(c.name in self.r.couplers for c in j.coords) else "frozen"
            vals = ", ".join(f"{c.name} = {ref[c.name][0]:.4g}" for c in j.coords)
            return [_Op(fixed=(R[0], p[0]))], (kind, f"welded at {vals}")
        if len(free) == 1 and all(c.name in self.r.couplers or c is free[0] for c in j.coords):
            detail = "; ".join(why) + f"; best fixed hinge over {free[0].name}'s range"
            return self._hinge_fit(j, free[0]), ("hinge fit", detail)
        frozen = {c.name for c in j.coords if c.name in self.r.couplers or c.translational}
        return self._exact_ops(j, frozen, freeze_nonlinear=True), ("frozen", "; ".join(why) + "; those axes frozen at "
                                                                    "mid-range")

    def _exact_ops(self, j: _Joint, frozen: set[str], freeze_nonlinear: bool = False) -> list[_Op]:
        p = np.zeros(3)
        ops: list[_Op] = []
        used: set[str] = set()
        for ax in j.axes:
            if ax.motion != "translation":
                continue
            x = self.ref_value(ax.coord) if ax.coord is not None else 0.0
            p = p + float(ax.func(np.array(x))) * ax.axis
        ops.append(_Op(fixed=(np.eye(3), p)))
        for ax in j.axes:
            if ax.motion != "rotation":
                continue
            lin = ax.func.linear
            moving = (ax.coord is not None and ax.func.constant is None and ax.coord not in frozen
                      and ax.coord not in used and lin is not None and abs(abs(lin[0]) - 1) <= 1e-12)
            if moving:
                ops.append(_Op(fixed=(_rot(ax.axis, lin[1]), np.zeros(3))))  # type: ignore[index]
                ops.append(_Op(coord=ax.coord, axis=np.sign(lin[0]) * ax.axis))  # type: ignore[index]
                used.add(ax.coord)  # type: ignore[arg-type]
            else:
                x = self.ref_value(ax.coord) if ax.coord is not None else 0.0
                ops.append(_Op(fixed=(_rot(ax.axis, float(ax.func(np.array(x)))), np.zeros(3))))
        return ops

    def _hinge_fit(self, j: _Joint, c: _Coord) -> list[_Op]:
        """Trans(centre) Rot(axis, q) Y, fitted to the child's points over the coordinate's range."""
        lo, hi = c.span()
        q = np.linspace(lo, hi, 61)
        values = self._joint_values(j, c.name, q)
        R, p = j.transform(values, q.size)
        pts = self._fit_points(j)
        target = np.einsum("nij,kj->nki", R, pts) + p[:, None, :]
        # initial guess: the screw axis between the range's ends
        Rr = R[-1] @ R[0].T
        rv = Rotation.from_matrix(Rr).as_rotvec()
        if np.linalg.norm(rv) > 1e-6:
            a0 = rv / np.linalg.norm(rv) * np.sign(hi - lo)
        else:
            a0 = next((ax.axis for ax in j.axes if ax.motion == "rotation" and ax.coord == c.name), np.eye(3)[2])
        tr = p[-1] - Rr @ p[0]
        c0 = np.linalg.lstsq(np.eye(3) - Rr, tr - (a0 @ tr) * a0, rcond=None)[0]
        mid = q.size // 2
        Ym = compose((_rot(a0, -q[mid]), np.zeros(3)), compose((np.eye(3), -c0), (R[mid], p[mid])))
        x0 = np.concatenate([a0, c0, Rotation.from_matrix(Ym[0]).as_rotvec(), Ym[1]])

        def model(x: np.ndarray) -> np.ndarray:
            a = x[:3] / np.linalg.norm(x[:3])
            RY = Rotation.from_rotvec(x[6:9]).as_matrix()
            Rq = _rot(a, q)
            RR = Rq @ RY
            pp = np.einsum("nij,j->ni", Rq, x[9:12]) + x[3:6]
            return np.einsum("nij,kj->nki", RR, pts) + pp[:, None, :]

        sol = least_squares(lambda x: (model(x) - target).ravel(), x0, method="lm", xtol=1e-14, ftol=1e-14)
        x = sol.x
        a = x[:3] / np.linalg.norm(x[:3])
        cen = x[3:6]
        Y = (Rotation.from_rotvec(x[6:9]).as_matrix(), x[9:12].copy())
        # the centre: the point of the axis nearest the child frame's origin at mid-range
        shift = float(a @ (p[mid] - cen))
        cen = cen + shift * a
        Y = (Y[0], Y[1] - shift * a)
        return [_Op(fixed=(np.eye(3), cen)), _Op(coord=c.name, axis=a), _Op(fixed=Y)]

    def _joint_values(self, j: _Joint, name: str, q: np.ndarray) -> dict[str, np.ndarray]:
        """Every coordinate of joint j when `name` takes the values q (couplers followed, others at reference)."""
        vals = {c.name: np.full(q.shape, self.ref_value(c.name)) for c in j.coords}
        vals[name] = q
        for c in j.coords:
            if c.name in self.r.couplers:
                ind, f, s = self.r.couplers[c.name]
                if ind == name:
                    vals[c.name] = s * f(q)
        return vals

    def _fit_points(self, j: _Joint) -> np.ndarray:
        """Points in the joint's M frame that the hinge fit matches: the child's markers and child joint
        frames at the default pose, plus a 10 cm cross so that the fit is never underdetermined."""
        inv = invert(j.child_offset)  # body -> M
        pts = [apply(inv, x) for x in self.points_below(j.child).values()]
        pts += [s * e for e in np.eye(3) * 0.1 for s in (1, -1)]
        return np.array(pts)

    def points_below(self, body: str) -> dict[str, np.ndarray]:
        """Markers on `body` and the bodies below it, and child-joint origins, in `body`'s frame, default pose."""
        out: dict[str, np.ndarray] = {}
        dv = self.defaults
        for mk, (b, loc) in self.r.markers.items():
            if b == body:
                out[mk] = loc
        for cj in self.children[body]:
            vals = {c.name: np.array([dv[c.name]]) for c in cj.coords}
            R, p = cj.transform(vals, 1)
            X = compose(cj.parent_offset, compose((R[0], p[0]), invert(cj.child_offset)))  # child body in body
            out[f"joint {cj.name}"] = X[1]
            for k, x in self.points_below(cj.child).items():
                out[k] = apply(X, x)
        return out

    def reach(self, body: str, origin: np.ndarray) -> float:
        """An upper bound of the distance from `origin` (in `body`'s frame) to any marker on or below
        `body`, in any pose within the coordinates' ranges (triangle inequality along the tree)."""
        r = 0.0
        for b, loc in self.r.markers.values():
            if b == body:
                r = max(r, float(np.linalg.norm(loc - origin)))
        for cj in self.children[body]:
            if not self.has_markers_below(cj.child):
                continue
            t_max = self.max_translation(cj)
            child_origin_in_child = cj.child_offset[1]  # M origin in the child body
            r = max(r, float(np.linalg.norm(cj.parent_offset[1] - origin)) + t_max
                    + self.reach(cj.child, child_origin_in_child))
        return r

    def has_markers_below(self, body: str) -> bool:
        return any(b == body for b, _ in self.r.markers.values()) or any(
            self.has_markers_below(cj.child) for cj in self.children[body])

    def max_translation(self, j: _Joint) -> float:
        """max |p(q)| of a joint's SpatialTransform translation over its coordinates' ranges (sampled)."""
        if not any(ax.motion == "translation" and ax.func.constant is None for ax in j.axes):
            _, p = j.transform({c.name: np.zeros(1) for c in j.coords}, 1)
            return float(np.linalg.norm(p[0]))
        best = 0.0
        for c in j.coords:
            lo, hi = c.span()
            q = np.linspace(lo, hi, GRID)
            _, p = j.transform(self._joint_values(j, c.name, q), q.size)
            best = max(best, float(np.linalg.norm(p, axis=1).max()))
        return best * 1.01

    def measure(self, j: _Joint, ops: list[_Op], kind: str, detail: str) -> Approximation:
        """Largest marker effect over the range (defaults elsewhere) and the any-pose bound."""
        pts = self.points_below(j.child)
        markers = {k: v for k, v in pts.items() if not k.startswith("joint ")}
        inv = invert(j.child_offset)
        w = np.array([apply(inv, x) for x in markers.values()]).reshape(-1, 3)
        names = list(markers)
        drivers = [c for c in j.coords if c.name not in self.r.couplers] or \
            [self.r.coords[self.r.couplers[c.name][0]] for c in j.coords]
        worst, worst_marker, bound = 0.0, "", 0.0
        reach = self.reach(j.child, j.child_offset[1])
        samples = []
        if len(drivers) == 1:
            c = drivers[0]
            q = np.linspace(*c.span(), GRID)
            vals = self._joint_values(j, c.name, q)
            if c.name not in {x.name for x in j.coords}:  # a coupled joint: its coordinates follow c
                vals = {x.name: self.r.couplers[x.name][2] * self.r.couplers[x.name][1](q) for x in j.coords}
            samples.append((vals, q.size))
        else:  # several coordinates: jointly, on a grid over their ranges (corners included)
            k = max(3, int(round(4000 ** (1 / len(drivers)))))
            grid = np.meshgrid(*[np.linspace(*c.span(), k) for c in drivers], indexing="ij")
            vals = {c.name: g.ravel() for c, g in zip(drivers, grid, strict=True)}
            n = grid[0].size
            for x in j.coords:
                if x.name in self.r.couplers:
                    ind, f, s = self.r.couplers[x.name]
                    vals[x.name] = s * f(vals[ind]) if ind in vals else np.full(n, self.ref_value(x.name))
            samples.append((vals, n))
        for vals, size in samples:
            R, p = j.transform(vals, size)
            Ra, pa = _ops_transform(ops, vals, size)
            if w.size:
                err = np.linalg.norm(np.einsum("nij,kj->nki", R - Ra, w) + (p - pa)[:, None, :], axis=2)
                k = np.unravel_index(np.argmax(err), err.shape)
                if err[k] > worst:
                    worst, worst_marker = float(err[k]), names[k[1]]
                dR = np.linalg.norm(R - Ra, ord=2, axis=(1, 2))
                bound = max(bound, float(np.max(dR * reach + np.linalg.norm(p - pa, axis=1))))
        return Approximation(j.name, kind, tuple(c.name for c in j.coords), detail, 1000 * worst, worst_marker,
                             1000 * bound, tuple(names))

    # -------------------------------------------------------------- the URDF
    def build(self) -> tuple[str, OsimInfo]:
        r = self.r
        self.defaults = self.default_values()
        seg_X: dict[str, Transform] = {self.root_joint.child: identity_transform()}  # body coords -> segment frame
        links: list[str] = []
        joints: list[str] = []
        approximations: list[Approximation] = []
        dropped: list[str] = []
        dofs: list[str] = []
        urdf_names: set[str] = set()

        def origin(X: Transform) -> str:
            return f'<origin xyz="{fmt_vec(X[1])}" rpy="{fmt_vec(_rpy(X[0]))}"/>'

        def add_joint(name: str, kind: str, parent: str, child: str, X: Transform, extra: str = "",
                      anatomical: str | None = None) -> None:
            if name in urdf_names:
                raise ModelError(f"{self.where}: the name '{name}' is used by two coordinates, joints or markers; "
                                 f"rename one")
            urdf_names.add(name)
            att = f' anatomical="{anatomical}"' if anatomical else ""
            joints.append(f'  <joint name="{name}" type="{kind}"{att}>\n    <parent link="{parent}"/>\n'
                          f'    <child link="{child}"/>\n    {origin(X)}{extra}\n  </joint>')

        for j in self.order:
            ops, approx = self.joint_ops(j)
            if approx is not None:
                approximations.append(self.measure(j, ops, *approx))
            revs = [op for op in ops if op.coord is not None]
            tail = identity_transform()
            if revs:
                ops, tail = _body_aligned(ops, j.child_offset)
            for c in j.coords:
                if c.name not in {op.coord for op in revs}:
                    dropped.append(c.name)
            pending = compose(seg_X[j.parent], j.parent_offset)
            prev = j.parent
            k = 0
            for op in ops:
                if op.fixed is not None:
                    pending = compose(pending, op.fixed)
                    continue
                k += 1
                last = k == len(revs)
                child = j.child if last else f"{j.name}_{op.coord}_frame"
                if not last:
                    links.append(f'  <link name="{child}"/>')
                c = r.coords[op.coord]  # type: ignore[index]
                lim = f'\n    <axis xyz="{fmt_vec(op.axis)}"/>\n    <limit lower="{fmt_float(c.lo)}" ' \
                      f'upper="{fmt_float(c.hi)}" effort="0" velocity="0"/>'
                add_joint(op.coord, "revolute", prev, child, pending, lim,  # type: ignore[arg-type]
                          anatomical=j.name if k == 1 else None)
                dofs.append(op.coord)  # type: ignore[arg-type]
                pending = identity_transform()
                prev = child
            if not revs:
                name = j.name if j.name not in r.coords else f"{j.name}_weld"
                add_joint(name, "fixed", j.parent, j.child, compose(pending, invert(j.child_offset)),
                          anatomical=j.name)
                seg_X[j.child] = identity_transform()
            else:
                seg_X[j.child] = tail
        # segments
        for body, (mass, com, inertia) in r.bodies.items():
            X = seg_X[body]
            c = apply(X, com)
            I = X[0] @ inertia @ X[0].T
            links.append(
                f'  <link name="{body}">\n    <inertial>\n      <origin xyz="{fmt_vec(c)}" rpy="0 0 0"/>\n'
                f'      <mass value="{fmt_float(max(mass, MIN_MASS))}"/>\n'
                f'      <inertia ixx="{fmt_float(I[0, 0])}" ixy="{fmt_float(I[0, 1])}" ixz="{fmt_float(I[0, 2])}" '
                f'iyy="{fmt_float(I[1, 1])}" iyz="{fmt_float(I[1, 2])}" izz="{fmt_float(I[2, 2])}"/>\n'
                f'    </inertial>\n  </link>')
        # markers
        skipped = []
        for name, (body, loc) in r.markers.items():
            if body == "ground":
                skipped.append(name)
                continue
            links.append(f'  <link name="{name}"/>')
            add_joint(f"{name}_marker", "fixed", body, name, (np.eye(3), apply(seg_X[body], loc)))
        if not [m for m in r.markers if m not in skipped]:
            raise ModelError(f"{self.where}: the model has no markers on its bodies; give its marker set with "
                             f"--marker-set FILE.xml (marker_set=...)")
        rj = self.root_joint
        root = None
        rots = [(ax.coord, ax.axis) for ax in rj.axes if ax.motion == "rotation" and ax.coord is not None]
        trs = [(ax.coord, ax.axis) for ax in rj.axes if ax.motion == "translation" and ax.coord is not None]
        lin_ok = all(ax.func.linear == (1.0, 0.0) for ax in rj.axes if ax.coord is not None)
        if len(rots) == 3 and len(trs) == 3 and lin_ok and rj.type in ("CustomJoint", "FreeJoint"):
            root = RootInfo(rj.name, rj.parent_offset, rj.child_offset, tuple(rots), tuple(trs))  # type: ignore[arg-type]
        locked = {c.name: c.default for c in r.coords.values() if c.locked and c.name in dofs}
        info = OsimInfo(str(r.path), root, locked, {n: self.defaults[n] for n in dofs}, tuple(approximations),
                        tuple(dropped))
        text = (f'<?xml version="1.0"?>\n<!-- imported by calibrate from {r.path.name} -->\n'
                f'<robot name="{r.name}">\n' + "\n".join(links) + "\n" + "\n".join(joints) + "\n"
                + _info_xml(info) + "\n</robot>\n")
        return text, info


# ---------------------------------------------------------------------- the <opensim> element
def _info_xml(info: OsimInfo) -> str:
    el = ET.Element("opensim", source=info.source)
    if info.root is not None:
        rt = info.root
        r = ET.SubElement(el, "root", joint=rt.joint)
        for tag, X in (("parent_offset", rt.parent_offset), ("child_offset", rt.child_offset)):
            ET.SubElement(r, tag, xyz=fmt_vec(X[1]), rpy=fmt_vec(_rpy(X[0])))
        for tag, items in (("rotation", rt.rotations), ("translation", rt.translations)):
            for name, axis in items:
                ET.SubElement(r, tag, coordinate=name, axis=fmt_vec(axis))
    for name, v in info.defaults.items():
        ET.SubElement(el, "coordinate", name=name, default=fmt_float(v),
                      locked="true" if name in info.locked else "false")
    for name in info.dropped:
        ET.SubElement(el, "dropped", coordinate=name)
    for a in info.approximations:
        ET.SubElement(el, "approximation", joint=a.joint, kind=a.kind, coordinates=" ".join(a.coordinates),
                      detail=a.detail, max_marker_mm=fmt_float(a.max_marker_mm), marker=a.marker,
                      bound_mm=fmt_float(a.bound_mm), markers=" ".join(a.markers))
    ET.indent(el, space="  ", level=1)
    return "  " + ET.tostring(el, encoding="unicode")


def osim_info(model) -> OsimInfo | None:
    """The OpenSim facts of a model imported from a .osim (or written from one), else None."""
    try:
        robot = ET.fromstring(model._text)
    except ET.ParseError:  # pragma: no cover - a Model's text is valid XML
        return None
    el = robot.find("opensim")
    if el is None:
        return None

    def X(e: ET.Element | None) -> Transform:
        xyz = _floats(e.get("xyz", "0 0 0")) if e is not None else np.zeros(3)
        rpy = _floats(e.get("rpy", "0 0 0")) if e is not None else np.zeros(3)
        R = np.eye(3) if not np.any(rpy) else Rotation.from_euler("xyz", rpy).as_matrix()
        return R, xyz

    root = None
    r = el.find("root")
    if r is not None:
        root = RootInfo(r.get("joint", ""), X(r.find("parent_offset")), X(r.find("child_offset")),
                        tuple((e.get("coordinate", ""), _floats(e.get("axis"))) for e in r.findall("rotation")),
                        tuple((e.get("coordinate", ""), _floats(e.get("axis"))) for e in r.findall("translation")))
    defaults = {e.get("name", ""): float(e.get("default", "0")) for e in el.findall("coordinate")}
    locked = {e.get("name", ""): float(e.get("default", "0")) for e in el.findall("coordinate")
              if e.get("locked") == "true"}
    approx = tuple(Approximation(e.get("joint", ""), e.get("kind", ""), tuple(e.get("coordinates", "").split()),
                                 e.get("detail", ""), float(e.get("max_marker_mm", "0")), e.get("marker", ""),
                                 float(e.get("bound_mm", "0")), tuple(e.get("markers", "").split()))
                   for e in el.findall("approximation"))
    dropped = tuple(e.get("coordinate", "") for e in el.findall("dropped"))
    return OsimInfo(el.get("source", ""), root, locked, defaults, approx, dropped)


# ---------------------------------------------------------------------- public API
def osim_to_urdf(path: str | os.PathLike[str], marker_set: str | os.PathLike[str] | None = None
                 ) -> tuple[str, OsimInfo]:
    """The calibrate URDF text of an OpenSim model (and MarkerSet file), with its OsimInfo."""
    path = Path(path)
    reader = _Reader(path, read_text_file(path, "an OpenSim model (.osim)"))
    if marker_set is not None:
        reader.add_marker_set(Path(marker_set))
    return _Importer(reader).build()


def load_osim(path: str | os.PathLike[str], marker_set: str | os.PathLike[str] | None = None):
    """Load an OpenSim 4 model (and optionally a MarkerSet file) as a calibrate Model.

    The model's ``osim`` attribute (also :func:`osim_info`) lists the locked coordinates and the
    approximations.  Raises ModelError with one line on bad input."""
    from ..model.model import Model

    text, info = osim_to_urdf(path, marker_set)
    model = Model(Path(path), text=text)
    model.osim = info  # type: ignore[attr-defined]
    return model


def with_locked(model, settings):
    """`settings` with the model's locked OpenSim coordinates added to Settings.lock (those the settings
    already lock keep their values)."""
    from dataclasses import replace

    info = osim_info(model)
    if info is None or not info.locked:
        return settings
    have = dict(settings.lock)
    merged = {**{k: v for k, v in info.locked.items() if k in set(model.dof_names)}, **have}
    return replace(settings, lock=tuple(sorted(merged.items())))


def approximation_table(info: OsimInfo) -> str:
    """One line per approximated joint (for `calibrate inspect MODEL.osim`)."""
    if not info.approximations:
        return "  every joint imported exactly"
    return "\n".join("  " + a.text() for a in info.approximations)


def root_coordinates(info: OsimInfo, root_translation: np.ndarray, root_quaternion: np.ndarray,
                     root_scale: float = 1.0) -> dict[str, np.ndarray]:
    """OpenSim's ground-joint coordinates (rad, m) of root poses (n, 3) and quaternions (n, 4; x, y, z, w)
    of the root segment.  The rotation axes must be coordinate axes (as in every OpenSim ground joint)."""
    rt = info.root
    if rt is None:
        raise ModelError(f"{info.source}: its ground joint is not three rotations and three translations of "
                         f"coordinates; cannot write its coordinates")
    letters = ""
    signs = []
    for name, a in rt.rotations:
        k = int(np.argmax(np.abs(a)))
        if abs(abs(a[k]) - 1) > 1e-9:
            raise ModelError(f"{info.source}: the ground joint's rotation axis for '{name}' is not a coordinate axis; "
                             f"cannot write its coordinates")
        letters += "XYZ"[k]
        signs.append(math.copysign(1.0, a[k]))
    Rm, tm = rt.child_offset[0], rt.child_offset[1] * root_scale
    RG = Rotation.from_quat(np.asarray(root_quaternion, float)).as_matrix()  # (n, 3, 3) root segment in lab
    Rf, tf = rt.parent_offset
    # X_FM = X_GF^-1 X_GB X_BM
    R_fm = np.einsum("ij,njk,kl->nil", Rf.T, RG, Rm)
    p_fm = np.einsum("ij,nj->ni", Rf.T, np.einsum("nij,j->ni", RG, tm) + np.asarray(root_translation, float) - tf)
    ang = Rotation.from_matrix(R_fm).as_euler(letters)  # intrinsic (body-fixed) sequence
    ang = np.unwrap(ang * np.array(signs), axis=0)
    T = np.array([a for _, a in rt.translations]).T
    tr = np.linalg.solve(T, p_fm.T).T
    out = {name: ang[:, k] for k, (name, _) in enumerate(rt.rotations)}
    out.update({name: tr[:, k] for k, (name, _) in enumerate(rt.translations)})
    return out


__all__ = ["Approximation", "OsimInfo", "RootInfo", "approximation_table", "load_osim", "osim_info", "osim_to_urdf",
           "root_coordinates", "with_locked"]
