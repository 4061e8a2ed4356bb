"""Eliminating the frame blocks of the damped normal equations: each frame's Cholesky factor and its
share of the Schur complement on the parameters (calibrate.solve.lm and calibrate.solve.chunks use it),
the model's predicted decrease, Marquardt's scaling and the retraction of a step onto the manifolds."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..problem.problem import Problem
from ..problem.state import Linearization, State
from .assembly import (
    ColumnRuns,
    Packing,
    Structure,
    column_runs,
    factor_frames,
    factor_pattern_of,
    factor_structure,
    in_parallel,
    split_frames,
    y_pattern_of,
)

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
    Y: PackedRows  # (F, nz, n)  L⁻¹ B_f (rows reversed), stored by its row classes
    yz: np.ndarray  # (F, nz)    L⁻¹ g_z (rows reversed)
    S: np.ndarray  # (n, n)      Σ_f Y_f' Y_f


@dataclass(frozen=True)
class RowPacking:
    """Where PackedRows keeps each row class of Y for F frames: the classes' blocks (F, rows, columns) one
    after another in one flat buffer, and the factorisation kernel's destination of each row's runs."""

    F: int
    nz: int
    n: int
    classes: tuple[tuple[np.ndarray, np.ndarray, int], ...]  # (rows, columns, offset in the buffer) per class
    runs: ColumnRuns  # each row's nonzero columns as runs (column_runs of y_pattern)
    packing: Packing  # factor_frames' destinations of the runs
    size: int  # the buffer's length
    structure: Structure | None = None  # the factor's nonzero structure (factor_structure), None: dense

    @staticmethod
    def of(classes: list[tuple[np.ndarray, np.ndarray]], runs: ColumnRuns, F: int, nz: int, n: int,
           structure: Structure | None = None) -> RowPacking:
        """The packing of Y's row classes (row_classes; classes with no columns are not kept: their rows are
        zero) for F frames, each row's runs (`runs`, the same pattern) in the order of its class's columns."""
        run_off, run_lo, run_hi, _ = runs
        base, fstride = np.zeros(nz, np.int64), np.zeros(nz, np.int64)
        run_dst = np.zeros(run_lo.size, np.int64)
        kept, at = [], 0
        for rows, cols in classes:
            if cols.size == 0:
                continue
            kept.append((rows, cols, at))
            for j, i in enumerate(rows):
                base[i], fstride[i] = at + j * cols.size, rows.size * cols.size
                rs = slice(run_off[i], run_off[i + 1])
                lengths = run_hi[rs] - run_lo[rs]
                run_dst[rs] = np.cumsum(lengths) - lengths  # each run's place among the row's columns
            at += F * rows.size * cols.size
        return RowPacking(F, nz, n, tuple(kept), runs, (base, fstride, run_dst), at, structure)


class PackedRows:
    """Y = L⁻¹ B_f of every frame (F, nz, n; rows reversed) stored row class by row class (row_classes: rows
    with the same nonzero columns), each class as one contiguous (F, rows, columns) block of its nonzero
    columns only: about a third of the dense array on gait models, and the Schur complement's products
    run on views of it (no gathers)."""

    def __init__(self, layout: RowPacking, data: np.ndarray):
        self.layout, self.data = layout, data

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.layout.F, self.layout.nz, self.layout.n

    def blocks(self, frames: slice | None = None):
        """(rows, columns, block) of every class, block (frames, rows, columns) a view of the buffer."""
        F = self.layout.F
        for rows, cols, at in self.layout.classes:
            block = self.data[at:at + F * rows.size * cols.size].reshape(F, rows.size, cols.size)
            yield rows, cols, block if frames is None else block[frames]

    def times(self, x: np.ndarray) -> np.ndarray:
        """Y_f x for every frame: (F, nz)."""
        F, nz, _ = self.shape
        out = np.zeros((F, nz))
        for rows, cols, block in self.blocks():
            out[:, rows] = (block.reshape(-1, cols.size) @ x[cols]).reshape(F, rows.size)
        return out

    def transpose_times(self, v: np.ndarray) -> np.ndarray:
        """Σ_f Y_f' v_f for v (F, nz): (n,)."""
        out = np.zeros(self.layout.n)
        for rows, cols, block in self.blocks():
            out[cols] += block.reshape(-1, cols.size).T @ v[:, rows].reshape(-1)
        return out

    def gram(self, frames: slice) -> np.ndarray:
        """Σ_f Y_f' Y_f over `frames` (a slice): (n, n), each class's product by BLAS on a view."""
        n = self.layout.n
        S = np.zeros((n, n))
        for _, cols, block in self.blocks(frames):
            M = block.reshape(-1, cols.size)
            if cols.size == n:
                S += M.T @ M
            else:
                S[np.ix_(cols, cols)] += M.T @ M
        return S

    def dense(self, frames: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Y of `frames` as a dense (frames, nz, n) array."""
        F, nz, n = self.shape
        out = np.zeros((np.arange(F)[frames].size, nz, n))
        for rows, cols, block in self.blocks():
            out[:, rows[:, None], cols] = block[frames]
        return out

    def put(self, frames: np.ndarray, dense: np.ndarray) -> None:
        """Y of `frames` set from a dense (frames, nz, n) array (zero outside the pattern)."""
        for rows, cols, block in self.blocks():
            block[frames] = dense[:, rows[:, None], cols]


class GaugeBasis:
    """An orthonormal basis N (n, n − rank K) of the parameter steps dp with K dp = 0 (the gauge
    constraints), held as the Householder reflectors of K's QR factorisation in compact WY form
    (Q = I − V T Vᵀ; N is Q's columns past K's rank), never as a dense n × n matrix: the reduced Schur
    complement NᵀSN then costs O(n²k) for k constraints rather than O(n³) (Rajagopal: 287 parameters,
    19 constraints, 0.45 against 1.04 ms per step), and N's products are a few thin ones."""

    def __init__(self, K: np.ndarray):
        k, n = K.shape
        h, tau = np.linalg.qr(K.T, mode="raw")  # h: LAPACK's (k, n) output, the reflectors below R's diagonal
        independent = _independent_rows(h)
        if 0 < independent.sum() < k:
            # A row (numerically) in the span of the rows before it adds no constraint; without it the first
            # reflectors span K's rows and the rest its null space, wherever in K the dependent row was.
            K = K[independent]
            k = K.shape[0]
            h, tau = np.linalg.qr(K.T, mode="raw")
            independent = _independent_rows(h)
        V = np.tril(h.T, -1)
        V[np.arange(k), np.arange(k)] = 1.0
        T = np.zeros((k, k))  # Q = H_1 ... H_k = I − V T Vᵀ, T upper triangular (LAPACK's dlarft, forward)
        for j in range(k):
            T[j, j] = tau[j]
            if j:
                T[:j, j] = -tau[j] * (T[:j, :j] @ (V[:, :j].T @ V[:, j]))
        self.rank = int(independent.sum())  # k, unless K is all zero
        self.n = n
        self.V, self.T = V, T

    def project(self, S: np.ndarray) -> np.ndarray:
        """NᵀSN for a symmetric S (n, n)."""
        V, T, r = self.V, self.T, self.rank
        SQ = S[:, r:] - ((S @ V) @ T) @ V[r:].T  # (S Q)[:, r:]
        return SQ[r:] - V[r:] @ (T.T @ (V.T @ SQ))

    def down(self, v: np.ndarray) -> np.ndarray:
        """Nᵀv for v (n,)."""
        V, r = self.V, self.rank
        return v[r:] - V[r:] @ (self.T.T @ (V.T @ v))

    def up(self, x: np.ndarray) -> np.ndarray:
        """N x for x (n − rank,)."""
        V, r = self.V, self.rank
        out = np.zeros(self.n)
        out[r:] = x
        return out - V @ (self.T @ (V[r:].T @ x))

    def dense(self) -> np.ndarray:
        """N as a dense (n, n − rank) matrix."""
        E = np.zeros((self.n, self.n - self.rank))
        E[self.rank:] = np.eye(self.n - self.rank)
        return E - self.V @ (self.T @ self.V[self.rank:].T)


def _independent_rows(h: np.ndarray) -> np.ndarray:
    """Which rows of K are independent of the rows before it, from its QR (np.linalg.qr's raw `h`): R's
    diagonal entry above a relative tolerance."""
    d = np.abs(np.diagonal(h))
    return d > 1e-10 * max(1e-300, d.max(initial=0.0))


def factor_pattern(lin: Linearization) -> np.ndarray:
    """Where the Cholesky factor of the reversed A_f can be nonzero, (nz, nz) booleans (factor_pattern_of);
    every entry without patterns."""
    nz = lin.A.shape[1]
    return np.ones((nz, nz), dtype=bool) if lin.a_pattern is None else factor_pattern_of(lin.a_pattern)


def y_pattern(lin: Linearization, n: int) -> np.ndarray:
    """Where Y = L⁻¹ B_f (rows reversed) can be nonzero, (nz, n) booleans: B's pattern propagated
    symbolically through the factorisation (y_pattern_of), so it is exact whatever the coordinate order."""
    nz = lin.A.shape[1]
    if lin.a_pattern is None or lin.b_pattern is None:
        return np.ones((nz, n), dtype=bool)
    return y_pattern_of(lin.a_pattern, lin.b_pattern)


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
    """The key (with the frames' and parameters' counts: _packing) under which `work` keeps Y's packing for
    the blocks' nonzero patterns (they change only with the free set); None without patterns."""
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
    packed = _packing(lin, F, n, work)
    if n == 0:
        none = np.empty((F, nz, 0))
        ok = factor_frames(lin.A, damping, none, lin.gz, L, none, yz, structure=packed.structure)
        return Elimination(L, PackedRows(packed, np.zeros(0)), yz, np.zeros((0, 0))) if ok else None
    data = buffer(work, "Y", (packed.size,))
    if not factor_frames(lin.A, damping, lin.B, lin.gz, L, data, yz, packed.runs, packed.packing, packed.structure):
        return None
    Y = PackedRows(packed, data)
    results = in_parallel(Y.gram, split_frames(F))
    return Elimination(L, Y, yz, sum(results[1:], results[0]))


def _packing(lin: Linearization, F: int, n: int, work: dict | None) -> RowPacking:
    """Y's row classes packed for F frames (kept in `work`: the patterns change only with the free set)."""
    key = _pattern_key(lin)
    key = None if key is None else (*key, F, n)
    packed = None if work is None or key is None else work.get(key)
    if packed is None:
        Yp = y_pattern(lin, n)
        structure = None if lin.a_pattern is None else factor_structure(factor_pattern(lin))
        packed = RowPacking.of(row_classes(lin, n, Yp), column_runs(Yp), F, lin.A.shape[1], n, structure)
        if work is not None and key is not None:
            work[key] = packed
    return packed


def refactor_frames(lin: Linearization, damping: np.ndarray, el: Elimination, frames: np.ndarray,
                    work: dict | None = None) -> bool:
    """`el` (eliminate's, at the same damping) brought up to date after the blocks of `frames` changed in
    `lin` (A_f, g_f): their factors formed again and their share of the Schur complement swapped, the other
    frames' untouched.  In place; False if one of the blocks is not positive definite."""
    frames = np.unique(frames)
    _, nz, n = el.Y.shape
    packed = _packing(lin, el.Y.shape[0], n, work)
    L, Y, yz = np.empty((frames.size, nz, nz)), np.zeros((frames.size, nz, n)), np.empty((frames.size, nz))
    B = lin.B[frames] if n else np.empty((frames.size, nz, 0))
    if not factor_frames(lin.A[frames], np.ascontiguousarray(damping[frames]), B, lin.gz[frames], L, Y, yz,
                         packed.runs if n else None, structure=packed.structure):
        return False
    if n:
        old = el.Y.dense(frames).reshape(-1, n)
        el.S -= old.T @ old
        new = Y.reshape(-1, n)
        el.S += new.T @ new
        el.Y.put(frames, Y)
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
