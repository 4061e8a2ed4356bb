"""Rotations in numpy: quaternions (x, y, z, w), rotation matrices, rotation vectors and Euler angles, computed
as scipy.spatial.transform.Rotation computes them (tests/test_kinematics.py checks them against it) without importing
scipy (a quarter of a second of every command's start), and the root's and balls' retraction on SO(3)
(calibrate.model.kinematics, the solver).  None of this enters the symbolic kinematics: the compiled per-frame code's
cache key (calibrate.problem.codegen) does not read this module."""

from __future__ import annotations

import math

import numpy as np


def cayley_np(delta: np.ndarray) -> np.ndarray:
    """Numeric Cayley map (same as :func:`cayley`)."""
    g = 0.5 * np.asarray(delta, dtype=float)
    G = np.array([[0, -g[2], g[1]], [g[2], 0, -g[0]], [-g[1], g[0], 0]])
    return np.eye(3) + (2.0 / (1.0 + g @ g)) * (G + G @ G)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (x, y, z, w), vectorised over leading axes."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 1] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 2] = aw * bz + ax * by - ay * bx + az * bw
    out[..., 3] = aw * bw - ax * bx - ay * by - az * bz
    return out


def cayley_quat(delta: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of Cay(delta), vectorised over leading axes."""
    g = 0.5 * np.asarray(delta, dtype=float)
    q = np.concatenate([g, np.ones(g.shape[:-1] + (1,))], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def retract_root(q_ref: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Fold rotation increments into reference quaternions: q_ref ⊗ Cay(delta), normalised."""
    if np.ndim(q_ref) == 1 and np.ndim(delta) == 1:
        return _retract_one(q_ref, delta)
    q = quat_multiply(q_ref, cayley_quat(delta))
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:4] < 0, -q, q)  # keep w >= 0 (same rotation)


def _retract_one(q_ref: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """retract_root of one quaternion and one increment in floats: the same operations in the same order
    (the same bits), 8 times sooner than numpy's calls on 4-vectors; frame-wise inverse kinematics makes
    one per step."""
    g0, g1, g2 = 0.5 * float(delta[0]), 0.5 * float(delta[1]), 0.5 * float(delta[2])
    n = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2 + 1.0)
    c0, c1, c2, c3 = g0 / n, g1 / n, g2 / n, 1.0 / n
    ax, ay, az, aw = (float(v) for v in q_ref)
    x = aw * c0 + ax * c3 + ay * c2 - az * c1
    y = aw * c1 - ax * c2 + ay * c3 + az * c0
    z = aw * c2 + ax * c1 - ay * c0 + az * c3
    w = aw * c3 - ax * c0 - ay * c1 - az * c2
    m = math.sqrt(x * x + y * y + z * z + w * w)
    q = np.array([x / m, y / m, z / m, w / m])
    return -q if q[3] < 0 else q


def _quat_multiply_floats(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    """quat_multiply of two quaternions given as floats, its arithmetic in its order (the same bits)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def quat_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (F, 3, 3) of quaternions (F, 4) (x, y, z, w), normalised inside."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrix_quats(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) (x, y, z, w) of rotation matrices (..., 3, 3), by the largest of
    the trace and the diagonal (Markley's choice), as Rotation.from_matrix(R).as_quat()."""
    R = np.asarray(R, dtype=float)
    d = np.concatenate([np.diagonal(R, axis1=-2, axis2=-1), np.trace(R, axis1=-2, axis2=-1)[..., None]], axis=-1)
    choice = d.argmax(axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    q[..., 0] = R[..., 2, 1] - R[..., 1, 2]
    q[..., 1] = R[..., 0, 2] - R[..., 2, 0]
    q[..., 2] = R[..., 1, 0] - R[..., 0, 1]
    q[..., 3] = 1 + d[..., 3]
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        on = choice == i
        q[on, i] = 1 - d[on, 3] + 2 * R[on, i, i]
        q[on, j] = R[on, j, i] + R[on, i, j]
        q[on, k] = R[on, k, i] + R[on, i, k]
        q[on, 3] = R[on, k, j] - R[on, j, k]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_rotvecs(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) (axis × angle, angle in [0, π]) of quaternions (..., 4) (x, y, z, w),
    as Rotation.from_quat(q).as_rotvec()."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., 3:4] < 0, -q, q)
    s = np.linalg.norm(q[..., :3], axis=-1)
    angle = 2 * np.arctan2(s, q[..., 3])
    small = angle <= 1e-3
    a2 = angle * angle
    scale = np.where(small, 2 + a2 / 12 + 7 * a2 * a2 / 2880, angle / np.sin(np.where(small, 1.0, angle / 2)))
    return scale[..., None] * q[..., :3]


def rotvec_quats(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) (x, y, z, w) of rotation vectors (..., 3), as
    Rotation.from_rotvec(v).as_quat()."""
    v = np.asarray(v, dtype=float)
    angle = np.linalg.norm(v, axis=-1)
    small = angle <= 1e-3
    a2 = angle * angle
    scale = np.where(small, 0.5 - a2 / 48 + a2 * a2 / 3840, np.sin(angle / 2) / np.where(small, 1.0, angle))
    return np.concatenate([scale[..., None] * v, np.cos(angle / 2)[..., None]], axis=-1)


def quat_inverse(q: np.ndarray) -> np.ndarray:
    """The inverse rotations of unit quaternions (..., 4) (x, y, z, w): their conjugates."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([-q[..., :3], q[..., 3:]], axis=-1)


def slerp_quats(times: np.ndarray, q: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Rotations (n, 4) between key rotations q (k, 4) (x, y, z, w) at increasing `times` (k ≥ 2),
    at times `at` (n, within the keys' range): along the shortest arc between the neighbouring keys,
    as scipy's Slerp(times, Rotation.from_quat(q))(at).as_quat()."""
    times, at = np.asarray(times, dtype=float), np.asarray(at, dtype=float)
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(at < times[0]) or np.any(at > times[-1]):
        raise ValueError("slerp_quats: interpolation times must lie within the key times")
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, times.size - 2)
    step = quat_rotvecs(quat_multiply(quat_inverse(q[:-1]), q[1:]))  # from each key to the next
    alpha = (at - times[i]) / np.diff(times)[i]
    return quat_multiply(q[i], rotvec_quats(step[i] * alpha[:, None]))


def rotvec_matrices(v: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of rotation vectors (..., 3), as Rotation.from_rotvec(v).as_matrix()."""
    return quat_matrices(rotvec_quats(v))


def matrix_rotvecs(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) (angle in [0, π]) of rotation matrices (..., 3, 3), as
    Rotation.from_matrix(R).as_rotvec()."""
    return quat_rotvecs(matrix_quats(R))


def _euler_sequence(seq: str, lengths: tuple[int, ...]) -> tuple[list[int], bool]:
    """The axis indices (x 0, y 1, z 2) of an Euler sequence as scipy's Rotation reads it, and whether it is
    intrinsic (upper case: each turn about the body's axes as turned so far) rather than extrinsic (lower case:
    about the fixed axes)."""
    intrinsic = len(seq) > 0 and set(seq) <= set("XYZ")
    if len(seq) not in lengths or not (intrinsic or set(seq) <= set("xyz")) or any(
            a == b for a, b in zip(seq, seq[1:], strict=False)):
        raise ValueError(f"Euler sequence {seq!r}: expected {' or '.join(map(str, lengths))} of the letters x, y, z "
                         "(fixed axes) or X, Y, Z (the body's), no axis twice in a row")
    return ["xyz".index(c) for c in seq.lower()], intrinsic


def euler_quats(seq: str, angles) -> np.ndarray:
    """Unit quaternions (..., 4) (x, y, z, w) of Euler angles (..., len(seq)) in radians (a single angle for a
    one-letter `seq`), as Rotation.from_euler(seq, angles).as_quat(): 'XYZ' is OpenSim's body-fixed
    x-y-z (R = Rx Ry Rz), 'xyz' URDF's roll-pitch-yaw (R = Rz Ry Rx)."""
    axes, intrinsic = _euler_sequence(seq, (1, 2, 3))
    angles = np.asarray(angles, dtype=float)
    if len(axes) == 1 and angles.ndim == 0:
        angles = angles[None]
    if angles.ndim == 0 or angles.shape[-1] != len(axes):
        raise ValueError(f"Euler sequence {seq!r} takes {len(axes)} angles, got an array of shape {angles.shape}")
    q = None
    for k, axis in enumerate(axes):
        e = np.zeros(angles.shape[:-1] + (4,))
        e[..., 3] = np.cos(angles[..., k] / 2.0)
        e[..., axis] = np.sin(angles[..., k] / 2.0)
        q = e if q is None else quat_multiply(q, e) if intrinsic else quat_multiply(e, q)
    return q


def euler_matrices(seq: str, angles) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of Euler angles (euler_quats), as Rotation.from_euler(seq, angles).as_matrix()."""
    return quat_matrices(euler_quats(seq, angles))


def quat_eulers(q: np.ndarray, seq: str) -> np.ndarray:
    """Euler angles (..., 3) in radians of quaternions (..., 4) (x, y, z, w) about a three-letter sequence
    (euler_quats' letters), as Rotation.from_quat(q).as_euler(seq): the quaternion method of Bernardes &
    Viollet (2022), scipy's.  The middle angle lies in [-π/2, π/2] (Tait-Bryan: x-y-z and the like) or [0, π]
    (proper Euler: z-x-z ...), the outer ones in [-π, π); at gimbal lock (the middle angle within 1e-7 of its
    end) the third is 0 and the first carries the whole turn (scipy warns there; this does not)."""
    axes, intrinsic = _euler_sequence(seq, (3,))
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    i, j, k = axes if not intrinsic else axes[::-1]
    symmetric = i == k
    if symmetric:
        k = 3 - i - j
    sign = float((i - j) * (j - k) * (k - i) // 2)
    if symmetric:
        a, b, c, d = q[..., 3], q[..., i], q[..., j], q[..., k] * sign
    else:
        a, b = q[..., 3] - q[..., j], q[..., i] + q[..., k] * sign
        c, d = q[..., j] + q[..., 3], q[..., k] * sign - q[..., i]
    extrinsic = not intrinsic
    half_sum, half_diff = np.arctan2(b, a), np.arctan2(d, c)
    out = np.zeros(a.shape + (3,))
    out[..., 1] = 2 * np.arctan2(np.hypot(c, d), np.hypot(a, b))
    first, third = (0, 2) if extrinsic else (2, 0)
    case1 = np.abs(out[..., 1]) <= 1e-7
    case2 = np.abs(out[..., 1] - np.pi) <= 1e-7
    case0 = ~(case1 | case2)
    out[..., 0] = np.where(case1, 2 * half_sum, 2 * half_diff * (-1 if extrinsic else 1))
    out[..., first] = np.where(case0, half_sum - half_diff, out[..., first])
    a3 = np.where(case0, half_sum + half_diff, out[..., third])
    if not symmetric:
        a3 = a3 * sign
        out[..., 1] = out[..., 1] - np.pi / 2
    out[..., third] = a3
    return (out + np.pi) % (2 * np.pi) - np.pi


def matrix_eulers(R: np.ndarray, seq: str) -> np.ndarray:
    """Euler angles (..., 3) of rotation matrices (..., 3, 3) (quat_eulers), as
    Rotation.from_matrix(R).as_euler(seq)."""
    return quat_eulers(matrix_quats(R), seq)
