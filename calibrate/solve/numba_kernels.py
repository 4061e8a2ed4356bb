"""The per-frame kernels of calibrate.solve.assembly compiled by numba: the fallback where no C compiler
is found (calibrate.solve.assembly compiles its C versions of the same loops with the system's
compiler, which loads in a millisecond where numba's first call in a process costs 0.2-0.4 s).
Arguments and results as the C functions in calibrate/kernels.c (calibrate.solve.assembly)."""

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, fastmath=True)
def _dot(a, b, n):  # pragma: no cover (compiled)
    """Σ_r a[r] b[r] over the first n entries (inlined by numba)."""
    s = 0.0
    for r in range(n):
        s += a[r] * b[r]
    return s


@njit(cache=True, nogil=True, fastmath=True)
def assemble(d, w, jz, jp, f0, f1, with_p, grad_only, rows, row_off, zcols, zc_off, z_src, z_r, z_c, z_off,
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
            if with_p == 1 or with_p == 3:
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
                gz[f, ia] += _dot(za, e, nr)
                if grad_only:
                    continue
                for b in range(nc):
                    A[f, ia, zcols[c0 + b]] += _dot(za, Jz[b], nr)
            if not with_p:
                continue
            q0 = fc_off[g]
            nq = fc_off[g + 1] - q0
            if nq == 0:
                continue
            Jp[:nq, :nr] = 0.0
            for k in range(p_off[g], p_off[g + 1]):
                Jp[p_c[k], p_r[k]] += jp[f, p_src[k]] * p_val[k] * wr[p_r[k]]
            for a in range(nc if not grad_only and with_p != 2 else 0):
                ia = zcols[c0 + a]
                za = Jz[a]
                for b in range(nq):
                    B[f, ia, fcols[q0 + b]] += _dot(za, Jp[b], nr)
            if with_p == 3:  # the coupling blocks B only
                continue
            for a in range(nq):
                ka = fcols[q0 + a]
                pa = Jp[a]
                gt[ka] += _dot(pa, e, nr)
                if grad_only:
                    continue
                for b in range(a + 1):
                    kb = fcols[q0 + b]
                    s = _dot(pa, Jp[b], nr)
                    if ka >= kb:
                        Ct[ka, kb] += s
                    else:
                        Ct[kb, ka] += s


@njit(cache=True, nogil=True, fastmath=True)
def factor(A, damping, B, gz, L, Y, yz, f0, f1, run_off, run_lo, run_hi, run_class, dst_base, dst_fstride,
           run_dst, lrow_off, lrow_idx, lcol_off, lcol_idx):  # pragma: no cover (compiled)
    # (run_class: the C kernel reduces rows of one class together; here one row at a time, the same sums)
    nz, n = A.shape[1], B.shape[2]
    W = np.empty((nz, max(n, 1)))  # the frame's rows of Y, formed here and then written out (Y: flat)
    ok = True
    for f in range(f0, f1):
        Lf = L[f]
        for i in range(nz):
            for j in range(nz):
                Lf[i, j] = A[f, nz - 1 - i, nz - 1 - j] if j <= i else 0.0
            Lf[i, i] += damping[f, nz - 1 - i]
        for j in range(nz):  # L's structure: row j's nonzeros lrow_idx, column j's lcol_idx (ascending)
            s = Lf[j, j]
            for t in range(lrow_off[j], lrow_off[j + 1]):
                v = Lf[j, lrow_idx[t]]
                if v != 0.0:
                    s -= v * v
            if not s > 0.0:
                ok = False
                s = 1.0
            piv = np.sqrt(s)
            Lf[j, j] = piv
            for u in range(lcol_off[j], lcol_off[j + 1]):
                i = lcol_idx[u]
                s = Lf[i, j]
                for t in range(lrow_off[j], lrow_off[j + 1]):
                    v = Lf[j, lrow_idx[t]]
                    if v != 0.0:
                        s -= Lf[i, lrow_idx[t]] * v
                Lf[i, j] = s / piv
        for i in range(nz):
            yi = W[i]
            bi = B[f, nz - 1 - i]
            for r in range(run_off[i], run_off[i + 1]):
                for c in range(run_lo[r], run_hi[r]):
                    yi[c] = bi[c]
            s = gz[f, nz - 1 - i]
            for t in range(lrow_off[i], lrow_off[i + 1]):
                k = lrow_idx[t]
                lik = Lf[i, k]
                if lik != 0.0:
                    s -= lik * yz[f, k]
                    yk = W[k]
                    for r in range(run_off[k], run_off[k + 1]):
                        for c in range(run_lo[r], run_hi[r]):
                            yi[c] -= lik * yk[c]
            inv = 1.0 / Lf[i, i]
            yz[f, i] = s * inv
            at = dst_base[i] + f * dst_fstride[i]
            for r in range(run_off[i], run_off[i + 1]):
                to = at + run_dst[r] - run_lo[r]
                for c in range(run_lo[r], run_hi[r]):
                    yi[c] *= inv
                    Y[to + c] = yi[c]
    return ok


@njit(cache=True, nogil=True, fastmath=True)
def back(L, t, x, f0, f1):  # pragma: no cover (compiled)
    nz = L.shape[1]
    for f in range(f0, f1):
        for i in range(nz - 1, -1, -1):
            s = t[f, i]
            for k in range(i + 1, nz):
                s -= L[f, k, i] * x[f, k]
            x[f, i] = s / L[f, i, i]


@njit(cache=True, nogil=True, fastmath=True)
def forward(L, g, y, f0, f1):  # pragma: no cover (compiled)
    nz = L.shape[1]
    for f in range(f0, f1):
        for i in range(nz):
            s = g[f, nz - 1 - i]
            for k in range(i):
                s -= L[f, i, k] * y[f, k]
            y[f, i] = s / L[f, i, i]



@njit(cache=True, nogil=True, fastmath=True)
def _gather(X, rowptr, xi, coef, dst, sub, out, f0, f1):  # pragma: no cover (compiled)
    for f in range(f0, f1):
        for i in range(rowptr.size - 1):
            s = 0.0
            for k in range(rowptr[i], rowptr[i + 1]):
                s += X[f, xi[k]] * coef[k]
            out[f, dst[i] if dst.size else i] = s - sub[f, i] if sub.shape[0] else s


_NO_DST = np.empty(0, dtype=np.int64)


def gather(X, rowptr, xi, coef, sub, out, f0, f1):
    """out[f, i] = Σ_k X[f, xi[k]] coef[k] over rowptr[i] <= k < rowptr[i + 1], less sub[f, i] where sub has
    rows (an empty sub: nothing subtracted), for frames f0..f1-1 (cal_gather in kernels.c)."""
    _gather(X, rowptr, xi, coef, _NO_DST, sub, out, f0, f1)


def gatherer(X, rowptr, xi, coef, dst, out):
    """As gather over every frame of X, output i stored at out[f, dst[i]], with these arrays bound (as the C
    kernels' gatherer)."""
    none = np.empty((0, 1))
    return lambda: _gather(X, rowptr, xi, coef, dst, none, out, 0, X.shape[0])
