"""Levenberg–Marquardt for the block-arrow calibration problem (seed 003).

Frames are coupled only through the parameters p, so the damped normal equations

    [ A_1 + λD_1                B_1 ] [dz_1]     [g_1]
    [            ...            ... ] [ ...]  = −[...]
    [ B_1'  ...        C + λD_p     ] [ dp ]     [g_p]

are solved by eliminating every frame block (a Cholesky of each small A_f, in compiled loops:
calibrate.solve.assembly):
S = C + λD_p − Σ_f B_f' (A_f + λD_f)⁻¹ B_f is only n_free × n_free, then each dz_f is
back-substituted.  Time and memory grow linearly with the number of frames; the full
(nz·F + n)² matrix is never formed.  D is Marquardt's diagonal scaling (diag of the
normal matrix, floored), λ follows Nielsen's update on the gain ratio.  The root rotation
and the hinge axes are updated on their manifolds (see Problem.retract_parameters and
kinematics.retract_root).  Each step carries a geodesic acceleration (Transtrum & Sethna 2012),
which lets it bend along curved valleys of the cost (see _accelerate).

Termination (first met wins, reported in words):
  relative cost decrease of an accepted step < ftol;  its absolute decrease < atol (the cost is
  χ²/2 in units of the marker noise, so atol = 0.5 is a χ² change of 1, its one-sigma level);
  |step| < xtol (|x| + xtol);
  largest gradient entry < gtol;  max_iterations reached (not converged);
  no step lowers the cost any more (λ too large: converged to the precision available).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..problem.options import SolverOptions
from ..problem.problem import Problem
from ..problem.state import Linearization, State
from .assembly import back_substitute, factor_frames, forward_substitute, in_parallel, split_frames

__all__ = ["Covariance", "SolverOptions", "SolverSummary", "State", "StepProblem", "covariance", "levenberg_marquardt",
           "minimise"]

DIAG_FLOOR = 1e-9  # relative floor of Marquardt's scaling diagonal
GEODESIC_H = 0.1  # finite-difference step (fraction of the LM step) of the geodesic acceleration
GEODESIC_RATIO = 0.75  # the acceleration is used while 2|a| <= this times |v| (Transtrum & Sethna's alpha)


@dataclass
class SolverSummary:
    """What the solver did, in the spirit of Ceres' Solver::Summary."""

    iterations: int = 0  # accepted + rejected steps
    accepted: int = 0
    initial_cost: float = float("nan")
    final_cost: float = float("nan")
    cost_history: list[float] = field(default_factory=list)  # cost after each accepted step (first: initial)
    termination: str = ""  # why it stopped, in words
    converged: bool = False
    seconds: float = 0.0
    linearize_seconds: float = 0.0
    linear_solver_seconds: float = 0.0
    evaluate_seconds: float = 0.0
    coarse: SolverSummary | None = None  # the solve on a subsample of frames that preceded this one
    coarse_frames: int = 0  # frames of that subsample
    rounds: int = 1  # solves of the subsample (or short trial): more when axes were held and it was solved again


@dataclass
class Covariance:
    """Posterior covariance of the free parameters (Gauss–Newton, at the solution), and the
    covariance the priors alone would give (to tell what the trial identified)."""

    matrix: np.ndarray  # (n_free, n_free), in the units of the free parameters
    prior_only: np.ndarray  # (n_free, n_free): the same with no marker data


@dataclass
class _Elimination:
    """The frame blocks eliminated, each in reverse coordinate order (leaves of the kinematic
    tree first, the root last), the order in which a Cholesky factor of A_f has no fill-in
    and Y_f = L_f⁻¹ B_f keeps the sparsity of B_f: a coordinate's row couples only with the
    parameters of the segments below it."""

    L: np.ndarray  # (F, nz, nz) Cholesky factor of the reversed (damped) A_f
    Y: np.ndarray  # (F, nz, n)  L⁻¹ B_f (rows reversed)
    yz: np.ndarray  # (F, nz)    L⁻¹ g_z (rows reversed)
    S: np.ndarray  # (n, n)      Σ_f Y_f' Y_f


def _row_classes(lin: Linearization, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rows of Y (reversed order) grouped by their nonzero columns: (rows, columns) per class.
    The pattern is propagated symbolically through the factorisation, so it is exact whatever
    the coordinate order."""
    nz = lin.A.shape[1]
    if lin.a_pattern is None or lin.b_pattern is None:
        return [(np.arange(nz), np.arange(n))]
    P = lin.a_pattern[::-1, ::-1] | np.eye(nz, dtype=bool)
    for k in range(nz):  # symbolic Cholesky: eliminating k joins its later neighbours
        nb = k + 1 + np.flatnonzero(P[k + 1:, k])
        P[np.ix_(nb, nb)] = True
    Yp = lin.b_pattern[::-1].copy()
    for i in range(nz):
        for j in np.flatnonzero(P[i, :i]):
            Yp[i] |= Yp[j]
    classes: dict[bytes, list[int]] = {}
    for i in range(nz):
        classes.setdefault(Yp[i].tobytes(), []).append(i)
    return [(np.array(rows), np.flatnonzero(Yp[rows[0]])) for rows in classes.values()]


def _buffer(work: dict | None, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """An uninitialised array, kept in `work` and reused by later calls (large temporaries
    allocated afresh on every step cost page faults and allocator churn)."""
    if work is None:
        return np.empty(shape)
    a = work.get((name, shape))
    if a is None:
        a = work[(name, shape)] = np.empty(shape)
    return a


def _eliminate(lin: Linearization, damping: np.ndarray, with_parameters: bool = True,
               work: dict | None = None) -> _Elimination | None:
    """Cholesky of every A_f + diag(damping_f) and the frames' share of the Schur complement;
    None if a block is not positive definite.  The factorisation runs in compiled loops
    (calibrate.solve.assembly.factor_frames); the Schur complement is accumulated by BLAS, class by
    class of Y's rows, with the frames split between the cores.  `work`: buffers to reuse."""
    F, nz, n = lin.B.shape
    n = n if with_parameters else 0
    L = _buffer(work, "L", (F, nz, nz))
    yz = _buffer(work, "yz", (F, nz))
    Y = _buffer(work, "Y", (F, nz, n))
    B = lin.B if n else np.empty((F, nz, 0))
    if not factor_frames(lin.A, np.ascontiguousarray(damping, dtype=float), B, lin.gz, L, Y, yz):
        return None
    if n == 0:
        return _Elimination(L, Y, yz, np.zeros((0, 0)))
    key = None if lin.a_pattern is None or lin.b_pattern is None else \
        ("row_classes", lin.a_pattern.tobytes(), lin.b_pattern.tobytes(), lin.b_pattern.shape)
    classes = None if work is None or key is None else work.get(key)
    if classes is None:
        classes = _row_classes(lin, n)
        if work is not None and key is not None:
            work[key] = classes  # the patterns change only with the free set: one per problem

    def part(fr: slice) -> np.ndarray:
        S = np.zeros((n, n))
        for rows, cols in classes:
            if cols.size == 0:
                continue
            if rows[-1] - rows[0] + 1 == rows.size:  # consecutive rows (a joint's coordinates): a view
                M = np.take(Y[fr, rows[0]:rows[-1] + 1], cols, axis=2)
            else:
                M = np.take(Y[fr][:, rows], cols, axis=2)
            M = M.reshape(-1, cols.size)
            S[np.ix_(cols, cols)] += M.T @ M
        return S

    results = in_parallel(part, split_frames(F))
    return _Elimination(L, Y, yz, sum(results[1:], results[0]))


class _Factored:
    """The damped normal equations of one LM iteration, factored: solve(g_z, g_p) gives the step
    for any right-hand side (the LM step, then the geodesic acceleration) at the cost of a few
    substitutions."""

    def __init__(self, el: _Elimination, Ls: np.ndarray | None, N: np.ndarray | None):
        self.el, self.Ls, self.N = el, Ls, N

    def solve(self, gz: np.ndarray, gp: np.ndarray, yz: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(dz, dp) minimising the damped Gauss–Newton model with gradient (g_z, g_p)."""
        el = self.el
        yz = forward_substitute(el.L, gz) if yz is None else yz  # L⁻¹ g_z, reversed rows
        if self.Ls is None:
            return -back_substitute(el.L, yz)[:, ::-1], np.zeros(0)
        F, nz, n = el.Y.shape
        rhs = -gp + el.Y.reshape(F * nz, n).T @ yz.reshape(-1)
        if self.N is not None:
            rhs = self.N.T @ rhs
        dp = np.linalg.solve(self.Ls.T, np.linalg.solve(self.Ls, rhs))
        if self.N is not None:
            dp = self.N @ dp
        t = yz + np.matmul(el.Y, dp)  # L⁻¹ (g_z + B dp), reversed rows
        return -back_substitute(el.L, t)[:, ::-1], dp


def factor_step(lin: Linearization, lam: float, Dz: np.ndarray, pose_only: bool = False,
                N: np.ndarray | None = None, work: dict | None = None) -> _Factored | None:
    """The damped normal equations for damping `lam` factored (frames eliminated, the Schur
    complement on p Cholesky-factored, restricted to the columns of `N` (gauge constraints) if
    given); None if a block is not positive definite.  `work`: buffers reused between steps."""
    el = _eliminate(lin, lam * Dz, with_parameters=not pose_only, work=work)
    if el is None:
        return None
    if pose_only or lin.C.size == 0:
        return _Factored(el, None, None)
    S = lin.C - el.S
    # Marquardt scaling on the reduced system: damp each parameter by its own curvature once the
    # frames are eliminated (diag S), not by diag C, which counts curvature the poses explain away.
    dS = np.diag(S)
    S = S + np.diag(lam * marquardt_diagonal(dS, float(dS.max(initial=0.0))))
    if N is not None:
        S = N.T @ S @ N
    try:
        return _Factored(el, np.linalg.cholesky(S), N)
    except np.linalg.LinAlgError:
        return None


def solve_step(lin: Linearization, lam: float, Dz: np.ndarray, pose_only: bool = False,
               N: np.ndarray | None = None, work: dict | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The LM step (dz (F, nz), dp (n,)) for damping `lam` (see factor_step); None if a block is
    not positive definite."""
    fac = factor_step(lin, lam, Dz, pose_only, N, work)
    return None if fac is None else fac.solve(lin.gz, lin.gp, fac.el.yz)


def retract(problem: Problem, state: State, dz: np.ndarray, dp: np.ndarray) -> State:
    """`state` moved by (dz, dp): root and ball-joint rotations folded into their references
    (Kinematics.retract), axes kept unit."""
    Z, Q, B = problem.kin.retract(state.Z + dz, state.Q, state.B)
    p = problem.retract_parameters(state.p, dp) if dp.size else state.p.copy()
    return State(Z, Q, p, B)


def null_space(K: np.ndarray, n: int) -> np.ndarray | None:
    """Orthonormal basis (n, n − rank K) of the steps that satisfy K dp = 0; None without constraints."""
    if K.shape[0] == 0:
        return None
    Qm, R = np.linalg.qr(K.T, mode="complete")
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > 1e-10 * max(1e-300, d.max(initial=0.0))))
    return Qm[:, rank:]


def _accelerate(problem: Problem, state: State, lin: Linearization, fac: _Factored, dz: np.ndarray,
                dp: np.ndarray, here: tuple) -> tuple[np.ndarray, np.ndarray]:
    """The LM step v = (dz, dp) with geodesic acceleration (Transtrum & Sethna 2012): the residuals'
    second derivative along v, r_vv ≈ (r(x + hv) − 2 r(x) + r(x − hv)) / h², gives the correction
    a = −(J'J + λD)⁻¹ J' r_vv, and the step becomes v + a/2: it bends with a curved valley (such as
    two hinges in series across a segment with no markers) instead of leaving it.  Kept only while
    small, 2|a| ≤ GEODESIC_RATIO |v|; otherwise v alone."""
    h = GEODESIC_H
    plus = problem.residual_parts(retract(problem, state, h * dz, h * dp))
    minus = problem.residual_parts(retract(problem, state, -h * dz, -h * dp))
    second = [(p - 2.0 * x + m) / h**2 for p, x, m in zip(plus, here, minus, strict=True)]
    if not all(np.all(np.isfinite(s)) for s in second):
        return dz, dp
    az, ap = fac.solve(*problem.gradient(lin, *second))
    v2 = float(np.sum(dz**2) + np.sum(dp**2))
    a2 = float(np.sum(az**2) + np.sum(ap**2))
    if 4.0 * a2 > GEODESIC_RATIO**2 * v2:
        return dz, dp
    return dz + 0.5 * az, dp + 0.5 * ap


def _model_decrease(lin: Linearization, dz: np.ndarray, dp: np.ndarray) -> float:
    """Decrease of the Gauss–Newton model −(g'h + ½ h'Hh) for the step h = (dz, dp)."""
    Adz = np.matmul(lin.A, dz[:, :, None])[:, :, 0]
    quad = float(np.sum(dz * Adz))
    lin_term = float(np.sum(lin.gz * dz))
    if dp.size:
        Bdp = np.matmul(lin.B, dp)
        quad += 2.0 * float(np.sum(dz * Bdp)) + float(dp @ lin.C @ dp)
        lin_term += float(lin.gp @ dp)
    return -(lin_term + 0.5 * quad)


class StepProblem(Protocol):
    """A least-squares problem as the Levenberg–Marquardt loop (`minimise`) sees it: the block-arrow
    calibration problem (`levenberg_marquardt`) and one frame's inverse kinematics
    (calibrate.solve.ik.FrameSolver) alike.  A scratch object for one run, like Pinocchio's Data:
    `linearize` keeps the linearization that `gradient_max` and `step` then use."""

    def linearize(self, x: Any) -> float:
        """Linearize the residuals at `x` (the start, then each accepted point); its cost."""

    def gradient_max(self) -> float:
        """Largest gradient entry at the last linearization."""

    def step(self, x: Any, lam: float) -> tuple[Any, float, float] | None:
        """The step of damping `lam` (scaling: marquardt_diagonal) from the last linearization:
        (the point it reaches, the Gauss–Newton model's predicted cost decrease, |step|); None
        if the damped normal equations are not positive definite."""

    def cost(self, x: Any) -> float:
        """The cost at a trial point."""

    def norm(self, x: Any) -> float:
        """|x|, for the step tolerance."""


def marquardt_diagonal(diagonal: np.ndarray, largest: float) -> np.ndarray:
    """Marquardt's scaling: the normal matrix's diagonal, floored relative to its largest entry
    (a coordinate the markers do not reach still gets some damping)."""
    return np.maximum(diagonal, DIAG_FLOOR * max(1.0, largest))


def minimise(steps: StepProblem, x: Any, options: SolverOptions, max_iterations: int | None = None,
             progress: Callable[[int, float, float], None] | None = None,
             summary: SolverSummary | None = None) -> tuple[Any, SolverSummary]:
    """Levenberg–Marquardt from `x`: Marquardt-scaled damping λ following Nielsen's update on the
    gain ratio, and the termination tests of the module docstring (tolerances and iteration limit:
    `options`; `max_iterations` overrides its limit; every step, accepted or not, counts).
    `progress(iteration, cost, lam)` after each accepted step."""
    max_it = max_iterations or options.max_iterations
    summary = SolverSummary() if summary is None else summary
    cost = steps.linearize(x)
    summary.initial_cost = cost
    summary.cost_history.append(cost)
    lam, nu = 1e-4, 2.0
    termination, converged = "", False
    while True:
        g_max = steps.gradient_max()
        if g_max < options.gtol:
            termination, converged = f"gradient {g_max:.2e} below gtol {options.gtol:.0e}", True
            break
        if summary.iterations >= max_it:
            termination = f"reached max_iterations ({max_it}) before converging"
            break
        summary.iterations += 1
        proposed = steps.step(x, lam)
        if proposed is None:
            lam, nu = lam * nu, nu * 2
            if lam > 1e16:
                termination, converged = "normal equations not positive definite at any damping", False
                break
            continue
        trial, predicted, step_norm = proposed
        new_cost = steps.cost(trial)
        rho = (cost - new_cost) / predicted if predicted > 0 else -1.0
        if np.isfinite(new_cost) and rho > 1e-4 and new_cost < cost:
            rel = (cost - new_cost) / max(cost, 1e-300)
            x, cost = trial, new_cost
            summary.accepted += 1
            summary.cost_history.append(cost)
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if progress is not None:
                progress(summary.iterations, cost, lam)
            if rel < options.ftol:
                termination, converged = f"relative cost decrease {rel:.2e} below ftol {options.ftol:.0e}", True
                break
            if summary.accepted > 1 and (summary.cost_history[-2] - cost) < options.atol:
                termination = f"cost decrease {summary.cost_history[-2] - cost:.2e} below atol {options.atol:g}"
                converged = True
                break
            if step_norm < options.xtol * (steps.norm(x) + options.xtol):
                termination, converged = f"step {step_norm:.2e} below xtol {options.xtol:.0e}", True
                break
            steps.linearize(x)
        else:
            lam, nu = lam * nu, nu * 2
            if step_norm < options.xtol * (steps.norm(x) + options.xtol):
                termination, converged = f"step {step_norm:.2e} below xtol {options.xtol:.0e}", True
                break
            if lam > 1e16:
                termination = "no step lowers the cost (damping exhausted): converged to the available precision"
                converged = True
                break
    summary.final_cost = cost
    summary.termination = termination
    summary.converged = converged
    return x, summary


class _BlockArrow:
    """The calibration problem as a StepProblem: steps from the Schur complement on p (factor_step),
    with geodesic acceleration when the loss is plain least squares; stage times go to `summary`."""

    def __init__(self, problem: Problem, options: SolverOptions, pose_only: bool, summary: SolverSummary):
        self.problem, self.pose_only, self.summary = problem, pose_only, summary
        # Buffers shared by every step, and by later runs on this problem (first touches of the large
        # per-step arrays, in page faults, cost as much as a step of a short run).
        self.work = problem.buffers()
        # Geodesic acceleration needs the residuals' second derivative, which a robust loss's changing
        # weights would blur: plain least squares only.
        self.accelerate = options.geodesic and problem.loss == "linear"
        self.lin: Linearization | None = None
        self.here: tuple | None = None
        self.N: np.ndarray | None = None

    def linearize(self, state: State) -> float:
        problem = self.problem
        t0 = time.perf_counter()
        self.lin = problem.linearize(state, with_parameters=not self.pose_only,
                                     reuse=True if self.lin is None else self.lin)
        self.here = problem.residual_parts(state) if self.accelerate else None
        self.summary.linearize_seconds += time.perf_counter() - t0
        self.N = None if self.pose_only else null_space(problem.gauge_constraints(state.p), problem.n_free)
        return self.lin.cost

    def gradient_max(self) -> float:
        lin = self.lin
        return max(float(np.abs(lin.gz).max(initial=0.0)), float(np.abs(lin.gp).max(initial=0.0)))

    def step(self, state: State, lam: float) -> tuple[State, float, float] | None:
        lin, summary = self.lin, self.summary
        Dz = marquardt_diagonal(np.diagonal(lin.A, axis1=1, axis2=2), float(lin.A.max(initial=0.0)))
        t0 = time.perf_counter()
        fac = factor_step(lin, lam, Dz, self.pose_only, self.N, self.work)
        if fac is None:
            summary.linear_solver_seconds += time.perf_counter() - t0
            return None
        dz, dp = fac.solve(lin.gz, lin.gp, fac.el.yz)
        summary.linear_solver_seconds += time.perf_counter() - t0
        predicted = _model_decrease(lin, dz, dp)
        if self.accelerate:
            t0 = time.perf_counter()
            dz, dp = _accelerate(self.problem, state, lin, fac, dz, dp, self.here)
            summary.evaluate_seconds += time.perf_counter() - t0
        step_norm = float(np.sqrt(np.sum(dz**2) + np.sum(dp**2)))
        return retract(self.problem, state, dz, dp), predicted, step_norm

    def cost(self, state: State) -> float:
        t0 = time.perf_counter()
        c = self.problem.cost(state)
        self.summary.evaluate_seconds += time.perf_counter() - t0
        return c

    def norm(self, state: State) -> float:
        return float(np.sqrt(np.sum(state.Z**2) + np.sum(state.p**2)))


def levenberg_marquardt(problem: Problem, state: State, options: SolverOptions | None = None, *,
                        pose_only: bool = False, max_iterations: int | None = None,
                        progress: Callable[[int, float, float], None] | None = None) -> tuple[State, SolverSummary]:
    """Minimise the problem's cost from `state` (tolerances, iteration limit and geodesic
    acceleration: `options`, default SolverOptions(); `max_iterations` overrides its limit).
    `pose_only` keeps p fixed (frame-wise inverse kinematics of all frames at once).
    `progress(iteration, cost, lam)` after each step."""
    options = SolverOptions() if options is None else options
    summary = SolverSummary()
    t_start = time.perf_counter()
    steps = _BlockArrow(problem, options, pose_only, summary)
    state, summary = minimise(steps, state, options, max_iterations, progress, summary)
    problem.recycle(steps.lin)  # its arrays are the next run's buffers
    summary.seconds = time.perf_counter() - t_start
    return state, summary


def covariance(problem: Problem, state: State, lin: Linearization | None = None) -> Covariance:
    """Posterior covariance of the free parameters: the inverse of the Schur complement
    S = C − Σ B_f' A_f⁻¹ B_f at the solution (λ = 0), with each segment frame's orientation
    held (the gauge; otherwise every offset in a segment would share its frame's uncertain
    turn).  A hinge centre's slide along its axis is *not* held here, so its prior-only
    uncertainty shows.  Singular directions get a pseudo-inverse."""
    lin = lin or problem.linearize(state)
    Dz = np.diagonal(lin.A, axis1=1, axis2=2)
    eps = 1e-12 * max(1.0, float(Dz.max(initial=0.0)))
    el = _eliminate(lin, np.full(Dz.shape, eps))
    if el is None:
        raise np.linalg.LinAlgError("covariance: a frame's normal matrix is not positive definite")
    S = lin.C - el.S
    S = 0.5 * (S + S.T)
    _, Jr = problem.prior(state.p)
    P = Jr.T @ Jr
    N = null_space(problem.gauge_constraints(state.p, slides=False), problem.n_free)
    if N is None:
        return Covariance(np.linalg.pinv(S, hermitian=True), np.linalg.pinv(P, hermitian=True))
    return Covariance(N @ np.linalg.pinv(N.T @ S @ N, hermitian=True) @ N.T,
                      N @ np.linalg.pinv(N.T @ P @ N, hermitian=True) @ N.T)
