"""Per-frame normal equations of the calibration problem, assembled in compiled loops (numba).

For every frame f and every segment that carries markers (a *group*: its marker rows, the
coordinates z and the free parameters its markers depend on), the weighted Jacobian blocks
Jz (rows x coordinates) and Jp (rows x free parameters) are gathered from CasADi's sparse
nonzeros and multiplied out:

    A_f += Jz'Jz    B_f += Jz'Jp    g_z,f += Jz'e    C += Jp'Jp    g_p += Jp'e

The blocks are tiny (at most ~20 rows, 16 coordinates, 60 parameters), so numpy spends its
time in call overhead and scattered writes; one compiled loop per frame writes A_f and B_f in
place instead.  Frames are split between the cores; each core keeps its own share of C and g_p.
The free-parameter map T (Problem.tangent_map: positions at the subject's scale, axes in their
tangent planes) is folded into the gather: each nonzero of ∂r/∂p_full is spread to the free
columns its row of T reaches (one or two), so ∂r/∂p_free is never formed densely.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit

WORKERS = max(1, min(2, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


def split_frames(F: int, min_frames: int = 64) -> list[slice]:
    """Frames 0..F-1 in one contiguous part per worker thread (a single part for few frames)."""
    k = max(1, min(WORKERS, F // min_frames))
    edges = np.linspace(0, F, k + 1).astype(int)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def in_parallel(work, parts: list) -> list:
    """work(part) for every part, on WORKERS threads (numpy's batched kernels and the compiled
    kernels here release the GIL)."""
    if len(parts) == 1:
        return [work(parts[0])]
    with ThreadPoolExecutor(len(parts)) as pool:
        return list(pool.map(work, parts))


@dataclass(frozen=True)
class GroupLayout:
    """The groups' fixed index arrays, concatenated (offsets per group)."""

    rows: np.ndarray  # residual rows of each group's markers
    row_off: np.ndarray  # (G + 1,)
    zcols: np.ndarray  # coordinates each group depends on
    zc_off: np.ndarray
    z_src: np.ndarray  # CasADi nonzero index of ∂r/∂z ...
    z_r: np.ndarray  # ... its local row ...
    z_c: np.ndarray  # ... and local coordinate column
    z_off: np.ndarray


@dataclass(frozen=True)
class ParameterLayout:
    """Each group's free columns and the gather ∂r/∂p_full nonzero -> (row, free column) x T value,
    for the current T (it depends on p)."""

    fcols: np.ndarray  # free parameter columns of each group
    fc_off: np.ndarray
    p_src: np.ndarray
    p_r: np.ndarray
    p_c: np.ndarray
    p_val: np.ndarray
    p_off: np.ndarray


def parameter_layout(groups, T: np.ndarray) -> ParameterLayout:
    """The gather of ∂r/∂p_free from ∂r/∂p_full's nonzeros through the free-parameter map T (n_full, n_free)."""
    fcols, src, rr, cc, val = [], [], [], [], []
    fc_off, off = [0], [0]
    for g in groups:
        Tg = T[g.pcols]
        fc = np.flatnonzero(np.any(Tg != 0, axis=0))
        local = np.full(T.shape[1], -1)
        local[fc] = np.arange(fc.size)
        npc = g.pcols.size
        r_of, c_of = g.p_dst // npc, g.p_dst % npc  # local row and full column of each ∂r/∂p nonzero
        ti, tj = np.nonzero(Tg)  # T's nonzeros (local full column, free column), by row
        lo, hi = np.searchsorted(ti, c_of, "left"), np.searchsorted(ti, c_of, "right")
        cnt = hi - lo
        rep = np.repeat(np.arange(c_of.size), cnt)  # each nonzero once per free column it reaches
        at = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(lo, cnt)
        src.append(g.p_src[rep])
        rr.append(r_of[rep])
        cc.append(local[tj[at]])
        val.append(Tg[c_of[rep], tj[at]])
        fcols.append(fc)
        fc_off.append(fc_off[-1] + fc.size)
        off.append(off[-1] + rep.size)
    cat = lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)  # noqa: E731
    return ParameterLayout(cat(fcols, np.int64), np.array(fc_off, dtype=np.int64), cat(src, np.int64),
                           cat(rr, np.int64), cat(cc, np.int64), cat(val, np.float64), np.array(off, dtype=np.int64))


def group_layout(groups) -> GroupLayout:
    """The fixed gather of ∂r/∂z per group (Problem.groups)."""
    rows, zcols, src, r, c = [], [], [], [], []
    row_off, zc_off, z_off = [0], [0], [0]
    for g in groups:
        rows.append(g.rows)
        zcols.append(g.zcols)
        nzc = g.zcols.size
        src.append(g.z_src)
        r.append(g.z_dst // nzc)
        c.append(g.z_dst % nzc)
        row_off.append(row_off[-1] + g.rows.size)
        zc_off.append(zc_off[-1] + nzc)
        z_off.append(z_off[-1] + g.z_src.size)
    i = lambda xs: np.concatenate(xs).astype(np.int64)  # noqa: E731
    o = lambda xs: np.array(xs, dtype=np.int64)  # noqa: E731
    return GroupLayout(i(rows), o(row_off), i(zcols), o(zc_off), i(src), i(r), i(c), o(z_off))


def assemble(d: np.ndarray, w: np.ndarray, jz: np.ndarray, jp: np.ndarray | None, gl: GroupLayout,
             pl: ParameterLayout | None, A: np.ndarray, B: np.ndarray, gz: np.ndarray,
             n: int, gradient_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Fill A (F, nz, nz), B (F, nz, n), gz (F, nz) in place from the residuals d (F, rows),
    row weights w (F, rows; 0 where a marker is not seen) and the CasADi nonzeros jz, jp;
    return (C, g_p) of the data.  `jp`/`pl` None: poses only (B, C, g_p untouched / empty).
    `gradient_only`: only g_z = Jz'(w d) and g_p (A, B and C untouched; C returned empty), e.g.
    for the geodesic acceleration, whose right-hand side is J' times a second derivative."""
    F = d.shape[0]
    with_p = jp is not None and pl is not None and n > 0
    if not with_p:
        none, offs = np.zeros(0, np.int64), np.zeros(len(gl.row_off), np.int64)
        pl = ParameterLayout(none, offs, none, none, none, np.zeros(0), offs)
        jp = np.zeros((F, 1))

    def part(fr: slice) -> tuple[np.ndarray, np.ndarray]:
        Ct, gt = np.zeros((n, n)), np.zeros(n)
        _assemble(d, w, jz, jp, fr.start, fr.stop, with_p, gradient_only,
                  gl.rows, gl.row_off, gl.zcols, gl.zc_off, gl.z_src, gl.z_r, gl.z_c, gl.z_off,
                  pl.fcols, pl.fc_off, pl.p_src, pl.p_r, pl.p_c, pl.p_val, pl.p_off, A, B, gz, Ct, gt)
        return Ct, gt

    parts = in_parallel(part, split_frames(F))
    C = sum(c for c, _ in parts[1:]) + parts[0][0] if len(parts) > 1 else parts[0][0]
    gp = sum(g for _, g in parts)
    if gradient_only:
        return np.zeros((0, 0)), gp
    C = np.tril(C) + np.tril(C, -1).T  # the kernel fills the lower triangle
    return C, gp


@njit(cache=True, nogil=True, fastmath=True)
def _assemble(d, w, jz, jp, f0, f1, with_p, grad_only, rows, row_off, zcols, zc_off, z_src, z_r, z_c, z_off,
              fcols, fc_off, p_src, p_r, p_c, p_val, p_off, A, B, gz, Ct, gt):  # pragma: no cover (compiled)
    # The blocks are kept transposed (column by row) so that every inner product runs over
    # contiguous memory and vectorises.
    n_groups = row_off.size - 1
    max_r = 1
    max_zc = 1
    max_fc = 1
    for g in range(n_groups):
        max_r = max(max_r, row_off[g + 1] - row_off[g])
        max_zc = max(max_zc, zc_off[g + 1] - zc_off[g])
        if with_p:
            max_fc = max(max_fc, fc_off[g + 1] - fc_off[g])
    Jz = np.zeros((max_zc, max_r))
    Jp = np.zeros((max_fc, max_r))
    e = np.zeros(max_r)
    wr = np.zeros(max_r)
    for f in range(f0, f1):
        gz[f] = 0.0
        if not grad_only:
            A[f] = 0.0
            if with_p:
                B[f] = 0.0
        for g in range(n_groups):
            r0 = row_off[g]
            nr = row_off[g + 1] - r0
            seen = False
            for a in range(nr):
                wr[a] = w[f, rows[r0 + a]]
                e[a] = d[f, rows[r0 + a]] * wr[a]
                if wr[a] != 0.0:
                    seen = True
            if not seen:
                continue
            c0 = zc_off[g]
            nc = zc_off[g + 1] - c0
            Jz[:nc, :nr] = 0.0
            for k in range(z_off[g], z_off[g + 1]):
                Jz[z_c[k], z_r[k]] = jz[f, z_src[k]] * wr[z_r[k]]
            for a in range(nc):
                ia = zcols[c0 + a]
                za = Jz[a]
                s = 0.0
                for r in range(nr):
                    s += za[r] * e[r]
                gz[f, ia] += s
                if grad_only:
                    continue
                for b in range(nc):
                    zb = Jz[b]
                    s = 0.0
                    for r in range(nr):
                        s += za[r] * zb[r]
                    A[f, ia, zcols[c0 + b]] += s
            if not with_p:
                continue
            q0 = fc_off[g]
            nq = fc_off[g + 1] - q0
            if nq == 0:
                continue
            Jp[:nq, :nr] = 0.0
            for k in range(p_off[g], p_off[g + 1]):
                Jp[p_c[k], p_r[k]] += jp[f, p_src[k]] * p_val[k] * wr[p_r[k]]
            for a in range(nc if not grad_only else 0):
                ia = zcols[c0 + a]
                za = Jz[a]
                for b in range(nq):
                    pb = Jp[b]
                    s = 0.0
                    for r in range(nr):
                        s += za[r] * pb[r]
                    B[f, ia, fcols[q0 + b]] += s
            for a in range(nq):
                ka = fcols[q0 + a]
                pa = Jp[a]
                s = 0.0
                for r in range(nr):
                    s += pa[r] * e[r]
                gt[ka] += s
                if grad_only:
                    continue
                for b in range(a + 1):
                    kb = fcols[q0 + b]
                    pb = Jp[b]
                    s = 0.0
                    for r in range(nr):
                        s += pa[r] * pb[r]
                    if ka >= kb:
                        Ct[ka, kb] += s
                    else:
                        Ct[kb, ka] += s


def factor_frames(A: np.ndarray, damping: np.ndarray, B: np.ndarray, gz: np.ndarray, L: np.ndarray,
                  Y: np.ndarray, yz: np.ndarray) -> bool:
    """Cholesky of every frame block A_f + diag(damping_f), in reverse coordinate order (leaves of the
    kinematic tree first: no fill-in), into L (F, nz, nz); Y = L⁻¹ B_f and yz = L⁻¹ g_z (rows
    reversed), in place.  False if a block is not positive definite."""
    return all(in_parallel(lambda fr: _factor(A, damping, B, gz, L, Y, yz, fr.start, fr.stop),
                           split_frames(A.shape[0])))


def back_substitute(L: np.ndarray, t: np.ndarray) -> np.ndarray:
    """x with L_fᵀ x_f = t_f for every frame (rows reversed, as factor_frames leaves them)."""
    x = np.empty_like(t)
    t = np.ascontiguousarray(t)
    in_parallel(lambda fr: _back(L, t, x, fr.start, fr.stop), split_frames(L.shape[0]))
    return x


def forward_substitute(L: np.ndarray, g: np.ndarray) -> np.ndarray:
    """y with L_f y_f = g_f (rows of g reversed, as factor_frames takes them) for every frame."""
    y = np.empty_like(g)
    g = np.ascontiguousarray(g)
    in_parallel(lambda fr: _forward(L, g, y, fr.start, fr.stop), split_frames(L.shape[0]))
    return y


@njit(cache=True, nogil=True, fastmath=True)
def _factor(A, damping, B, gz, L, Y, yz, f0, f1):  # pragma: no cover (compiled)
    nz = A.shape[1]
    n = B.shape[2]
    ok = True
    for f in range(f0, f1):
        Lf = L[f]
        for i in range(nz):
            for j in range(nz):
                Lf[i, j] = A[f, nz - 1 - i, nz - 1 - j] if j <= i else 0.0
            Lf[i, i] += damping[f, nz - 1 - i]
        for j in range(nz):
            s = Lf[j, j]
            for k in range(j):
                if Lf[j, k] != 0.0:
                    s -= Lf[j, k] * Lf[j, k]
            if not s > 0.0:
                ok = False
                s = 1.0
            piv = np.sqrt(s)
            Lf[j, j] = piv
            for i in range(j + 1, nz):
                s = Lf[i, j]
                for k in range(j):
                    if Lf[j, k] != 0.0:
                        s -= Lf[i, k] * Lf[j, k]
                Lf[i, j] = s / piv
        for i in range(nz):
            yi = Y[f, i]
            yi[:] = B[f, nz - 1 - i]
            s = gz[f, nz - 1 - i]
            for k in range(i):
                lik = Lf[i, k]
                if lik != 0.0:
                    s -= lik * yz[f, k]
                    yk = Y[f, k]
                    for c in range(n):
                        yi[c] -= lik * yk[c]
            inv = 1.0 / Lf[i, i]
            yz[f, i] = s * inv
            for c in range(n):
                yi[c] *= inv
    return ok


@njit(cache=True, nogil=True, fastmath=True)
def _back(L, t, x, f0, f1):  # pragma: no cover (compiled)
    nz = L.shape[1]
    for f in range(f0, f1):
        for i in range(nz - 1, -1, -1):
            s = t[f, i]
            for k in range(i + 1, nz):
                s -= L[f, k, i] * x[f, k]
            x[f, i] = s / L[f, i, i]


@njit(cache=True, nogil=True, fastmath=True)
def _forward(L, g, y, f0, f1):  # pragma: no cover (compiled)
    nz = L.shape[1]
    for f in range(f0, f1):
        for i in range(nz):
            s = g[f, nz - 1 - i]
            for k in range(i):
                s -= L[f, i, k] * y[f, k]
            y[f, i] = s / L[f, i, i]
