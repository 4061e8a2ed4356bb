"""Eliminating the frame blocks of the damped normal equations: each frame's Cholesky factor and its
share of the Schur complement on the parameters (calibrate.solve.lm and calibrate.solve.chunks use it),
the model's predicted decrease, Marquardt's scaling and the retraction of a step onto the manifolds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..problem.problem import Problem
from ..problem.state import Linearization, State
from .assembly import column_runs, factor_frames, in_parallel, split_frames

DIAG_FLOOR = 1e-9  # relative floor of Marquardt's scaling diagonal
GEODESIC_H = 0.1  # finite-difference step (fraction of the LM step) of the geodesic acceleration
GEODESIC_RATIO = 0.75  # the acceleration is used while 2|a| <= this times |v| (Transtrum & Sethna's alpha)


@dataclass
class Elimination:
    """The frame blocks eliminated, each in reverse coordinate order (leaves of the kinematic
    tree first, the root last), the order in which a Cholesky factor of A_f has no fill-in
    and Y_f = L_f⁻¹ B_f keeps the sparsity of B_f: a coordinate's row couples only with the
    parameters of the segments below it."""

    L: np.ndarray  # (F, nz, nz) Cholesky factor of the reversed (damped) A_f
    Y: np.ndarray  # (F, nz, n)  L⁻¹ B_f (rows reversed)
    yz: np.ndarray  # (F, nz)    L⁻¹ g_z (rows reversed)
    S: np.ndarray  # (n, n)      Σ_f Y_f' Y_f


def y_pattern(lin: Linearization, n: int) -> np.ndarray:
    """Where Y = L⁻¹ B_f (rows reversed) can be nonzero, (nz, n) booleans: B's pattern propagated
    symbolically through the factorisation, so it is exact whatever the coordinate order."""
    nz = lin.A.shape[1]
    if lin.a_pattern is None or lin.b_pattern is None:
        return np.ones((nz, n), dtype=bool)
    P = lin.a_pattern[::-1, ::-1] | np.eye(nz, dtype=bool)
    for k in range(nz):  # symbolic Cholesky: eliminating k joins its later neighbours
        nb = k + 1 + np.flatnonzero(P[k + 1:, k])
        P[np.ix_(nb, nb)] = True
    Yp = lin.b_pattern[::-1].copy()
    for i in range(nz):
        for j in np.flatnonzero(P[i, :i]):
            Yp[i] |= Yp[j]
    return Yp


def row_classes(lin: Linearization, n: int, Yp: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rows of Y (reversed order) grouped by their nonzero columns (y_pattern): (rows, columns) per class."""
    nz = lin.A.shape[1]
    Yp = y_pattern(lin, n) if Yp is None else Yp
    classes: dict[bytes, list[int]] = {}
    for i in range(nz):
        classes.setdefault(Yp[i].tobytes(), []).append(i)
    return [(np.array(rows), np.flatnonzero(Yp[rows[0]])) for rows in classes.values()]


def buffer(work: dict | None, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """An uninitialised array, kept in `work` and reused by later calls (large temporaries
    allocated afresh on every step cost page faults and allocator churn)."""
    if work is None:
        return np.empty(shape)
    a = work.get((name, shape))
    if a is None:
        a = work[(name, shape)] = np.empty(shape)
    return a


def _pattern_key(lin: Linearization) -> tuple | None:
    """The key under which `work` keeps Y's row classes and column runs for the blocks' nonzero patterns
    (they change only with the free set); None without patterns."""
    if lin.a_pattern is None or lin.b_pattern is None:
        return None
    return ("row_classes", lin.a_pattern.tobytes(), lin.b_pattern.tobytes(), lin.b_pattern.shape)


def eliminate(lin: Linearization, damping: np.ndarray, with_parameters: bool = True,
               work: dict | None = None) -> Elimination | None:
    """Cholesky of every A_f + diag(damping_f) and the frames' share of the Schur complement;
    None if a block is not positive definite.  The factorisation runs in compiled loops
    (calibrate.solve.assembly.factor_frames); the Schur complement is accumulated by BLAS, class by
    class of Y's rows, with the frames split between the cores.  `work`: buffers to reuse."""
    F, nz, n = lin.B.shape
    n = n if with_parameters else 0
    L = buffer(work, "L", (F, nz, nz))
    yz = buffer(work, "yz", (F, nz))
    damping = np.ascontiguousarray(damping, dtype=float)
    if n == 0:
        Y = np.empty((F, nz, 0))
        ok = factor_frames(lin.A, damping, Y, lin.gz, L, Y, yz)
        return Elimination(L, Y, yz, np.zeros((0, 0))) if ok else None
    key = _pattern_key(lin)
    cached = None if work is None or key is None else work.get(key)
    if cached is None:
        Yp = y_pattern(lin, n)
        cached = (row_classes(lin, n, Yp), None if Yp.all() else column_runs(Yp))
        if work is not None and key is not None:
            work[key] = cached  # the patterns change only with the free set: one per problem
    classes, runs = cached
    # Y is formed only on its nonzero pattern (factor_frames): the rest stays zero.  A new buffer is zeroed
    # by the allocator (its pages first touched by the factorisation's threads); a kept one again only when
    # the pattern changes.
    Y, zeroed_for = (None, None) if work is None else work.get(("Y", (F, nz, n)), (None, None))
    if Y is None:
        Y = np.zeros((F, nz, n))
    elif runs is not None and zeroed_for != key:
        Y.fill(0.0)
    if work is not None:
        work[("Y", Y.shape)] = (Y, key)
    if not factor_frames(lin.A, damping, lin.B, lin.gz, L, Y, yz, runs):
        return None

    def part(fr: slice) -> np.ndarray:
        S = np.zeros((n, n))
        for rows, cols in classes:
            if cols.size == 0:
                continue
            if rows[-1] - rows[0] + 1 == rows.size and cols.size == n:  # every column (the root's rows): a copy,
                M = np.ascontiguousarray(Y[fr, rows[0]:rows[-1] + 1])  # the same array as take's, 15x sooner
                M = M.reshape(-1, n)
                S += M.T @ M
                continue
            if rows[-1] - rows[0] + 1 == rows.size:  # consecutive rows (a joint's coordinates): a view
                M = np.take(Y[fr, rows[0]:rows[-1] + 1], cols, axis=2)
            else:
                M = np.take(Y[fr][:, rows], cols, axis=2)
            M = M.reshape(-1, cols.size)
            S[np.ix_(cols, cols)] += M.T @ M
        return S

    results = in_parallel(part, split_frames(F))
    return Elimination(L, Y, yz, sum(results[1:], results[0]))


def refactor_frames(lin: Linearization, damping: np.ndarray, el: Elimination, frames: np.ndarray,
                    work: dict | None = None) -> bool:
    """`el` (eliminate's, at the same damping) brought up to date after the blocks of `frames` changed in
    `lin` (A_f, g_f): their factors formed again and their share of the Schur complement swapped, the other
    frames' untouched.  In place; False if one of the blocks is not positive definite."""
    frames = np.unique(frames)
    _, nz, n = el.Y.shape
    key = _pattern_key(lin)
    cached = None if work is None or key is None else work.get(key)
    runs = None if cached is None or n == 0 else cached[1]
    L, Y, yz = np.empty((frames.size, nz, nz)), np.zeros((frames.size, nz, n)), np.empty((frames.size, nz))
    B = lin.B[frames] if n else np.empty((frames.size, nz, 0))
    if not factor_frames(lin.A[frames], np.ascontiguousarray(damping[frames]), B, lin.gz[frames], L, Y, yz, runs):
        return False
    if n:
        old = el.Y[frames].reshape(-1, n)
        el.S -= old.T @ old
        new = Y.reshape(-1, n)
        el.S += new.T @ new
        el.Y[frames] = Y
    el.L[frames], el.yz[frames] = L, yz
    return True


def retract(problem: Problem, state: State, dz: np.ndarray, dp: np.ndarray) -> State:
    """`state` moved by (dz, dp): root and ball-joint rotations folded into their references
    (Kinematics.retract), axes kept unit."""
    Z, Q, B = problem.kin.retract(state.Z + dz, state.Q, state.B)
    p = problem.retract_parameters(state.p, dp) if dp.size else state.p.copy()
    return State(Z, Q, p, B)


def frames_times(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    """M_f x for every frame of the blocks M (F, rows, n): (F, rows).  One matrix-vector product over
    the frames' rows stacked (a view of M), 2.5 times sooner than matmul's product frame by frame
    (pig_walk's B and Y: 821 frames x 38 rows x 200 columns)."""
    F, rows, n = M.shape
    return (M.reshape(F * rows, n) @ x).reshape(F, rows)


def model_decrease(lin: Linearization, dz: np.ndarray, dp: np.ndarray) -> float:
    """Decrease of the Gauss–Newton model −(g'h + ½ h'Hh) for the step h = (dz, dp)."""
    Adz = np.matmul(lin.A, dz[:, :, None])[:, :, 0]
    quad = float(np.sum(dz * Adz))
    lin_term = float(np.sum(lin.gz * dz))
    if dp.size:
        Bdp = frames_times(lin.B, dp)
        quad += 2.0 * float(np.sum(dz * Bdp)) + float(dp @ lin.C @ dp)
        lin_term += float(lin.gp @ dp)
    return -(lin_term + 0.5 * quad)


def marquardt_diagonal(diagonal: np.ndarray, largest: float) -> np.ndarray:
    """Marquardt's scaling: the normal matrix's diagonal, floored relative to its largest entry
    (a coordinate the markers do not reach still gets some damping)."""
    return np.maximum(diagonal, DIAG_FLOOR * max(1.0, largest))
