"""Symbolic forward kinematics h(z, p) in CasADi, built by walking the model's tree.

The ``pin`` wheel has no ``pinocchio.casadi``, so the expressions are assembled here
from the joint types, origins and axes that :class:`calibrate.model.Model` read off
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

Geometric parameters ``p = Parameters.vector()`` = [scale, centre, axis, marker]:
a joint centre sits at ``scale[parent segment] * centre`` in the parent segment frame,
a marker at ``scale[segment] * marker``, a revolute joint turns about ``axis/|axis|``.

Outputs: ``markers`` (3 × n_markers) and ``centres`` (3 × n_joints), lab frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from .model import Model, Parameters


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


def cayley_np(delta: np.ndarray) -> np.ndarray:
    """Numeric Cayley map (same as :func:`cayley`)."""
    g = 0.5 * np.asarray(delta, dtype=float)
    G = np.array([[0, -g[2], g[1]], [g[2], 0, -g[0]], [-g[1], g[0], 0]])
    return np.eye(3) + (2.0 / (1.0 + g @ g)) * (G + G @ G)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (x, y, z, w), vectorised over leading axes."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, float), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ], axis=-1)


def cayley_quat(delta: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of Cay(delta), vectorised over leading axes."""
    g = 0.5 * np.asarray(delta, dtype=float)
    q = np.concatenate([g, np.ones(g.shape[:-1] + (1,))], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def retract_root(q_ref: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Fold rotation increments into reference quaternions: q_ref ⊗ Cay(delta), normalised."""
    q = quat_multiply(q_ref, cayley_quat(delta))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)  # keep w >= 0 (same rotation)


@dataclass(frozen=True)
class Kinematics:
    """CasADi functions of one model's forward kinematics.

    h:        (z, q_ref, p) -> (markers 3×n_markers, centres 3×n_joints)
    jac:      (z, q_ref, p) -> (d vec(markers)/dz, d vec(markers)/dp), sparse, exact;
              vec() stacks marker after marker: rows 3k..3k+2 are marker k's x, y, z.
    h_jz:     (z, q_ref, p) -> (vec(markers), d vec(markers)/dz): one call per IK iteration.
    """

    model: Model
    h: ca.Function
    h_jz: ca.Function

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

    def markers(self, z, q_ref, p) -> np.ndarray:
        """Marker positions (n_markers, 3) for one frame."""
        return np.asarray(self.h(z, q_ref, _pvec(p))[0]).T

    def centres(self, z, q_ref, p) -> np.ndarray:
        """Joint-centre positions (n_joints, 3) for one frame."""
        return np.asarray(self.h(z, q_ref, _pvec(p))[1]).T

    def frame_evaluator(self, p) -> FrameEvaluator:
        """A fast evaluator of (vec(markers), d vec(markers)/dz) for one frame at fixed `p`."""
        return FrameEvaluator(self.h_jz, _pvec(p))

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
    """Evaluates h_jz into preallocated numpy memory (CasADi's Function.buffer), skipping the
    DM-to-numpy conversion that otherwise costs more than the evaluation itself.

    ``ev(z, q_ref)`` returns (markers (3 n_markers,), dm_dz (3 n_markers, nz)); both are
    reused buffers, overwritten by the next call: copy what you keep.
    """

    def __init__(self, h_jz: ca.Function, p: np.ndarray):
        self._f = h_jz  # keep the Function alive while its buffer is used
        self._buf, self._eval = h_jz.buffer()
        self._z = np.zeros(h_jz.nnz_in(0))
        self._q = np.zeros(4)
        self._p = np.array(p, dtype=float)
        self.markers = np.zeros(h_jz.nnz_out(0))
        self.jacobian = np.zeros(h_jz.size_out(1), order="F")
        for i, a in enumerate((self._z, self._q, self._p)):
            self._buf.set_arg(i, memoryview(a))
        self._buf.set_res(0, memoryview(self.markers))
        self._buf.set_res(1, memoryview(self.jacobian.reshape(-1, order="F")))

    def __call__(self, z: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._z[:] = z
        self._q[:] = q_ref
        self._eval()
        return self.markers, self.jacobian


def _pvec(p) -> np.ndarray:
    return p.vector() if isinstance(p, Parameters) else np.asarray(p, dtype=float).ravel()


def build_kinematics(model: Model) -> Kinematics:
    """Build h(z, q_ref, p) and its exact Jacobians for `model` (SX graph, one frame)."""
    nz = model.nz
    ns, nj, nd, nm = len(model.segments), len(model.joints), model.n_dofs, len(model.markers)
    z = ca.SX.sym("z", nz)
    q_ref = ca.SX.sym("q_ref", 4)
    p = ca.SX.sym("p", ns + 3 * (nj + nd + nm))
    a = np.cumsum([0, ns, 3 * nj, 3 * nd, 3 * nm])
    scale = p[a[0]:a[1]]
    centre = ca.reshape(p[a[1]:a[2]], 3, nj)  # column j = centre of joint j
    axis = ca.reshape(p[a[2]:a[3]], 3, nd)
    marker = ca.reshape(p[a[3]:a[4]], 3, nm)
    theta = z[6:]

    seg_idx = {s.name: i for i, s in enumerate(model.segments)}
    pose: dict[str, tuple[ca.SX, ca.SX]] = {model.root: (quat_to_matrix(q_ref) @ cayley(z[3:6]), z[0:3])}
    mk_pos: list[ca.SX] = [None] * nm  # type: ignore[list-item]
    jc_pos: list[ca.SX] = [None] * nj  # type: ignore[list-item]
    for u in model.urdf_joints:
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
        if u.dof >= 0:
            R_o = R_o @ axis_angle(axis[:, u.dof], theta[u.dof])
        pose[u.child_link] = (R_o, t_o)

    M = ca.horzcat(*mk_pos)
    C = ca.horzcat(*jc_pos) if jc_pos else ca.SX(3, 0)
    h = ca.Function("h", [z, q_ref, p], [M, C], ["z", "q_ref", "p"], ["markers", "centres"])
    m_vec = ca.vec(M)
    h_jz = ca.Function("h_jz", [z, q_ref, p], [m_vec, ca.densify(ca.jacobian(m_vec, z))],
                       ["z", "q_ref", "p"], ["markers", "dm_dz"])
    return Kinematics(model, h, h_jz)
