"""OpenSim 4 model XML read into plain records: bodies, frames, joints with their SpatialTransform axes
and functions (Constant, LinearFunction, SimmSpline...), coordinates, markers; calibrate.io.osim turns
them into a URDF."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from xml.parsers import expat

import numpy as np

from ..errors import ModelError, read_text_file
from ..model.rotations import euler_matrices, matrix_eulers
from ..seed.geometry import Transform, apply, compose, identity_transform
from .text import finite_numbers

#: How an OpenSim 3.x model is converted without OpenSim's window (pyCGM2 ships its models as 2.x / 3.x files).
_CONVERT = (", or with OpenSim's Python package: python -c \"import opensim; "
            "opensim.Model('OLD.osim').printToXML('NEW.osim')\"")
JOINT_TYPES = ("CustomJoint", "WeldJoint", "PinJoint", "UniversalJoint", "BallJoint", "GimbalJoint", "FreeJoint",
               "PlanarJoint", "SliderJoint")


FUNCTION_TYPES = ("Constant", "LinearFunction", "PolynomialFunction", "SimmSpline", "NaturalCubicSpline",
                  "PiecewiseLinearFunction", "MultiplierFunction")


# ---------------------------------------------------------------------- geometry
def axis_rotation(axis: np.ndarray, angle) -> np.ndarray:
    """Rotation matrices about a unit axis, for an angle or an array of angles ((..., 3, 3))."""
    a = np.asarray(axis, dtype=float)
    th = np.asarray(angle, dtype=float)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    s, c = np.sin(th)[..., None, None], np.cos(th)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def urdf_rpy(R: np.ndarray) -> np.ndarray:
    """URDF rpy (R = Rz(y) Ry(p) Rx(r)); exactly 0 for I."""
    if np.allclose(R, np.eye(3), atol=1e-15, rtol=0):
        return np.zeros(3)
    return matrix_eulers(R, "xyz")


# ---------------------------------------------------------------------- functions
@dataclass(frozen=True)
class OsimFunction:
    """An OpenSim function of one coordinate: kind, evaluation, and (a, b) when it is a*x + b."""

    kind: str
    f: Callable[[np.ndarray], np.ndarray]
    linear: tuple[float, float] | None = None  # (slope, intercept)
    constant: float | None = None

    def __call__(self, x) -> np.ndarray:
        return self.f(np.asarray(x, dtype=float))


def parse_xml(text: str) -> ET.Element:
    """The root element of an OpenSim XML document.  OpenSim names some nested classes with C++ scope
    (`<HuntCrossleyForce::ContactParametersSet>`, in every model with contact forces): well-formed XML 1.0,
    but not namespace-well-formed, which ElementTree's parser requires.  Such a document is parsed again by
    expat without namespace processing, the tags kept as written.  ET.ParseError when neither reads it."""
    try:
        return ET.fromstring(text)
    except ET.ParseError as first:
        if "::" not in text:
            raise
        builder = ET.TreeBuilder()
        parser = expat.ParserCreate()
        parser.buffer_text = True
        parser.StartElementHandler = builder.start
        parser.EndElementHandler = builder.end
        parser.CharacterDataHandler = builder.data
        try:
            parser.Parse(text, True)
        except expat.ExpatError:
            raise first from None
        return builder.close()


def xml_root(path: Path, read_as: str, give: str) -> ET.Element:
    """The root element of the XML file at `path`; ModelError with one line when the file cannot be read (`read_as`:
    what it should be) or is not XML (`give`: what to give instead)."""
    text = read_text_file(path, read_as)
    try:
        return parse_xml(text)
    except ET.ParseError as e:
        raise ModelError(f"{path}: not valid XML ({e}); give {give}") from None


def xml_element(path: Path, tag: str, read_as: str, give: str, missing: str) -> ET.Element:
    """The <tag> element of the XML file at `path` (its root or the first below it); ModelError with one line when
    the file cannot be read (`read_as`: what it should be), is not XML (`give`: what to give instead) or has no
    such element (`missing`: what to do)."""
    root = xml_root(path, read_as, give)
    el = root if root.tag == tag else root.find(f".//{tag}")
    if el is None:
        raise ModelError(f"{path}: no <{tag}>; {missing}")
    return el


def xml_floats(text: str | None) -> np.ndarray:
    return np.array([float(v) for v in (text or "").split()], dtype=float)


class BadNumbers(ValueError):
    """A number field of an OpenSim file that holds no finite numbers, or not as many as it should; the reader
    (OsimReader) turns it into one line naming the file."""


def el_numbers(el: ET.Element, tag: str, default: str, count: int | None = None) -> np.ndarray:
    """The finite numbers of `el`'s <tag> (`default` where it has none), `count` of them if given; BadNumbers naming
    the element otherwise (a number cut, 'nan', '1e999', a range of one value)."""
    text = el.findtext(tag, default)
    values = finite_numbers(text)
    if values is None or (count is not None and len(values) != count):
        name = el.get("name")
        owner = f"<{el.tag} name='{name}'>" if name else f"<{el.tag}>"
        want = "a finite number" if count == 1 else f"{count} finite numbers" if count else "finite numbers"
        raise BadNumbers(f"{owner}'s <{tag}> is {' '.join((text or '').split())[:40]!r}, not {want}")
    return np.array(values, dtype=float)


def el_number(el: ET.Element, tag: str, default: str) -> float:
    """The one finite number of `el`'s <tag> (el_numbers)."""
    return float(el_numbers(el, tag, default, 1)[0])


def simm_spline(x: np.ndarray, y: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
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


def osim_function(el: ET.Element, where: str) -> OsimFunction:
    tag = el.tag
    if tag == "Constant":
        v = el_number(el, "value", "0")
        return OsimFunction(tag, lambda x: np.full(np.shape(x), v), linear=(0.0, v), constant=v)
    if tag == "LinearFunction":
        co = el_numbers(el, "coefficients", "1 0")
        if co.size != 2:
            raise ModelError(f"{where}: LinearFunction needs 2 coefficients, has {co.size}; fix the model")
        a, b = float(co[0]), float(co[1])
        return OsimFunction(tag, lambda x: a * x + b, linear=(a, b), constant=b if a == 0 else None)
    if tag == "PolynomialFunction":  # coefficients from the highest order to the lowest
        co = el_numbers(el, "coefficients", "0")
        if co.size == 0:
            raise ModelError(f"{where}: PolynomialFunction without coefficients; fix the model")
        nz = np.flatnonzero(co)
        co = co[nz[0]:] if nz.size else np.zeros(1)
        if co.size <= 2:  # constant or linear: exact
            a, b = (0.0, float(co[0])) if co.size == 1 else (float(co[0]), float(co[1]))
            return OsimFunction(tag, lambda x: a * x + b, linear=(a, b), constant=b if a == 0 else None)
        return OsimFunction(tag, lambda x: np.polyval(co, x))
    if tag in ("SimmSpline", "NaturalCubicSpline", "PiecewiseLinearFunction"):
        x, y = el_numbers(el, "x", ""), el_numbers(el, "y", "")
        if x.size < 2 or x.size != y.size or np.any(np.diff(x) <= 0):
            raise ModelError(f"{where}: {tag} needs at least 2 points with increasing x; fix the model")
        if tag == "SimmSpline":
            return OsimFunction(tag, simm_spline(x, y))
        if tag == "PiecewiseLinearFunction":
            def pl(v: np.ndarray) -> np.ndarray:
                k = np.clip(np.searchsorted(x, v, side="right") - 1, 0, x.size - 2)
                return y[k] + (v - x[k]) * (y[k + 1] - y[k]) / (x[k + 1] - x[k])
            return OsimFunction(tag, pl)
        if x.size == 2:
            return OsimFunction(tag, lambda v: y[0] + (v - x[0]) * (y[1] - y[0]) / (x[1] - x[0]))
        from scipy.interpolate import CubicSpline  # here: no command on a model without one pays scipy's import

        cs = CubicSpline(x, y, bc_type="natural", extrapolate=True)
        return OsimFunction(tag, lambda v: cs(v))
    if tag == "MultiplierFunction":
        s = el_number(el, "scale", "1")
        inner = inner_function(el, where)
        lin = None if inner.linear is None else (s * inner.linear[0], s * inner.linear[1])
        return OsimFunction(tag, lambda x: s * inner(x), linear=lin,
                         constant=None if inner.constant is None else s * inner.constant)
    raise ModelError(f"{where}: function type {tag} is not read (calibrate reads {', '.join(FUNCTION_TYPES)}); "
                     f"replace it with one of those")


def inner_function(el: ET.Element, where: str) -> OsimFunction:
    """The function held by a TransformAxis, MultiplierFunction or coupler (directly or in <function>)."""
    for child in el:
        if child.tag == "function" and len(child) and not child.get("name"):
            return osim_function(child[0], where)
        if child.tag in ("function", "coupled_coordinates_function") and len(child):
            return osim_function(child[0], where)
        if child.get("name") == "function" or child.tag in FUNCTION_TYPES:
            return osim_function(child, where)
    raise ModelError(f"{where}: no function; give it one (e.g. <LinearFunction>)")


# ---------------------------------------------------------------------- the OpenSim model
@dataclass
class OsimCoordinate:
    name: str
    joint: str
    lo: float
    hi: float
    default: float
    locked: bool
    translational: bool = False
    clamped: bool = False  # OpenSim's default: the range limits the value only where <clamped> says so

    def span(self) -> tuple[float, float]:
        """The range, limited to one turn for rotations (couplers declare +-99999)."""
        if self.translational:
            return self.lo, self.hi
        return max(self.lo, -np.pi), min(self.hi, np.pi)


@dataclass
class OsimAxis:
    motion: str  # 'rotation' | 'translation'
    axis: np.ndarray  # unit
    coord: str | None
    func: OsimFunction


@dataclass
class OsimJoint:
    name: str
    type: str
    parent: str  # body name or 'ground'
    parent_offset: Transform  # pose of F in the parent body
    child: str
    child_offset: Transform  # pose of M in the child body
    coords: list[OsimCoordinate]
    axes: list[OsimAxis]  # rotations (body-fixed, in order) then translations (in F)

    def transform(self, values: Mapping[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
        """X_FM for n coordinate sets: (R (n, 3, 3), p (n, 3)), OpenSim's SpatialTransform."""
        R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        p = np.zeros((n, 3))
        for ax in self.axes:
            x = values[ax.coord] if ax.coord is not None else np.zeros(n)
            v = np.broadcast_to(ax.func(x), (n,))
            if ax.motion == "rotation":
                R = R @ axis_rotation(ax.axis, v)
            else:
                p = p + v[:, None] * ax.axis
        return R, p


def frame_of(el: ET.Element, where: str) -> Transform:
    t = el_numbers(el, "translation", "0 0 0")
    o = el_numbers(el, "orientation", "0 0 0")
    if t.size != 3 or o.size != 3:
        raise ModelError(f"{where}: frame '{el.get('name')}' needs 3 translation and 3 orientation values")
    R = np.eye(3) if not np.any(o) else euler_matrices("XYZ", o)  # body-fixed x-y-z
    return R, t


def body_name(path: str) -> str:
    """'/bodyset/femur_r', '../bodyset/femur_r', 'femur_r', '/ground' -> body name (or 'ground')."""
    return path.strip().rstrip("/").split("/")[-1]


class OsimReader:
    """Parses the .osim document into bodies, joints, coordinates, couplers and markers."""

    def __init__(self, path: Path, text: str):
        self.path = path
        where = str(path)
        try:
            root = parse_xml(text)
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
                             f"and save it (File > Save Model) to convert it to the 4.x format{_CONVERT}")
        if version < 40000 and root.find(".//Connector_PhysicalFrame_") is not None:
            # OpenSim 4.0's pre-releases (Version 305xx: opensim-models' double_pendulum tutorial) named a joint's
            # frames by connectors and located them by location_in_parent; 4.0 itself by sockets and offset frames.
            raise ModelError(f"{where}: an OpenSim 4.0 pre-release model (Version {root.get('Version')}: its joints "
                             f"name their frames by connectors); open it in OpenSim 4 and save it (File > Save Model) "
                             f"to convert it to the 4.x format{_CONVERT}")
        m = root.find("Model")
        assert m is not None
        self.name = m.get("name", path.stem)
        try:
            # the ground's gravity: OpenSim's default (y up) where the model gives none
            self.gravity = tuple(float(v) for v in el_numbers(m, "gravity", "0 -9.80665 0", 3))
            self._read(m, where)
        except BadNumbers as e:
            raise ModelError(f"{where}: {e}; fix the number in the model file") from None

    def _read(self, m: ET.Element, where: str) -> None:
        """The model's bodies, offset frames, joints, coordinates, couplers and markers from its <Model> `m`."""
        self.bodies: dict[str, tuple[float, np.ndarray, np.ndarray]] = {}
        for b in m.findall("BodySet/objects/Body"):
            name = b.get("name", "")
            mass = el_number(b, "mass", "0")
            com = el_numbers(b, "mass_center", "0 0 0")
            iv = el_numbers(b, "inertia", "0 0 0 0 0 0")
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
        self.coords: dict[str, OsimCoordinate] = {}
        self.joints: list[OsimJoint] = []
        for jel in m.findall("JointSet/objects/*"):
            self.joints.append(self._joint(jel, m))
        self.couplers: dict[str, tuple[str, OsimFunction, float]] = {}  # dependent -> (independent, f, scale)
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
            self.couplers[dep] = (indep[0], inner_function(c, cw), el_number(c, "scale_factor", "1"))
        self.markers: dict[str, tuple[str, np.ndarray]] = {}
        for mk in m.findall("MarkerSet/objects/Marker"):
            self._marker(mk, where)

    def frame(self, ref: str, local: dict[str, ET.Element], where: str) -> tuple[str, Transform]:
        """(body, pose of the frame in the body) of a socket path."""
        ref = ref.strip()
        name = body_name(ref)
        el = local.get(name)
        if el is None and name not in self.bodies and name != "ground":
            el = self.frames.get(name)
        if el is not None:
            parent = el.findtext("socket_parent", "")
            if body_name(parent) == name:
                raise ModelError(f"{where}: frame '{ref}' is its own parent; fix its socket_parent")
            body, X = self.frame(parent, {}, where)
            return body, compose(X, frame_of(el, where))
        if name == "ground" or name in self.bodies:
            return name, identity_transform()
        raise ModelError(f"{where}: frame '{ref}' is not a body or an offset frame of the model; fix the path")

    def _joint(self, jel: ET.Element, m: ET.Element) -> OsimJoint:
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
        coords: list[OsimCoordinate] = []
        for c in jel.findall("coordinates/Coordinate"):
            rng = el_numbers(c, "range", "-3.14159 3.14159", 2)
            co = OsimCoordinate(c.get("name", ""), name, float(rng[0]), float(rng[1]),
                                el_number(c, "default_value", "0"),
                                c.findtext("locked", "false").strip().lower() == "true",
                                clamped=c.findtext("clamped", "false").strip().lower() == "true")
            if co.name in self.coords:
                raise ModelError(f"{where}: coordinate '{co.name}' is declared twice; rename one")
            self.coords[co.name] = co
            coords.append(co)
        cn = [c.name for c in coords]
        e = np.eye(3)
        lin = OsimFunction("LinearFunction", lambda x: x, linear=(1.0, 0.0))
        zero = OsimFunction("Constant", lambda x: np.zeros(np.shape(x)), linear=(0.0, 0.0), constant=0.0)
        axes: list[OsimAxis] = []
        want = {"WeldJoint": 0, "PinJoint": 1, "UniversalJoint": 2, "BallJoint": 3, "GimbalJoint": 3, "FreeJoint": 6,
                "PlanarJoint": 3, "SliderJoint": 1}
        if jel.tag in want and len(cn) != want[jel.tag]:
            raise ModelError(f"{where}: a {jel.tag} needs {want[jel.tag]} coordinates, has {len(cn)}; fix the model")
        if jel.tag == "PinJoint":
            axes = [OsimAxis("rotation", e[2], cn[0], lin)]
        elif jel.tag == "UniversalJoint":
            axes = [OsimAxis("rotation", e[0], cn[0], lin), OsimAxis("rotation", e[1], cn[1], lin)]
        elif jel.tag in ("BallJoint", "GimbalJoint"):
            axes = [OsimAxis("rotation", e[k], cn[k], lin) for k in range(3)]
        elif jel.tag == "PlanarJoint":  # rotation about z, translations along x and y of the parent frame
            axes = [OsimAxis("rotation", e[2], cn[0], lin), OsimAxis("translation", e[0], cn[1], lin),
                    OsimAxis("translation", e[1], cn[2], lin)]
            for c in coords[1:]:
                c.translational = True
        elif jel.tag == "SliderJoint":  # translation along x
            axes = [OsimAxis("translation", e[0], cn[0], lin)]
            coords[0].translational = True
        elif jel.tag == "FreeJoint":
            axes = [OsimAxis("rotation", e[k], cn[k], lin) for k in range(3)]
            axes += [OsimAxis("translation", e[k], cn[3 + k], lin) for k in range(3)]
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
                    a = el_numbers(ta, "axis", "0 0 1")
                    if a.size != 3 or np.linalg.norm(a) == 0:
                        raise ModelError(f"{aw}: axis must be 3 numbers, not all 0; fix the model")
                    names = (ta.findtext("coordinates") or "").split()
                    if len(names) > 1:
                        raise ModelError(f"{aw}: a function of {len(names)} coordinates is not read; use one")
                    if names and names[0] not in cn:
                        raise ModelError(f"{aw}: coordinate '{names[0]}' is not one of the joint's ({', '.join(cn)})")
                    has_f = any(ch.tag not in ("coordinates", "axis") for ch in ta)
                    f = inner_function(ta, aw) if has_f else (lin if names else zero)
                    axes.append(OsimAxis(motion, a / np.linalg.norm(a), names[0] if names else None, f))
                    if motion == "translation" and names:
                        tr = [x for x in axes if x.coord == names[0]]
                        if all(x.motion == "translation" for x in tr):
                            self.coords[names[0]].translational = True
        return OsimJoint(name, jel.tag, parent, X_pf, child, X_bm, coords, axes)

    def _marker(self, mk: ET.Element, where: str, source: str | None = None) -> None:
        name = mk.get("name", "")
        ref = mk.findtext("socket_parent_frame") or mk.findtext("body") or ""
        loc = el_numbers(mk, "location", "0 0 0")
        src = source or where
        body = body_name(ref)
        if loc.size != 3:
            raise ModelError(f"{src}: marker '{name}' needs 3 location values; fix the file")
        if body not in self.bodies and body != "ground" and self.frames.get(body) is None:
            raise ModelError(f"{src}: marker '{name}' is on body '{ref.strip()}', which {self.path.name} does not "
                             f"have; attach it to one of its bodies ({', '.join(list(self.bodies)[:6])}, ...)")
        body, X = self.frame(ref, {}, src)  # a marker on an offset frame: its location in the body
        self.markers[name] = (body, apply(X, loc))

    def add_marker_set(self, path: Path) -> None:
        ms = xml_element(path, "MarkerSet", "an OpenSim MarkerSet file (.xml)", "an OpenSim MarkerSet file",
                         "give an OpenSim MarkerSet file (as the Scale tool reads)")
        try:
            for mk in ms.findall("objects/Marker"):
                self._marker(mk, str(path), source=str(path))
        except BadNumbers as e:
            raise ModelError(f"{path}: {e}; fix the number in the marker set file") from None
