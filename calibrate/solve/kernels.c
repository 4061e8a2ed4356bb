#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
typedef int64_t I;

/* O (nx × ny) += Σ_r x_r y_rᵀ over the nr rows of X (nr × nx) and Y (nr × ny) (`lower`: only O[a][b] with
   b <= a), four rows at a time: each pass over O adds four rows' products (loads and stores of O, not the
   arithmetic, bound a row-by-row update), and its inner loop runs over contiguous memory and vectorises.  A
   row of X whose entry is zero adds nothing to that row of O (a marker's own columns in the other markers'
   rows). */
static inline __attribute__((always_inline)) void rank_update(const double *X, I nx, const double *Y, I ny, I nr,
                                                              double *O, int lower)
{
    I r = 0;
    for (; r + 4 <= nr; r += 4) {
        const double *x0 = X + r * nx, *x1 = x0 + nx, *x2 = x1 + nx, *x3 = x2 + nx;
        const double *y0 = Y + r * ny, *y1 = y0 + ny, *y2 = y1 + ny, *y3 = y2 + ny;
        for (I a = 0; a < nx; ++a) {
            double s0 = x0[a], s1 = x1[a], s2 = x2[a], s3 = x3[a];
            if (s0 == 0.0 && s1 == 0.0 && s2 == 0.0 && s3 == 0.0) continue;
            double *Oa = O + a * ny;
            I nb = lower ? a + 1 : ny;
            for (I b = 0; b < nb; ++b) Oa[b] += s0 * y0[b] + s1 * y1[b] + s2 * y2[b] + s3 * y3[b];
        }
    }
    for (; r + 2 <= nr; r += 2) {
        const double *x0 = X + r * nx, *x1 = x0 + nx, *y0 = Y + r * ny, *y1 = y0 + ny;
        for (I a = 0; a < nx; ++a) {
            double s0 = x0[a], s1 = x1[a];
            if (s0 == 0.0 && s1 == 0.0) continue;
            double *Oa = O + a * ny;
            I nb = lower ? a + 1 : ny;
            for (I b = 0; b < nb; ++b) Oa[b] += s0 * y0[b] + s1 * y1[b];
        }
    }
    for (; r < nr; ++r) {
        const double *xr = X + r * nx, *yr = Y + r * ny;
        for (I a = 0; a < nx; ++a) {
            double s = xr[a];
            if (s == 0.0) continue;
            double *Oa = O + a * ny;
            I nb = lower ? a + 1 : ny;
            for (I b = 0; b < nb; ++b) Oa[b] += s * yr[b];
        }
    }
}

/* O (nx × ny) = Σ_r x_r y_rᵀ (rank_update from zero). */
static inline __attribute__((always_inline)) void outer_sum(const double *X, I nx, const double *Y, I ny, I nr, double *O)
{
    memset(O, 0, (size_t)(nx * ny) * sizeof(double));
    rank_update(X, nx, Y, ny, nr, O, 0);
}

/* M[ri[a] * stride + ci[b]] += O[a * ny + b]: a dense block added where its rows and columns belong. */
static inline __attribute__((always_inline)) void scatter_add(const double *O, I nx, I ny, const I *ri, const I *ci, double *M, I stride)
{
    for (I a = 0; a < nx; ++a) {
        double *Ma = M + ri[a] * stride;
        const double *Oa = O + a * ny;
        for (I b = 0; b < ny; ++b) Ma[ci[b]] += Oa[b];
    }
}

/* Normal equations of frames f0..f1-1 (see calibrate.solve.assembly.assemble; with_p: 0 no parameters,
   1 B, C and g_p, 2 C and g_p only, 3 B only).  Each group's weighted Jacobian rows are gathered row by
   row (a row: every coordinate's, every free column's entry) and its products formed as sums of the rows'
   outer products into small dense blocks, whose inner loops run over contiguous memory and vectorise (the
   groups are small: inner products over their 3-21 rows cost more in loop overhead than in arithmetic);
   then added where they belong.  A group's share of C and g_p is summed over the frames first and added
   to Ct and gt once, at the end. */
int cal_assemble(const double *d, const double *w, const double *jz, const double *jp,
                 I nrow, I njz, I njp, I nz, I n, I f0, I f1, I with_p, I grad_only, I n_groups,
                 const I *rows, const I *row_off, const I *zcols, const I *zc_off,
                 const I *z_src, const I *z_r, const I *z_c, const I *z_off,
                 const I *fcols, const I *fc_off, const I *p_src, const I *p_r, const I *p_c,
                 const double *p_val, const I *p_off,
                 double *A, double *B, double *gz, double *Ct, double *gt)
{
    I max_r = 1, max_zc = 1, max_fc = 1, c_size = 1, g_size = 1;
    for (I g = 0; g < n_groups; ++g) {
        I nq = with_p ? fc_off[g + 1] - fc_off[g] : 0;
        if (row_off[g + 1] - row_off[g] > max_r) max_r = row_off[g + 1] - row_off[g];
        if (zc_off[g + 1] - zc_off[g] > max_zc) max_zc = zc_off[g + 1] - zc_off[g];
        if (nq > max_fc) max_fc = nq;
        c_size += nq * nq;
        g_size += nq;
    }
    int want_b = with_p && !grad_only && with_p != 2, want_c = with_p && with_p != 3;
    double *Jz = malloc((size_t)(max_zc * max_r) * sizeof(double));
    double *Jp = malloc((size_t)(max_fc * max_r) * sizeof(double));
    double *e = malloc((size_t)max_r * sizeof(double));
    double *wr = malloc((size_t)max_r * sizeof(double));
    double *Al = malloc((size_t)(max_zc * max_zc) * sizeof(double));
    double *Bl = malloc((size_t)(max_zc * max_fc) * sizeof(double));
    double *gl = malloc((size_t)max_zc * sizeof(double));
    double *Cg = calloc((size_t)c_size, sizeof(double));  /* each group's share of C (lower triangle) ... */
    double *Gg = calloc((size_t)g_size, sizeof(double));  /* ... and of g_p, over the frames */
    if (!Jz || !Jp || !e || !wr || !Al || !Bl || !gl || !Cg || !Gg) {
        free(Jz); free(Jp); free(e); free(wr); free(Al); free(Bl); free(gl); free(Cg); free(Gg);
        return 0;
    }
    for (I f = f0; f < f1; ++f) {
        const double *df = d + f * nrow, *wf = w + f * nrow, *jzf = jz + f * njz, *jpf = jp + f * njp;
        double *Af = A + f * nz * nz, *Bf = B + f * nz * n, *gzf = gz + f * nz;
        memset(gzf, 0, (size_t)nz * sizeof(double));
        if (!grad_only) {
            memset(Af, 0, (size_t)(nz * nz) * sizeof(double));
            if (want_b) memset(Bf, 0, (size_t)(nz * n) * sizeof(double));
        }
        I c_at = 0, g_at = 0;
        for (I g = 0; g < n_groups; ++g) {
            I q0 = fc_off[g], nq = with_p ? fc_off[g + 1] - q0 : 0;
            double *Cgg = Cg + c_at, *Ggg = Gg + g_at;
            c_at += nq * nq;
            g_at += nq;
            I r0 = row_off[g], nr = row_off[g + 1] - r0, seen = 0;
            for (I a = 0; a < nr; ++a) {
                wr[a] = wf[rows[r0 + a]];
                e[a] = df[rows[r0 + a]] * wr[a];
                if (wr[a] != 0.0) seen = 1;
            }
            if (!seen) continue;
            I c0 = zc_off[g], nc = zc_off[g + 1] - c0;
            const I *zc = zcols + c0;
            /* Jz row by row: Jz[r * nc + a] */
            memset(Jz, 0, (size_t)(nc * nr) * sizeof(double));
            for (I k = z_off[g]; k < z_off[g + 1]; ++k) Jz[z_r[k] * nc + z_c[k]] = jzf[z_src[k]] * wr[z_r[k]];
            for (I a = 0; a < nc; ++a) gl[a] = 0.0;
            for (I r = 0; r < nr; ++r) {
                const double *zr = Jz + r * nc;
                double er = e[r];
                for (I a = 0; a < nc; ++a) gl[a] += zr[a] * er;
            }
            for (I a = 0; a < nc; ++a) gzf[zc[a]] += gl[a];
            if (!grad_only) {
                outer_sum(Jz, nc, Jz, nc, nr, Al);
                scatter_add(Al, nc, nc, zc, zc, Af, nz);
            }
            if (nq == 0) continue;
            const I *fc = fcols + q0;
            /* Jp row by row: Jp[r * nq + b] */
            memset(Jp, 0, (size_t)(nq * nr) * sizeof(double));
            for (I k = p_off[g]; k < p_off[g + 1]; ++k)
                Jp[p_r[k] * nq + p_c[k]] += jpf[p_src[k]] * p_val[k] * wr[p_r[k]];
            if (want_b) {
                outer_sum(Jz, nc, Jp, nq, nr, Bl);
                scatter_add(Bl, nc, nq, zc, fc, Bf, n);
            }
            if (!want_c) continue;
            for (I r = 0; r < nr; ++r) {
                const double *pr = Jp + r * nq;
                double er = e[r];
                for (I a = 0; a < nq; ++a) Ggg[a] += pr[a] * er;
            }
            if (!grad_only) rank_update(Jp, nq, Jp, nq, nr, Cgg, 1);
        }
    }
    if (want_c) {
        I c_at = 0, g_at = 0;
        for (I g = 0; g < n_groups; ++g) {
            I q0 = fc_off[g], nq = fc_off[g + 1] - q0;
            const double *Cgg = Cg + c_at, *Ggg = Gg + g_at;
            c_at += nq * nq;
            g_at += nq;
            for (I a = 0; a < nq; ++a) {
                I ka = fcols[q0 + a];
                gt[ka] += Ggg[a];
                if (grad_only) continue;
                for (I b = 0; b <= a; ++b) {
                    I kb = fcols[q0 + b];
                    if (ka >= kb) Ct[ka * n + kb] += Cgg[a * nq + b]; else Ct[kb * n + ka] += Cgg[a * nq + b];
                }
            }
        }
    }
    free(Jz); free(Jp); free(e); free(wr); free(Al); free(Bl); free(gl); free(Cg); free(Gg);
    return 1;
}

/* Cholesky of A_f + diag(damping_f) in reverse coordinate order, Y = L^-1 B_f, yz = L^-1 g_z
   (rows reversed); 0 if a block is not positive definite.  Row i of Y is formed only on its column runs
   [run_lo[r], run_hi[r]) for r in run_off[i]..run_off[i+1]-1 (Y's nonzero pattern: the columns outside
   them are zero in B and in every row it is reduced with), in a scratch frame that stays in the cache,
   and each run is then written to Y + dst_base[i] + f * dst_fstride[i] + run_dst[r]: a dense (F, nz, n)
   Y (dst_base i * n, dst_fstride nz * n, run_dst run_lo; the columns outside the runs left as they are)
   or Y packed row class by row class (calibrate.solve.schur.PackedRows). */
int cal_factor(const double *A, const double *damping, const double *B, const double *gz,
               double *L, double *Y, double *yz, I nz, I n, I f0, I f1,
               const I *run_off, const I *run_lo, const I *run_hi,
               const I *dst_base, const I *dst_fstride, const I *run_dst,
               const I *lrow_off, const I *lrow_idx, const I *lcol_off, const I *lcol_idx, const I *run_class)
{
    int ok = 1;
    double *W = malloc((size_t)(nz * (n > 0 ? n : 1)) * sizeof(double));
    if (!W) return -1;
    for (I f = f0; f < f1; ++f) {
        const double *Af = A + f * nz * nz;
        double *Lf = L + f * nz * nz;
        for (I i = 0; i < nz; ++i) {
            for (I j = 0; j < nz; ++j) Lf[i * nz + j] = j <= i ? Af[(nz - 1 - i) * nz + (nz - 1 - j)] : 0.0;
            Lf[i * nz + i] += damping[f * nz + nz - 1 - i];
        }
        /* L's structure: row j's nonzeros left of the diagonal lrow_idx[lrow_off[j]..] (ascending), column j's
           below it lcol_idx[lcol_off[j]..]; every other entry below the diagonal stays zero. */
        for (I j = 0; j < nz; ++j) {
            const I *rj = lrow_idx + lrow_off[j];
            I nrj = lrow_off[j + 1] - lrow_off[j];
            double s = Lf[j * nz + j];
            for (I t = 0; t < nrj; ++t) {
                double v = Lf[j * nz + rj[t]];
                if (v != 0.0) s -= v * v;
            }
            if (!(s > 0.0)) { ok = 0; s = 1.0; }
            double piv = sqrt(s);
            Lf[j * nz + j] = piv;
            for (I u = lcol_off[j]; u < lcol_off[j + 1]; ++u) {
                I i = lcol_idx[u];
                s = Lf[i * nz + j];
                for (I t = 0; t < nrj; ++t) {
                    double v = Lf[j * nz + rj[t]];
                    if (v != 0.0) s -= Lf[i * nz + rj[t]] * v;
                }
                Lf[i * nz + j] = s / piv;
            }
        }
        for (I i = 0; i < nz; ++i) {
            double *yi = W + i * n;
            const double *bi = B + (f * nz + nz - 1 - i) * n;
            for (I r = run_off[i]; r < run_off[i + 1]; ++r)
                memcpy(yi + run_lo[r], bi + run_lo[r], (size_t)(run_hi[r] - run_lo[r]) * sizeof(double));
            double s = gz[f * nz + nz - 1 - i];
            /* yi -= Σ_k L_ik y_k, up to four rows k of one run class (the same runs: class[k]) per pass */
            for (I t = lrow_off[i], te = lrow_off[i + 1]; t < te;) {
                I k0 = lrow_idx[t], m = 1;
                while (m < 4 && t + m < te && run_class[lrow_idx[t + m]] == run_class[k0]) ++m;
                double l0 = 0.0, l1 = 0.0, l2 = 0.0, l3 = 0.0;
                const double *y0 = W, *y1 = W, *y2 = W, *y3 = W;
                for (I q = 0; q < m; ++q) {
                    I k = lrow_idx[t + q];
                    double lik = Lf[i * nz + k];
                    s -= lik * yz[f * nz + k];
                    if (q == 0) { l0 = lik; y0 = W + k * n; }
                    else if (q == 1) { l1 = lik; y1 = W + k * n; }
                    else if (q == 2) { l2 = lik; y2 = W + k * n; }
                    else { l3 = lik; y3 = W + k * n; }
                }
                t += m;
                if (l0 == 0.0 && l1 == 0.0 && l2 == 0.0 && l3 == 0.0) continue;
                for (I r = run_off[k0]; r < run_off[k0 + 1]; ++r) {
                    I c0 = run_lo[r], c1 = run_hi[r];
                    if (m == 1) for (I c = c0; c < c1; ++c) yi[c] -= l0 * y0[c];
                    else if (m == 2) for (I c = c0; c < c1; ++c) yi[c] -= l0 * y0[c] + l1 * y1[c];
                    else if (m == 3) for (I c = c0; c < c1; ++c) yi[c] -= l0 * y0[c] + l1 * y1[c] + l2 * y2[c];
                    else for (I c = c0; c < c1; ++c) yi[c] -= l0 * y0[c] + l1 * y1[c] + l2 * y2[c] + l3 * y3[c];
                }
            }
            double inv = 1.0 / Lf[i * nz + i];
            yz[f * nz + i] = s * inv;
            double *out = Y + dst_base[i] + f * dst_fstride[i];
            for (I r = run_off[i]; r < run_off[i + 1]; ++r) {
                for (I c = run_lo[r]; c < run_hi[r]; ++c) yi[c] *= inv;
                memcpy(out + run_dst[r], yi + run_lo[r], (size_t)(run_hi[r] - run_lo[r]) * sizeof(double));
            }
        }
    }
    free(W);
    return ok;
}

/* x with L_f' x_f = t_f. */
int cal_back(const double *L, const double *t, double *x, I nz, I f0, I f1)
{
    for (I f = f0; f < f1; ++f)
        for (I i = nz - 1; i >= 0; --i) {
            double s = t[f * nz + i];
            for (I k = i + 1; k < nz; ++k) s -= L[(f * nz + k) * nz + i] * x[f * nz + k];
            x[f * nz + i] = s / L[(f * nz + i) * nz + i];
        }
    return 1;
}

/* y with L_f y_f = g_f reversed. */
int cal_forward(const double *L, const double *g, double *y, I nz, I f0, I f1)
{
    for (I f = f0; f < f1; ++f)
        for (I i = 0; i < nz; ++i) {
            double s = g[f * nz + nz - 1 - i];
            for (I k = 0; k < i; ++k) s -= L[(f * nz + i) * nz + k] * y[f * nz + k];
            y[f * nz + i] = s / L[(f * nz + i) * nz + i];
        }
    return 1;
}

/* Σ_k x[xi[k]] c[k] over k0 <= k < k1: four terms at a time (most of the markers' sums have four: the
   translation's and the rotation's three; the loads then overlap). */
static inline __attribute__((always_inline)) double dot_at(const double *x, const I *xi, const double *c, I k0, I k1)
{
    double s = 0.0;
    I k = k0;
    for (; k + 4 <= k1; k += 4)
        s += (x[xi[k]] * c[k] + x[xi[k + 1]] * c[k + 1]) + (x[xi[k + 2]] * c[k + 2] + x[xi[k + 3]] * c[k + 3]);
    for (; k < k1; ++k) s += x[xi[k]] * c[k];
    return s;
}

/* out_f[i] = Σ_k X_f[xi[k]] coef[k] over k in rowptr[i] .. rowptr[i+1]-1, less sub_f[i] where sub is not NULL,
   for frames f0..f1-1: the markers and their Jacobians' nonzeros, linear in the segments' poses and their
   derivatives X_f (calibrate.problem.marker_map).  X (frames × nx), sub (frames × nout), out's frames nstride
   apart; where dst is not NULL, output i is stored at out_f[dst[i]] instead (a frame-wise fit's evaluator writes
   the markers and their Jacobian's nonzeros straight into its dense array). */
int cal_gather(const double *X, I nx, const I *rowptr, const I *xi, const double *coef, I nout, const I *dst,
               const double *sub, double *out, I nstride, I f0, I f1)
{
    for (I f = f0; f < f1; ++f) {
        const double *x = X + f * nx;
        double *o = out + f * nstride;
        for (I i = 0; i < nout; ++i) {
            double s = dot_at(x, xi, coef, rowptr[i], rowptr[i + 1]);
            o[dst ? dst[i] : i] = sub ? s - sub[f * nout + i] : s;
        }
    }
    return 1;
}
