"""Symbolic forward kinematics h(z, p) in CasADi, built by walking the model's tree.

The ``pin`` wheel has no ``pinocchio.casadi``, so the expressions are assembled here
from the joint types, origins and axes that :class:`calibrate.model.model.Model` read off
Pinocchio's frame tree.  Pinocchio stays the numerical reference (tests compare the two).

Per-frame coordinates (the optimiser's unknowns for one frame)::

    z = [t (3), delta (3), theta (n_dofs)]

* ``t`` — root (pelvis) origin in the lab frame, metres;
* ``delta`` — root rotation increment about a per-frame reference orientation
  ``q_ref`` (unit quaternion x, y, z, w):  R_root = R(q_ref) · Cay(delta), where
  Cay(delta) = I + 2/(1 + |g|²) ([g]× + [g]×²) with g = delta/2 is the Cayley map.
  It is rational (no branches, smooth everywhere), equals exp([delta]×) to first order
  (dR/d delta = R [·]× at 0) and reaches every rotation below 180° (angle 2·atan(|delta|/2)).
  After each step the solver folds delta into q_ref and resets it to zero, so
  the root rotation lives on SO(3) with no Euler-angle singularity;
* ``theta`` — joint angles (rad), in the model's DoF order (Pinocchio's).

The solver's form (``h_ref``): the rotation of every ball joint (three revolutes about
orthonormal axes with coincident origins) is parametrised on SO(3) as the root's is, by a
per-frame reference rotation B_j (unit quaternion) times the joint's three-angle rotation
E(theta_j) = R(a1, theta1) R(a2, theta2) R(a3, theta3) taken as a small increment: after each
step the increment is folded into B_j and reset to zero (:meth:`Kinematics.retract`), so the
increment's Jacobian is always that at theta_j = 0 (columns a1, a2, a3: orthonormal) and a
shoulder abducted through 90° meets no gimbal lock.  The URDF's three angles of each ball joint
are recovered only for output (:meth:`Kinematics.absolute`: continuous over time, one branch).
With every B_j the identity the two forms are the same function: ``h(z, q, p) ==
h_ref(z, [q, I, ..., I], p)``.

Geometric parameters ``p = Parameters.vector()`` = [scale, centre, axis, marker]:
a joint centre sits at ``scale[parent segment] * centre`` in the parent segment frame,
a marker at ``scale[segment] * marker``, a revolute joint turns about ``axis/|axis|``.

Outputs: ``markers`` (3 × n_markers) and ``centres`` (3 × n_joints), lab frame, metres.
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property

import casadi as ca
import numpy as np

from .blocks import FrameLayout
from .model import Model, Parameters
from .rotations import _quat_multiply_floats, _retract_one, quat_matrices, quat_multiply, retract_root

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])  # unit quaternion (x, y, z, w) of no rotation
BRANCH_TIE = 1e-6  # rad^-2: the weight of a ball's angles' distance from their range's middle in its branch choice
SINGULAR_COS = 1e-9  # |cos(middle angle)| below which a ball joint's outer angles share one sum (gimbal lock)


def skew(v):
    """[v]×, the cross-product matrix (works for CasADi and numpy 3-vectors)."""
    return ca.vertcat(
        ca.horzcat(0, -v[2], v[1]),
        ca.horzcat(v[2], 0, -v[0]),
        ca.horzcat(-v[1], v[0], 0),
    )


def quat_to_matrix(q):
    """Rotation matrix of quaternion (x, y, z, w); exact for any non-zero q (normalised inside)."""
    v = q[0:3]
    w = q[3]
    n2 = ca.dot(q, q)
    V = skew(v)
    return ca.SX.eye(3) + (2.0 / n2) * (w * V + V @ V)


def cayley(delta):
    """Cayley map of delta/2: a rotation equal to exp([delta]x) to first order."""
    g = 0.5 * delta
    G = skew(g)
    return ca.SX.eye(3) + (2.0 / (1.0 + ca.dot(g, g))) * (G + G @ G)


def axis_angle(axis, angle):
    """Rodrigues' formula about axis/|axis| (the axis need not be unit)."""
    a = axis / ca.norm_2(axis)
    K = skew(a)
    return ca.SX.eye(3) + ca.sin(angle) * K + (1.0 - ca.cos(angle)) * (K @ K)


@dataclass(frozen=True)
class BallJoint:
    """A ball joint the solver keeps on SO(3): three revolutes about orthonormal axes with
    coincident origins (calibrate.model.model: a ball joint), whose rotation is B · E(theta)."""

    name: str
    dofs: tuple[int, int, int]  # indices into the DoF vector, proximal first
    axes: np.ndarray  # (3, 3): row k = the k-th revolute's unit axis (never calibrated)
    lower: np.ndarray  # (3,) the base model's joint limits (rad; -inf if none)
    upper: np.ndarray  # (3,)

    def quaternion(self, angles: np.ndarray) -> np.ndarray:
        """Unit quaternions (F, 4) of E(theta) = R(a1, t1) R(a2, t2) R(a3, t3), angles (F, 3)."""
        h = 0.5 * np.asarray(angles, dtype=float)
        q = None
        for k in range(3):
            qk = np.concatenate([np.sin(h[:, k:k + 1]) * self.axes[k], np.cos(h[:, k:k + 1])], axis=1)
            q = qk if q is None else quat_multiply(q, qk)
        return q

    def angles(self, R: np.ndarray, previous: np.ndarray | None = None) -> np.ndarray:
        """The three angles (F, 3) with E(angles) = R (F, 3, 3) for a trial's frames, continuous
        over time on one branch.  Each rotation has two solutions, (t1, t2, t3) and (t1 + π,
        π − t2, t3 + π), plus 2π turns of each angle.  The branch of every frame is chosen by
        dynamic programming over the trial (Viterbi, two states): each frame costs how far its
        angles lie outside the joint's limits, each step between frames the squared change of
        the angles (mod 2π); so the path is the smooth one that stays in the range of motion, and
        near the gimbal lock (t2 → ±90°, where the two solutions meet and t1, t3 are individually
        ill-conditioned) it does not wander onto the other branch.  The angles are then unwrapped
        (no 2π jumps) and each is turned by whole turns so that its median lies nearest the middle
        of its limits (or, given `previous` (3,), its first frame nearest that); a frame more than
        half a turn from that middle is then turned back within it (the only 2π jumps, beyond any
        joint's range).  In exact gimbal lock, where only t1 ± t3 is defined, t1 keeps the previous
        frame's value."""
        B = self.axes.T.copy()  # columns a1, a2, a3
        sign = np.array([1.0, 1.0, -1.0 if np.linalg.det(B) < 0 else 1.0])
        B[:, 2] *= sign[2]  # a left-handed axis order: R(-a3, -t3) = R(a3, t3)
        lower, upper = self.lower * sign, self.upper * sign
        lower[2], upper[2] = min(lower[2], upper[2]), max(lower[2], upper[2])
        M = np.einsum("ji,fjk,kl->fil", B, R, B)  # intrinsic x-y-z rotations in the axes' basis
        t2 = np.arctan2(M[:, 0, 2], np.hypot(M[:, 0, 0], M[:, 0, 1]))
        t1 = np.arctan2(-M[:, 1, 2], M[:, 2, 2])
        t3 = np.arctan2(-M[:, 0, 1], M[:, 0, 0])
        plus = np.arctan2(M[:, 1, 0], M[:, 1, 1])  # t1 + t3 where t2 = +90°, t3 - t1 where t2 = -90°
        singular = np.abs(np.cos(t2)) < SINGULAR_COS
        F = R.shape[0]
        cand = np.stack([np.column_stack([t1, t2, t3]), np.column_stack([t1 + math.pi, math.pi - t2, t3 + math.pi])])
        cand = _wrap(cand)
        node = np.sum(_outside(cand, lower, upper) ** 2, axis=2)  # (2, F)
        # Where the limits do not decide (a shoulder of ±180 deg: both branches inside), the branch nearer the range's
        # middle, by a cost too small to outweigh a step: the two branches' step costs are equal but for rounding,
        # which had chosen between them (Expert1's shoulders: arm_flex, arm_add, arm_rot of -160, -175, -170 deg in
        # one `calibrate ik` fit, -13, -17, 11 in another of the same poses).
        centre = np.where(np.isfinite(lower) & np.isfinite(upper), 0.5 * (lower + upper), 0.0)
        node += BRANCH_TIE * np.sum(_wrap(cand - centre) ** 2, axis=2)
        prev = None if previous is None else _wrap(np.asarray(previous, dtype=float) * sign)
        # Viterbi over the first and the non-singular frames (2 states: the branch; a singular frame
        # keeps the branch of the frame before it).  The steps' costs are formed at once; the loop over
        # the frames is scalar (100 000 frames: a tenth of a second per ball, not seconds).
        cost = node[:, 0].copy() if prev is None else node[:, 0] + np.sum(_wrap(cand[:, 0] - prev) ** 2, axis=1)
        seq = np.concatenate([[0], 1 + np.flatnonzero(~singular[1:])])
        step = np.sum(_wrap(cand[:, None, seq[1:]] - cand[None, :, seq[:-1]]) ** 2, axis=3)  # (now, before, step)
        c0, c1 = float(cost[0]), float(cost[1])
        s00, s01, s10, s11 = (step[i, j].tolist() for i in (0, 1) for j in (0, 1))
        n0, n1 = node[0, seq[1:]].tolist(), node[1, seq[1:]].tolist()
        back0, back1 = [0] * seq.size, [1] * seq.size
        for j in range(seq.size - 1):
            a, b = c0 + s00[j], c1 + s01[j]
            back0[j + 1], c0new = (0, a) if a <= b else (1, b)
            a, b = c0 + s10[j], c1 + s11[j]
            back1[j + 1], c1 = (0, a) if a <= b else (1, b)
            c0, c1 = n0[j] + c0new, n1[j] + c1
        b = 0 if c0 <= c1 else 1
        on_seq = np.empty(seq.size, dtype=int)
        for j in range(seq.size - 1, -1, -1):
            on_seq[j] = b
            b = back0[j] if b == 0 else back1[j]
        # every frame takes the branch of the last sequence frame at or before it
        branch = on_seq[np.searchsorted(seq, np.arange(F), side="right") - 1]
        out = cand[branch, np.arange(F)]
        for f in np.flatnonzero(singular):  # only t1 + t3 or t3 - t1 is defined: keep t1
            a = out[f - 1, 0] if f else (0.0 if prev is None else prev[0])
            out[f, 0] = a
            out[f, 2] = plus[f] - a if t2[f] > 0 else plus[f] + a
        out = np.unwrap(out, axis=0)
        mid = np.where(np.isfinite(lower) & np.isfinite(upper), 0.5 * (lower + upper), 0.0)
        if prev is not None:
            target, at = prev, out[0]
        else:
            target, at = mid, np.median(out, axis=0)
        out += 2 * math.pi * np.round((target - at) / (2 * math.pi))
        # Each angle within half a turn of its range's middle, frame by frame (the same rotation): unwrapped, the outer
        # angles wound up whole turns where a trial passes near the gimbal lock again and again (a tennis serve's
        # shoulders, kineticstoolkit's sample: -1104 to +1128 deg).  A human joint's range spans less than a turn, so
        # a frame is only moved where it already lies beyond it.
        out = mid + _wrap(out - mid)
        return out * sign


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped into (-π, π]."""
    return np.pi - np.mod(np.pi - a, 2 * np.pi)


def _outside(a: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """How far angles a (wrapped) lie outside [lower, upper], on the circle (0 inside; infinite
    limits: 0)."""
    finite = np.isfinite(lower) & np.isfinite(upper)
    lo, hi = np.where(finite, lower, -np.pi), np.where(finite, upper, np.pi)
    mid = 0.5 * (lo + hi)
    d = np.abs(_wrap(a - mid))  # distance from the middle of the range, along the shorter way
    return np.where(finite, np.maximum(d - 0.5 * (hi - lo), 0.0), 0.0)


def locked_balls(model: Model, locked) -> tuple[str, ...]:
    """The ball joints with a coordinate among `locked` (names, or a mapping name -> value): the solver keeps them
    on their three angles (build_kinematics' `euler`), so that a lock holds an angle, as an OpenSim IK setup's
    coordinate task holds one of L5/S1's three."""
    return tuple(j.name for j in model.joints if j.kind == "ball" and any(d in locked for d in j.dofs))


def so3_balls(model: Model, euler: tuple[str, ...] = ()) -> tuple[BallJoint, ...]:
    """The model's ball joints that the solver keeps on SO(3): three revolutes with coincident
    origins, no fixed rotation between them, orthonormal axes; not those named in `euler`
    (kept on their three angles, e.g. because a coordinate of theirs is locked)."""
    urdf = {u.name: u for u in model.urdf_joints}
    out = []
    for j in model.joints:
        if j.kind != "ball" or j.name in euler:
            continue
        chain = [urdf[n] for n in j.urdf_joints]
        if len(chain) != 3 or any(u.dof < 0 for u in chain):
            continue
        if any(np.any(u.xyz != 0) or not np.allclose(u.rotation, np.eye(3)) for u in chain[1:]):
            continue
        axes = np.array([model.dofs[u.dof].axis for u in chain], dtype=float)
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        if not np.allclose(axes @ axes.T, np.eye(3), atol=1e-9):
            continue
        lim = [model.dofs[u.dof] for u in chain]
        out.append(BallJoint(j.name, tuple(u.dof for u in chain), axes,
                             np.array([d.lower for d in lim]), np.array([d.upper for d in lim])))
    return tuple(out)


Evaluator = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]  # (z, q_ref) -> (markers, dm/dz)


@dataclass(frozen=True)
class Kinematics:
    """CasADi functions of one model's forward kinematics.

    h:        (z, q_ref, p) -> (markers 3×n_markers, centres 3×n_joints)
    jac:      (z, q_ref, p) -> (d vec(markers)/dz, d vec(markers)/dp), sparse, exact;
              vec() stacks marker after marker: rows 3k..3k+2 are marker k's x, y, z.
    h_jz:     (z, q_ref, p) -> (vec(markers), d vec(markers)/dz): one call per IK iteration.
    h_ref:    (z, refs, p) -> markers, centres: the solver's form (module docstring), refs =
              [root q_ref (4), B of each ball in `balls` (4 each)]; h_ref_jz likewise.
    """

    model: Model
    h: ca.Function
    h_jz: ca.Function
    h_ref: ca.Function
    h_ref_jz: ca.Function
    balls: tuple[BallJoint, ...] = field(default=())
    # frame_evaluator(p, reference=True) from compiled code, where one was made for this model's structure
    # (calibrate.problem.problem.compiled_kinematics; a codegen.MapEvaluator, called as a FrameEvaluator is):
    # 10-30 times sooner than CasADi's virtual machine.
    compiled: Callable[[np.ndarray], Evaluator] | None = field(default=None, compare=False, repr=False)

    @cached_property
    def jac(self) -> ca.Function:
        """(z, q_ref, p) -> (d vec(markers)/dz, d vec(markers)/dp), built on first use (the
        calibration builds its own per-frame Jacobians, in Problem)."""
        z, q, p = (ca.SX.sym(n, self.h.size1_in(i)) for i, n in enumerate(("z", "q_ref", "p")))
        m_vec = ca.vec(self.h(z, q, p)[0])
        return ca.Function("h_jac", [z, q, p], [ca.jacobian(m_vec, z), ca.jacobian(m_vec, p)],
                           ["z", "q_ref", "p"], ["dm_dz", "dm_dp"])

    @property
    def n_params(self) -> int:
        return int(self.h.size1_in(2))

    @cached_property
    def _ball_dofs(self) -> np.ndarray:
        """(n_balls, 3) DoF indices of the SO(3) balls, proximal first (retract)."""
        return np.array([b.dofs for b in self.balls], dtype=int).reshape(-1, 3)

    @cached_property
    def _ball_axes(self) -> np.ndarray:
        """(n_balls, 3, 3) the balls' revolute axes, row k the k-th (retract)."""
        return np.array([b.axes for b in self.balls], dtype=float).reshape(-1, 3, 3)

    @property
    def n_refs(self) -> int:
        """Length of the solver form's reference input: 4 (root) + 4 per SO(3) ball joint."""
        return 4 * (1 + len(self.balls))

    def markers(self, z, q_ref, p) -> np.ndarray:
        """Marker positions (n_markers, 3) for one frame."""
        return np.asarray(self.h(z, q_ref, _pvec(p))[0]).T

    def centres(self, z, q_ref, p) -> np.ndarray:
        """Joint-centre positions (n_joints, 3) for one frame."""
        return np.asarray(self.h(z, q_ref, _pvec(p))[1]).T

    def frame_evaluator(self, p, reference: bool = False) -> Evaluator:
        """A fast evaluator of (vec(markers), d vec(markers)/dz) for one frame at fixed `p`
        (`reference`: of the solver's form h_ref, called with the refs vector; from the compiled code
        `compiled` where there is one)."""
        if reference and self.compiled is not None:
            return self.compiled(_pvec(p))
        return FrameEvaluator(self.h_ref_jz if reference else self.h_jz, _pvec(p))

    # -------------------------------------------------------------- the solver's form
    def refs(self, Q: np.ndarray, B: np.ndarray | None) -> np.ndarray:
        """The refs input (F, n_refs) from root quaternions Q (F, 4) and ball references B
        (F, n_balls, 4) (None: every ball's the identity)."""
        Q = np.atleast_2d(Q)
        if B is None:
            B = np.broadcast_to(IDENTITY, (Q.shape[0], len(self.balls), 4))
        return np.concatenate([Q, np.reshape(B, (Q.shape[0], -1))], axis=1)

    def retract(self, Z: np.ndarray, Q: np.ndarray,
                B: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Fold the root's rotation increments Z[:, FrameLayout.rotation] into Q and every SO(3) ball's increments
        into B (B ← B · E(theta)), resetting them to zero: (Z, Q, B) of the same pose, new arrays."""
        Z = np.array(Z, dtype=float)
        Q = retract_root(Q, Z[:, FrameLayout.rotation])
        Z[:, FrameLayout.rotation] = 0.0
        F = Z.shape[0]
        if not self.balls:
            return Z, Q, np.empty((F, 0, 4))
        # Every ball at once: E(theta) = R(a1, t1) R(a2, t2) R(a3, t3) as quaternions (F, n_balls, 4).
        cols = FrameLayout.angle(self._ball_dofs)  # (n_balls, 3)
        h = 0.5 * Z[:, cols]  # (F, n_balls, 3)
        axes = self._ball_axes  # (n_balls, 3, 3): row k the k-th revolute's axis
        q = None
        for k in range(3):
            qk = np.concatenate([np.sin(h[..., k:k + 1]) * axes[:, k], np.cos(h[..., k:k + 1])], axis=-1)
            q = qk if q is None else quat_multiply(q, qk)
        if B is not None:
            q = quat_multiply(B, q)
        q /= np.linalg.norm(q, axis=-1, keepdims=True)
        Z[:, cols.ravel()] = 0.0
        return Z, Q, np.where(q[..., 3:4] < 0, -q, q)

    def retract_refs(self, Z: np.ndarray, refs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """retract for poses in the refs form (F, n_refs) (per-frame solvers)."""
        Z, Q, B = self.retract(np.atleast_2d(Z), np.atleast_2d(refs)[:, :4],
                               np.atleast_2d(refs)[:, 4:].reshape(-1, len(self.balls), 4))
        return Z, self.refs(Q, B)

    def retract_one(self, z: np.ndarray, refs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """retract_refs of one frame's pose z (nz,) and refs (n_refs,), new arrays: the same operations in the
        same order in floats (the same bits), about three times sooner than numpy's calls on 4-vectors; frame-wise
        inverse kinematics folds its balls' increments once per frame's solve."""
        z = np.array(z, dtype=float)
        out = np.empty(self.n_refs)
        out[:4] = _retract_one(refs[:4], z[FrameLayout.rotation])
        z[FrameLayout.rotation] = 0.0
        if not self.balls:
            return z, out
        cols = FrameLayout.angle(self._ball_dofs)
        h = 0.5 * z[cols]
        s, c = np.sin(h).tolist(), np.cos(h).tolist()
        for i, axes in enumerate(self._ball_axes.tolist()):
            q = (*(s[i][0] * a for a in axes[0]), c[i][0])  # the proximal revolute's quaternion, times the next's
            for k in (1, 2):
                q = _quat_multiply_floats(q, (*(s[i][k] * a for a in axes[k]), c[i][k]))
            x, y, zq, w = _quat_multiply_floats(tuple(float(v) for v in refs[4 + 4 * i:8 + 4 * i]), q)
            n = math.sqrt(x * x + y * y + zq * zq + w * w)
            q = (x / n, y / n, zq / n, w / n)
            out[4 + 4 * i:8 + 4 * i] = q if q[3] >= 0 else (-q[0], -q[1], -q[2], -q[3])
        z[cols.ravel()] = 0.0
        return z, out

    def absolute(self, Z: np.ndarray, Q: np.ndarray, B: np.ndarray | None,
                 previous: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The URDF's coordinates (Z with every joint angle absolute, root increment folded; Q)
        of a solver-form pose, the ball angles continuous over the frames (BallJoint.angles;
        `previous`: the angles (n_dofs,) the first frame continues from, default zero)."""
        Z = np.array(Z, dtype=float)
        Q = retract_root(Q, Z[:, FrameLayout.rotation])
        Z[:, FrameLayout.rotation] = 0.0
        if B is None:
            return Z, Q
        for i, b in enumerate(self.balls):
            cols = FrameLayout.angle(b.dofs)
            R = quat_matrices(quat_multiply(B[:, i], b.quaternion(Z[:, cols])))
            Z[:, cols] = b.angles(R, None if previous is None else np.asarray(previous)[list(b.dofs)])
        return Z, Q

    def batch(self, Z: np.ndarray, Q_ref: np.ndarray, p) -> tuple[np.ndarray, np.ndarray]:
        """Markers (n_frames, n_markers, 3) and centres (n_frames, n_joints, 3) for many frames.

        Evaluated by one mapped CasADi call, not a Python loop over frames.
        """
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        Q_ref = np.atleast_2d(np.asarray(Q_ref, dtype=float))
        nf = Z.shape[0]
        if Z.shape[1] != self.model.nz or Q_ref.shape != (nf, 4):
            raise ValueError(f"batch: expected Z ({nf}, {self.model.nz}) and Q_ref ({nf}, 4), "
                             f"got {Z.shape} and {Q_ref.shape}")
        nm, nj = len(self.model.markers), len(self.model.joints)
        f = self.h.map(nf, "thread", 2)
        M, C = f(Z.T, Q_ref.T, np.tile(_pvec(p)[:, None], (1, nf)))
        M = np.asarray(M).reshape(3, nf, nm).transpose(1, 2, 0)
        C = np.asarray(C).reshape(3, nf, nj).transpose(1, 2, 0)
        return M, C


class FrameEvaluator:
    """Evaluates a per-frame function f(z, q_ref, p, ...) -> (markers, d markers/dz) into preallocated
    numpy memory (CasADi's Function.buffer), skipping the DM-to-numpy conversion that otherwise
    costs more than the evaluation itself.  Inputs after p (e.g. the calibration problem's observed
    markers) are held at zero.  The Jacobian output is dense (Kinematics.h_jz), or sparse with
    `pattern` = (rows, cols, n_rows, nz) of its nonzeros, which are spread into a dense array.

    ``ev(z, q_ref)`` returns (markers (3 n_markers,), dm_dz (3 n_markers, nz)); both are
    reused buffers, overwritten by the next call: copy what you keep.
    """

    def __init__(self, f: ca.Function, p: np.ndarray,
                 pattern: tuple[np.ndarray, np.ndarray, int, int] | None = None):
        self._f = f  # keep the Function alive while its buffer is used
        self._buf, self._eval = f.buffer()
        self._z = np.zeros(f.nnz_in(0))
        self._q = np.zeros(f.nnz_in(1))
        self._p = np.array(p, dtype=float)
        args = [self._z, self._q, self._p] + [np.zeros(f.nnz_in(i)) for i in range(3, f.n_in())]
        self._args = args
        self.markers = np.zeros(f.nnz_out(0))
        if pattern is None:
            self.jacobian = np.zeros(f.size_out(1), order="F")
            self._jnz = self.jacobian.reshape(-1, order="F")
            self._flat = None
        else:
            rows, cols, n_rows, nz = pattern
            self._jnz = np.zeros(rows.size)
            self.jacobian = np.zeros((n_rows, nz))
            self._flat = rows * nz + cols
        for i, a in enumerate(args):
            self._buf.set_arg(i, memoryview(a))
        self._buf.set_res(0, memoryview(self.markers))
        self._buf.set_res(1, memoryview(self._jnz))

    def __call__(self, z: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._z[:] = z
        self._q[:] = q_ref
        self._eval()
        if self._flat is not None:
            self.jacobian.reshape(-1)[self._flat] = self._jnz
        return self.markers, self.jacobian


def _pvec(p) -> np.ndarray:
    return p.vector() if isinstance(p, Parameters) else np.asarray(p, dtype=float).ravel()


def kinematic_structure(model: Model, balls: tuple[BallJoint, ...], markers: bool = True) -> str:
    """A digest of everything build_kinematics' graphs are made of: the model's tree (each URDF joint's links,
    owner, role, index and DoF), its fixed rotations and offsets, its sizes, and the SO(3) balls' DoFs and axes.
    Two models with the same digest have the same functions of (z, refs, p); their parameter values, limits and
    names of markers may differ.  `markers` false: of the tree without its markers (segment_poses' graph,
    which any marker set on the model shares)."""
    h = hashlib.sha256(repr((model.root, model.nz, len(model.segments), len(model.joints), model.n_dofs,
                             len(model.markers) if markers else -1, [s.name for s in model.segments])).encode())
    h.update(repr([(b.name, b.dofs, np.asarray(b.axes, dtype=float).tolist()) for b in balls]).encode())
    for u in model.urdf_joints:
        if u.role == "marker" and not markers:
            continue
        h.update(repr((u.parent_link, u.child_link, u.owner, u.role, u.index, u.dof)).encode())
        h.update(np.asarray(u.rotation, dtype=float).tobytes())
        if u.role not in ("centre", "marker"):  # a fixed offset (the others read p)
            h.update(np.asarray(u.xyz, dtype=float).tobytes())
    return h.hexdigest()[:24]


BUILT_KEPT = 8  # build_kinematics keeps the graphs of this many model structures (the latest used)
_BUILT: OrderedDict[str, Kinematics] = OrderedDict()  # by kinematic_structure; a memo, never changed in place
_BUILT_LOCK = threading.Lock()


def build_kinematics(model: Model, euler: tuple[str, ...] = ()) -> Kinematics:
    """Build h(z, q_ref, p), the solver's form h_ref(z, refs, p) and their exact Jacobians for
    `model` (SX graphs, one frame).  `euler`: ball joints the solver keeps on their three angles
    (those with a locked coordinate; see so3_balls).  The graphs are made once per model structure
    (kinematic_structure) and shared, CasADi functions being immutable: a simulation, its calibration and
    the checks after it would build the same graphs three times (0.15-0.3 s each).  The Kinematics
    returned is `model`'s own (its model, its balls' limits)."""
    balls = so3_balls(model, tuple(euler))
    key = kinematic_structure(model, balls)
    with _BUILT_LOCK:
        built = _BUILT.get(key)
        if built is not None:
            _BUILT.move_to_end(key)
    if built is None:
        built = _build(model, balls)
        with _BUILT_LOCK:
            _BUILT[key] = built
            while len(_BUILT) > BUILT_KEPT:
                _BUILT.popitem(last=False)
    return replace(built, model=model, balls=balls, compiled=None)


def _walk(model: Model, balls: tuple[BallJoint, ...], z, q_in, p, so3: bool, markers: bool = True):
    """The model's tree walked symbolically from the root: each link's pose (R, t) in the lab frame, and the
    markers' and joint centres' positions (None for the markers when `markers` is false: then `p` may stop
    before the markers' entries, as the per-frame segment poses of calibrate.problem.codegen take it).
    `q_in`: the root's reference quaternion, or (so3) the refs vector of h_ref."""
    nj, nm = len(model.joints), len(model.markers)
    L = model.layout
    scale = p[L.scales]
    centre = ca.reshape(p[L.group("centre")], 3, nj)  # column j = centre of joint j
    axis = ca.reshape(p[L.group("axis")], 3, model.n_dofs)
    marker = ca.reshape(p[L.group("marker")], 3, nm) if markers else None
    theta = z[L.frame.all_angles]
    seg_idx = {s.name: i for i, s in enumerate(model.segments)}
    # First DoF of each SO(3) ball -> (reference slot, constant unit axes of its three DoFs).
    first = {b.dofs[0]: i for i, b in enumerate(balls)}
    ball_axis = {d: b.axes[k] for b in balls for k, d in enumerate(b.dofs)}
    R_root = quat_to_matrix(q_in[0:4]) @ cayley(z[FrameLayout.rotation])
    pose: dict[str, tuple[ca.SX, ca.SX]] = {model.root: (R_root, z[FrameLayout.translation])}
    mk_pos: list[ca.SX] = [None] * nm  # type: ignore[list-item]
    jc_pos: list[ca.SX] = [None] * nj  # type: ignore[list-item]
    for u in model.urdf_joints:
        if u.role == "marker" and not markers:
            continue
        R_p, t_p = pose[u.parent_link]
        s = scale[seg_idx[u.owner]]
        if u.role == "centre":
            xyz = s * centre[:, u.index]
        elif u.role == "marker":
            xyz = s * marker[:, u.index]
        else:
            xyz = s * ca.DM(u.xyz)
        t_o = t_p + R_p @ xyz
        if u.role == "marker":
            mk_pos[u.index] = t_o
            continue
        if u.role == "centre":
            jc_pos[u.index] = t_o
        R_o = R_p if np.array_equal(u.rotation, np.eye(3)) else R_p @ ca.DM(u.rotation)
        if u.dof >= 0 and so3 and u.dof in ball_axis:
            if u.dof in first:  # the ball's reference rotation, then its increment
                i = first[u.dof]
                R_o = R_o @ quat_to_matrix(q_in[4 + 4 * i:8 + 4 * i])
            R_o = R_o @ axis_angle(ca.DM(ball_axis[u.dof]), theta[u.dof])
        elif u.dof >= 0:
            R_o = R_o @ axis_angle(axis[:, u.dof], theta[u.dof])
        pose[u.child_link] = (R_o, t_o)
    return pose, (mk_pos if markers else None), jc_pos


def segment_poses(model: Model, balls: tuple[BallJoint, ...]) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
    """(z, refs, p_kin, X): every segment's pose in the solver's form h_ref, X = [t, vec(R)] segment after
    segment (12 each, R column by column), as a function of the frame's coordinates, its refs and the
    geometry before the markers' entries (p_kin = p[:layout.offsets['marker']]): what the markers of any
    marker set on this model are linear in (calibrate.problem.marker_map)."""
    z = ca.SX.sym("z", model.nz)
    refs = ca.SX.sym("refs", 4 * (1 + len(balls)))
    p = ca.SX.sym("p", model.layout.offsets["marker"])
    pose, _, _ = _walk(model, balls, z, refs, p, True, markers=False)
    X = ca.vertcat(*[ca.vertcat(pose[s.name][1], ca.vec(pose[s.name][0])) for s in model.segments])
    return z, refs, p, X


def _build(model: Model, balls: tuple[BallJoint, ...]) -> Kinematics:
    """build_kinematics' graphs for `model` (uncached)."""
    z = ca.SX.sym("z", model.nz)
    q_ref = ca.SX.sym("q_ref", 4)
    refs = ca.SX.sym("refs", 4 * (1 + len(balls)))
    p = ca.SX.sym("p", model.layout.n_full)
    outs = []
    for name, arg, q_in, so3 in (("h", "q_ref", q_ref, False), ("h_ref", "refs", refs, True)):
        _, mk_pos, jc_pos = _walk(model, balls, z, q_in, p, so3)
        M = ca.horzcat(*mk_pos)
        C = ca.horzcat(*jc_pos) if jc_pos else ca.SX(3, 0)
        m_vec = ca.vec(M)
        outs.append(ca.Function(name, [z, q_in, p], [M, C], ["z", arg, "p"], ["markers", "centres"]))
        outs.append(ca.Function(f"{name}_jz", [z, q_in, p], [m_vec, ca.densify(ca.jacobian(m_vec, z))],
                                ["z", arg, "p"], ["markers", "dm_dz"]))
    return Kinematics(model, *outs, balls)
