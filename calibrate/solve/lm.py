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
rotations.retract_root).  Each step may carry a geodesic acceleration (Transtrum & Sethna 2012),
which lets it bend along curved valleys of the cost (see _accelerate); the bent and the plain step
are both evaluated, the lower taken, and the acceleration is dropped for the rest of a run where its
bend does not pay (_BlockArrow._bent_or_not).

Termination (first met wins, reported in words):
  relative cost decrease of an accepted step < ftol;  its absolute decrease < atol (the cost is
  χ²/2 in units of the marker noise, so atol = 0.5 is a χ² change of 1, its one-sigma level);
  |step| < xtol (|x| + xtol);
  largest gradient entry < gtol;  max_iterations reached (not converged);
  no step lowers the cost any more (λ too large: converged to the precision available).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from ..model.blocks import FrameLayout
from ..problem.options import SolverOptions
from ..problem.problem import Problem
from ..problem.state import Linearization, State
from .assembly import back_substitute, cho_solve, forward_substitute
from .chunks import Bend, FrameBlocks, chunked_step, each_chunk
from .schur import (
    GEODESIC_H,
    GEODESIC_RATIO,
    Elimination,
    GaugeBasis,
    eliminate,
    marquardt_diagonal,
    model_decrease,
    refactor_frames,
    retract,
)

__all__ = ["Covariance", "Run", "SolverOptions", "SolverSummary", "State", "StepProblem", "covariance",
           "fit_least_squares", "iterate", "levenberg_marquardt", "minimise"]



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
    rounds: int = 1  # solves of the subsample (or short trial): more when axes or centres were held, hinges locked
    # or moved markers left out, and it was solved again
    levels: list[tuple[int, int]] = field(default_factory=list)  # larger subsamples solved next: (frames, iterations)
    bent: int = 0  # steps whose bent point (geodesic acceleration) was chosen over the plain one, accepted or not
    # The iteration of this run after which the acceleration was dropped (its bend did not pay); 0: never.  A
    # summary merged from several runs (calibrate.calibration.pipeline.merge_summaries) keeps 0.
    bend_dropped: int = 0


@dataclass
class Covariance:
    """Posterior covariance of the free parameters (Gauss–Newton, at the solution), and the
    covariance the priors alone would give (to tell what the trial identified)."""

    matrix: np.ndarray  # (n_free, n_free), in the units of the free parameters
    prior_only: np.ndarray  # (n_free, n_free): the same with no marker data


class _Factored:
    """The damped normal equations of one LM iteration, factored: solve(g_z, g_p) gives the step
    for any right-hand side (the LM step, then the geodesic acceleration) at the cost of a few
    substitutions."""

    def __init__(self, el: Elimination, Ls: np.ndarray | None, N: GaugeBasis | None):
        self.el, self.Ls, self.N = el, Ls, N

    def solve(self, gz: np.ndarray, gp: np.ndarray, yz: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(dz, dp) minimising the damped Gauss–Newton model with gradient (g_z, g_p)."""
        el = self.el
        yz = forward_substitute(el.L, gz) if yz is None else yz  # L⁻¹ g_z, reversed rows
        if self.Ls is None:
            return -back_substitute(el.L, yz)[:, ::-1], np.zeros(0)
        rhs = -gp + el.Y.transpose_times(yz)
        if self.N is not None:
            rhs = self.N.down(rhs)
        dp = cho_solve(self.Ls, rhs)
        if self.N is not None:
            dp = self.N.up(dp)
        t = yz + el.Y.times(dp)  # L⁻¹ (g_z + B dp), reversed rows
        return -back_substitute(el.L, t)[:, ::-1], dp


def factor_step(lin: Linearization, lam: float, Dz: np.ndarray, pose_only: bool = False,
                N: GaugeBasis | None = None, work: dict | None = None) -> _Factored | None:
    """The damped normal equations for damping `lam` factored (frames eliminated, the Schur
    complement on p Cholesky-factored, restricted to the columns of `N` (gauge constraints) if
    given); None if a block is not positive definite.  `work`: buffers reused between steps."""
    el = eliminate(lin, lam * Dz, with_parameters=not pose_only, work=work)
    return None if el is None else _factor_schur(lin, el, lam, pose_only, N)


def _factor_schur(lin: Linearization, el: Elimination, lam: float, pose_only: bool,
                  N: GaugeBasis | None) -> _Factored | None:
    """factor_step's second half: the damped Schur complement of the eliminated frames `el` factored."""
    if pose_only or lin.C.size == 0:
        return _Factored(el, None, None)
    S = lin.C - el.S
    # Marquardt scaling on the reduced system: damp each parameter by its own curvature once the
    # frames are eliminated (diag S), not by diag C, which counts curvature the poses explain away.
    dS = np.diag(S)
    S = S + np.diag(lam * marquardt_diagonal(dS, float(dS.max(initial=0.0))))
    if N is not None:
        S = N.project(S)
    try:
        return _Factored(el, np.linalg.cholesky(S), N)
    except np.linalg.LinAlgError:
        return None


def solve_step(lin: Linearization, lam: float, Dz: np.ndarray, pose_only: bool = False,
               N: GaugeBasis | None = None, work: dict | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The LM step (dz (F, nz), dp (n,)) for damping `lam` (see factor_step); None if a block is
    not positive definite."""
    fac = factor_step(lin, lam, Dz, pose_only, N, work)
    return None if fac is None else fac.solve(lin.gz, lin.gp, fac.el.yz)


def null_space(K: np.ndarray, n: int) -> GaugeBasis | None:
    """Orthonormal basis (n, n − rank K) of the steps that satisfy K dp = 0; None without constraints."""
    return None if K.shape[0] == 0 else GaugeBasis(K)


def _accelerate(problem: Problem, state: State, lin: Linearization, fac: _Factored, dz: np.ndarray,
                dp: np.ndarray, here: tuple) -> Bend:
    """Half the geodesic acceleration (Transtrum & Sethna 2012) of the LM step v = (dz, dp): the
    residuals' second derivative along v, r_vv ≈ (r(x + hv) − 2 r(x) + r(x − hv)) / h², gives the
    correction a = −(J'J + λD)⁻¹ J' r_vv, and the step v + a/2 bends with a curved valley (such as
    two hinges in series across a segment with no markers) instead of leaving it.  None unless
    small, 2|a| ≤ GEODESIC_RATIO |v|."""
    h = GEODESIC_H
    plus = problem.residual_parts(retract(problem, state, h * dz, h * dp))
    minus = problem.residual_parts(retract(problem, state, -h * dz, -h * dp))
    second = [(p - 2.0 * x + m) / h**2 for p, x, m in zip(plus, here, minus, strict=True)]
    if not all(np.all(np.isfinite(s)) for s in second):
        return None
    az, ap = fac.solve(*problem.gradient(lin, *second))
    v2 = float(np.sum(dz**2) + np.sum(dp**2))
    a2 = float(np.sum(az**2) + np.sum(ap**2))
    if 4.0 * a2 > GEODESIC_RATIO**2 * v2:
        return None
    return 0.5 * az, 0.5 * ap


class StepProblem(Protocol):
    """A least-squares problem as the Levenberg–Marquardt loop (`minimise`) sees it: the block-arrow
    calibration problem (`levenberg_marquardt`) and one frame's inverse kinematics
    (calibrate.solve.ik.FrameSolver) alike.  A scratch object for one run, like Pinocchio's Data:
    `linearize` keeps the linearization that `gradient_max` and `step` then use."""

    def linearize(self, x: Any, lam: float) -> float:
        """Linearize the residuals at `x` (the start, then each accepted point); its cost.  `lam`:
        the damping of the step that comes next (a long trial's blocks are eliminated with it as
        they are formed)."""

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


# The least damping after a rejected step.  Doubling λ (Nielsen) from the 1e-12 it reaches along a
# well-modelled stretch takes six or more rejected steps before the step changes at all (each as dear as
# an iteration on a long trial); at this damping a step is shortened only in directions whose curvature
# (Marquardt-scaled) is under a millionth of the largest: those a rejected step has overshot.
LAMBDA_REJECTED = 1e-6
# The damping of a run's first step: a run of the calibration starts near its optimum (from a subsample's
# solution, or the last run's under new weights or without outliers), where a Gauss–Newton step carries the
# angles the markers barely fix (a foot on its markers' plane, a wrist) far past their joint limits, and
# the limits' residuals, with no Jacobian row inside the range, are what the step's model cannot see:
# pig_walk's runs began with 4-5 such rejected steps each, from 1e-4 up to 0.1.  Frame-wise inverse
# kinematics (calibrate.solve.ik; pose_only) starts at LAMBDA_START_POSES.
LAMBDA_START = 0.1
LAMBDA_START_POSES = 1e-4
# The geodesic acceleration is kept while its bend pays: a bent step lowering the cost by at least BEND_GAIN
# times what the plain step does (a bent step costs about a third more), judged on BEND_TRIALS steps running.
BEND_GAIN = 1.25
BEND_TRIALS = 2


def minimise(steps: StepProblem, x: Any, options: SolverOptions, max_iterations: int | None = None,
             progress: Callable[[int, float, float], None] | None = None,
             summary: SolverSummary | None = None, lam0: float = LAMBDA_START_POSES) -> tuple[Any, SolverSummary]:
    """Levenberg–Marquardt from `x`: Marquardt-scaled damping λ following Nielsen's update on the
    gain ratio, and the termination tests of the module docstring (tolerances and iteration limit:
    `options`; `max_iterations` overrides its limit; every step, accepted or not, counts).
    `progress(iteration, cost, lam)` after each accepted step; `lam0` the first step's damping."""
    loop = iterate(steps, x, options, max_iterations, progress, summary, lam0)
    while True:
        try:
            next(loop)
        except StopIteration as done:
            return done.value


class _DenseFit:
    """min |r(x)|² over a vector x as a StepProblem, for the small fits of model import (a hinge over a
    coordinate's range): the Jacobian by forward differences (steps of √eps · max(1, |x_k|), as scipy's
    '2-point'), the step from the damped normal equations."""

    def __init__(self, fun: Callable[[np.ndarray], np.ndarray]):
        self.fun = fun
        self.last: tuple[np.ndarray, np.ndarray] | None = None  # (x, r) at the last point costed
        self.A = self.g = np.zeros(0)

    def _residuals(self, x: np.ndarray) -> np.ndarray:
        if self.last is not None and self.last[0] is x:
            return self.last[1]
        return np.asarray(self.fun(x), dtype=float).ravel()

    def linearize(self, x: np.ndarray, lam: float = 0.0) -> float:
        r = self._residuals(x)
        h = FD_STEP * np.maximum(1.0, np.abs(x)) * np.where(x >= 0, 1.0, -1.0)
        J = np.empty((r.size, x.size))
        for k in range(x.size):
            xk = x.copy()
            xk[k] += h[k]
            J[:, k] = (np.asarray(self.fun(xk), dtype=float).ravel() - r) / (xk[k] - x[k])
        self.A, self.g = J.T @ J, J.T @ r
        return float(r @ r)

    def gradient_max(self) -> float:
        return 2.0 * float(np.abs(self.g).max(initial=0.0))

    def step(self, x: np.ndarray, lam: float) -> tuple[np.ndarray, float, float] | None:
        d = self.A.diagonal()
        damped = self.A + np.diag(lam * marquardt_diagonal(d, float(self.A.max(initial=0.0))))
        try:
            dx = -np.linalg.solve(damped, self.g)
        except np.linalg.LinAlgError:
            return None
        predicted = -(2.0 * float(self.g @ dx) + float(dx @ self.A @ dx))
        return x + dx, predicted, float(np.sqrt(dx @ dx))

    def cost(self, x: np.ndarray) -> float:
        r = np.asarray(self.fun(x), dtype=float).ravel()
        self.last = (x, r)
        return float(r @ r)

    def norm(self, x: np.ndarray) -> float:
        return float(np.sqrt(x @ x))


FD_STEP = float(np.sqrt(np.finfo(float).eps))  # _DenseFit's forward-difference step, relative to max(1, |x_k|)
_TINY = 1e-300  # a test that is off (SolverOptions wants a positive tolerance)


def fit_least_squares(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray, ftol: float, xtol: float,
                      max_iterations: int = 400) -> tuple[np.ndarray, SolverSummary]:
    """x minimising |fun(x)|² from x0 by Levenberg–Marquardt (minimise) with a forward-difference Jacobian,
    until a step lowers the cost by less than the fraction `ftol` or is shorter than xtol · (|x| + xtol): the
    small dense fits of an OpenSim model's import, without scipy's least_squares (whose import cost every
    command on an .osim model a quarter of a second)."""
    options = SolverOptions(max_iterations=max_iterations, ftol=ftol, atol=_TINY, xtol=xtol, gtol=_TINY,
                            geodesic=False)
    return minimise(_DenseFit(fun), np.asarray(x0, dtype=float), options)


def iterate(steps: StepProblem, x: Any, options: SolverOptions, max_iterations: int | None = None,
            progress: Callable[[int, float, float], None] | None = None,
            summary: SolverSummary | None = None, lam0: float = LAMBDA_START_POSES):
    """minimise one iteration at a time: a generator that yields the current point after each step
    (accepted or not) and returns (point, summary) when a termination test is met; a caller may stop
    pulling and the run simply ends there (choose_start races candidate starts this way)."""
    max_it = max_iterations or options.max_iterations
    summary = SolverSummary() if summary is None else summary
    lam, nu = lam0, 2.0
    cost = steps.linearize(x, lam)
    summary.initial_cost = cost
    summary.cost_history.append(cost)
    termination, converged = "", False
    while True:
        if summary.iterations:
            yield x
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
            steps.linearize(x, lam)
        else:
            lam, nu = max(lam * nu, LAMBDA_REJECTED), nu * 2
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


# A step that carries joint angles across their limits is solved again with those limits in its model
# (Problem.limit_crossings; only those frames factored again), this many times at most: without them such a
# step was judged on limit residuals its model never saw, and 28 of pig_walk's 30 rejected steps were; with
# them, 3 (docs/benchmarks.md); two rounds left 4, at more factorisations.
LIMIT_ROUNDS = 1


class _HeldLimits:
    """Joint-limit rows taken into one step's Gauss–Newton model: each (frame, DoF) adds its weight w² to
    A_f's diagonal and w·r to g_f, in place in the linearization, whose entries are put back as they were
    by release().  `offset`: the added rows' ½Σr² at the current point, where the limit costs nothing, so
    the model's decrease less it is the decrease of the cost the step is judged on."""

    def __init__(self, lin: Linearization, frame: FrameLayout):
        self.lin, self.frame = lin, frame
        self.rows: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.done: set[tuple[int, int]] = set()
        self.offset = 0.0

    def take(self, f: np.ndarray, d: np.ndarray, w: np.ndarray, r: np.ndarray) -> bool:
        """Add the limits (frames f, DoFs d, weights w, residuals r) not taken yet; whether any was."""
        new = np.array([(int(a), int(b)) not in self.done for a, b in zip(f, d, strict=True)], dtype=bool)
        if not new.any():
            return False
        f, d, w, r = f[new], d[new], w[new], r[new]
        self.done.update(zip(f.tolist(), d.tolist(), strict=True))
        c = self.frame.angle(d)
        lin = self.lin
        self.rows.append((f, c, lin.A[f, c, c].copy(), lin.gz[f, c].copy()))
        lin.A[f, c, c] += w * w
        lin.gz[f, c] += w * r
        self.offset += 0.5 * float(r @ r)
        return True

    def release(self) -> None:
        for f, c, a, g in reversed(self.rows):
            self.lin.A[f, c, c] = a
            self.lin.gz[f, c] = g
        self.rows.clear()


class _BlockArrow:
    """The calibration problem as a StepProblem: steps from the Schur complement on p (factor_step),
    with geodesic acceleration when the loss is plain least squares; the frame blocks held chunk by
    chunk within the memory budget (calibrate.solve.chunks); stage times go to `summary`."""

    def __init__(self, problem: Problem, options: SolverOptions, pose_only: bool, summary: SolverSummary):
        self.problem, self.pose_only, self.summary = problem, pose_only, summary
        self.budget = problem.settings.memory_mb * 1e6
        # Buffers shared by every step, and by later runs on this problem (first touches of the large
        # per-step arrays, in page faults, cost as much as a step of a short run).
        self.work = problem.buffers()
        self.chunk_work: list[dict] = []  # buffers of each chunk kept in memory (long trials)
        self.scratch: dict = {}  # buffers of the chunks formed again in each pass
        # Geodesic acceleration needs the residuals' second derivative, which a robust loss's changing
        # weights would blur: plain least squares only.
        self.accelerate = options.geodesic and problem.loss == "linear"
        self.unpaid = 0  # steps running whose bend did not pay (_bent_or_not)
        self.costs: dict[int, tuple[State, float]] = {}  # the cost of the point the last step chose
        self.blocks: FrameBlocks | None = None
        self.here: tuple | None = None
        self.N: GaugeBasis | None = None

    def linearize(self, state: State, lam: float) -> float:
        problem = self.problem
        self.lam_at = lam  # Run.advance linearizes a suspended run again at the same point and damping
        t0 = time.perf_counter()
        self.blocks = FrameBlocks(problem, state, not self.pose_only, self.budget, previous=self.blocks,
                                  eliminate_at=lam, work=(self.chunk_work, self.scratch))
        self.here = problem.residual_parts(state) if self.accelerate else None
        self.summary.linearize_seconds += time.perf_counter() - t0
        self.N = None if self.pose_only else null_space(problem.gauge_constraints(state.p), problem.n_free)
        return self.blocks.cost

    def release(self) -> None:
        """Every frame block and scratch array let go (a paused run; the next linearize forms them again)."""
        self.blocks = self.here = None
        self.chunk_work.clear()
        self.scratch.clear()
        self.work.clear()

    def gradient_max(self) -> float:
        return self.blocks.gradient_max()

    def step(self, state: State, lam: float) -> tuple[State, float, float] | None:
        # A step far too long (a scale's exp overflowing, a position divided by a scale gone to zero) gives
        # a non-finite point, which the loop rejects: no floating-point warnings for it.
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            return self._step(state, lam)

    def _step(self, state: State, lam: float) -> tuple[State, float, float] | None:
        blocks, summary = self.blocks, self.summary
        Dz = marquardt_diagonal(blocks.diagonal, float(blocks.diagonal.max(initial=0.0)))
        t0 = time.perf_counter()
        if not blocks.whole:  # a long trial: its blocks chunk by chunk (calibrate.solve.chunks)
            out = chunked_step(self.problem, blocks, state, lam, Dz, self.N, self.accelerate, self.here,
                               self.scratch, self.chunk_work)
            summary.linear_solver_seconds += time.perf_counter() - t0
            if out is None:
                return None
            dz, dp, predicted, bend = out
        else:
            lin = blocks.linearization
            held = _HeldLimits(lin, self.problem.layout.frame)
            try:
                fac = factor_step(lin, lam, Dz, self.pose_only, self.N, self.work)
                for rounds in range(LIMIT_ROUNDS + 1):
                    if fac is None:
                        summary.linear_solver_seconds += time.perf_counter() - t0
                        return None
                    dz, dp = fac.solve(lin.gz, lin.gp, fac.el.yz)
                    crossed = self.problem.limit_crossings(state.Z, dz) if rounds < LIMIT_ROUNDS else None
                    if crossed is None or not held.take(*crossed):
                        break
                    # Only the frames whose limits were taken in are factored again (Schur's share swapped).
                    el = fac.el
                    ok = refactor_frames(lin, lam * Dz, el, held.rows[-1][0], self.work)
                    fac = _factor_schur(lin, el, lam, self.pose_only, self.N) if ok else None
                summary.linear_solver_seconds += time.perf_counter() - t0
                predicted = model_decrease(lin, dz, dp) - held.offset
                bend = None
                if self.accelerate:
                    t0 = time.perf_counter()
                    bend = _accelerate(self.problem, state, lin, fac, dz, dp, self.here)
                    summary.evaluate_seconds += time.perf_counter() - t0
            finally:
                held.release()
        trial = retract(self.problem, state, dz, dp)
        self.costs = {}
        if bend is not None:
            trial, dz, dp = self._bent_or_not(state, trial, dz, dp, bend)
        step_norm = float(np.sqrt(np.sum(dz**2) + np.sum(dp**2)))
        return trial, predicted, step_norm

    def _bent_or_not(self, state: State, plain: State, dz: np.ndarray, dp: np.ndarray,
                     bend: tuple[np.ndarray, np.ndarray]) -> tuple[State, np.ndarray, np.ndarray]:
        """The step bent by the geodesic acceleration or the plain step, whichever reaches the lower cost
        (both are evaluated; the chosen point's cost is kept for the loop's test).  Where the bend does not
        lower the cost by BEND_GAIN times the plain step's decrease in BEND_TRIALS steps running, the
        acceleration is dropped for the rest of the run: on gait's valleys it bends the steps no better than
        plain Gauss–Newton and costs a third more per step (docs/benchmarks.md)."""
        bz, bp = bend
        bent = retract(self.problem, state, dz + bz, dp + bp)
        c0 = self.blocks.cost
        c_plain, c_bent = (c if np.isfinite(c) else np.inf for c in (self.cost(plain), self.cost(bent)))
        if c_bent < c0 and (c_plain >= c0 or c0 - c_bent >= BEND_GAIN * (c0 - c_plain)):
            self.unpaid = 0
        elif c_plain < c0:  # both rejected tells nothing
            self.unpaid += 1
            if self.unpaid >= BEND_TRIALS:
                self.accelerate = False
                self.summary.bend_dropped = self.summary.iterations
        if c_bent < c_plain:
            self.costs[id(bent)] = (bent, c_bent)
            self.summary.bent += 1
            return bent, dz + bz, dp + bp
        self.costs[id(plain)] = (plain, c_plain)
        return plain, dz, dp

    def cost(self, state: State) -> float:
        kept = self.costs.get(id(state))
        if kept is not None and kept[0] is state:
            return kept[1]
        t0 = time.perf_counter()
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            c = self.problem.cost(state)
        self.summary.evaluate_seconds += time.perf_counter() - t0
        return c

    def norm(self, state: State) -> float:
        with np.errstate(over="ignore"):  # a trial step gone far astray (rejected by its cost): inf, quietly
            return float(np.sqrt(np.sum(state.Z**2) + np.sum(state.p**2)))


def levenberg_marquardt(problem: Problem, state: State, options: SolverOptions | None = None, *,
                        pose_only: bool = False, max_iterations: int | None = None,
                        progress: Callable[[int, float, float], None] | None = None) -> tuple[State, SolverSummary]:
    """Minimise the problem's cost from `state` (tolerances, iteration limit and geodesic acceleration:
    `options`, default SolverOptions(); `max_iterations` overrides its limit; the memory budget of the
    frames' blocks: the problem's, ProblemOptions.memory_mb).
    `pose_only` keeps p fixed (frame-wise inverse kinematics of all frames at once).
    `progress(iteration, cost, lam)` after each step."""
    return Run(problem, state, options, pose_only=pose_only, max_iterations=max_iterations,
               progress=progress).finish()


class Run:
    """A levenberg_marquardt run (same arguments) taken a few iterations at a time: `advance(n)` runs
    it until n steps are done, a condition holds or it ends; `cost` is its cost so far; `finish()` runs
    it to the end and returns (state, summary) as levenberg_marquardt does.  Advanced in parts, a run
    takes exactly the steps it takes in one go.  `suspend()` lets its frame blocks go while it waits (the
    memory budget's worth of them on a long trial); the next `advance` forms them again at the same point
    and damping, so that the steps stay the same."""

    def __init__(self, problem: Problem, state: State, options: SolverOptions | None = None, *,
                 pose_only: bool = False, max_iterations: int | None = None,
                 progress: Callable[[int, float, float], None] | None = None):
        t0 = time.perf_counter()
        options = SolverOptions() if options is None else options
        self.summary = SolverSummary()
        self.state, self.done, self._suspended = state, False, False
        self._steps = _BlockArrow(problem, options, pose_only, self.summary)
        self._loop = iterate(self._steps, state, options, max_iterations, progress, self.summary,
                             LAMBDA_START_POSES if pose_only else LAMBDA_START)
        self._t = time.perf_counter() - t0

    @property
    def cost(self) -> float:
        """The cost at the run's point (its last accepted step's)."""
        return self.summary.cost_history[-1] if self.summary.cost_history else float("nan")

    def advance(self, iterations: int | None = None, until: Callable[[SolverSummary], bool] | None = None) -> Run:
        """Run on until `iterations` steps in all are done (None: no limit but the run's own), `until(summary)`
        holds after a step, or a termination test is met."""
        t0 = time.perf_counter()
        if self._suspended and not self.done:
            self._steps.linearize(self.state, self._steps.lam_at)
            self._suspended = False
        while not self.done and (iterations is None or self.summary.iterations < iterations):
            try:
                self.state = next(self._loop)
            except StopIteration as end:
                self.state, _ = end.value
                self.done = True
                self._steps.blocks.recycle()  # the whole trial's arrays are the next run's buffers
                break
            if until is not None and until(self.summary):
                break
        self._t += time.perf_counter() - t0
        self.summary.seconds = self._t
        return self

    def suspend(self) -> None:
        """Let the frame blocks and every scratch array go until the next `advance` (which forms them again):
        the elimination's buffers and the problem's (Problem.buffers) too, which a long trial's pass in the
        meantime would otherwise hold twice (30 000 squat frames: 842 against 743 MB at the peak)."""
        if not self.done and not self._suspended:
            self._steps.release()
            self._suspended = True

    def finish(self) -> tuple[State, SolverSummary]:
        self.advance()
        return self.state, self.summary


def covariance(problem: Problem, state: State, lin: Linearization | None = None,
               progress: Callable[[float], None] | None = None) -> Covariance:
    """Posterior covariance of the free parameters: the inverse of the Schur complement
    S = C − Σ B_f' A_f⁻¹ B_f at the solution (λ = 0), with each segment frame's orientation
    held (the gauge; otherwise every offset in a segment would share its frame's uncertain
    turn).  A hinge centre's slide along its axis is *not* held here, so its prior-only
    uncertainty shows.  Singular directions get a pseudo-inverse.  The frames' blocks are formed
    chunk by chunk within the problem's memory budget (or taken from `lin`, the whole trial's);
    `progress(share of the frames done)` after each chunk."""
    if lin is not None:
        S, n = lin.C.copy(), lin.C.shape[0]
        chunks: Iterable[tuple[slice, Linearization]] = [(slice(0, lin.A.shape[0]), lin)]
    else:
        _, S, gp = problem.prior_normal(state.p, True)
        n = gp.size
        chunks = each_chunk(problem, state, True, problem.settings.memory_mb * 1e6)
    for sl, part in chunks:
        if lin is None:
            S = S + part.C
        eps = 1e-12 * max(1.0, float(np.diagonal(part.A, axis1=1, axis2=2).max(initial=0.0)))
        el = eliminate(part, np.full((sl.stop - sl.start, part.A.shape[1]), eps))
        if el is None:
            raise np.linalg.LinAlgError("covariance: a frame's normal matrix is not positive definite")
        S = S - el.S if n else S
        if progress is not None:
            progress(sl.stop / problem.F)
    S = 0.5 * (S + S.T)
    _, Jr = problem.prior(state.p)
    P = Jr.T @ Jr
    N = null_space(problem.gauge_constraints(state.p, slides=False), problem.n_free)
    if N is None:
        return Covariance(np.linalg.pinv(S, hermitian=True), np.linalg.pinv(P, hermitian=True))
    D = N.dense()
    return Covariance(D @ np.linalg.pinv(N.project(S), hermitian=True) @ D.T,
                      D @ np.linalg.pinv(N.project(P), hermitian=True) @ D.T)
