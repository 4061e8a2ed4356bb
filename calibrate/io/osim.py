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
gets OpenSim's names back (:func:`calibrate.io.osim_info.osim_info`).

Do not ``import opensim`` in a process that uses calibrate (see calibrate.io.osim_export).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from calibrate.io.osim_read import OsimCoordinate, OsimJoint, OsimReader, axis_rotation, urdf_rpy

from ..errors import ModelError, NoMarkersError, read_text_file
from ..model.rotations import matrix_rotvecs, rotvec_matrices
from ..seed.geometry import Transform, apply, compose, identity_transform, invert
from ..solve.lm import fit_least_squares
from .text import fmt_float, fmt_vec

GRID = 401  # coordinate values over a range at which approximations are measured


MIN_MASS = 1e-6  # kg: a massless OpenSim body is kept as a segment with this mass
FLOATING_ROOT = ("root_rz", "root_ry", "root_rx", "root_x", "root_y", "root_z")  # the export's floating root's
# coordinates (its ROOT_ROTATIONS, ROOT_TRANSLATIONS), unless the source names some (OsimInfo.root_names)
GIMBAL_MASS = 1e-3  # kg: a body between two hinges about one point lighter than this is a phantom (find_gimbals)
TOGETHER_POSES = 500  # random poses where the approximations' joint effect is measured (Together)
PROBE = "calibrate_default_pose_probe"  # the marker at the root's origin of a model read without its markers


# ---------------------------------------------------------------------- records
LEFT_OUT = "left out"  # Approximation.kind of a tree on ground that is not the subject's (a platform, a ball)
FLOATING = "floating base"  # Approximation.kind of a ground joint that is not six coordinates (a weld, a pin)
LUMPED = "lumped chain"  # Approximation.kind of a joint standing for a chain of joints coupled to its coordinates
JOINT_FIT = "joint fit"  # Approximation.kind of a joint of several rotations by splines, fitted as one joint of ratios
IN_CHAIN = "in a lumped chain"  # Approximation.kind of a coupled joint of that chain (welded; its turn lumped above)
# Approximation.kind of a joint whose rotation coupled to another joint's coordinate turns about the next joint's axis:
# moved there exactly, that joint's URDF angle its own coordinate plus the coupled turn (MoBL-ARMS's shoulder1_r2)
FOLDED = "folded"
# kinds that move no marker of the subject: no effect or bound to state (IN_CHAIN's effect is its chain's line; FOLDED
# is exact)
NO_MARKER_EFFECT = (LEFT_OUT, FLOATING, IN_CHAIN, FOLDED)


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
    kind: str  # 'hinge fit', 'welded (coupled)', 'frozen', LUMPED, JOINT_FIT, IN_CHAIN, LEFT_OUT, FLOATING
    coordinates: tuple[str, ...]  # the joint's OpenSim coordinates
    detail: str  # what was not expressible
    max_marker_mm: float
    marker: str  # the marker where max_marker_mm occurs ('' if none)
    bound_mm: float
    markers: tuple[str, ...]  # markers on the child body and below
    # a joint of several coordinates (LUMPED): the largest marker effect with one coordinate over its range at a
    # time (the others at their mid-range); max_marker_mm is over them jointly, ranges' ends together included
    one_mm: float | None = None

    def text(self) -> str:
        if self.kind in NO_MARKER_EFFECT:
            return f"{self.joint}: {self.kind} ({self.detail})"
        where = f" at {self.marker}" if self.marker else " (no marker below)"
        return (f"{self.joint}: {self.kind} ({self.detail}); largest marker effect {self.max_marker_mm:.2f} mm"
                f"{where}, bound {self.bound_mm:.2f} mm in any pose")


@dataclass(frozen=True)
class Together:
    """The import's approximations together: each marker below two or more approximated joints, OpenSim's
    kinematics against the imported model's at `poses` random poses (every coordinate uniform over its range, within
    one turn; the couplers followed), in the root body's frame."""

    max_marker_mm: float  # the largest displacement of such a marker
    marker: str  # where it occurs
    mean_mm: float  # the mean displacement over those markers and poses
    poses: int

    def text(self) -> str:
        return (f"all approximations together ({self.poses} random poses, every coordinate within its range): "
                f"largest marker effect {self.max_marker_mm:.2f} mm at {self.marker}, mean {self.mean_mm:.2f} mm "
                f"over the markers below two or more of them")


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
    # each OpenSim body's coordinates -> its segment frame (a translation when the child offset frame translates;
    # else the identity): where the source model's muscle points and wrap objects go (calibrate.io.osim_forces)
    bodies: dict[str, Transform] = field(default_factory=dict)
    body_scale: dict[str, float] = field(default_factory=dict)  # each body's scale from the source's (written models)
    # coordinate -> the URDF joint's angle per unit of OpenSim's coordinate: a lumped chain's whole turn (its
    # coordinates only; absent means 1).  The URDF, the motion CSV, `defaults` and `locked` are in the URDF's angle;
    # the .mot, the .osim export and OpenSim setups' values in OpenSim's coordinate.
    ratios: dict[str, float] = field(default_factory=dict)
    # where a marker lies below several approximated joints (MoBL-ARMS's hand: four welded shoulder-girdle joints and
    # the shoulder's hinge fit), their per-joint figures do not add up to its effect: the effect of every
    # approximation together, measured at random poses (Together); None where no marker is below two
    together: Together | None = None
    # the coordinates (DoFs) whose range OpenSim enforces (<clamped>true</clamped>; OpenSim's default is false): the
    # .osim export writes each as the source did (gait2392 clamps none of its 23, Rajagopal 37 of 39)
    clamped: tuple[str, ...] = ()
    # a floating root's coordinates the source names (FLOATING_ROOT -> the source's coordinate; _Importer.
    # source_root_names): the export and its .mot write them so
    root_names: dict[str, str] = field(default_factory=dict)
    # the source's gravity (m/s^2, in ground): OpenSim's models are y up, a model calibrate exported from a URDF z up
    gravity: tuple[float, float, float] = (0.0, -9.80665, 0.0)

    # coordinate -> its fold (a joint's coupled turn moved onto this coordinate's revolute, FOLDED): the URDF angle is
    # ratio · coordinate + mix · independent, OpenSim's coordinates on both sides
    mixes: dict[str, Mix] = field(default_factory=dict)
    # hinges the source chains about one centre through light bodies without markers (MoBL-ARMS's shoulder0, 1, 2
    # through humphant and humphant1): an angle convention for one ball, their axes no subject's to calibrate
    # (_Importer.find_gimbals; with_gimbals holds them): (coordinates, the bodies between) per chain
    gimbals: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = ()

    def ratio(self, coordinate: str) -> float:
        """The URDF angle per unit of OpenSim's `coordinate` (1 but in a lumped chain)."""
        return self.ratios.get(coordinate, 1.0)

    def urdf_angle(self, name: str, values: Mapping[str, Any]) -> Any:
        """The URDF joint `name`'s angle at OpenSim's coordinate `values` (name -> value or array)."""
        v = self.ratio(name) * np.asarray(values[name], dtype=float)
        mix = self.mixes.get(name)
        return v if mix is None else v + mix.mix * np.asarray(values[mix.independent], dtype=float)

    def coordinates(self, angles: Mapping[str, Any]) -> dict[str, Any]:
        """OpenSim's coordinates at the URDF joints' `angles` (name -> value or array; the inverse of urdf_angle)."""
        out = {n: np.asarray(a, dtype=float) / self.ratio(n) for n, a in angles.items()}
        for n, mix in self.mixes.items():
            if n in out and mix.independent in out:
                out[n] = out[n] - mix.mix * out[mix.independent] / self.ratio(n)
        return out


@dataclass(frozen=True)
class Mix:
    """A URDF joint whose angle is ratio · its coordinate + mix · independent (OsimInfo.mixes; a _Fold), and what the
    .osim export needs to write the coupled turn back: the coupled coordinate and the coordinate's own range."""

    independent: str
    mix: float
    dependent: str
    lo: float
    hi: float


# ---------------------------------------------------------------------- the import
@dataclass
class _Op:
    """One factor of a joint's transform as calibrate builds it: fixed, or a revolute of a coordinate."""

    fixed: Transform | None = None
    coord: str | None = None
    axis: np.ndarray | None = None
    ratio: float = 1.0  # the revolute's angle per unit of the coordinate (a lumped chain's whole turn)


def _line_over(f: Any, span: tuple[float, float]) -> tuple[float, float] | None:
    """(slope, intercept) where the function is a straight line over `span` (MoBL-ARMS's couplers: SimmSplines of
    two points), else None."""
    x = np.linspace(span[0], span[1], 13)
    y = np.asarray(f(x), dtype=float)
    a, b = np.polyfit(x, y, 1)
    return (float(a), float(b)) if np.max(np.abs(a * x + b - y)) <= 1e-10 * max(1.0, float(np.max(np.abs(y)))) else None


@dataclass(frozen=True)
class _Fold:
    """A rotation of joint `joint` by `dependent` = slope · `independent` + constant (a CoordinateCouplerConstraint
    on another joint's coordinate), about an axis that only constant turns separate from the first moving axis of
    the one joint below it (`child`, turning by `coordinate`): Rot(a, x) T Rot(b, q) = T Rot(b, q ± x), so the coupled
    turn rides on that revolute exactly, whose URDF angle is then ratio · q + `mix` · independent."""

    joint: str
    child: str
    dependent: str
    independent: str
    coordinate: str
    constant: float  # the coupled turn at independent = 0 (kept in `joint`, about its own axis)
    slope: float  # the coupled turn per unit of independent, about `joint`'s axis
    mix: float  # the URDF angle of `coordinate` per unit of independent (slope, signed against the revolute's axis)


def _ops_transform(ops: list[_Op], values: Mapping[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
    R = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    p = np.zeros((n, 3))
    for op in ops:
        if op.fixed is not None:
            p = p + np.einsum("nij,j->ni", R, op.fixed[1])
            R = R @ op.fixed[0]
        else:
            R = R @ axis_rotation(op.axis, op.ratio * np.asarray(values[op.coord]))  # type: ignore[arg-type,index]
    return R, p


def _then(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Batched composition a · b of poses (R (n, 3, 3) or (3, 3), p (n, 3) or (3,))."""
    return a[0] @ b[0], np.einsum("...ij,...j->...i", a[0], b[1]) + a[1]


# How an imported model is drawn in a URDF viewer (RViz, MeshCat, yourdfpy): OpenSim's bone meshes (.vtp) are not a
# URDF format, so each segment is drawn as models/human.urdf is, by primitives: a rod from its origin to each child
# joint, or where it has no child (a foot's toes, a hand, gait2392's torso with its head) the box of its inertia.
MATERIALS = ('  <material name="segment"><color rgba="0.80 0.72 0.62 1"/></material>\n'
             '  <material name="marker"><color rgba="0.95 0.95 0.20 1"/></material>')
MARKER_VISUAL = '<visual><geometry><sphere radius="0.007"/></geometry><material name="marker"/></visual>'
BONE_RADIUS = (0.08, 0.008, 0.035)  # a rod's radius: this share of its length, within these (m)
BONE_MIN = 0.02  # m: a child joint nearer the segment origin than this draws no rod
# m: an inertia box's sides within these (a plate's, gait2392's toes, drawn 1 cm thick; a light, spread-out body's box
# would fill the scene)
BOX_SIDES = (0.01, 0.8)


def bone_visuals(ends: list[np.ndarray], mass: float, com: np.ndarray, inertia: np.ndarray) -> str:
    """A segment's URDF <visual> elements: a cylinder from its frame's origin to each of `ends` (its child joints'
    places in the segment frame), or, with none of them farther than BONE_MIN, the box of uniform density with the
    segment's `mass` and `inertia` about its centre of mass `com` (the segment frame's axes), along its principal
    axes; nothing for a massless leaf."""
    out = []
    for end in ends:
        length = float(np.linalg.norm(end))
        if length < BONE_MIN:
            continue
        radius = float(np.clip(BONE_RADIUS[0] * length, *BONE_RADIUS[1:]))
        out.append(f'    <visual>\n      <origin xyz="{fmt_vec(end / 2)}" rpy="{fmt_vec(_rod_rpy(end))}"/>\n'
                   f'      <geometry><cylinder radius="{fmt_float(radius)}" length="{fmt_float(length)}"/></geometry>\n'
                   f'      <material name="segment"/>\n    </visual>\n')
    if out or mass <= 0:
        return "".join(out)
    moments, axes = np.linalg.eigh((inertia + inertia.T) / 2)
    sides = 6 * (moments.sum() - 2 * moments) / mass  # a box's I_xx = m (b² + c²) / 12 ...
    if not np.all(np.isfinite(sides)) or np.any(sides < -1e-9 * np.abs(sides).max()) or not np.any(sides > 0):
        return ""  # no box has that inertia
    axes, size = _near_identity(axes, np.clip(np.sqrt(np.maximum(sides, 0.0)), *BOX_SIDES))
    return (f'    <visual>\n      <origin xyz="{fmt_vec(com)}" rpy="{fmt_vec(urdf_rpy(axes))}"/>\n'
            f'      <geometry><box size="{fmt_vec(size)}"/></geometry>\n      <material name="segment"/>\n'
            '    </visual>\n')


def _rod_rpy(v: np.ndarray) -> np.ndarray:
    """URDF rpy turning the z axis (a cylinder's) along `v`, with pitch 0 (never the Euler angles' gimbal lock):
    Rz(yaw) Rx(roll) ez = (sin yaw sin roll, -cos yaw sin roll, cos roll)."""
    u = v / np.linalg.norm(v)
    return np.array([np.arccos(np.clip(u[2], -1.0, 1.0)), 0.0, np.arctan2(u[0], -u[1])])


def _near_identity(axes: np.ndarray, sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box's principal axes (columns) and sizes, its axes renumbered and turned to lie nearest the segment frame's
    (the same box): each frame axis takes the principal axis most along it, pointing its way, so that the rotation is
    far from the Euler angles' gimbal lock."""
    free, order = [0, 1, 2], [0, 0, 0]
    taken: set[int] = set()
    for _ in range(3):  # the largest remaining entry first
        i, k = max(((i, k) for i in range(3) if i not in taken for k in free), key=lambda ik: abs(axes[ik]))
        order[i] = k
        taken.add(i)
        free.remove(k)
    A = axes[:, order] * np.sign(np.diagonal(axes[:, order]) + 1e-300)
    if np.linalg.det(A) < 0:
        A[:, int(np.argmin(np.abs(np.diagonal(A))))] *= -1
    return A, sizes[order]


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
            out.append(_Op(coord=op.coord, axis=R.T @ op.axis, ratio=op.ratio))  # type: ignore[operator]
    return out, (np.eye(3), R.T @ tail[1])


class _Importer:
    def __init__(self, reader: OsimReader):
        self.r = reader
        self.where = str(reader.path)
        by_child: dict[str, OsimJoint] = {}
        for j in reader.joints:
            if j.child in by_child:
                raise ModelError(f"{self.where}: body '{j.child}' is the child of two joints "
                                 f"('{by_child[j.child].name}',"
                                 f" '{j.name}'); closed loops are not read; remove one joint")
            by_child[j.child] = j
        self.by_child = by_child
        grounded = [j for j in reader.joints if j.parent == "ground"]
        if not grounded:
            raise ModelError(f"{self.where}: no joint connects a body to ground; calibrate needs one (the root's, "
                             f"e.g. ground_pelvis)")
        self.left_out: list[Approximation] = []  # other trees on ground (a platform, a ball), left out of the subject
        self.root_joint = grounded[0] if len(grounded) == 1 else self._one_tree(grounded)
        self.children: dict[str, list[OsimJoint]] = {b: [] for b in reader.bodies}
        for j in reader.joints:
            if j.parent != "ground":
                if j.parent not in reader.bodies:
                    raise ModelError(f"{self.where}: joint '{j.name}' has parent '{j.parent}', not a body; fix it")
                self.children[j.parent].append(j)
        orphans = [b for b in reader.bodies if b not in by_child]
        if orphans:
            raise ModelError(f"{self.where}: body '{orphans[0]}' has no joint; connect it with a joint")
        self.order: list[OsimJoint] = []  # depth-first from the root

        def walk(body: str) -> None:
            for j in self.children[body]:
                self.order.append(j)
                walk(j.child)
        walk(self.root_joint.child)
        if len(self.order) + 1 != len(reader.joints):
            raise ModelError(f"{self.where}: some joints are not connected to the root body; fix the tree")

    def _one_tree(self, grounded: list[OsimJoint]) -> OsimJoint:
        """The subject's tree when several joints connect bodies to ground (a landing platform, a ball, a
        goal-keeper beside the subject): the tree that carries the markers (without markers, the largest).
        The others' bodies, joints and coordinates are taken out of the reader and named in `left_out`."""
        r = self.r
        below: dict[str, list[OsimJoint]] = {}
        for j in r.joints:
            below.setdefault(j.parent, []).append(j)

        def tree(body: str) -> list[str]:
            out = [body]
            for j in below.get(body, []):
                out += tree(j.child)
            return out

        trees = {j.name: tree(j.child) for j in grounded}
        marked = {j.name: [m for m, (b, _) in r.markers.items() if b in trees[j.name]] for j in grounded}
        with_markers = [j for j in grounded if marked[j.name]]
        if len(with_markers) > 1:
            which = ", ".join(f"{j.name}: {len(marked[j.name])}" for j in with_markers)
            raise ModelError(f"{self.where}: markers on {len(with_markers)} separate trees on ground ({which} "
                             f"markers); calibrate fits one subject: remove the other trees' markers from the model or "
                             f"marker set")
        root = with_markers[0] if with_markers else max(grounded, key=lambda j: len(trees[j.name]))
        gone: set[str] = set()
        for j in grounded:
            if j is root:
                continue
            bodies = trees[j.name]
            gone.update(bodies)
            coords = tuple(c.name for k in r.joints if k.child in bodies for c in k.coords)
            self.left_out.append(Approximation(
                j.name, LEFT_OUT, coords, f"a second tree on ground, no marker on it: {', '.join(bodies)}; not in "
                f"the subject nor in its .osim export", 0.0, "", 0.0, ()))
        r.joints = [j for j in r.joints if j.child not in gone]
        r.bodies = {b: v for b, v in r.bodies.items() if b not in gone}
        kept = {c.name for j in r.joints for c in j.coords}
        r.coords = {n: c for n, c in r.coords.items() if n in kept}
        r.couplers = {d: v for d, v in r.couplers.items() if d in kept and v[0] in kept}
        return root

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
    def free_rotations(self, j: OsimJoint) -> list[OsimCoordinate]:
        """The joint's rotational coordinates that are not coupled to others."""
        return [c for c in j.coords if c.name not in self.r.couplers and not c.translational]

    def exactness(self, j: OsimJoint) -> tuple[bool, list[str]]:
        """Whether the joint is a product of constant transforms and rotations of a·coordinate + b, each coordinate
        in one (no coupled coordinate; a ≠ ±1 is the coordinate's ratio), and what is not, one phrase per axis."""
        used: set[str] = set()
        coupled = [c.name for c in j.coords if c.name in self.r.couplers]
        exact = not coupled
        # a coupled coordinate's axis follows another coordinate, which may be another joint's (MoBL-ARMS's
        # shoulder1_r2 = -elv_angle): named, so that the detail never starts empty
        why: list[str] = [f"{c} follows {self.r.couplers[c][0]} (CoordinateCouplerConstraint)" for c in coupled
                          if self.r.couplers[c][0] not in {x.name for x in j.coords}]
        for ax in j.axes:
            if ax.coord is None or ax.func.constant is not None:
                continue
            if ax.motion == "translation":
                exact = False
                why.append(f"translation along {fmt_vec(np.round(ax.axis, 3))} is a {ax.func.kind} of {ax.coord}")
            elif ax.func.linear is None or abs(ax.func.linear[0]) < 1e-12 or ax.coord in used:
                exact = False
                why.append(f"rotation about {fmt_vec(np.round(ax.axis, 3))} is a {ax.func.kind} of {ax.coord}")
            used.add(ax.coord)
        return exact, why

    def joint_ops(self, j: OsimJoint) -> tuple[list[_Op], tuple[str, str] | None]:
        """Ops of the imported joint and, if approximated, (kind, detail)."""
        free = self.free_rotations(j)
        exact, why = self.exactness(j)
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

    # -------------------------------------------------------------- folds
    def find_folds(self, skip: set[str]) -> dict[str, _Fold]:
        """The joint below -> its fold (_Fold), for each joint (not in `skip`) of free linear rotations and one rotation
        by a coordinate coupled linearly to another joint's free coordinate, where only constant turns separate that
        rotation from the first moving axis of the single joint below it, about the same line: MoBL-ARMS's shoulder1
        turns by shoulder_elv and by shoulder1_r2 = -elv_angle about the axis shoulder2 then turns by shoulder_rot.
        The child body must carry no markers, and the coordinate below be free where the coupled one is (a locked
        coordinate's URDF angle is one value in every frame)."""
        r = self.r
        joint_of = {c.name: j for j in self.order for c in j.coords}
        out: dict[str, _Fold] = {}
        for j in self.order:
            coupled = [c for c in j.coords if c.name in r.couplers]
            if j.name in skip or len(coupled) != 1 or any(c.translational for c in j.coords):
                continue
            dep = coupled[0].name
            ind, f, s = r.couplers[dep]
            home = joint_of.get(ind)
            line = f.linear if f.linear is not None or ind not in r.coords else _line_over(f, r.coords[ind].span())
            if (line is None or home is None or home is j or ind in r.couplers or home.name in skip
                    or not self.exactness(home)[0] or r.coords[ind].translational):
                continue
            rots = [ax for ax in j.axes if ax.motion == "rotation"]
            at = [i for i, ax in enumerate(rots) if ax.coord == dep]
            if len(at) != 1 or rots[at[0]].func.linear is None or any(
                    ax.coord is not None and ax.func.constant is None for ax in rots[at[0] + 1:]):
                continue
            if any(ax.motion == "translation" and ax.coord is not None and ax.func.constant is None for ax in j.axes):
                continue
            others = [ax for ax in rots if ax.coord not in (None, dep) and ax.func.constant is None]
            if any(ax.func.linear is None or ax.coord in r.couplers for ax in others) or len(
                    {ax.coord for ax in others}) != len(others):
                continue
            kids = self.children[j.child]
            if len(kids) != 1 or any(b == j.child for b, _ in r.markers.values()):
                continue
            k = kids[0]
            if k.name in skip or not self.exactness(k)[0] or any(
                    c.translational and c.name not in r.couplers for c in k.coords):
                continue
            # T: what lies between the coupled rotation and k's first moving one (all constant)
            T = identity_transform()
            for ax in rots[at[0] + 1:]:
                x = self.ref_value(ax.coord) if ax.coord is not None else 0.0
                T = compose(T, (axis_rotation(ax.axis, float(ax.func(np.array(x)))), np.zeros(3)))
            T = compose(compose(T, invert(j.child_offset)), k.parent_offset)
            pk = np.zeros(3)
            for ax in k.axes:
                if ax.motion == "translation":
                    pk = pk + float(ax.func(np.array(self.ref_value(ax.coord) if ax.coord else 0.0))) * ax.axis
            T = compose(T, (np.eye(3), pk))
            first = None
            for ax in k.axes:
                if ax.motion != "rotation":
                    continue
                if ax.coord is not None and ax.func.constant is None:
                    first = ax
                    break
                T = compose(T, (axis_rotation(ax.axis, float(ax.func(np.array(0.0)))), np.zeros(3)))
            if first is None or first.func.linear is None or np.linalg.norm(T[1]) > 1e-9:
                continue
            q = r.coords[first.coord]  # type: ignore[index]
            if q.locked and not r.coords[ind].locked:
                continue
            there = T[0].T @ rots[at[0]].axis  # the coupled axis in k's frame, before its first moving rotation
            along = float(there @ first.axis)
            if abs(abs(along) - 1.0) > 1e-9:
                continue
            a1, b1 = rots[at[0]].func.linear
            kf, bf = line
            slope, constant = a1 * s * kf, a1 * s * bf + b1
            constant = 0.0 if abs(constant) < 1e-12 else constant
            # k's revolute turns about sign(its slope) · its axis (_exact_ops)
            sign = np.sign(along) * np.sign(first.func.linear[0])
            out[k.name] = _Fold(j.name, k.name, dep, ind, q.name, constant, slope, float(sign * slope))
        return out

    # -------------------------------------------------------------- gimbals
    def find_gimbals(self, ops_of: Mapping[str, list[_Op]]) -> tuple[tuple[tuple[str, ...], tuple[str, ...]], ...]:
        """Chains of joints that turn about one point through bodies lighter than GIMBAL_MASS without markers, each
        body between with that one joint below it: (their coordinates, the bodies between) per chain of two or
        more.  Every translation from the chain's first revolute to its last is zero, so the chain is one ball
        written as a sequence of hinges (MoBL-ARMS's shoulder: elv_angle, shoulder_elv, shoulder_rot through
        humphant and humphant1).  `ops_of`: each joint's ops as the import built them."""
        r = self.r
        marked = {b for b, _ in r.markers.values()}

        def inner(ops: list[_Op], first: bool) -> bool:
            """No translation between the revolutes of `ops` (from its first revolute on, or up to its last)."""
            at = [i for i, op in enumerate(ops) if op.coord is not None]
            part = (ops[at[0]:] if first else ops[at[0]:at[-1]]) if at else []
            return bool(at) and all(op.fixed is None or np.linalg.norm(op.fixed[1]) < 1e-9 for op in part)

        def light(body: str) -> bool:
            return (body not in marked and r.bodies[body][0] < GIMBAL_MASS and len(self.children[body]) == 1)

        out = []
        seen: set[str] = set()
        for j in self.order:
            if j.name in seen or j.name not in ops_of or not inner(ops_of[j.name], True):
                continue
            chain, bodies = [j], []
            while light(chain[-1].child) and inner(ops_of[chain[-1].name], True):
                k = self.children[chain[-1].child][0]
                gap = compose(invert(chain[-1].child_offset), k.parent_offset)
                ops_k = ops_of.get(k.name, [])
                head = [i for i, op in enumerate(ops_k) if op.coord is not None]
                if (not head or np.linalg.norm(gap[1]) > 1e-9 or not inner(ops_k, False)
                        or any(op.fixed is not None and np.linalg.norm(op.fixed[1]) > 1e-9
                               for op in ops_k[:head[0]])):
                    break
                bodies.append(chain[-1].child)
                chain.append(k)
            if len(chain) >= 2:
                seen.update(k.name for k in chain)
                coords = tuple(op.coord for k in chain for op in ops_of[k.name] if op.coord is not None)
                out.append((coords, tuple(bodies)))  # type: ignore[arg-type]
        return tuple(out)

    # -------------------------------------------------------------- lumped chains
    def lumpable(self, j: OsimJoint) -> bool:
        """Whether a joint can be one joint of fitted axes, centre and ratios: each of its free rotations drives one
        rotation axis of it (by any function), and none of its free coordinates translates."""
        free = self.free_rotations(j)
        if not free or any(c.translational and c.name not in self.r.couplers for c in j.coords):
            return False
        for c in free:
            moving = [ax for ax in j.axes if ax.coord == c.name and ax.func.constant is None]
            if len(moving) != 1 or moving[0].motion != "rotation":
                return False
        return True

    def find_chains(self) -> dict[str, list[OsimJoint]]:
        """Joints made one fitted joint: the driving joint's name -> the joints below it whose every coordinate
        follows its own through CoordinateCouplerConstraints, top down (a lumbar spine whose vertebrae follow
        L5/S1's coordinates: Pose2Sim's, Christophy's and the lifting models; a neck's, Mortensen's).  The chain
        runs while exactly one joint below the body it has reached follows the driving joint and no other branch
        from that body carries markers; it ends at a body with markers on it or below.  A joint of several
        rotations that are not ±coordinate + constant (splines of its coordinates) is fitted alone (an empty
        chain), where the import froze those rotations before."""
        chains: dict[str, list[OsimJoint]] = {}
        for j in self.order:
            if not self.lumpable(j):
                continue
            free = {c.name for c in self.free_rotations(j)}
            chain: list[OsimJoint] = []
            body = j.child
            while True:
                nxt = [k for k in self.children[body] if k.coords and all(
                    c.name in self.r.couplers and self.r.couplers[c.name][0] in free for c in k.coords)]
                others = [k for k in self.children[body] if k not in nxt]
                if len(nxt) != 1 or any(self.has_markers_below(k.child) for k in others):
                    break
                chain.append(nxt[0])
                body = nxt[0].child
            if chain and self.has_markers_below(body):
                chains[j.name] = chain
            elif len(free) >= 2 and not self.exactness(j)[0]:
                chains[j.name] = []
        return chains

    def chain_weld(self, k: OsimJoint) -> Transform:
        """A coupled joint of a lumped chain welded at its default pose (the couplers followed from the defaults):
        at the model's default pose the chain's bodies then sit as OpenSim's do (its muscles' lengths there are
        the source's), and the lumped joint turns them all with the chain's last body."""
        R, p = k.transform({c.name: np.array([self.defaults[c.name]]) for c in k.coords}, 1)
        return R[0], p[0]

    def _chain_poses(self, j: OsimJoint, chain: list[OsimJoint], values: Mapping[str, np.ndarray],
                     n: int) -> list[tuple[np.ndarray, np.ndarray]]:
        """Each body of the chain (the driving joint's child, then each coupled joint's) in the driving joint's
        parent offset frame F, by OpenSim's kinematics, for n sets of the driving joint's free rotations
        (`values`; its other coordinates at their reference, the couplers followed)."""
        vals = {c.name: np.full(n, self.ref_value(c.name)) for c in j.coords}
        vals.update({k: np.broadcast_to(np.asarray(v, float), (n,)) for k, v in values.items()})
        for k in chain:
            for c in k.coords:
                ind, f, s = self.r.couplers[c.name]
                vals[c.name] = s * f(vals[ind])
        X = _then(j.transform(vals, n), invert(j.child_offset))
        out = [X]
        for k in chain:
            X = _then(_then(_then(X, k.parent_offset), k.transform(vals, n)), invert(k.child_offset))
            out.append(X)
        return out

    def _chain_rests(self, j: OsimJoint, chain: list[OsimJoint]) -> list[Transform]:
        """Each body of the chain in the driving joint's M frame, each coupled joint welded (chain_weld)."""
        X = invert(j.child_offset)
        out = [X]
        for k in chain:
            X = compose(compose(compose(X, k.parent_offset), self.chain_weld(k)), invert(k.child_offset))
            out.append(X)
        return out

    def _chain_points(self, j: OsimJoint, chain: list[OsimJoint]) -> list[dict[str, np.ndarray]]:
        """Per body of the chain, the points that ride on it in its frame: the markers of the bodies the chain
        passes, and on its last body every marker and joint origin on it or below (points_below)."""
        bodies = [j.child] + [k.child for k in chain]
        out = [{m: loc for m, (b, loc) in self.r.markers.items() if b == body} for body in bodies[:-1]]
        return out + [self.points_below(bodies[-1])]

    def _chain_grid(self, j: OsimJoint, total: int, part: float = 1.0) -> tuple[dict[str, np.ndarray], int]:
        """The driving joint's free rotations on a joint grid of about `total` points over the middle `part` of
        their ranges (corners included)."""
        free = self.free_rotations(j)
        k = max(3, int(round(total ** (1 / len(free)))))
        spans = [c.span() for c in free]
        grid = np.meshgrid(*[np.linspace(0.5 * (lo + hi) - 0.5 * part * (hi - lo),
                                         0.5 * (lo + hi) + 0.5 * part * (hi - lo), k) for lo, hi in spans],
                           indexing="ij")
        return {c.name: g.ravel() for c, g in zip(free, grid, strict=True)}, grid[0].size

    def _chain_sweeps(self, j: OsimJoint, k: int = 41) -> tuple[dict[str, np.ndarray], int]:
        """Each free rotation of the driving joint over its range, the others at their reference."""
        free = self.free_rotations(j)
        vals = {c.name: np.concatenate([np.linspace(*c.span(), k) if d is c else np.full(k, self.ref_value(c.name))
                                        for d in free]) for c in free}
        return vals, k * len(free)

    def _lumped_start(self, j: OsimJoint) -> list[_Op]:
        """The driving joint as fixed parts and one revolute (ratio 1) per free rotation along its axis, every
        other function at its reference: where the fit starts."""
        free = {c.name for c in self.free_rotations(j)}
        p = np.zeros(3)
        for ax in j.axes:
            if ax.motion == "translation":
                p = p + float(ax.func(np.array(self.ref_value(ax.coord) if ax.coord is not None else 0.0))) * ax.axis
        ops = [_Op(fixed=(np.eye(3), p))]
        used: set[str] = set()
        for ax in j.axes:
            if ax.motion != "rotation":
                continue
            if ax.coord in free and ax.coord not in used and ax.func.constant is None:
                ops.append(_Op(coord=ax.coord, axis=ax.axis))
                used.add(ax.coord)  # type: ignore[arg-type]
            else:
                x = self.ref_value(ax.coord) if ax.coord is not None else 0.0
                ops.append(_Op(fixed=(axis_rotation(ax.axis, float(ax.func(np.array(x)))), np.zeros(3))))
        return ops

    def lumped_fit(self, j: OsimJoint, chain: list[OsimJoint]) -> list[_Op]:
        """Trans(centre) Rot(a1, g1 q1) Rot(a2, g2 q2) ... Y from F to the driving joint's M frame, fitted to
        the points riding on the chain (_chain_points, and a 10 cm cross on its last body) over the coordinates'
        ranges, jointly: axes, centre, Y and each coordinate's ratio g (the chain's whole turn per unit of the
        coordinate) free."""
        rests = self._chain_rests(j, chain)
        points = self._chain_points(j, chain)
        points[-1] = {**points[-1], **{f"cross {k}": x for k, x in
                                        enumerate(s * e for e in np.eye(3) * 0.1 for s in (1, -1))}}
        body_pts = [np.array(list(pts.values())).reshape(-1, 3) for pts in points]
        pts = np.concatenate([np.array([apply(X, x) for x in b]).reshape(-1, 3) for X, b in zip(rests, body_pts,
                                                                                                 strict=True)])
        # Fitted to each coordinate's sweep and a grid over the middle half of the ranges: where several
        # coordinates are large at once, a chain of small turns is not one sequence of three (Euler's order
        # matters), and no fixed joint fits the corners of the ranges well (measure_lumped reports them).
        (sw, ns), (gr, ng) = self._chain_sweeps(j, 15), self._chain_grid(j, 64, 0.5)  # 0.2 s; 4x more: the same
        vals, n = {c: np.concatenate([sw[c], gr[c]]) for c in sw}, ns + ng
        poses = self._chain_poses(j, chain, vals, n)
        target = np.concatenate([np.einsum("nij,kj->nki", R, b) + p[:, None, :]
                                 for (R, p), b in zip(poses, body_pts, strict=True)], axis=1)
        # The start: the driving joint's own axes, constant rotations pushed to the end (C Rot(a) = Rot(Ca) C),
        # each ratio the chain's turn per unit of its coordinate at mid-range.
        centre = np.zeros(3)
        C = np.eye(3)
        revs: list[tuple[str, np.ndarray]] = []
        for op in self._lumped_start(j):
            if op.fixed is not None:
                centre = centre + C @ op.fixed[1]
                C = C @ op.fixed[0]
            else:
                revs.append((op.coord, C @ op.axis))  # type: ignore[arg-type,operator]
        ref = {c: np.array([self.ref_value(c)]) for c, _ in revs}
        prefix = np.eye(3)
        x0: list[float] = []
        for c, a in revs:
            lo, hi = ({**ref, c: ref[c] + d} for d in (-1e-3, 1e-3))
            w = matrix_rotvecs(self._chain_poses(j, chain, hi, 1)[-1][0][0]
                               @ self._chain_poses(j, chain, lo, 1)[-1][0][0].T) / 2e-3
            g = float(np.linalg.norm(w)) * (1.0 if w @ (prefix @ a) >= 0 else -1.0)
            x0 += [*a, g if abs(g) > 1e-3 else 1.0]
            prefix = prefix @ axis_rotation(a, np.array(ref[c][0]))
        Rr, pr = self._chain_poses(j, chain, ref, 1)[-1]
        head = [_Op(fixed=(np.eye(3), centre))] + [_Op(coord=c, axis=np.array(x0[4 * i:4 * i + 3]),
                                                       ratio=x0[4 * i + 3]) for i, (c, _) in enumerate(revs)]
        Rh, ph = _ops_transform(head, ref, 1)
        Y0 = compose(invert((Rh[0], ph[0])), compose((Rr[0], pr[0]), invert(rests[-1])))
        x0 += [*centre, *matrix_rotvecs(Y0[0]), *Y0[1]]
        m = len(revs)

        def ops_of(x: np.ndarray) -> list[_Op]:
            out = [_Op(fixed=(np.eye(3), x[4 * m:4 * m + 3]))]
            for i, (c, _) in enumerate(revs):
                a = x[4 * i:4 * i + 3]
                out.append(_Op(coord=c, axis=a / np.linalg.norm(a), ratio=float(x[4 * i + 3])))
            Y = (rotvec_matrices(x[4 * m + 3:4 * m + 6]), x[4 * m + 6:4 * m + 9])
            return out + [_Op(fixed=Y)]

        def residual(x: np.ndarray) -> np.ndarray:
            Ra, pa = _ops_transform(ops_of(x), vals, n)
            return (np.einsum("nij,kj->nki", Ra, pts) + pa[:, None, :] - target).ravel()

        axes0 = np.array([a for _, a in revs])
        if np.allclose(axes0 @ axes0.T, np.eye(m), atol=1e-9):
            # Orthonormal axes (a ball's, a universal joint's) stay orthonormal: one turn of them all is fitted, so
            # that the joint is still a ball the solver keeps on SO(3) (kinematics.so3_balls), with no limits.
            x0a = np.array(x0)
            rest = np.r_[[x0a[4 * i + 3] for i in range(m)], x0a[4 * m:]]

            def full(y: np.ndarray) -> np.ndarray:
                Rw = rotvec_matrices(y[:3])
                axes = [Rw @ a for a in axes0]
                return np.concatenate([np.r_[axes[i], y[3 + i]] for i in range(m)] + [y[3 + m:]])

            y, _ = fit_least_squares(lambda y: residual(full(y)), np.r_[np.zeros(3), rest], ftol=1e-10, xtol=1e-10)
            ops = ops_of(full(y))
        else:
            ops = ops_of(fit_least_squares(residual, np.array(x0), ftol=1e-10, xtol=1e-10)[0])
        for op in ops:  # Rot(a, g q) = Rot(-a, -g q): every ratio positive
            if op.coord is not None and op.ratio < 0:
                op.axis, op.ratio = -op.axis, -op.ratio  # type: ignore[operator]
        return ops

    def measure_lumped(self, j: OsimJoint, chain: list[OsimJoint], ops: list[_Op]) -> Approximation:
        """Largest marker effect of a lumped chain (or a fitted joint) over its coordinates' ranges (jointly,
        and one coordinate at a time), and the bound."""
        rests = self._chain_rests(j, chain)
        markers = [{k: v for k, v in pts.items() if not k.startswith("joint ")} for pts in self._chain_points(j, chain)]
        names = [m for pts in markers for m in pts]
        end = chain[-1].child if chain else j.child

        def errors(vals: dict[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
            """(n, markers) distances and (n,) the any-pose bound of each sample."""
            A = _ops_transform(ops, vals, n)
            err, bound = [], np.zeros(n)
            for i, ((R, p), X, pts) in enumerate(zip(self._chain_poses(j, chain, vals, n), rests, markers,
                                                   strict=True)):
                Ra, pa = _then(A, X)
                w = np.array(list(pts.values())).reshape(-1, 3)
                err.append(np.linalg.norm(np.einsum("nij,kj->nki", R - Ra, w) + (p - pa)[:, None, :], axis=2))
                reach = self.reach(end, np.zeros(3)) if i == len(rests) - 1 else float(
                    np.linalg.norm(w, axis=1).max(initial=0.0))
                bound = np.maximum(bound, np.linalg.norm(R - Ra, ord=2, axis=(1, 2)) * reach
                                   + np.linalg.norm(p - pa, axis=1))
            return np.concatenate(err, axis=1), bound

        err, bound = errors(*self._chain_grid(j, 4000))
        worst, worst_marker = 0.0, ""
        if names:
            k = np.unravel_index(np.argmax(err), err.shape)
            worst, worst_marker = float(err[k]), names[k[1]]
        one = float(errors(*self._chain_sweeps(j))[0].max()) if names else 0.0
        turns = ", ".join(f"{op.ratio:.3g} × {op.coord}" for op in ops if op.coord is not None)
        tail = (f"about a fitted centre: the URDF's angles and the motion CSV's are that turn, the .mot's and the "
                f".osim export's OpenSim's coordinates; one coordinate at a time up to {1000 * one:.1f} mm, the "
                f"largest where several are near their range's ends at once")
        if chain:
            kind = LUMPED
            passed = [b for b, pts in zip([j.child] + [k.child for k in chain[:-1]], markers, strict=False) if pts]
            carried = f" (the markers on {', '.join(passed)} carried with them)" if passed else ""
            detail = (f"{', '.join(k.name for k in chain)} follow its coordinates (CoordinateCouplerConstraint), "
                      f"welded at their default pose{carried}; one joint turns {end} by the chain's whole turn "
                      f"({turns}) {tail}")
        else:
            kind = JOINT_FIT
            detail = (f"{'; '.join(self.exactness(j)[1])}; one joint turning {end} by a fitted ratio of each "
                      f"coordinate ({turns}) {tail}")
        return Approximation(j.name, kind, tuple(c.name for c in j.coords), detail, 1000 * worst, worst_marker,
                             1000 * float(bound.max()), tuple(names), 1000 * one)

    def _exact_ops(self, j: OsimJoint, frozen: set[str], freeze_nonlinear: bool = False,
                   folded: Mapping[str, float] | None = None) -> list[_Op]:
        """The joint as fixed parts and revolutes (a·q + b: a constant turn b, then a revolute of ratio |a|);
        `folded`: coupled coordinates whose turn rides on the joint below (_Fold) -> the constant turn kept here."""
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
            if folded is not None and ax.coord in folded:
                ops.append(_Op(fixed=(axis_rotation(ax.axis, folded[ax.coord]), np.zeros(3))))
                continue
            lin = ax.func.linear
            moving = (ax.coord is not None and ax.func.constant is None and ax.coord not in frozen
                      and ax.coord not in used and lin is not None and abs(lin[0]) >= 1e-12)
            if moving:  # a·q + b: a revolute of ratio |a| (the URDF's angle |a| q) after a constant turn b
                ops.append(_Op(fixed=(axis_rotation(ax.axis, lin[1]), np.zeros(3))))  # type: ignore[index]
                ops.append(_Op(coord=ax.coord, axis=np.sign(lin[0]) * ax.axis,  # type: ignore[index]
                               ratio=abs(float(lin[0]))))  # type: ignore[index]
                used.add(ax.coord)  # type: ignore[arg-type]
            else:
                x = self.ref_value(ax.coord) if ax.coord is not None else 0.0
                ops.append(_Op(fixed=(axis_rotation(ax.axis, float(ax.func(np.array(x)))), np.zeros(3))))
        return ops

    def _hinge_fit(self, j: OsimJoint, c: OsimCoordinate) -> list[_Op]:
        """Trans(centre) Rot(axis, q) Y, fitted to the child's points over the coordinate's range."""
        lo, hi = c.span()
        q = np.linspace(lo, hi, 61)
        values = self._joint_values(j, c.name, q)
        R, p = j.transform(values, q.size)
        pts = self._fit_points(j)
        target = np.einsum("nij,kj->nki", R, pts) + p[:, None, :]
        # initial guess: the screw axis between the range's ends
        Rr = R[-1] @ R[0].T
        rv = matrix_rotvecs(Rr)
        if np.linalg.norm(rv) > 1e-6:
            a0 = rv / np.linalg.norm(rv) * np.sign(hi - lo)
        else:
            a0 = next((ax.axis for ax in j.axes if ax.motion == "rotation" and ax.coord == c.name), np.eye(3)[2])
        tr = p[-1] - Rr @ p[0]
        c0 = np.linalg.lstsq(np.eye(3) - Rr, tr - (a0 @ tr) * a0, rcond=None)[0]
        mid = q.size // 2
        Ym = compose((axis_rotation(a0, -q[mid]), np.zeros(3)), compose((np.eye(3), -c0), (R[mid], p[mid])))
        x0 = np.concatenate([a0, c0, matrix_rotvecs(Ym[0]), Ym[1]])

        def model(x: np.ndarray) -> np.ndarray:
            a = x[:3] / np.linalg.norm(x[:3])
            RY = rotvec_matrices(x[6:9])
            Rq = axis_rotation(a, q)
            RR = Rq @ RY
            pp = np.einsum("nij,j->ni", Rq, x[9:12]) + x[3:6]
            return np.einsum("nij,kj->nki", RR, pts) + pp[:, None, :]

        # Deterministic: MINPACK's Levenberg-Marquardt (scipy's) came out 1e-13 apart from process to process
        # (tests/test_osim_import.py), and every calibration on the model 1e-6 apart.
        x, _ = fit_least_squares(lambda x: (model(x) - target).ravel(), x0, ftol=1e-14, xtol=1e-14)
        a = x[:3] / np.linalg.norm(x[:3])
        cen = x[3:6]
        Y = (rotvec_matrices(x[6:9]), x[9:12].copy())
        # the centre: the point of the axis nearest the child frame's origin at mid-range
        shift = float(a @ (p[mid] - cen))
        cen = cen + shift * a
        Y = (Y[0], Y[1] - shift * a)
        return [_Op(fixed=(np.eye(3), cen)), _Op(coord=c.name, axis=a), _Op(fixed=Y)]

    def _joint_values(self, j: OsimJoint, name: str, q: np.ndarray) -> dict[str, np.ndarray]:
        """Every coordinate of joint j when `name` takes the values q (couplers followed, others at reference)."""
        vals = {c.name: np.full(q.shape, self.ref_value(c.name)) for c in j.coords}
        vals[name] = q
        for c in j.coords:
            if c.name in self.r.couplers:
                ind, f, s = self.r.couplers[c.name]
                if ind == name:
                    vals[c.name] = s * f(q)
        return vals

    def _fit_points(self, j: OsimJoint) -> np.ndarray:
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

    def max_translation(self, j: OsimJoint) -> float:
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

    def measure(self, j: OsimJoint, ops: list[_Op], kind: str, detail: str) -> Approximation:
        """Largest marker effect over the range (defaults elsewhere) and the any-pose bound."""
        pts = self.points_below(j.child)
        markers = {k: v for k, v in pts.items() if not k.startswith("joint ")}
        inv = invert(j.child_offset)
        w = np.array([apply(inv, x) for x in markers.values()]).reshape(-1, 3)
        names = list(markers)
        # The joint's free coordinates and those its coupled ones follow: a coupled coordinate of another joint's
        # (MoBL-ARMS's shoulder1_r2 = -elv_angle, shoulder0's) turns this joint over that coordinate's range, which
        # the approximation holds at its reference (measured with the free coordinate alone: 0 mm, not 182 at the hand).
        own = {c.name for c in j.coords}
        drivers = [c for c in j.coords if c.name not in self.r.couplers]
        for c in j.coords:
            ind = self.r.couplers[c.name][0] if c.name in self.r.couplers else None
            if ind is not None and ind not in own and all(d.name != ind for d in drivers):
                drivers.append(self.r.coords[ind])
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
    def build(self, need_markers: bool = True) -> tuple[str, OsimInfo]:
        """The URDF text and its OsimInfo; `need_markers` False: a model without markers is read too, with one
        marker (PROBE) at the root segment's origin, for a calibrate model's sake (its kinematics only, e.g. the
        source model's muscle lengths at export, calibrate.io.osim_forces; `calibrate inspect`)."""
        r = self.r
        self.defaults = self.default_values()
        seg_X: dict[str, Transform] = {self.root_joint.child: identity_transform()}  # body coords -> segment frame
        links: list[str] = []
        joints: list[str] = []
        approximations: list[Approximation] = list(self.left_out)
        dropped: list[str] = [c for a in self.left_out for c in a.coordinates]
        dofs: list[str] = []
        urdf_names: set[str] = set()

        def origin(X: Transform) -> str:
            return f'<origin xyz="{fmt_vec(X[1])}" rpy="{fmt_vec(urdf_rpy(X[0]))}"/>'

        def add_joint(name: str, kind: str, parent: str, child: str, X: Transform, extra: str = "",
                      anatomical: str | None = None) -> None:
            if name in urdf_names:
                raise ModelError(f"{self.where}: the name '{name}' is used by two coordinates, joints or markers; "
                                 f"rename one")
            urdf_names.add(name)
            att = f' anatomical="{anatomical}"' if anatomical else ""
            joints.append(f'  <joint name="{name}" type="{kind}"{att}>\n    <parent link="{parent}"/>\n'
                          f'    <child link="{child}"/>\n    {origin(X)}{extra}\n  </joint>')

        chains = self.find_chains()
        head_of = {k.name: j for j, ks in chains.items() for k in ks}
        folds = self.find_folds(set(chains) | set(head_of))
        folded_from = {f.joint: f for f in folds.values()}
        mixes: dict[str, Mix] = {}
        ops_of: dict[str, list[_Op]] = {}  # each joint's ops as built (find_gimbals reads them)
        ratios: dict[str, float] = {}
        ends: dict[str, list[np.ndarray]] = {b: [] for b in r.bodies}  # each child joint's place in the segment frame
        for j in self.order:
            if j.name in chains:
                ops = self.lumped_fit(j, chains[j.name])
                approximations.append(self.measure_lumped(j, chains[j.name], ops))
                ratios.update({op.coord: op.ratio for op in ops if op.coord is not None})  # type: ignore[misc]
            elif j.name in head_of:
                ops = [_Op(fixed=self.chain_weld(j))]
                vals = ", ".join(f"{c.name} = {self.defaults[c.name]:.4g}" for c in j.coords)
                approximations.append(Approximation(
                    j.name, IN_CHAIN, tuple(c.name for c in j.coords), f"welded at {vals} (its default pose); "
                    f"{head_of[j.name]}'s lumped joint turns the chain", 0.0, "", 0.0, ()))
            elif j.name in folded_from:
                f = folded_from[j.name]
                ops = self._exact_ops(j, set(), folded={f.dependent: f.constant})
                approximations.append(Approximation(
                    j.name, FOLDED, tuple(c.name for c in j.coords),
                    f"{f.dependent} (= {f.slope:.4g} × {f.independent}"
                    + (f" {'+' if f.constant >= 0 else '-'} {abs(f.constant):.4g}" if f.constant else "")
                    + f") turns about the axis {f.child}'s {f.coordinate} turns about next: moved there, exactly; "
                    f"the URDF's {f.coordinate} and the motion CSV's are {f.coordinate} "
                    f"{'+' if f.mix >= 0 else '-'} {abs(f.mix):.4g} × {f.independent}, the .mot's and the .osim "
                    f"export's OpenSim's coordinates", 0.0, "", 0.0, ()))
            else:
                ops, approx = self.joint_ops(j)
                if approx is not None:
                    approximations.append(self.measure(j, ops, *approx))
                # a rotation of a·coordinate + b (Christophy's spine: L5/S1 turns by a share of the lumbar coordinates)
                ratios.update({op.coord: op.ratio for op in ops if op.coord is not None and op.ratio != 1.0})
            revs = [op for op in ops if op.coord is not None]
            ops_of[j.name] = list(ops)
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
                lo, hi = op.ratio * c.lo, op.ratio * c.hi
                fold = folds.get(j.name)
                if fold is not None and fold.coordinate == op.coord:  # the angle carries the coupled turn too
                    ind = r.coords[fold.independent]
                    lo, hi = lo + min(fold.mix * ind.lo, fold.mix * ind.hi), hi + max(fold.mix * ind.lo,
                                                                                     fold.mix * ind.hi)
                    mixes[op.coord] = Mix(fold.independent, fold.mix, fold.dependent, c.lo, c.hi)  # type: ignore[index]
                lim = f'\n    <axis xyz="{fmt_vec(op.axis)}"/>\n    <limit lower="{fmt_float(lo)}" ' \
                      f'upper="{fmt_float(hi)}" effort="0" velocity="0"/>'
                if k == 1:
                    ends[j.parent].append(pending[1])
                add_joint(op.coord, "revolute", prev, child, pending, lim,  # type: ignore[arg-type]
                          anatomical=j.name if k == 1 else None)
                dofs.append(op.coord)  # type: ignore[arg-type]
                pending = identity_transform()
                prev = child
            if not revs:
                name = j.name if j.name not in r.coords else f"{j.name}_weld"
                ends[j.parent].append(compose(pending, invert(j.child_offset))[1])
                add_joint(name, "fixed", j.parent, j.child, compose(pending, invert(j.child_offset)),
                          anatomical=j.name)
                seg_X[j.child] = identity_transform()
            else:
                seg_X[j.child] = tail
        # segments, drawn as bones (bone_visuals)
        links.insert(0, MATERIALS)
        for body, (mass, com, inertia) in r.bodies.items():
            X = seg_X[body]
            c = apply(X, com)
            I = X[0] @ inertia @ X[0].T
            links.append(
                f'  <link name="{body}">\n    <inertial>\n      <origin xyz="{fmt_vec(c)}" rpy="0 0 0"/>\n'
                f'      <mass value="{fmt_float(max(mass, MIN_MASS))}"/>\n'
                f'      <inertia ixx="{fmt_float(I[0, 0])}" ixy="{fmt_float(I[0, 1])}" ixz="{fmt_float(I[0, 2])}" '
                f'iyy="{fmt_float(I[1, 1])}" iyz="{fmt_float(I[1, 2])}" izz="{fmt_float(I[2, 2])}"/>\n'
                f'    </inertial>\n{bone_visuals(ends.get(body, []), mass, c, I)}  </link>')
        # markers
        skipped = []
        for name, (body, loc) in r.markers.items():
            if body == "ground":
                skipped.append(name)
                continue
            links.append(f'  <link name="{name}">\n    {MARKER_VISUAL}\n  </link>')
            add_joint(f"{name}_marker", "fixed", body, name, (np.eye(3), apply(seg_X[body], loc)))
        if need_markers and not [m for m in r.markers if m not in skipped]:
            raise NoMarkersError(f"{self.where}: the model has no markers on its bodies; give its marker set with "
                                 f"--marker-set FILE.xml (marker_set=...)")
        if not need_markers:
            links.append(f'  <link name="{PROBE}"/>')
            add_joint(f"{PROBE}_marker", "fixed", self.root_joint.child, PROBE, identity_transform())
        rj = self.root_joint
        root = None
        root_names: dict[str, str] = {}  # a floating root's coordinates the source names
        rots = [(ax.coord, ax.axis) for ax in rj.axes if ax.motion == "rotation" and ax.coord is not None]
        trs = [(ax.coord, ax.axis) for ax in rj.axes if ax.motion == "translation" and ax.coord is not None]
        lin_ok = all(ax.func.linear == (1.0, 0.0) for ax in rj.axes if ax.coord is not None)
        if len(rots) == 3 and len(trs) == 3 and lin_ok and rj.type in ("CustomJoint", "FreeJoint"):
            root = RootInfo(rj.name, rj.parent_offset, rj.child_offset, tuple(rots), tuple(trs))  # type: ignore[arg-type]
        else:  # a weld, a pin, a planar joint...: calibrate's root floats (the export writes it under this name)
            gone = tuple(c.name for c in rj.coords)
            held = f" ({', '.join(gone)} not a coordinate here)" if gone else ""
            root_names = self.source_root_names()
            six = ", ".join(root_names.get(n, n) for n in FLOATING_ROOT)
            approximations.insert(0, Approximation(
                rj.name, FLOATING, gone, f"its {rj.type} from ground to {rj.child} gives {len(gone)} of 6 coordinates; "
                f"calibrate fits the root segment's pose freely in every frame{held}, and the .osim export writes "
                f"it as a CustomJoint '{rj.name}' of six coordinates ({six}"
                + ("; the source's names where its axes are the export's" if root_names else "") + ")",
                0.0, "", 0.0, ()))
            dropped.extend(c for c in gone if c not in dropped)
        # the source's absolute path: the export reads its muscles from it, from wherever it runs (osim_forces)
        info = OsimInfo(str(r.path.resolve()), root, {}, {}, tuple(approximations), tuple(dropped),
                        {b: seg_X[b] for b in r.bodies}, ratios=ratios, clamped=tuple(n for n in dofs if
                                                                                     r.coords[n].clamped),
                        root_names=root_names, gravity=r.gravity, mixes=mixes,
                        gimbals=self.find_gimbals(ops_of))
        own = {c.name: c.default for c in r.coords.values()}
        info = replace(info, locked={c.name: float(info.urdf_angle(c.name, own)) for c in r.coords.values()
                                     if c.locked and c.name in dofs},
                       defaults={n: float(info.urdf_angle(n, self.defaults)) for n in dofs})
        body = f'<robot name="{r.name}">\n' + "\n".join(links) + "\n" + "\n".join(joints) + "\n"
        together = self.measure_together(body + "</robot>\n", info)
        if together is not None:
            info = replace(info, together=together)
        text = (f'<?xml version="1.0"?>\n<!-- imported by calibrate from {r.path.name} -->\n' + body
                + _info_xml(info) + "\n</robot>\n")
        return text, info

    def source_root_names(self) -> dict[str, str]:
        """The source's names for the floating root's coordinates (FLOATING_ROOT -> its coordinate) where its ground
        joint turns and slides the root as the export's root does: its frames unturned, each coordinate's function
        the identity about or along a ground axis, no constant turn, the turns in the export's order (body-fixed z,
        y', x'').  Gait10dof18musc's planar pelvis: root_rz, root_x, root_y become pelvis_tilt, pelvis_tx, pelvis_ty
        (the lab's setups name them; the three out-of-plane coordinates keep calibrate's names)."""
        rj = self.root_joint
        if not all(np.allclose(X[0], np.eye(3), atol=1e-12) for X in (rj.parent_offset, rj.child_offset)):
            return {}
        names: dict[str, str] = {}
        order = []
        for ax in rj.axes:
            if ax.func.constant is not None or ax.coord is None:
                if ax.motion == "rotation" and abs(ax.func.constant or 0.0) > 1e-12:
                    return {}  # a constant turn: the coordinates' meaning is not the export's
                continue
            k = int(np.argmax(np.abs(ax.axis)))
            if ax.func.linear != (1.0, 0.0) or not np.allclose(ax.axis, np.eye(3)[k], atol=1e-12):
                return {}
            if ax.motion == "rotation":
                names[("root_rx", "root_ry", "root_rz")[k]] = ax.coord
                order.append(2 - k)  # z, y, x: 0, 1, 2
            else:
                names[("root_x", "root_y", "root_z")[k]] = ax.coord
        every = [names.get(n, n) for n in FLOATING_ROOT]
        if order != sorted(order) or len(set(every)) != len(every):
            return {}
        return names

    def measure_together(self, urdf: str, info: OsimInfo, poses: int = TOGETHER_POSES) -> Together | None:
        """The approximations' joint effect on each marker below two or more of them (Together): OpenSim's
        kinematics (the reader's joints, every coordinate at random, the couplers followed) against the imported
        URDF's (Pinocchio, each coordinate times its ratio), both in the root body's frame."""
        import pinocchio as pin

        count: dict[str, int] = {}
        for a in info.approximations:
            if a.kind not in NO_MARKER_EFFECT:
                for m in a.markers:
                    count[m] = count.get(m, 0) + 1
        stacked = sorted(m for m, k in count.items() if k >= 2 and m in self.r.markers)
        if not stacked:
            return None
        r = self.r
        rng = np.random.default_rng(0)
        vals = {c.name: rng.uniform(*c.span(), poses) for c in r.coords.values() if c.name not in r.couplers}
        for dep, (ind, f, s) in r.couplers.items():
            if ind in vals:
                vals[dep] = s * f(vals[ind])
        ones = (np.broadcast_to(np.eye(3), (poses, 3, 3)), np.zeros((poses, 3)))
        X: dict[str, tuple[np.ndarray, np.ndarray]] = {self.root_joint.child: ones}
        for j in self.order:
            X[j.child] = _then(_then(_then(X[j.parent], j.parent_offset), j.transform(vals, poses)),
                               invert(j.child_offset))
        exact = np.stack([np.einsum("nij,j->ni", X[r.markers[m][0]][0], r.markers[m][1]) + X[r.markers[m][0]][1]
                          for m in stacked], axis=1)  # (poses, markers, 3)
        pm = pin.buildModelFromXML(urdf)
        data = pm.createData()
        fids = [pm.getFrameId(m, pin.FrameType.BODY) for m in stacked]
        ours = np.empty_like(exact)
        for n in range(poses):
            q = pin.neutral(pm)
            for jid in range(1, pm.njoints):
                name, jm = pm.names[jid], pm.joints[jid]
                angle = float(info.urdf_angle(name, {k: v[n] for k, v in vals.items()})) if name in vals else 0.0
                if jm.nq == 1:
                    q[jm.idx_q] = angle
                else:  # an unbounded revolute: (cos, sin)
                    q[jm.idx_q:jm.idx_q + 2] = np.cos(angle), np.sin(angle)
            pin.framesForwardKinematics(pm, data, q)
            ours[n] = [data.oMf[f].translation for f in fids]
        err = np.linalg.norm(exact - ours, axis=2)
        k = np.unravel_index(np.argmax(err), err.shape)
        return Together(1000 * float(err[k]), stacked[k[1]], 1000 * float(err.mean()), poses)


# ---------------------------------------------------------------------- the <opensim> element
def _info_xml(info: OsimInfo) -> str:
    el = ET.Element("opensim", source=info.source, gravity=fmt_vec(info.gravity))
    if info.root is not None:
        rt = info.root
        r = ET.SubElement(el, "root", joint=rt.joint)
        for tag, X in (("parent_offset", rt.parent_offset), ("child_offset", rt.child_offset)):
            ET.SubElement(r, tag, xyz=fmt_vec(X[1]), rpy=fmt_vec(urdf_rpy(X[0])))
        for tag, items in (("rotation", rt.rotations), ("translation", rt.translations)):
            for name, axis in items:
                ET.SubElement(r, tag, coordinate=name, axis=fmt_vec(axis))
    for name, v in info.defaults.items():
        c = ET.SubElement(el, "coordinate", name=name, default=fmt_float(v),
                          locked="true" if name in info.locked else "false",
                          clamped="true" if name in info.clamped else "false")
        if name in info.ratios:
            c.set("ratio", fmt_float(info.ratios[name]))
        mix = info.mixes.get(name)
        if mix is not None:
            c.set("plus", mix.independent)
            c.set("times", fmt_float(mix.mix))
            c.set("coupled", mix.dependent)
            c.set("range", f"{fmt_float(mix.lo)} {fmt_float(mix.hi)}")
    for name in info.dropped:
        ET.SubElement(el, "dropped", coordinate=name)
    for coords, bodies in info.gimbals:
        ET.SubElement(el, "gimbal", coordinates=" ".join(coords), bodies=" ".join(bodies))
    for ours, theirs in info.root_names.items():
        ET.SubElement(el, "root_name", coordinate=ours, source=theirs)
    for name, (R, t) in info.bodies.items():
        ET.SubElement(el, "body", name=name, xyz=fmt_vec(t), rpy=fmt_vec(urdf_rpy(R)))
    for a in info.approximations:
        e = ET.SubElement(el, "approximation", joint=a.joint, kind=a.kind, coordinates=" ".join(a.coordinates),
                          detail=a.detail, max_marker_mm=fmt_float(a.max_marker_mm), marker=a.marker,
                          bound_mm=fmt_float(a.bound_mm), markers=" ".join(a.markers))
        if a.one_mm is not None:
            e.set("one_mm", fmt_float(a.one_mm))
    if info.together is not None:
        t = info.together
        ET.SubElement(el, "together", max_marker_mm=fmt_float(t.max_marker_mm), marker=t.marker,
                      mean_mm=fmt_float(t.mean_mm), poses=str(t.poses))
    ET.indent(el, space="  ", level=1)
    return "  " + ET.tostring(el, encoding="unicode")


# ---------------------------------------------------------------------- public API
def osim_to_urdf(path: str | os.PathLike[str], marker_set: str | os.PathLike[str] | None = None,
                 need_markers: bool = True) -> tuple[str, OsimInfo]:
    """The calibrate URDF text of an OpenSim model (and MarkerSet file), with its OsimInfo (`need_markers`
    False: a model without markers is read too)."""
    path = Path(path)
    reader = OsimReader(path, read_text_file(path, "an OpenSim model (.osim)"))
    if marker_set is not None:
        reader.add_marker_set(Path(marker_set))
    return _Importer(reader).build(need_markers)


__all__ = ["FLOATING", "FLOATING_ROOT", "FOLDED", "IN_CHAIN", "JOINT_FIT", "LEFT_OUT", "LUMPED", "NO_MARKER_EFFECT",
           "PROBE", "Approximation", "Mix", "OsimInfo", "RootInfo", "Together", "osim_to_urdf"]
