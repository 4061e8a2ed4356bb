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

import ctypes
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

WORKERS = max(1, min(2, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


def split_frames(F: int, min_frames: int = 64) -> list[slice]:
    """Frames 0..F-1 in one contiguous part per worker thread (a single part for few frames)."""
    return list(_split_frames(F, min_frames))


@functools.cache
def _split_frames(F: int, min_frames: int) -> tuple[slice, ...]:
    """split_frames, kept: it is asked for the same few frame counts several times in every step."""
    k = max(1, min(WORKERS, F // min_frames))
    edges = np.linspace(0, F, k + 1).astype(int)
    return tuple(slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:], strict=True))


@functools.cache
def _workers(n: int) -> ThreadPoolExecutor:
    """The process's pool of `n` worker threads, started once: a solve calls in_parallel several
    times per iteration, and starting threads afresh each time cost more than some of the work."""
    return ThreadPoolExecutor(n, thread_name_prefix=WORKER_NAME)


WORKER_NAME = "calibrate-worker"  # the pool's threads' names start with it (and a child of run_ahead's is named so)


def worker_thread() -> bool:
    """Whether this thread is a worker (the pool's, or a calibrate.solve.ahead child's): its parallel
    parts run one after another."""
    return threading.current_thread().name.startswith(WORKER_NAME)


def in_parallel(work, parts: list) -> list:
    """work(part) for every part: the first in the calling thread, the others on the worker pool
    (numpy's batched kernels and the compiled kernels here release the GIL).  Called from a worker
    itself, the parts run one after another (a nested wait on the pool could deadlock it)."""
    if len(parts) == 1 or worker_thread():
        return [work(p) for p in parts]
    pool = _workers(max(1, WORKERS - 1))
    later = [pool.submit(work, p) for p in parts[1:]]
    return [work(parts[0]), *(f.result() for f in later)]


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


def parameter_pattern(groups, T: np.ndarray) -> tuple[ParameterLayout, np.ndarray, np.ndarray]:
    """The part of parameter_layout that depends only on where T is nonzero: the layout with empty values
    and the (row, column) of T each value is read from (parameter_layout(groups, T) is
    layout with p_val = T[rows, cols])."""
    fcols, src, rr, cc, vr, vc = [], [], [], [], [], []
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
        vr.append(g.pcols[c_of[rep]])
        vc.append(tj[at])
        fcols.append(fc)
        fc_off.append(fc_off[-1] + fc.size)
        off.append(off[-1] + rep.size)
    cat = lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)  # noqa: E731
    layout = ParameterLayout(cat(fcols, np.int64), np.array(fc_off, dtype=np.int64), cat(src, np.int64),
                             cat(rr, np.int64), cat(cc, np.int64), np.zeros(0), np.array(off, dtype=np.int64))
    return layout, cat(vr, np.int64), cat(vc, np.int64)


def parameter_layout(groups, T: np.ndarray,
                     pattern: tuple[ParameterLayout, np.ndarray, np.ndarray] | None = None) -> ParameterLayout:
    """The gather of ∂r/∂p_free from ∂r/∂p_full's nonzeros through the free-parameter map T (n_full, n_free).
    `pattern`: parameter_pattern(groups, T) if known (it is the same for every T with the same nonzeros)."""
    layout, rows, cols = pattern or parameter_pattern(groups, T)
    return replace(layout, p_val=np.ascontiguousarray(T[rows, cols], dtype=np.float64))


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


PARTS = {"all": 1, "no_coupling": 2, "coupling": 3}  # the kernels' with_p codes


def assemble(d: np.ndarray, w: np.ndarray, jz: np.ndarray, jp: np.ndarray | None, gl: GroupLayout,
             pl: ParameterLayout | None, A: np.ndarray, B: np.ndarray, gz: np.ndarray,
             n: int, gradient_only: bool = False, parts: str = "all") -> tuple[np.ndarray, np.ndarray]:
    """Fill A (F, nz, nz), B (F, nz, n), gz (F, nz) in place from the residuals d (F, rows),
    row weights w (F, rows; 0 where a marker is not seen) and the CasADi nonzeros jz, jp;
    return (C, g_p) of the data.  `jp`/`pl` None: poses only (B, C, g_p untouched / empty).
    `gradient_only`: only g_z = Jz'(w d) and g_p (A, B and C untouched; C returned empty), e.g.
    for the geodesic acceleration, whose right-hand side is J' times a second derivative.
    `parts`: 'all'; 'no_coupling' (B untouched: it may have no columns); 'coupling' (B but not C
    or g_p, returned as zeros): what a long trial's chunks need in each pass (calibrate.solve.chunks)."""
    F = d.shape[0]
    with_p = jp is not None and pl is not None and n > 0
    if not with_p:
        none, offs = np.zeros(0, np.int64), np.zeros(len(gl.row_off), np.int64)
        pl = ParameterLayout(none, offs, none, none, none, np.zeros(0), offs)
        jp = np.zeros((F, 1))

    def part(fr: slice) -> tuple[np.ndarray, np.ndarray]:
        Ct, gt = np.zeros((n, n)), np.zeros(n)
        kernels().assemble(d, w, jz, jp, fr.start, fr.stop, PARTS[parts] if with_p else 0, gradient_only,
                  gl.rows, gl.row_off, gl.zcols, gl.zc_off, gl.z_src, gl.z_r, gl.z_c, gl.z_off,
                  pl.fcols, pl.fc_off, pl.p_src, pl.p_r, pl.p_c, pl.p_val, pl.p_off, A, B, gz, Ct, gt)
        return Ct, gt

    parts = in_parallel(part, split_frames(F))
    C = sum(c for c, _ in parts[1:]) + parts[0][0] if len(parts) > 1 else parts[0][0]
    gp = sum(g for _, g in parts)
    if gradient_only:
        return np.zeros((0, 0)), gp
    # The kernel fills the lower triangle; mirrored (+ 0.0: the same bits, signed zeros included, as the
    # sum of np.tril(C) and np.tril(C, -1).T), with the mask kept for the size.
    return np.where(_lower_triangle(n), C, C.T) + 0.0, gp


@functools.cache
def _lower_triangle(n: int) -> np.ndarray:
    """(n, n) mask of the lower triangle and the diagonal (read-only: shared by every call)."""
    mask = np.tri(n, dtype=bool)
    mask.setflags(write=False)
    return mask


def factor_frames(A: np.ndarray, damping: np.ndarray, B: np.ndarray, gz: np.ndarray, L: np.ndarray,
                  Y: np.ndarray, yz: np.ndarray, runs: ColumnRuns | None = None,
                  packing: Packing | None = None, structure: Structure | None = None) -> bool:
    """Cholesky of every frame block A_f + diag(damping_f), in reverse coordinate order (leaves of the
    kinematic tree first: no fill-in), into L (F, nz, nz); Y = L⁻¹ B_f and yz = L⁻¹ g_z (rows
    reversed), in place.  `runs`: Y's nonzero columns row by row (column_runs), the only ones formed
    (a dense Y must already hold zeros elsewhere); None: every column.  `packing`: where each row's runs
    go in Y, a flat buffer (calibrate.solve.schur.PackedRows); None: Y dense (F, nz, n).  `structure`: the
    factor's nonzero structure (factor_structure of the symbolic factorisation), the only entries formed;
    None: the whole lower triangle.  False if a block is not positive definite."""
    nz, n = B.shape[1], B.shape[2]
    runs = runs or dense_runs(nz, n)
    packing = packing or dense_packing(runs, nz, n)
    structure = structure or dense_structure(nz)
    Y = Y.reshape(-1)  # a view (C-contiguous): the kernels write through it
    return all(in_parallel(lambda fr: kernels().factor(A, damping, B, gz, L, Y, yz, fr.start, fr.stop, *runs,
                                                       *packing, *structure), split_frames(A.shape[0])))


# (run_off (rows + 1,), run_lo, run_hi, run_class (rows,)): each row's half-open runs, and a class number the
# rows with the same runs share (the factorisation reduces up to four such rows at once)
ColumnRuns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def dense_runs(rows: int, n: int) -> ColumnRuns:
    """Every row's columns as one run [0, n)."""
    return (np.arange(rows + 1, dtype=np.int64), np.zeros(rows, np.int64), np.full(rows, n, np.int64),
            np.zeros(rows, np.int64))


Packing = tuple[np.ndarray, np.ndarray, np.ndarray]  # (dst_base (rows,), dst_fstride (rows,), run_dst (runs,))


Structure = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # (row_off, row_idx, col_off, col_idx)


def factor_pattern_of(a_pattern: np.ndarray) -> np.ndarray:
    """Where the Cholesky factor of the reversed A_f (pattern `a_pattern`, (nz, nz)) can be nonzero, (nz, nz)
    booleans: the symbolic Cholesky, in which eliminating a coordinate joins its later neighbours."""
    nz = a_pattern.shape[0]
    P = a_pattern[::-1, ::-1] | np.eye(nz, dtype=bool)
    for k in range(nz):
        nb = k + 1 + np.flatnonzero(P[k + 1:, k])
        P[np.ix_(nb, nb)] = True
    return P


def y_pattern_of(a_pattern: np.ndarray, b_pattern: np.ndarray) -> np.ndarray:
    """Where Y = L⁻¹ B_f (rows reversed) can be nonzero, (nz, n) booleans, from A_f's and B_f's patterns: B's
    pattern propagated symbolically through the factorisation (factor_pattern_of), exact in any coordinate
    order."""
    P = factor_pattern_of(a_pattern)
    Yp = b_pattern[::-1].copy()
    for i in range(Yp.shape[0]):
        for j in np.flatnonzero(P[i, :i]):
            Yp[i] |= Yp[j]
    return Yp


def factor_structure(pattern: np.ndarray) -> Structure:
    """A Cholesky factor's structure from its (nz, nz) pattern (lower triangle used): each row's nonzeros left
    of the diagonal and each column's below it, in ascending order, as offsets and indices."""
    low = np.tril(pattern, -1)
    rows, cols = np.nonzero(low)  # row-major: each row's columns ascending
    c_cols, c_rows = np.nonzero(low.T)  # column by column: each column's rows ascending
    off = lambda counts: np.r_[0, np.cumsum(counts)].astype(np.int64)  # noqa: E731
    return off(low.sum(1)), cols.astype(np.int64), off(low.sum(0)), c_rows.astype(np.int64)


@functools.cache
def dense_structure(nz: int) -> Structure:
    """factor_structure of a full lower triangle (kept: asked for by every factorisation without a pattern)."""
    return factor_structure(np.tri(nz, dtype=bool))


def dense_packing(runs: ColumnRuns, rows: int, n: int) -> Packing:
    """Each row's runs written where they lie in a dense (F, rows, n) Y."""
    return (np.arange(rows, dtype=np.int64) * n, np.full(rows, rows * n, np.int64), runs[1])


def column_runs(pattern: np.ndarray) -> ColumnRuns:
    """A boolean (rows, n) pattern as each row's runs of consecutive True columns (and the rows' classes:
    rows with the same pattern, the same class)."""
    off, lo, hi = [0], [], []
    for row in pattern:
        edges = np.flatnonzero(np.diff(np.r_[0, row.astype(np.int8), 0]))
        lo.extend(edges[0::2])
        hi.extend(edges[1::2])
        off.append(len(lo))
    _, cls = np.unique(pattern.reshape(pattern.shape[0], -1), axis=0, return_inverse=True)
    return (np.array(off, np.int64), np.array(lo, np.int64), np.array(hi, np.int64),
            np.asarray(cls, np.int64).reshape(-1))


def back_substitute(L: np.ndarray, t: np.ndarray) -> np.ndarray:
    """x with L_fᵀ x_f = t_f for every frame (rows reversed, as factor_frames leaves them)."""
    x = np.empty_like(t)
    t = np.ascontiguousarray(t)
    in_parallel(lambda fr: kernels().back(L, t, x, fr.start, fr.stop), split_frames(L.shape[0]))
    return x


def forward_substitute(L: np.ndarray, g: np.ndarray) -> np.ndarray:
    """y with L_f y_f = g_f (rows of g reversed, as factor_frames takes them) for every frame."""
    y = np.empty_like(g)
    g = np.ascontiguousarray(g)
    in_parallel(lambda fr: kernels().forward(L, g, y, fr.start, fr.stop), split_frames(L.shape[0]))
    return y


def cho_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with L Lᵀ x = b for one dense lower Cholesky factor L (n, n), by the frames' substitution
    kernels (one frame of n coordinates): 20 µs for the Schur complement's n = 200, where two LU
    solves (np.linalg.solve, which does not see that L is triangular) take 330 µs."""
    n = b.size
    L = np.ascontiguousarray(L, dtype=float)[None]
    y, x = np.empty((1, n)), np.empty((1, n))
    kernels().forward(L, np.ascontiguousarray(b[::-1], dtype=float)[None], y, 0, 1)  # L y = b
    kernels().back(L, y, x, 0, 1)  # Lᵀ x = y
    return x[0]


# ---------------------------------------------------------------------- kernels
def c_source() -> str:
    """The kernels' C source (calibrate/kernels.c, a package data file)."""
    return (resources.files(__package__) / "kernels.c").read_text()


# Reassociation lets the compiler vectorise the inner products; NaN and infinity keep their meaning
# (no -ffast-math: the Cholesky's "not positive definite" test must see a NaN pivot).
_C_FLAGS = ("-O3", "-fassociative-math", "-fno-signed-zeros", "-fno-trapping-math", "-ffp-contract=fast")


def _ptr(a: np.ndarray, dtype=np.float64) -> int:
    """Address of `a`'s data, which must already be C-contiguous of `dtype` (no silent copies:
    the kernels write into their outputs in place)."""
    if a.dtype != dtype or not a.flags.c_contiguous:
        raise TypeError(f"kernel argument must be C-contiguous {np.dtype(dtype).name}, got {a.dtype}")
    return a.ctypes.data


class _CKernels:
    """The kernels compiled from kernels.c with the system's C compiler (ctypes releases the GIL
    during each call, so the frame parts run on both cores)."""

    def __init__(self, path: Path):
        lib = ctypes.CDLL(str(path))
        I, P = ctypes.c_int64, ctypes.c_void_p
        self._assemble = lib.cal_assemble
        self._assemble.argtypes = [P] * 4 + [I] * 10 + [P] * 20
        self._factor = lib.cal_factor
        self._factor.argtypes = [P] * 7 + [I] * 4 + [P] * 11
        self._back, self._forward = lib.cal_back, lib.cal_forward
        for f in (self._back, self._forward):
            f.argtypes = [P] * 3 + [I] * 3
        self._gather = lib.cal_gather
        self._gather.argtypes = [P, I, P, P, P, I, P, P, P, I, I, I]
        for f in (self._assemble, self._factor, self._back, self._forward, self._gather):
            f.restype = ctypes.c_int

    def assemble(self, d, w, jz, jp, f0, f1, with_p, grad_only, rows, row_off, zcols, zc_off, z_src, z_r, z_c,
                 z_off, fcols, fc_off, p_src, p_r, p_c, p_val, p_off, A, B, gz, Ct, gt) -> None:
        ints = [_ptr(x, np.int64) for x in (rows, row_off, zcols, zc_off, z_src, z_r, z_c, z_off,
                                            fcols, fc_off, p_src, p_r, p_c)]
        ok = self._assemble(_ptr(d), _ptr(w), _ptr(jz), _ptr(jp), d.shape[1], jz.shape[1], jp.shape[1], A.shape[1],
                            Ct.shape[0], f0, f1, int(with_p), int(grad_only), row_off.size - 1, *ints, _ptr(p_val),
                            _ptr(p_off, np.int64), _ptr(A), _ptr(B), _ptr(gz), _ptr(Ct), _ptr(gt))
        if not ok:
            raise MemoryError("calibrate kernels: out of memory assembling the normal equations")

    def factor(self, A, damping, B, gz, L, Y, yz, f0, f1, run_off, run_lo, run_hi, run_class, dst_base,
               dst_fstride, run_dst, lrow_off, lrow_idx, lcol_off, lcol_idx) -> bool:
        ints = [_ptr(x, np.int64) for x in (run_off, run_lo, run_hi, dst_base, dst_fstride, run_dst,
                                            lrow_off, lrow_idx, lcol_off, lcol_idx, run_class)]
        ok = self._factor(_ptr(A), _ptr(damping), _ptr(B), _ptr(gz), _ptr(L), _ptr(Y), _ptr(yz),
                          A.shape[1], B.shape[2], f0, f1, *ints)
        if ok < 0:
            raise MemoryError("calibrate kernels: out of memory factoring the frame blocks")
        return bool(ok)

    def gather(self, X, rowptr, xi, coef, sub, out, f0, f1) -> None:
        self._gather(_ptr(X), X.shape[1], _ptr(rowptr, np.int64), _ptr(xi, np.int64), _ptr(coef), out.shape[1], None,
                     _ptr(sub) if sub.shape[0] else None, _ptr(out), out.shape[1], f0, f1)

    def gatherer(self, X, rowptr, xi, coef, dst, out):
        """cal_gather over every frame of X (n, nx), output i stored at out[f, dst[i]], with these arrays bound:
        their addresses taken once, for a caller that gathers into the same memory again and again (a frame-wise
        fit's evaluator: thousands of calls, where the checks of each call cost as much as the loop)."""
        args = (_ptr(X), X.shape[1], _ptr(rowptr, np.int64), _ptr(xi, np.int64), _ptr(coef), dst.size,
                _ptr(dst, np.int64), None, _ptr(out), out.shape[1], 0, X.shape[0])
        f = self._gather
        return lambda: f(*args)

    def back(self, L, t, x, f0, f1) -> None:
        self._back(_ptr(L), _ptr(t), _ptr(x), L.shape[1], f0, f1)

    def forward(self, L, g, y, f0, f1) -> None:
        self._forward(_ptr(L), _ptr(g), _ptr(y), L.shape[1], f0, f1)


def cache_dir() -> Path:
    """Where compiled code is kept: $CALIBRATE_CACHE, else ~/.cache/calibrate."""
    env = os.environ.get("CALIBRATE_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "calibrate"


@functools.cache
def kernels():
    """The per-frame kernels: compiled from kernels.c with the system's C compiler (once per machine,
    kept in the cache directory of calibrate.problem.problem), else numba's versions of the same loops."""
    path = _compile_kernels()
    if path is not None:
        return _CKernels(path)
    from . import numba_kernels

    return numba_kernels


def c_compiler() -> str | None:
    """The system's C compiler ($CC, else gcc, else cc), or None."""
    return shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")


def _compile_kernels() -> Path | None:
    cc = c_compiler()
    if cc is None:
        return None
    cache = cache_dir()
    source = c_source()
    digest = hashlib.sha256(f"{cc} {' '.join(_C_FLAGS)} {source}".encode()).hexdigest()[:20]
    so = cache / f"kernels_{digest}.so"
    try:
        if not so.exists():
            cache.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory() as tmp:
                c = Path(tmp) / "kernels.c"
                c.write_text(source)
                part = cache / f".kernels_{digest}.{os.getpid()}.so"
                subprocess.run([cc, *_C_FLAGS, "-fPIC", "-shared", str(c), "-o", str(part), "-lm"], check=True,
                               capture_output=True, timeout=300)
                os.replace(part, so)
        return so
    except (OSError, subprocess.SubprocessError):
        return None
