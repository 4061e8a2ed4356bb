"""A frame's markers and their exact Jacobians as a linear map of its segments' poses.

A marker k on segment s sits at m_k = t_s + R_s (c_s o_k) (c_s the segment's scale, o_k the marker's unscaled
offset, both in p): given X_f = [t_s, vec(R_s)] of every segment and X's derivatives in z and in the geometry
before the markers (calibrate.model.kinematics.segment_poses, compiled per model structure by
calibrate.problem.codegen), each marker coordinate and each nonzero of ∂m/∂z and ∂m/∂p is a sum of entries of
X_f times coefficients that depend on p alone (1, c_s o_kj, o_kj or c_s):

    m_ka        = t_sa + Σ_j R_saj c_s o_kj
    ∂m_ka/∂z_c  = ∂t_sa/∂z_c + Σ_j ∂R_saj/∂z_c c_s o_kj             (likewise for the geometry before the markers)
    ∂m_ka/∂c_s += Σ_j R_saj o_kj,      ∂m_ka/∂o_kj = R_saj c_s.

So the compiled code depends on the model's tree, not on its markers: a lab's own labels placed on a model
already compiled (a new marker set, markers added or left out) evaluate at once, through one generic kernel
(calibrate.solve.assembly's cal_gather).  The nonzeros come out in CasADi's order for the same Jacobians
(column by column, rows ascending), so the rest of the problem reads them as it read CasADi's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.model import Model

POSE = 12  # entries of X per segment: t (3), then R column by column (9)


@dataclass(frozen=True)
class Gather:
    """out[i] = Σ_k X[xi[k]] · p̄[pa[k]] · p̄[pb[k]] over rowptr[i] <= k < rowptr[i + 1], p̄ = [p, 1]: one output's
    nonzeros from a frame's X (calibrate.solve.assembly.kernels().gather)."""

    rowptr: np.ndarray  # (n_out + 1,) int64
    xi: np.ndarray  # (n_terms,) int64: entry of X
    pa: np.ndarray  # (n_terms,) int64: entries of p̄ whose product is the term's coefficient
    pb: np.ndarray

    @property
    def size(self) -> int:
        return self.rowptr.size - 1

    def coefficients(self, p_bar: np.ndarray) -> np.ndarray:
        """Each term's coefficient at the geometry p̄ = [p, 1]."""
        return p_bar[self.pa] * p_bar[self.pb]


@dataclass(frozen=True)
class MarkerMap:
    """The markers (`d`), ∂m/∂z's nonzeros (`z`) and ∂m/∂p's (`p`) of one marker set on one model, as gathers
    from X; `z_pattern` / `p_pattern`: (row, column) of each nonzero, rows 3k..3k+2 marker k's x, y, z."""

    d: Gather
    z: Gather
    p: Gather
    z_pattern: tuple[np.ndarray, np.ndarray]
    p_pattern: tuple[np.ndarray, np.ndarray]
    n_values: int  # entries of X before its derivatives (POSE per segment)


def _by_row(rows: np.ndarray, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """(order, start): the nonzeros of a pattern sorted by row (stable), and where each row's begin."""
    order = np.argsort(rows, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n_rows))])
    return order, start


def _through(src: np.ndarray, pattern: tuple[np.ndarray, np.ndarray], n_rows: int, base: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For terms reading row src[t] of X's values through a Jacobian of X (its nonzeros' (row, column)
    `pattern`, stored in X from entry `base` on): (term, column, entry of X) of each nonzero they read."""
    rows, cols = pattern
    order, start = _by_row(rows, n_rows)
    n = start[src + 1] - start[src]
    term = np.repeat(np.arange(src.size), n)
    within = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
    nz = order[start[src][term] + within]
    return term, cols[nz], base + nz


def _gather(out_row: np.ndarray, out_col: np.ndarray, xi: np.ndarray, pa: np.ndarray, pb: np.ndarray,
            n_rows: int) -> tuple[Gather, tuple[np.ndarray, np.ndarray]]:
    """The gather summing the terms that land on each (row, column), the outputs in column-major order."""
    key = out_col.astype(np.int64) * n_rows + out_row
    keys, out = np.unique(key, return_inverse=True)
    order = np.argsort(out, kind="stable")
    rowptr = np.concatenate([[0], np.cumsum(np.bincount(out, minlength=keys.size))]).astype(np.int64)
    g = Gather(rowptr, xi[order].astype(np.int64), pa[order].astype(np.int64), pb[order].astype(np.int64))
    return g, (keys % n_rows, keys // n_rows)


def marker_map(model: Model, z_pattern: tuple[np.ndarray, np.ndarray],
               p_pattern: tuple[np.ndarray, np.ndarray]) -> MarkerMap:
    """The MarkerMap of `model`'s markers from the patterns of X's Jacobians in z and in p before the markers
    (segment_poses' X stored as [values, ∂X/∂z's nonzeros, ∂X/∂p's nonzeros], in the patterns' order)."""
    L = model.layout
    seg = {s.name: i for i, s in enumerate(model.segments)}
    nm, n_values = len(model.markers), POSE * len(model.segments)
    one = L.n_full  # p̄'s last entry: 1
    s_of = np.array([seg[mk.segment] for mk in model.markers], dtype=np.int64)
    k, a = np.repeat(np.arange(nm), 3), np.tile(np.arange(3), nm)
    row = 3 * k + a
    scale = L.scale(s_of[k])
    # Each coordinate's four terms: t_a (coefficient 1), and R_aj times c_s o_kj for j = 0, 1, 2.
    src = np.column_stack([POSE * s_of[k] + a] + [POSE * s_of[k] + 3 + a + 3 * j for j in range(3)])
    offset = np.column_stack([L.offsets["marker"] + 3 * k + j for j in range(3)])
    pa = np.column_stack([np.full(row.size, one), scale, scale, scale])
    pb = np.column_stack([np.full(row.size, one), offset])
    t_row, t_src, t_pa, t_pb = np.repeat(row, 4), src.ravel(), pa.ravel(), pb.ravel()
    d, _ = _gather(t_row, np.zeros_like(t_row), t_src, t_pa, t_pb, 3 * nm)
    n_z = z_pattern[0].size
    term, col, xi = _through(t_src, z_pattern, n_values, n_values)
    z, zpat = _gather(t_row[term], col, xi, t_pa[term], t_pb[term], 3 * nm)
    term, col, xi = _through(t_src, p_pattern, n_values, n_values + n_z)
    # The marker's own terms in p: its segment's scale (Σ_j R_aj o_kj) and its offset (R_aj c_s).
    rot = src[:, 1:].ravel()
    own_row, own_scale, own_offset = np.repeat(row, 3), np.repeat(scale, 3), offset.ravel()
    ones = np.full(rot.size, one)
    p, ppat = _gather(np.concatenate([t_row[term], own_row, own_row]),
                      np.concatenate([col, own_scale, own_offset]),
                      np.concatenate([xi, rot, rot]),
                      np.concatenate([t_pa[term], own_offset, own_scale]),
                      np.concatenate([t_pb[term], ones, ones]), 3 * nm)
    return MarkerMap(d, z, p, zpat, ppat, n_values)
