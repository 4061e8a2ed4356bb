"""The compiled per-frame functions of the calibration problem: every segment's pose and its exact sparse
Jacobians (CasADi), C-compiled and kept on disk by the model's tree (its markers left out, so that any marker
set on a model shares one compile), evaluated over frames in blocks; the markers, their residuals and their
Jacobians follow from the poses through calibrate.problem.marker_map."""

from __future__ import annotations

import contextlib
import hashlib
import os
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import casadi as ca
import numpy as np

from calibrate.problem.state import FrameGroup, State

from ..model.kinematics import Kinematics, kinematic_structure, segment_poses
from ..model.model import Model
from ..solve.assembly import c_compiler, cache_dir, group_layout, in_parallel, kernels, split_frames
from .marker_map import Gather, MarkerMap, marker_map

KINDS = ("full", "pose", "resid")  # what _run evaluates: markers with ∂/∂z and ∂/∂p, with ∂/∂z, alone

EVAL_BLOCK = 64  # frames per call of a mapped CasADi function (building a map costs more than linearly in its size)


EVAL_PAD = 16  # a shorter last block is padded to EVAL_BLOCK frames when longer than this (one map size)


def _pattern(sp: ca.Sparsity) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of every nonzero of a CasADi sparsity, in nonzero order (column-major)."""
    colind = np.asarray(sp.colind())
    row = np.asarray(sp.row())
    col = np.repeat(np.arange(sp.size2()), np.diff(colind))
    return row, col


def _structure_key(model: Model, kin: Kinematics) -> str | None:
    """A digest of everything the per-frame functions are built from: the model's kinematic
    structure without its markers (tree, fixed rotations and offsets, which parameter each origin reads)
    and the code that builds them, so that a cached build is reused exactly when it would come out the
    same.  None without a C compiler (nothing to cache)."""
    if c_compiler() is None:
        return None
    h = hashlib.sha256(f"{ca.__version__} -O1 {kinematic_structure(model, kin.balls, markers=False)}".encode())
    for src in (Path(__file__), Path(__file__).parent.parent / "model" / "kinematics.py",
                Path(__file__).parent.parent / "model" / "blocks.py"):
        h.update(src.read_bytes())
    return h.hexdigest()[:20]


def _cached_files(key: str) -> tuple[Path, Path] | None:
    """The compiled library and its Jacobian patterns cached under `key`, or None if either is missing."""
    so, npz = cache_dir() / f"frame_{key}.so", cache_dir() / f"frame_{key}.npz"
    return (so, npz) if so.exists() and npz.exists() else None


def _load_compiled(key: str) -> tuple[list[ca.Function], tuple] | None:
    """The compiled per-frame functions and their Jacobian patterns cached under `key`, or None."""
    files = _cached_files(key)
    if files is None:
        return None
    so, npz = files
    try:
        with np.load(npz) as z:
            patterns = (z["zr"], z["zc"], z["pr"], z["pc"])
        return [ca.external(f"calibrate_segments_{k}", str(so)) for k in KINDS], patterns
    except (OSError, RuntimeError, KeyError, ValueError):
        return None


def is_compiled(model: Model, kin: Kinematics) -> bool:
    """Whether the per-frame functions of this model structure are compiled and in the cache."""
    key = _structure_key(model, kin)
    return key is not None and _cached_files(key) is not None


def _compile(funcs: list[ca.Function], key: str, patterns: dict[str, np.ndarray]) -> list[ca.Function] | None:
    """Generate C for `funcs`, compile it, keep it (with the Jacobian `patterns` beside it) in the
    cache under `key`, and load it.

    Returns None (the caller then keeps CasADi's virtual machine) when there is no C
    compiler or the compile fails: compiling is an optimisation, never a requirement.
    """
    cc = c_compiler()
    if cc is None:
        return None
    try:
        cache = cache_dir()
        cache.mkdir(parents=True, exist_ok=True)
        so = cache / f"frame_{key}.so"
        with tempfile.TemporaryDirectory() as tmp:
            # One translation unit per function, compiled side by side (the per-frame function with
            # its Jacobians takes most of the time), then linked into one library.  -Og: on this
            # straight-line code it compiles in 60 % of -O1's time and runs within ~5 % of it.
            objs, jobs = [], []
            for f in funcs:
                cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
                cg.add(f)
                cg.generate(tmp + os.sep)
                src, obj = Path(tmp) / f"{f.name()}.c", Path(tmp) / f"{f.name()}.o"
                objs.append(str(obj))
                jobs.append(subprocess.Popen([cc, "-Og", "-fPIC", "-c", str(src), "-o", str(obj)],
                                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            failed = [j.wait(timeout=600) for j in jobs]
            if any(failed):
                raise RuntimeError("C compile failed")
            part = cache / f".frame_{key}.{os.getpid()}.so"
            subprocess.run([cc, "-shared", *objs, "-o", str(part)], check=True, capture_output=True, timeout=600)
            side = cache / f".frame_{key}.{os.getpid()}.npz"
            with open(side, "wb") as fh:
                np.savez(fh, **patterns)
            os.replace(part, so)
            os.replace(side, cache / f"frame_{key}.npz")
        return [ca.external(f.name(), str(so)) for f in funcs]
    except (OSError, subprocess.SubprocessError, RuntimeError):
        return None


@contextlib.contextmanager
def _compile_lock(key: str | None) -> Iterator[None]:
    """Held while the structure `key` is built and compiled, so that processes sharing the cache (a batch's
    workers, the test suite's) compile it once: the others wait, then load it.  No lock for None, nor where
    the system has no advisory file locks (not POSIX): compiles may then run side by side, each kept whole."""
    try:
        import fcntl
    except ImportError:
        fcntl = None
    if key is None or fcntl is None:
        yield
        return
    try:
        cache_dir().mkdir(parents=True, exist_ok=True)
        fh = open(cache_dir() / f".frame_{key}.lock", "a")  # held across the yield below
    except OSError:  # a cache that cannot be written: nothing to share, the compile fails and the VM is kept
        yield
        return
    with fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


class CodegenMixin:
    """Problem's compiled functions (calibrate.problem.problem.Problem inherits it)."""

    # ------------------------------------------------------------------ CasADi
    def _build_functions(self) -> None:
        key = _structure_key(self.model, self.kin) if self.settings.compile else None
        cached = _load_compiled(key) if key else None
        with _compile_lock(key if cached is None else None):
            # Another process (a batch's or the tests' other worker) may have compiled this structure while
            # this one waited for the lock: then it is loaded, not compiled a second time beside it.
            if cached is None and key:
                cached = _load_compiled(key)
            self._build_or_load(cached, key)

    def _build_or_load(self, cached: tuple | None, key: str | None) -> None:
        """_build_functions' work: the compiled functions `cached` loaded, else built symbolically and compiled under
        `key` (None: CasADi's virtual machine); then this marker set's map from the poses (marker_map)."""
        m, kin = self.model, self.kin
        self.compiled = cached is not None
        if cached is not None:  # a model of this structure was compiled before: no symbolic work
            funcs, (zr, zc, pr, pc) = cached
        else:
            z, refs, p, X = segment_poses(m, kin.balls)
            Jz, Jp = ca.jacobian(X, z), ca.jacobian(X, p)
            nzs = lambda J: ca.vertcat(*[J.nz[i] for i in range(J.nnz())])  # noqa: E731
            outs = {"full": ca.vertcat(X, nzs(Jz), nzs(Jp)), "pose": ca.vertcat(X, nzs(Jz)), "resid": X}
            funcs = [ca.Function(f"calibrate_segments_{k}", [z, refs, p], [outs[k]]) for k in KINDS]
            zr, zc = _pattern(Jz.sparsity())
            pr, pc = _pattern(Jp.sparsity())
            if key:
                if self._progress is not None and c_compiler() is not None:
                    self._progress("build: compiling the model's C code (once per model tree, any markers; cached)")
                comp = _compile(funcs, key, {"zr": zr, "zc": zc, "pr": pr, "pc": pc})
                if comp is not None:
                    funcs = comp
                    self.compiled = True
        self._funcs = dict(zip(KINDS, funcs, strict=True))
        self._n_kin = m.layout.offsets["marker"]  # p's entries before the markers': the poses' input
        self._map = marker_map(m, (zr, zc), (pr, pc))
        mm = self._map
        self._gathers: dict[str, tuple[Gather, ...]] = {"full": (mm.d, mm.z, mm.p), "pose": (mm.d, mm.z),
                                                        "resid": (mm.d,)}
        # Per-segment groups from the sparsity patterns.
        (zr, zc), (pr, pc) = mm.z_pattern, mm.p_pattern
        self._jz_pattern = (zr, zc, 3 * len(m.markers), m.nz)
        self._jp_pattern = (pr, pc)
        self.groups: list[FrameGroup] = []
        for s in range(len(m.segments)):
            mk = np.flatnonzero(self.marker_segment == s)
            if mk.size == 0:
                continue
            rows = (3 * mk[:, None] + np.arange(3)).ravel()
            row_pos = {int(x): i for i, x in enumerate(rows)}
            zsel = np.isin(zr, rows)
            psel = np.isin(pr, rows)
            zcols = np.unique(zc[zsel])
            pcols = np.unique(pc[psel])
            zpos = {int(c): i for i, c in enumerate(zcols)}
            ppos = {int(c): i for i, c in enumerate(pcols)}
            z_src = np.flatnonzero(zsel)
            p_src = np.flatnonzero(psel)
            z_dst = np.array([row_pos[int(zr[i])] * zcols.size + zpos[int(zc[i])] for i in z_src], dtype=int)
            p_dst = np.array([row_pos[int(pr[i])] * pcols.size + ppos[int(pc[i])] for i in p_src], dtype=int)
            self.groups.append(FrameGroup(rows, zcols, pcols, z_src, z_dst, p_src, p_dst))
        self._layout_z = group_layout(self.groups)

    def jacobian_rows(self) -> tuple:
        """(rows_z, cols_z, rows_p, cols_p): for the per-frame Jacobians' nonzeros, sparse (nnz, rows)
        maps of each nonzero to its residual row, and each nonzero's column (z, or full p)."""
        if getattr(self, "_rows_of", None) is None:
            from scipy import sparse

            zr, zc, nrows, _ = self._jz_pattern
            pr, pc = self._jp_pattern
            rz = sparse.csr_matrix((np.ones(zr.size), (np.arange(zr.size), zr)), shape=(zr.size, nrows))
            rp = sparse.csr_matrix((np.ones(pr.size), (np.arange(pr.size), pr)), shape=(pr.size, nrows))
            self._rows_of = (rz, np.asarray(zc), rp, np.asarray(pc))
        return self._rows_of

    @property
    def output_sizes(self) -> tuple[int, int, int]:
        """Per frame: residual rows, nonzeros of d markers/dz and of d markers/dp (what one frame's
        evaluation writes; calibrate.solve.chunks sizes its chunks by them)."""
        return self._map.d.size, self._map.z.size, self._map.p.size

    def frame_evaluator(self, p: np.ndarray) -> MapEvaluator:
        """One frame's (markers (3 n_markers,), d markers/dz (3 n_markers, nz)) at fixed full
        parameters `p`, through the compiled segment poses (as Kinematics.frame_evaluator)."""
        return MapEvaluator(self._funcs["pose"], np.asarray(p, dtype=float), self._map, self._jz_pattern)

    def _run(self, kind: str, state: State, out: tuple | None = None, frames: slice = slice(None)) -> list[np.ndarray]:
        """Evaluate `kind` (KINDS) over every frame, into numpy arrays (F, nnz_out): the residuals d, and
        for "full" / "pose" the nonzeros of ∂d/∂z and ∂d/∂p; those of `out` where their shapes fit (buffers
        no longer needed), else fresh ones.  The frames are split between the worker threads
        (calibrate.solve.assembly.in_parallel; CasADi's evaluation and the gather kernel release the GIL),
        each evaluating the segments' poses of EVAL_BLOCK frames per call of a serial map (a map's
        construction grows with its size, and costs ~15 ms: a short last block is padded with copies of its
        last frame so that one map size serves every problem), then gathering the markers from them
        (marker_map).  CasADi's own threaded map started two threads per call: 3 700 on pig_walk.
        `frames`: only those frames (a chunk of a long trial), taken from `state` or, if it has as many
        frames as they are, its own."""
        n_sel = len(range(*frames.indices(self.F)))
        state = state if state.Z.shape[0] == n_sel else State(state.Z[frames], state.Q[frames], state.p,
                                                              None if state.B is None else state.B[frames])
        Z = np.ascontiguousarray(state.Z, dtype=float)
        F = Z.shape[0]
        f0, gathers = self._funcs[kind], self._gathers[kind]
        outs = [np.empty((F, g.size)) for g in gathers]
        for i, o in enumerate(out or ()):
            if i < len(outs) and isinstance(o, np.ndarray) and o.shape == outs[i].shape and o.flags.c_contiguous:
                outs[i] = o
        Q = np.ascontiguousarray(self.kin.refs(state.Q, state.B), dtype=float)
        target = np.ascontiguousarray(self.target[frames])
        p = np.asarray(state.p, dtype=float)
        P = np.tile(p[:self._n_kin], EVAL_BLOCK)
        p_bar = np.append(p, 1.0)
        coefs = [g.coefficients(p_bar) for g in gathers]
        nx, none = f0.nnz_out(0), np.empty((0, 1))
        K = kernels()
        # Each part's blocks (first frame, end, map size), and each part its own buffers (a buffer is one
        # evaluation's memory, with the poses it writes), made here in the calling thread.
        blocks = []
        for k, sl in enumerate(split_frames(F, EVAL_BLOCK)):
            ends = [(s, min(sl.stop, s + EVAL_BLOCK)) for s in range(sl.start, sl.stop, EVAL_BLOCK)]
            blocks.append([(s, e, EVAL_BLOCK if e - s > EVAL_PAD else e - s) for s, e in ends])
            for _, _, size in blocks[k]:
                if (kind, size, k) not in self._mapped:
                    if (kind, size) not in self._mapped:
                        self._mapped[(kind, size)] = (f0.map(size, "serial"),)
                    buf, ev = self._mapped[(kind, size)][0].buffer()
                    X = np.empty((size, nx))
                    buf.set_res(0, memoryview(X))
                    self._mapped[(kind, size, k)] = (buf, ev, X)

        def evaluate(k: int) -> None:
            for s, e, size in blocks[k]:
                n = e - s
                buf, ev, X = self._mapped[(kind, size, k)]
                ins = [Z[s:e], Q[s:e]]
                if size > n:
                    ins = [np.concatenate([a, np.repeat(a[-1:], size - n, axis=0)]) for a in ins]
                for i, a in enumerate((ins[0], ins[1], P[:size * self._n_kin])):
                    buf.set_arg(i, memoryview(a))
                ev()
                for i, (g, c) in enumerate(zip(gathers, coefs, strict=True)):
                    K.gather(X, g.rowptr, g.xi, c, target[s:e] if i == 0 else none, outs[i][s:e], 0, n)

        in_parallel(evaluate, list(range(len(blocks))))
        return outs


class MapEvaluator:
    """One frame's markers (3 n_markers,) and ∂markers/∂z (3 n_markers, nz, dense) at fixed geometry `p`: the
    segments' poses by the compiled function `f` (KINDS' "pose"), the markers gathered from them (`mm`).  As
    calibrate.model.kinematics.FrameEvaluator: ``ev(z, q_ref)`` returns reused buffers, overwritten by the
    next call (copy what you keep)."""

    def __init__(self, f: ca.Function, p: np.ndarray, mm: MarkerMap, pattern: tuple[np.ndarray, np.ndarray, int, int]):
        self._f = f  # keep the Function alive while its buffer is used
        self._buf, self._eval = f.buffer()
        self._z, self._q = np.zeros(f.nnz_in(0)), np.zeros(f.nnz_in(1))
        self._p = np.array(p[:f.nnz_in(2)], dtype=float)
        self._X = np.zeros((1, f.nnz_out(0)))
        for i, a in enumerate((self._z, self._q, self._p)):
            self._buf.set_arg(i, memoryview(a))
        self._buf.set_res(0, memoryview(self._X))
        # The markers' gather and their Jacobian's, as one: each output written to its place in one buffer, the
        # markers then the dense Jacobian row by row (one call, no scatter after it).
        p_bar = np.append(np.asarray(p, dtype=float), 1.0)
        rows, cols, n_rows, nz = pattern
        self._out = np.zeros((1, n_rows * (1 + nz)))
        self.markers = self._out[0, :n_rows]
        self.jacobian = self._out[0, n_rows:].reshape(n_rows, nz)
        d, jz = mm.d, mm.z
        self._rowptr = np.concatenate([d.rowptr, jz.rowptr[1:] + d.rowptr[-1]])
        self._xi = np.concatenate([d.xi, jz.xi])
        self._coef = np.concatenate([d.coefficients(p_bar), jz.coefficients(p_bar)])
        self._dst = np.concatenate([np.arange(n_rows), n_rows + rows * nz + cols]).astype(np.int64)
        self._gather = kernels().gatherer(self._X, self._rowptr, self._xi, self._coef, self._dst, self._out)

    def __call__(self, z: np.ndarray, q_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._z[:] = z
        self._q[:] = q_ref
        self._eval()
        self._gather()
        return self.markers, self.jacobian
