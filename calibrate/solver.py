"""Levenberg–Marquardt for the block-arrow calibration problem (seed 003).

Frames are coupled only through the parameters p, so the damped normal equations

    [ A_1 + λD_1                B_1 ] [dz_1]     [g_1]
    [            ...            ... ] [ ...]  = −[...]
    [ B_1'  ...        C + λD_p     ] [ dp ]     [g_p]

are solved by eliminating every frame block (a batched Cholesky of the small A_f):
S = C + λD_p − Σ_f B_f' (A_f + λD_f)⁻¹ B_f is only n_free × n_free, then each dz_f is
back-substituted.  Time and memory grow linearly with the number of frames; the full
(nz·F + n)² matrix is never formed.  D is Marquardt's diagonal scaling (diag of the
normal matrix, floored), λ follows Nielsen's update on the gain ratio.  The root rotation
and the hinge axes are updated on their manifolds (see Problem.retract_parameters and
kinematics.retract_root).

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

import numpy as np

from .kinematics import retract_root
from .problem import Linearization, Problem, State

DIAG_FLOOR = 1e-9  # relative floor of Marquardt's scaling diagonal


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


@dataclass
class Covariance:
    """Posterior covariance of the free parameters (Gauss–Newton, at the solution), and the
    covariance the priors alone would give (to tell what the trial identified)."""

    matrix: np.ndarray  # (n_free, n_free), in the units of the free parameters
    prior_only: np.ndarray  # (n_free, n_free): the same with no marker data


def _cholesky_batch(H: np.ndarray) -> np.ndarray | None:
    try:
        return np.linalg.cholesky(H)
    except np.linalg.LinAlgError:
        return None


def _solve_lower(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched L⁻¹ b via the inverse of L (small blocks; numpy has no batched triangular solve)."""
    return np.matmul(np.linalg.inv(L), b)


def solve_step(lin: Linearization, lam: float, Dz: np.ndarray,
               pose_only: bool = False, N: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """The LM step (dz (F, nz), dp (n,)) for damping `lam`, with dp restricted to the columns of
    `N` (gauge constraints) if given; None if a block is not positive definite."""
    Hz = lin.A + lam * Dz[:, :, None] * np.eye(Dz.shape[1])[None]
    L = _cholesky_batch(Hz)
    if L is None:
        return None
    Linv = np.linalg.inv(L)
    yz = np.matmul(Linv, lin.gz[:, :, None])[:, :, 0]  # L⁻¹ g_z
    if pose_only or lin.C.size == 0:
        dz = -np.matmul(np.swapaxes(Linv, 1, 2), yz[:, :, None])[:, :, 0]
        return dz, np.zeros(0)
    Y = np.matmul(Linv, lin.B)  # (F, nz, n)
    F, nz, n = Y.shape
    Yf = Y.reshape(F * nz, n)
    S = lin.C - Yf.T @ Yf
    # Marquardt scaling on the reduced system: damp each parameter by its own curvature once the
    # frames are eliminated (diag S), not by diag C, which counts curvature the poses explain away.
    dS = np.diag(S)
    S = S + np.diag(lam * np.maximum(dS, DIAG_FLOOR * max(1.0, float(dS.max(initial=0.0)))))
    rhs = -lin.gp + Yf.T @ yz.reshape(-1)
    if N is not None:
        S, rhs = N.T @ S @ N, N.T @ rhs
    try:
        Ls = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return None
    dp = np.linalg.solve(Ls.T, np.linalg.solve(Ls, rhs))
    if N is not None:
        dp = N @ dp
    t = yz + np.matmul(Y, dp)  # L⁻¹ (g_z + B dp)
    dz = -np.matmul(np.swapaxes(Linv, 1, 2), t[:, :, None])[:, :, 0]
    return dz, dp


def retract(problem: Problem, state: State, dz: np.ndarray, dp: np.ndarray) -> State:
    """`state` moved by (dz, dp): root rotation folded into q_ref, axes kept unit."""
    Z = state.Z + dz
    Q = retract_root(state.Q, Z[:, 3:6])
    Z[:, 3:6] = 0.0
    p = problem.retract_parameters(state.p, dp) if dp.size else state.p.copy()
    return State(Z, Q, p)


def null_space(K: np.ndarray, n: int) -> np.ndarray | None:
    """Orthonormal basis (n, n − rank K) of the steps that satisfy K dp = 0; None without constraints."""
    if K.shape[0] == 0:
        return None
    Qm, R = np.linalg.qr(K.T, mode="complete")
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > 1e-10 * max(1e-300, d.max(initial=0.0))))
    return Qm[:, rank:]


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


def levenberg_marquardt(problem: Problem, state: State, *, pose_only: bool = False,
                        max_iterations: int | None = None,
                        progress: Callable[[int, float, float], None] | None = None) -> tuple[State, SolverSummary]:
    """Minimise the problem's cost from `state`.  `pose_only` keeps p fixed (frame-wise inverse
    kinematics of all frames at once).  `progress(iteration, cost, lam)` after each step."""
    st = problem.settings
    max_it = max_iterations or st.max_iterations
    summary = SolverSummary()
    t_start = time.perf_counter()
    t0 = time.perf_counter()
    lin = problem.linearize(state, with_parameters=not pose_only)
    summary.linearize_seconds += time.perf_counter() - t0
    cost = lin.cost
    summary.initial_cost = cost
    summary.cost_history.append(cost)
    lam, nu = 1e-4, 2.0
    N = None if pose_only else null_space(problem.gauge_constraints(state.p), problem.n_free)
    x_norm = lambda s: float(np.sqrt(np.sum(s.Z**2) + np.sum(s.p**2)))  # noqa: E731
    termination, converged = "", False
    while True:
        g_max = max(float(np.abs(lin.gz).max(initial=0.0)), float(np.abs(lin.gp).max(initial=0.0)))
        if g_max < st.gtol:
            termination, converged = f"gradient {g_max:.2e} below gtol {st.gtol:.0e}", True
            break
        if summary.iterations >= max_it:
            termination = f"reached max_iterations ({max_it}) before converging"
            break
        summary.iterations += 1
        Dz = np.maximum(np.diagonal(lin.A, axis1=1, axis2=2), DIAG_FLOOR * max(1.0, float(lin.A.max(initial=0.0))))
        t0 = time.perf_counter()
        step = solve_step(lin, lam, Dz, pose_only, N)
        summary.linear_solver_seconds += time.perf_counter() - t0
        if step is None:
            lam, nu = lam * nu, nu * 2
            if lam > 1e16:
                termination, converged = "normal equations not positive definite at any damping", False
                break
            continue
        dz, dp = step
        step_norm = float(np.sqrt(np.sum(dz**2) + np.sum(dp**2)))
        predicted = _model_decrease(lin, dz, dp)
        trial = retract(problem, state, dz, dp)
        t0 = time.perf_counter()
        new_cost = problem.cost(trial)
        summary.evaluate_seconds += time.perf_counter() - t0
        rho = (cost - new_cost) / predicted if predicted > 0 else -1.0
        if np.isfinite(new_cost) and rho > 1e-4 and new_cost < cost:
            rel = (cost - new_cost) / max(cost, 1e-300)
            state, cost = trial, new_cost
            summary.accepted += 1
            summary.cost_history.append(cost)
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if progress is not None:
                progress(summary.iterations, cost, lam)
            if rel < st.ftol:
                termination, converged = f"relative cost decrease {rel:.2e} below ftol {st.ftol:.0e}", True
                break
            if summary.accepted > 1 and (summary.cost_history[-2] - cost) < st.atol:
                termination = f"cost decrease {summary.cost_history[-2] - cost:.2e} below atol {st.atol:g}"
                converged = True
                break
            if step_norm < st.xtol * (x_norm(state) + st.xtol):
                termination, converged = f"step {step_norm:.2e} below xtol {st.xtol:.0e}", True
                break
            t0 = time.perf_counter()
            lin = problem.linearize(state, with_parameters=not pose_only)
            summary.linearize_seconds += time.perf_counter() - t0
            N = None if pose_only else null_space(problem.gauge_constraints(state.p), problem.n_free)
        else:
            lam, nu = lam * nu, nu * 2
            if step_norm < st.xtol * (x_norm(state) + st.xtol):
                termination, converged = f"step {step_norm:.2e} below xtol {st.xtol:.0e}", True
                break
            if lam > 1e16:
                termination = "no step lowers the cost (damping exhausted): converged to the available precision"
                converged = True
                break
    summary.final_cost = cost
    summary.termination = termination
    summary.converged = converged
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
    Hz = lin.A + eps * np.eye(lin.A.shape[1])[None]
    Linv = np.linalg.inv(np.linalg.cholesky(Hz))
    Y = np.matmul(Linv, lin.B)
    Yf = Y.reshape(-1, Y.shape[2])
    S = lin.C - Yf.T @ Yf
    S = 0.5 * (S + S.T)
    _, Jr = problem.prior(state.p)
    P = Jr.T @ Jr
    N = null_space(problem.gauge_constraints(state.p, slides=False), problem.n_free)
    if N is None:
        return Covariance(np.linalg.pinv(S, hermitian=True), np.linalg.pinv(P, hermitian=True))
    return Covariance(N @ np.linalg.pinv(N.T @ S @ N, hermitian=True) @ N.T,
                      N @ np.linalg.pinv(N.T @ P @ N, hermitian=True) @ N.T)
