"""Named parameter blocks: where each piece of the geometry and of a frame's coordinates lives.

The one place the layout of the flat vectors is computed (in the manner of Ceres' parameter
blocks and manifolds); everything else asks a :class:`ParameterLayout`.

Geometry p (shared by all frames), in this order, each block with its size in p and the size
of its tangent (the free coordinates a solver step moves):

* ``scale[segment]``  1 entry, tangent 1: the segment's isotropic scale factor, on R+;
* ``centre[joint]``   3 entries, tangent 3: the joint centre in its parent segment's frame;
* ``axis[dof]``       3 entries, tangent 2: a hinge or universal axis on the unit sphere,
  retracted by a ← normalise(a + B u) with B (3, 2) perpendicular to a (``perpendicular_basis``);
  a ball joint's axes are never free;
* ``marker[marker]``  3 entries, tangent 3: the marker's offset in its segment's frame.

A block is held (no free columns) when its group is not free, when it belongs to a held segment
(Settings.hold_segments) or, for an axis, when its DoF is locked or held (Settings.lock,
hold_axes).  The free columns follow p's order except that the axes come joint by joint.

A frame's coordinates z (FrameLayout): the root translation (3) and rotation increment (3, on
SO(3) about a reference quaternion), then one angle per DoF; an SO(3) ball's three angles are
increments about its own reference quaternion (Kinematics.balls).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .model import Model

GROUPS = ("scale", "centre", "axis", "marker")
SIZE = {"scale": 1, "centre": 3, "axis": 3, "marker": 3}
TANGENT = {"scale": 1, "centre": 3, "axis": 2, "marker": 3}
ROOT = 6  # root translation (3) + rotation increment (3) at the start of a frame's coordinates
# A segment's scale stays within these bounds of the base model's (ParameterLayout.retract).  Labels the model
# cannot fit (a knee and an ankle label exchanged for a whole trial) drove a tibia's scale towards zero: the
# positions expressed in it, stored unscaled, grew without bound, and the solve stopped "converged" on the step
# tolerance, relative to |p| ~ 1e51.  No subject is a fifth or five times the base model in any segment;
# within the bounds nothing changes, and a scale held at one is flagged (Calibration.implausible).
SCALE_BOUNDS = (0.2, 5.0)


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b for 3-vectors (np.cross costs tens of microseconds per call in its axis handling)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def perpendicular_basis(a: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal columns perpendicular to unit `a` (a fixed, smooth-enough choice): the
    tangent basis B of an axis block."""
    return perpendicular_bases(np.asarray(a, dtype=float)[None])[0]


def perpendicular_bases(a: np.ndarray) -> np.ndarray:
    """(n, 3, 2): perpendicular_basis of each row of unit vectors `a` (n, 3), in one pass: u = a × e_k
    with k the smallest component of a, normalised, and a × u."""
    n = a.shape[0]
    e = np.zeros((n, 3))
    e[np.arange(n), np.argmin(np.abs(a), axis=1)] = 1.0
    u = cross_rows(a, e)
    u /= np.sqrt(u[:, 0] * u[:, 0] + u[:, 1] * u[:, 1] + u[:, 2] * u[:, 2])[:, None]
    return np.stack([u, cross_rows(a, u)], axis=2)


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a × b of (n, 3) arrays (cross3's arithmetic)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def unit_rows(a: np.ndarray) -> np.ndarray:
    """Each row of (n, 3) `a` divided by its length."""
    return a / np.sqrt(a[:, 0] * a[:, 0] + a[:, 1] * a[:, 1] + a[:, 2] * a[:, 2])[:, None]


@dataclass(frozen=True)
class Block:
    """One named block of the geometry vector p."""

    group: str  # 'scale', 'centre', 'axis' or 'marker'
    index: int  # the segment's, joint's, DoF's or marker's index in the model
    name: str  # ... and its name
    offset: int  # first entry in p
    free_offset: int  # first column in the free vector; -1 when held

    @property
    def size(self) -> int:
        """Entries in p."""
        return SIZE[self.group]

    @property
    def tangent(self) -> int:
        """Free coordinates when free (an axis: 2, the unit sphere's tangent)."""
        return TANGENT[self.group]

    @property
    def held(self) -> bool:
        return self.free_offset < 0

    @property
    def full(self) -> slice:
        """Its entries in p."""
        return slice(self.offset, self.offset + self.size)

    @property
    def cols(self) -> np.ndarray:
        """Its columns in the free vector (none when held)."""
        return np.arange(0 if self.held else self.tangent) + self.free_offset

    @property
    def label(self) -> str:
        """e.g. 'centre[knee_r]'."""
        return f"{self.group}[{self.name}]"


@dataclass(frozen=True)
class FrameBlock:
    """One block of a frame's coordinates z: the root pose, or an SO(3) ball joint's angles."""

    name: str  # 'root' or the ball joint's name
    cols: np.ndarray  # its columns in z
    tangent: int  # 6 (root: translation + rotation increment) or 3 (ball: rotation increment)


class FrameLayout:
    """Where the root pose and each DoF's angle sit in a frame's coordinates z (nz = 6 + n_dofs)."""

    n_root = ROOT  # coordinates of the root pose
    translation = slice(0, 3)
    rotation = slice(3, ROOT)  # the root's rotation increment (retracted into its reference quaternion)
    root_pose = slice(0, ROOT)

    def __init__(self, n_dofs: int, balls: Iterable = ()):
        """`balls`: the SO(3) ball joints (Kinematics.balls: .name and .dofs)."""
        self.n_dofs = n_dofs
        self.nz = ROOT + n_dofs
        self.all_angles = slice(ROOT, self.nz)
        self.root = FrameBlock("root", np.arange(ROOT), ROOT)
        self.balls = tuple(FrameBlock(b.name, ROOT + np.array(b.dofs, dtype=int), 3) for b in balls)

    @staticmethod
    def angle(d: int | np.ndarray | Sequence[int]) -> int | np.ndarray:
        """The column(s) of DoF(s) `d` in z."""
        return ROOT + d if isinstance(d, (int, np.integer)) else ROOT + np.asarray(d, dtype=int)

    @staticmethod
    def dof(col: int | np.ndarray) -> int | np.ndarray:
        """The DoF of column(s) `col` of z (inverse of angle)."""
        return col - ROOT

    @staticmethod
    def coordinates(translation: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """Coordinates Z (F, nz) of root translations (F, 3) and joint angles (F, n_dofs), the root's
        rotation increments zero (its orientation is the reference quaternion's)."""
        return np.column_stack([translation, np.zeros((len(translation), 3)), angles])

    @staticmethod
    def angles(Z: np.ndarray) -> np.ndarray:
        """The joint angles of coordinates Z (..., nz): a view (..., n_dofs)."""
        return Z[..., ROOT:]


class ParameterLayout:
    """The blocks of the geometry vector p of `model` and which of them a solve moves.

    `free`: the groups that are free (GROUPS); `held_axes`: DoF names whose axis is held (locked or
    held coordinates); `held_segments`: segments whose geometry is held (their scale, the joint
    centres and markers expressed in them, the axes of the joints into them); `held_markers`: markers
    whose offsets are held (those no frame shows); `balls`: the SO(3) ball joints of the frames'
    coordinates (Kinematics.balls)."""

    def __init__(self, model: Model, free: Iterable[str] = GROUPS, held_axes: Iterable[str] = (),
                 held_segments: Iterable[str] = (), balls: Iterable = (), held_markers: Iterable[str] = ()):
        m = model
        free, held, still, ghosts = set(free), set(held_axes), set(held_segments), set(held_markers)
        ns, nj, nd, nm = len(m.segments), len(m.joints), m.n_dofs, len(m.markers)
        self.offsets = dict(zip(GROUPS, (int(x) for x in np.cumsum([0, ns, 3 * nj, 3 * nd])), strict=True))
        self.n_full = ns + 3 * (nj + nd + nm)
        self.frame = FrameLayout(nd, balls)
        # Axes that are calibrated: those of hinge and universal joints (never a ball's), joint by joint.
        self.axis_dofs = [m.dof_index(d) for j in m.joints if j.kind in ("hinge", "universal")
                          and j.child not in still for d in j.dofs if d not in held] if "axis" in free else []
        free_of: dict[tuple[str, int], bool] = {}
        for i, s in enumerate(m.segments):
            free_of["scale", i] = "scale" in free and s.name not in still
        for i, j in enumerate(m.joints):
            free_of["centre", i] = "centre" in free and j.parent not in still
        for i, mk in enumerate(m.markers):
            free_of["marker", i] = "marker" in free and mk.segment not in still and mk.name not in ghosts
        free_axes = set(self.axis_dofs)
        for i in range(nd):
            free_of["axis", i] = i in free_axes
        # Free columns: scales, centres, axes (in axis_dofs' order), markers.
        order = [("scale", i) for i in range(ns)] + [("centre", i) for i in range(nj)] + \
            [("axis", d) for d in self.axis_dofs] + [("marker", i) for i in range(nm)]
        at, col = {}, 0
        for key in order:
            if free_of[key]:
                at[key] = col
                col += TANGENT[key[0]]
        self.n_free = col  # segment scales are free with their offsets: the priors split s x between them
        names = {"scale": [s.name for s in m.segments], "centre": [j.name for j in m.joints],
                 "axis": [d.name for d in m.dofs], "marker": [mk.name for mk in m.markers]}
        self._blocks = {g: tuple(Block(g, i, n, self.offsets[g] + SIZE[g] * i, at.get((g, i), -1))
                                 for i, n in enumerate(names[g])) for g in GROUPS}
        self.blocks = tuple(b for g in GROUPS for b in self._blocks[g])  # in p's order
        self.free_blocks = tuple(sorted((b for b in self.blocks if not b.held), key=lambda b: b.free_offset))
        # (free column, entry of p) of the free columns that move one entry of p each (every free
        # block but the axes, whose tangent is a basis).
        self.direct = np.array([(b.free_offset + c, b.offset + c) for b in self.free_blocks if b.group != "axis"
                                for c in range(b.tangent)], dtype=int).reshape(-1, 2)
        # Free joint centres and markers: entry of p, free column, the entry of the scale of the segment
        # that holds them (which multiplies them), and that scale's free column (-1 if it is held).
        seg_of = {s.name: i for i, s in enumerate(m.segments)}
        owner_of = {}
        for group, owners in (("centre", [j.parent for j in m.joints]), ("marker", [mk.segment for mk in m.markers])):
            for i, name in enumerate(owners):
                for e in self.entries(group, [i])[0]:
                    owner_of[int(e)] = self.scale(seg_of[name])
        scale_col = {i: k for k, i in self.direct if i < self.scales.stop}
        pos = [(i, k, owner_of[i], scale_col.get(owner_of[i], -1)) for k, i in self.direct if i in owner_of]
        self._positions = tuple(np.array([x[c] for x in pos], dtype=int) for c in range(4))
        # The calibrated axes' entries in p (n, 3) and free columns (n, 2), in axis_dofs' order.
        self.axis_entries = self.entries("axis", self.axis_dofs)
        self.axis_columns = np.array([self.axis_cols(d) for d in self.axis_dofs], dtype=int).reshape(-1, 2)

    # ---------------------------------------------------------------- the full vector p
    def block(self, group: str, i: int) -> Block:
        """The block of segment / joint / DoF / marker `i` of `group`."""
        return self._blocks[group][i]

    def group(self, group: str) -> slice:
        """The entries of a whole group in p."""
        n = len(self._blocks[group]) * SIZE[group]
        return slice(self.offsets[group], self.offsets[group] + n)

    @property
    def scales(self) -> slice:
        """The segments' scale factors in p (segment i at entry i)."""
        return self.group("scale")

    def scale(self, i: int | np.ndarray) -> int | np.ndarray:
        """Segment i's scale factor's entry (entries) in p."""
        return self.offsets["scale"] + i

    def centre(self, j: int) -> slice:
        """Joint j's centre in p."""
        return self._blocks["centre"][j].full

    def axis(self, d: int) -> slice:
        """DoF d's axis in p."""
        return self._blocks["axis"][d].full

    def marker(self, k: int) -> slice:
        """Marker k's offset in p."""
        return self._blocks["marker"][k].full

    def entries(self, group: str, which: np.ndarray | Sequence[int] | None = None) -> np.ndarray:
        """(n, 3) the entries in p of the 3-vector blocks `which` (default all) of `group`."""
        idx = np.arange(len(self._blocks[group])) if which is None else np.asarray(which, dtype=int)
        return self.offsets[group] + SIZE[group] * idx[:, None] + np.arange(SIZE[group])

    def split(self, p: np.ndarray) -> dict[str, np.ndarray]:
        """Copies of p's groups: 'scale' (n_segments,), the others (n, 3)."""
        p = np.asarray(p, dtype=float).ravel()
        if p.size != self.n_full:
            raise ValueError(f"parameter vector: expected {self.n_full} entries, got {p.size}")
        return {g: p[self.group(g)].copy() if g == "scale" else p[self.group(g)].reshape(-1, 3).copy()
                for g in GROUPS}

    def names(self) -> list[str]:
        """One name per entry of p, e.g. 'centre[knee_r].y'."""
        return [b.label if b.size == 1 else f"{b.label}.{c}" for b in self.blocks for c in "xyz"[:b.size]]

    # ---------------------------------------------------------------- the free vector
    def cols(self, group: str, i: int) -> np.ndarray:
        """The free columns of block `i` of `group` (none when held)."""
        return self._blocks[group][i].cols

    def axis_cols(self, d: int) -> np.ndarray:
        """The two tangent columns of DoF d's free axis."""
        return self._blocks["axis"][d].cols

    @property
    def free_names(self) -> list[str]:
        """One name per free column, e.g. 'centre[knee_r].y', 'axis[knee_r].u1'."""
        out = []
        for b in self.free_blocks:
            if b.group == "axis":
                out += [f"{b.label}.u{k}" for k in (1, 2)]
            else:
                out += [b.label if b.size == 1 else f"{b.label}.{c}" for c in "xyz"[:b.size]]
        return out

    # ---------------------------------------------------------------- manifolds
    def axis_direction(self, p: np.ndarray, d: int) -> np.ndarray:
        """DoF d's axis in `p`, normalised (unit)."""
        return unit_rows(p[self.axis(d)][None])[0]

    def axis_directions(self, p: np.ndarray) -> np.ndarray:
        """(n, 3) the calibrated axes (axis_dofs' order) in `p`, normalised."""
        return unit_rows(p[self.axis_entries])

    def tangent_map(self, p: np.ndarray) -> np.ndarray:
        """T (n_full, n_free): change of p per unit change of the free coordinates at `p`.

        The free coordinates of joint centres and markers are positions at the subject's scale
        (q = s x, metres), and a scale step keeps them fixed (x ← (s x + dq)/(s + ds)): the data
        see only s x, so a segment's size then trades against its offsets along a straight line
        (the priors, linear in (s, q), settle it in one step) instead of the hyperbola s x = const
        that Gauss-Newton would only crawl along.  An axis moves along its tangent basis B."""
        T = np.zeros((self.n_full, self.n_free))
        if self.direct.size:
            T[self.direct[:, 1], self.direct[:, 0]] = 1.0
        rows, cols, owner, scol = self._positions
        if rows.size:
            s = p[owner]
            T[rows, cols] = 1.0 / s
            with_scale = scol >= 0
            T[rows[with_scale], scol[with_scale]] = -p[rows[with_scale]] / s[with_scale]
        if self.axis_dofs:
            B = perpendicular_bases(self.axis_directions(p))
            T[self.axis_entries[:, :, None], self.axis_columns[:, None, :]] = B
        return T

    def tangent_pattern(self) -> np.ndarray:
        """(n_full, n_free) booleans: where tangent_map(p) may be nonzero at some p.  An entry of T can be
        zero at one p and not at the next (an axis's tangent basis turns to another component as the axis
        moves; an offset leaves zero), so what is built on T's nonzeros is built on this instead."""
        T = np.zeros((self.n_full, self.n_free), dtype=bool)
        if self.direct.size:
            T[self.direct[:, 1], self.direct[:, 0]] = True
        rows, _, _, scol = self._positions
        if rows.size:
            T[rows[scol >= 0], scol[scol >= 0]] = True
        if self.axis_dofs:
            T[self.axis_entries[:, :, None], self.axis_columns[:, None, :]] = True
        return T

    def tangent_nonzeros(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows, columns) of tangent_pattern's entries, row by row: made once per layout."""
        if getattr(self, "_tangent_nonzeros", None) is None:
            self._tangent_nonzeros = np.nonzero(self.tangent_pattern())
        return self._tangent_nonzeros

    def tangent_values(self, p: np.ndarray) -> np.ndarray:
        """tangent_map(p)'s entries at tangent_nonzeros(), in their order: the same numbers, written in the same
        order, without the dense (n_full, n_free) matrix (the priors need only these, at every cost evaluation)."""
        if getattr(self, "_tangent_slots", None) is None:
            rows, cols = self.tangent_nonzeros()
            slot = np.full((self.n_full, self.n_free), -1, dtype=int)
            slot[rows, cols] = np.arange(rows.size)
            pr, pc, _, scol = self._positions
            ws = scol >= 0
            self._tangent_slots = (slot[self.direct[:, 1], self.direct[:, 0]], slot[pr, pc], slot[pr[ws], scol[ws]],
                                   ws, slot[self.axis_entries[:, :, None], self.axis_columns[:, None, :]])
        direct, pos, pos_scale, ws, axes = self._tangent_slots
        v = np.zeros(self.tangent_nonzeros()[0].size)
        v[direct] = 1.0
        rows, _, owner, _ = self._positions
        if rows.size:
            s = p[owner]
            v[pos] = 1.0 / s
            v[pos_scale] = -p[rows[ws]] / s[ws]
        if self.axis_dofs:
            v[axes] = perpendicular_bases(self.axis_directions(p))
        return v

    def retract(self, p: np.ndarray, dp: np.ndarray) -> np.ndarray:
        """p moved by the free step dp, each block on its manifold: scales to s exp(ds / s) (s + ds to
        first order, and never zero or negative: a segment with no marker of its own, whose scale only
        the priors hold, must not shrink through zero into a mirror image; kept within SCALE_BOUNDS), free positions to
        (s x + dq)/s' (see tangent_map), axes kept unit (normalise(a + B u))."""
        out = p.copy()
        if self.direct.size:
            out[self.direct[:, 1]] += dp[self.direct[:, 0]]
            sc = self.direct[self.direct[:, 1] < self.scales.stop]
            out[sc[:, 1]] = np.clip(p[sc[:, 1]] * np.exp(dp[sc[:, 0]] / p[sc[:, 1]]), *SCALE_BOUNDS)
        rows, cols, owner, _ = self._positions
        if rows.size:
            out[rows] = (p[owner] * p[rows] + dp[cols]) / out[owner]
        if self.axis_dofs:  # normalise(a + B u)
            a = self.axis_directions(p)
            B, u = perpendicular_bases(a), dp[self.axis_columns]
            out[self.axis_entries] = unit_rows(a + B[:, :, 0] * u[:, :1] + B[:, :, 1] * u[:, 1:])
        return out
