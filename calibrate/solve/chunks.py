"""The frame blocks of the block-arrow normal equations, chunk by chunk: long trials in bounded memory.

Frames are coupled only through the parameters p.  The Schur complement on p is a sum over frames,
S = C + λD_p − Σ_f Y_f' Y_f  (Y_f = L_f⁻¹ B_f, L_f the Cholesky factor of A_f + λD_f),
and each frame's step dz_f = −(A_f + λD_f)⁻¹ (g_f + B_f dp) needs only that frame's blocks.  So the
blocks of a trial too long to hold (about 170 kB per frame for the full-body model: A_f, B_f, their
factors and the Jacobian's nonzeros) are formed, used and dropped chunk by chunk, and formed again
from the linearization point when a later pass needs them.  The chunks that fit in the memory budget
(SolverOptions.memory_mb) are kept; a trial that fits whole is one chunk, kept, and solved exactly as
before (every existing figure is unchanged).  What is kept for every frame is small: the gradient,
the diagonal of A_f (Marquardt's scaling) and L_f⁻¹ g_f, nz numbers each.

Passes of one Levenberg–Marquardt step over the chunks not kept (each forms their blocks again):
factorisation and the Schur complement; back-substitution with the model's predicted decrease; and,
with the geodesic acceleration, the second right-hand side forward and back.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..problem.problem import Problem
from ..problem.state import Linearization, State
from .assembly import back_substitute, cho_solve, forward_substitute
from .schur import (
    DIAG_FLOOR,
    GEODESIC_H,
    GEODESIC_RATIO,
    Elimination,
    GaugeBasis,
    eliminate,
    frames_times,
    marquardt_diagonal,
    retract,
)

Bend = tuple[np.ndarray, np.ndarray] | None  # half a step's geodesic acceleration (dz, dp), to add to it
CHUNK_FRAMES = 256  # frames per chunk of a trial whose blocks do not all fit in the budget
# The arrays of the chunks formed again in each pass (blocks with and without B, an elimination, a factor),
# in chunks' worth of the kept blocks: counted in the budget before any chunk is kept.
SCRATCH_CHUNKS = 1.5


def frame_bytes(problem: Problem, with_parameters: bool) -> int:
    """Bytes of one frame's blocks while a step uses them: A_f, B_f, L_f, Y_f (its nonzeros only:
    calibrate.solve.schur.PackedRows), the gradient and L_f⁻¹ g_f, the residuals and their weights, and
    the Jacobian's nonzeros."""
    nz, n = problem.model.nz, (problem.n_free if with_parameters else 0)
    rows, nnz_z, nnz_p = problem.output_sizes
    y = problem.y_entries() if n else 0
    return 8 * (2 * nz * nz + nz * n + y + 3 * nz + 2 * rows + nnz_z + (nnz_p if with_parameters else 0))


def chunk_slices(F: int, per_frame: int, budget: float, chunk_frames: int) -> tuple[list[slice], int]:
    """The chunks of F frames and how many of them (the first) stay in memory: one chunk, kept,
    if the whole trial fits in `budget` bytes; else chunks of `chunk_frames`, as many kept as fit
    besides the scratch arrays of the chunks formed again (SCRATCH_CHUNKS chunks' worth)."""
    if F * per_frame <= budget:
        return [slice(0, F)], 1
    edges = list(range(0, F, chunk_frames)) + [F]
    slices = [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    chunk = chunk_frames * per_frame
    return slices, int(max(0.0, budget - SCRATCH_CHUNKS * chunk) // chunk)


@dataclass(frozen=True)
class Prepared:
    """The first pass of the step of damping `lam` (chunked_step), made as the blocks were formed."""

    lam: float
    S: np.ndarray  # −Σ_f Y_f' Y_f
    rhs: np.ndarray  # Σ_f Y_f' L_f⁻¹ g_f
    els: list[Elimination]  # the kept chunks' eliminations


class FrameBlocks:
    """The normal equations at one state, their frame blocks held chunk by chunk.

    Fields every pass may read: cost, gz (F, nz), gp, C (with the priors), diagonal (F, nz) of A_f,
    the patterns of A_f and B_f.  `chunk(i)` gives chunk i's Linearization (kept, or formed again)."""

    def __init__(self, problem: Problem | None, state: State | None, with_parameters: bool, budget: float,
                 previous: FrameBlocks | None = None, chunk_frames: int | None = None,
                 linearization: Linearization | None = None, eliminate_at: float | None = None,
                 work: tuple[list[dict], dict] | None = None):
        """`previous`: the blocks of an earlier state no longer needed, whose kept arrays are overwritten
        (else the problem's buffers from its last solve); `linearization`: blocks already formed for
        the whole trial (then `problem` and `state` may be None).  `eliminate_at`: the damping λ of
        the step to come: a long trial's chunks are then eliminated as they are formed, and that
        step's first pass is saved (`prepared`); `work`: the buffers of the kept chunks (one dict
        each, extended here) and of the others."""
        self.problem, self.state, self.with_parameters = problem, state, with_parameters
        self.prepared: Prepared | None = None
        if linearization is not None:
            self.slices, self.n_kept = [slice(0, linearization.A.shape[0])], 1
        else:
            F = problem.F
            self.slices, self.n_kept = chunk_slices(F, frame_bytes(problem, with_parameters), budget,
                                                     chunk_frames or CHUNK_FRAMES)
        self.whole = len(self.slices) == 1
        self._previous = previous.kept if previous is not None else []
        if self.whole:
            lin = linearization
            if lin is None:
                lin = problem.linearize(state, with_parameters, reuse=self._previous[0] if self._previous else True)
            self._previous = []
            self.kept: list[Linearization] = [lin]
            self.cost, self.C, self.gp, self.gz = lin.cost, lin.C, lin.gp, lin.gz
            self.diagonal = np.diagonal(lin.A, axis1=1, axis2=2)
            self.a_pattern, self.b_pattern = lin.a_pattern, lin.b_pattern
            return
        F, nz = problem.F, problem.model.nz
        self.kept = []
        self._scratch_parts: dict[str, Linearization] = {}
        self.layout = problem.parameter_layout(state.p) if with_parameters else None
        self.tangent = problem.tangent_map(state.p) if with_parameters else None
        self.gz, self.diagonal = np.empty((F, nz)), np.empty((F, nz))
        cost, C, gp = problem.prior_normal(state.p, with_parameters)
        kept_work, scratch = work if work is not None else ([], {})
        kept_work.extend({} for _ in range(self.n_kept - len(kept_work)))
        self.kept_work, self.scratch = kept_work, scratch
        prepare = eliminate_at is not None and with_parameters
        if prepare:
            n = gp.size
            S, rhs, els, largest, floors = np.zeros((n, n)), np.zeros(n), [], 0.0, []
        for i, sl in enumerate(self.slices):
            lin = self._form(i, "all" if prepare else "no_coupling")
            cost += lin.cost
            if with_parameters:
                C = C + lin.C
                gp = gp + lin.gp
            self.gz[sl] = lin.gz
            self.diagonal[sl] = np.diagonal(lin.A, axis1=1, axis2=2)
            self.a_pattern, self.b_pattern = lin.a_pattern, lin.b_pattern
            if prepare:  # the next step's first pass (chunked_step), with the largest diagonal so far
                largest = max(largest, float(self.diagonal[sl].max(initial=0.0)))
                floors.append(largest)
                el = eliminate(lin, eliminate_at * marquardt_diagonal(self.diagonal[sl], largest), True,
                               work=kept_work[i] if i < self.n_kept else scratch)
                if el is None:
                    prepare = False
                    continue
                if i < self.n_kept:
                    els.append(el)
                S -= el.S
                rhs += el.Y.transpose_times(el.yz)
        self.cost, self.C, self.gp = cost, C, gp
        self._previous = []
        if prepare:  # valid if the floor of Marquardt's scaling changed no frame's damping since
            final = max(1.0, largest)
            if all(max(1.0, f) == final or bool(np.all(self.diagonal[sl] >= DIAG_FLOOR * final))
                   for f, sl in zip(floors, self.slices, strict=True)):
                self.prepared = Prepared(eliminate_at, S, rhs, els)

    @property
    def linearization(self) -> Linearization | None:
        """The whole trial's Linearization when it is one chunk (else None)."""
        return self.kept[0] if self.whole else None

    def _form(self, i: int, parts: str) -> Linearization:
        """Chunk i's blocks formed at the state: all of them if the chunk is kept (within the budget),
        else only `parts` (Problem.linearize) in scratch arrays that the next chunk overwrites."""
        sl = self.slices[i]
        if i < self.n_kept:
            old = self._previous[i] if i < len(self._previous) else None
            lin = self.problem.linearize(self.state, self.with_parameters, reuse=old, frames=sl, layout=self.layout)
            self.kept.append(lin)
            return lin
        key = "with_B" if parts in ("all", "coupling") else parts  # never two of these at once
        lin = self.problem.linearize(self.state, self.with_parameters, reuse=self._scratch_parts.get(key),
                                     frames=sl, parts=parts, layout=self.layout)
        self._scratch_parts[key] = lin
        return lin

    def chunk(self, i: int, parts: str = "all") -> Linearization:
        """Chunk i's blocks: kept (all parts), or formed again at the state with `parts` at least."""
        return self.kept[i] if i < len(self.kept) else self._form(i, parts)

    def gradient_max(self) -> float:
        return max(float(np.abs(self.gz).max(initial=0.0)), float(np.abs(self.gp).max(initial=0.0)))

    def recycle(self) -> None:
        """Hand the whole trial's Linearization back to the problem (its arrays: the next run's buffers)."""
        if self.whole:
            self.problem.recycle(self.kept[0])

    def chunks(self, parts: str = "all") -> Iterator[tuple[int, slice, Linearization]]:
        """(index, frames, blocks) of every chunk in turn (those not kept formed with `parts`)."""
        for i, sl in enumerate(self.slices):
            yield i, sl, self.chunk(i, parts)


def each_chunk(problem: Problem, state: State, with_parameters: bool, budget: float,
               parts: str = "all") -> Iterator[tuple[slice, Linearization]]:
    """(frames, blocks) of every chunk at `state` in turn, each formed once (Problem.linearize `parts`;
    no priors) into arrays the next chunk overwrites: for a single pass over the frames (the
    leverage, the covariance), which FrameBlocks would form twice where chunks are not kept."""
    slices, _ = chunk_slices(problem.F, frame_bytes(problem, with_parameters), budget, CHUNK_FRAMES)
    layout = problem.parameter_layout(state.p) if with_parameters else None
    lin: Linearization | bool = len(slices) == 1  # a whole trial: in the arrays of the solver's last run on it
    for sl in slices:
        lin = problem.linearize(state, with_parameters, reuse=lin, frames=sl, parts=parts, layout=layout)
        yield sl, lin


def _frame_steps(L: np.ndarray, el: Elimination | None, g: np.ndarray, Bdp: np.ndarray | None, dp: np.ndarray,
                 yz: np.ndarray | None = None) -> np.ndarray:
    """Each frame's step −(A_f + λD_f)⁻¹ (g_f + B_f dp) from the factor L (reversed rows): with the
    chunk's elimination kept, through Y = L⁻¹B (yz: L⁻¹g if known); else from B dp (`Bdp`)."""
    if el is not None:
        yz = forward_substitute(L, g) if yz is None else yz
        t = yz + el.Y.times(dp) if dp.size else yz
        return -back_substitute(L, t)[:, ::-1]
    t = g + Bdp if Bdp is not None else g
    return -back_substitute(L, forward_substitute(L, np.ascontiguousarray(t)))[:, ::-1]


def chunked_step(problem: Problem, blocks: FrameBlocks, state: State, lam: float, Dz: np.ndarray,
                 N: GaugeBasis | None, accelerate: bool, here: tuple | None, scratch: dict,
                 kept_work: list[dict]) -> tuple[np.ndarray, np.ndarray, float, Bend] | None:
    """One Levenberg–Marquardt step of damping `lam` (scaling Dz (F, nz); gauge basis N) on blocks
    held chunk by chunk: (dz, dp, the Gauss–Newton model's predicted decrease, the bend), the bend
    (half the geodesic acceleration, to add to the step) if `accelerate` and it is small enough, else
    None (`here`: the residual parts at `state`); None if a block is not positive definite.  Chunks
    not kept are formed again in each pass: once to eliminate them (the Schur complement), once to
    back-substitute (the step, its predicted decrease and the acceleration's right-hand side), once
    more for the acceleration's back-substitution.  The same arithmetic as calibrate.solve.lm's step
    on the whole trial, up to the order of sums."""
    wp = blocks.with_parameters
    n = blocks.gp.size if wp else 0
    damping = lam * Dz
    if n == 0:
        return _pose_step(problem, blocks, state, damping, accelerate, here, scratch, kept_work)
    pose_work: dict = {}
    # Pass 1: every chunk eliminated, the Schur complement and its right-hand side summed (done already
    # if the blocks were eliminated at this damping as they were formed).
    pre = blocks.prepared
    S, rhs, els = (pre.S.copy(), pre.rhs, pre.els) if pre is not None and pre.lam == lam else \
        (np.zeros((n, n)), np.zeros(n), [])
    for i, sl, lin in (() if pre is not None and pre.lam == lam else blocks.chunks("coupling")):
        el = eliminate(lin, damping[sl], wp, work=kept_work[i] if i < blocks.n_kept else scratch)
        if el is None:
            return None
        if i < blocks.n_kept:
            els.append(el)
        if n:
            S -= el.S
            rhs += el.Y.transpose_times(el.yz)
    Ls = None
    if n:
        S = blocks.C + S
        dS = np.diag(S)
        S = S + np.diag(lam * marquardt_diagonal(dS, float(dS.max(initial=0.0))))
        if N is not None:
            S = N.project(S)
        try:
            Ls = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            return None

    def parameters(g: np.ndarray, r: np.ndarray) -> np.ndarray:
        if Ls is None:
            return np.zeros(0)
        r = -g + r
        if N is not None:
            r = N.down(r)
        x = cho_solve(Ls, r)
        return N.up(x) if N is not None else x

    def factors(i: int, sl: slice, lin: Linearization) -> tuple[np.ndarray, Elimination | None]:
        if i < len(els):
            return els[i].L, els[i]
        return eliminate(lin, damping[sl], False, work=pose_work).L, None

    dp = parameters(blocks.gp, rhs)
    # Pass 2: each frame's step and the model's decrease; the acceleration's right-hand side.
    h = GEODESIC_H
    dz = np.empty_like(blocks.gz)
    quad = lin_term = cross = 0.0
    if accelerate:
        p_plus, p_minus = (problem.retract_parameters(state.p, s * h * dp) if n else state.p for s in (1, -1))
        r_vv = (problem.prior(p_plus, jacobian=False)[0] - 2.0 * here[2]
                + problem.prior(p_minus, jacobian=False)[0]) / h**2
        accelerate = bool(np.all(np.isfinite(r_vv)))
        g2z = np.empty_like(blocks.gz)
        g2p = problem.prior_gradient(state.p, r_vv) if n and accelerate else np.zeros(n)
        rhs2 = np.zeros(n)
    full_step = blocks.tangent @ dp if n else None
    for i, sl, lin in blocks.chunks("frames"):
        L, el = factors(i, sl, lin)
        Bdp = (frames_times(lin.B, dp) if el is not None else problem.coupling_times(lin, full_step)) if n else None
        dz[sl] = _frame_steps(L, el, lin.gz, Bdp, dp, el.yz if el is not None else None)
        quad += float(np.sum(dz[sl] * np.matmul(lin.A, dz[sl][:, :, None])[:, :, 0]))
        lin_term += float(np.sum(lin.gz * dz[sl]))
        if n:
            cross += float(np.sum(dz[sl] * Bdp))
        if not accelerate:
            continue
        sub = State(state.Z[sl], state.Q[sl], state.p, None if state.B is None else state.B[sl])
        plus = problem.residual_parts(retract(problem, sub, h * dz[sl], h * dp), frames=sl)
        minus = problem.residual_parts(retract(problem, sub, -h * dz[sl], -h * dp), frames=sl)
        second = [(pl - 2.0 * x[sl] + mi) / h**2 for pl, x, mi in zip(plus[:2], here[:2], minus[:2], strict=True)]
        if not all(np.all(np.isfinite(v)) for v in second):
            accelerate = False
            continue
        g2z[sl], gp_c = problem.gradient(lin, second[0], second[1], None)
        if n:
            g2p = g2p + gp_c
            if el is not None:
                rhs2 += el.Y.transpose_times(forward_substitute(L, g2z[sl]))
            else:
                u = back_substitute(L, forward_substitute(L, np.ascontiguousarray(g2z[sl])))[:, ::-1]
                rhs2 += problem.coupling_transpose(lin, np.ascontiguousarray(u))
    if n:
        quad += 2.0 * cross + float(dp @ blocks.C @ dp)
        lin_term += float(blocks.gp @ dp)
    predicted = -(lin_term + 0.5 * quad)
    if not accelerate:
        return dz, dp, predicted, None
    # Pass 3: the acceleration a = −(J'J + λD)⁻¹ J' r_vv back-substituted; kept while 2|a| <= ratio |v|
    # (its parameters' part alone may already be too large: then no pass).
    ap = parameters(g2p, rhs2)
    v2 = float(np.sum(dz**2) + np.sum(dp**2))
    if 4.0 * float(np.sum(ap**2)) > GEODESIC_RATIO**2 * v2:
        return dz, dp, predicted, None
    az = np.empty_like(dz)
    full_step = blocks.tangent @ ap if n else None
    for i, sl, lin in blocks.chunks("frames"):
        L, el = factors(i, sl, lin)
        Bdp = (frames_times(lin.B, ap) if el is not None else problem.coupling_times(lin, full_step)) if n else None
        az[sl] = _frame_steps(L, el, g2z[sl], Bdp, ap)
    a2 = float(np.sum(az**2) + np.sum(ap**2))
    if 4.0 * a2 > GEODESIC_RATIO**2 * v2:
        return dz, dp, predicted, None
    return dz, dp, predicted, (0.5 * az, 0.5 * ap)


def _pose_step(problem: Problem, blocks: FrameBlocks, state: State, damping: np.ndarray, accelerate: bool,
               here: tuple | None, scratch: dict,
               kept_work: list[dict]) -> tuple[np.ndarray, np.ndarray, float, Bend] | None:
    """chunked_step with the parameters fixed: the frames are not coupled, so each chunk's step, its
    predicted decrease and its geodesic acceleration are made in one pass (each chunk formed and
    factorised once instead of three times)."""
    h, dp = GEODESIC_H, np.zeros(0)
    dz = np.empty_like(blocks.gz)
    az = np.empty_like(dz) if accelerate else None
    quad = lin_term = 0.0
    for i, sl, lin in blocks.chunks("frames"):
        el = eliminate(lin, damping[sl], False, work=kept_work[i] if i < blocks.n_kept else scratch)
        if el is None:
            return None
        dz[sl] = _frame_steps(el.L, el, lin.gz, None, dp, el.yz)
        quad += float(np.sum(dz[sl] * np.matmul(lin.A, dz[sl][:, :, None])[:, :, 0]))
        lin_term += float(np.sum(lin.gz * dz[sl]))
        if not accelerate:
            continue
        sub = State(state.Z[sl], state.Q[sl], state.p, None if state.B is None else state.B[sl])
        plus = problem.residual_parts(retract(problem, sub, h * dz[sl], dp), frames=sl)
        minus = problem.residual_parts(retract(problem, sub, -h * dz[sl], dp), frames=sl)
        second = [(pl - 2.0 * x[sl] + mi) / h**2 for pl, x, mi in zip(plus[:2], here[:2], minus[:2], strict=True)]
        if not all(np.all(np.isfinite(v)) for v in second):
            accelerate = False
            continue
        g2z, _ = problem.gradient(lin, second[0], second[1], None)
        az[sl] = _frame_steps(el.L, el, g2z, None, dp)
    predicted = -(lin_term + 0.5 * quad)
    if not accelerate:
        return dz, dp, predicted, None
    if 4.0 * float(np.sum(az**2)) > GEODESIC_RATIO**2 * float(np.sum(dz**2)):
        return dz, dp, predicted, None
    return dz, dp, predicted, (0.5 * az, dp)
