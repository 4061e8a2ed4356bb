"""The closed forms of the MTB framework (seed 000) and seed 002: a segment's basis from three or more
of its points (affine or rigid), a joint as a fixed point of that basis refined on the joint-marker
variance (mtb_refine), the per-frame JMV optimisation and its multistart."""

from __future__ import annotations

import itertools
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .geometry import MIN_SPREAD, RigidFrames, spread

MIN_FRAMES = 10  # fewer usable frames than this: no estimate


# --------------------------------------------------------------------------- bases
@dataclass(frozen=True)
class Basis:
    """A segment's marker-trajectory basis: a point fixed on the segment is o[f] + B[f] @ λ."""

    o: np.ndarray  # (F, 3)
    B: np.ndarray  # (F, 3, 3); NaN in frames where a basis point is missing
    kind: str  # 'affine' (seed 000 Eq. 1-6, four points or three plus Eq. 9's auxiliary) or 'rigid'

    def point(self, lam: np.ndarray) -> np.ndarray:
        return self.o + self.B @ lam


def auxiliary_point(r1: np.ndarray, r2: np.ndarray, r3: np.ndarray) -> np.ndarray:
    """Seed 000 Eq. 9: r3 + (r1 − r3) × (r2 − r3), a virtual fourth point rigid with three others."""
    return r3 + cross3(r1 - r3, r2 - r3)


def affine_basis(points: np.ndarray, names: Sequence[str] | None = None) -> Basis:
    """The MTB basis of seed 000 from 3 non-collinear or 4 non-coplanar trajectories (F, P, 3).

    With four non-coplanar points the basis vectors are a_i = r_i − r_4; with three (or
    four nearly coplanar ones) the auxiliary point of Eq. 9 replaces the fourth.
    """
    P = points.shape[1]
    ref = reference_shape(points)
    if P == 4 and spread(ref)[1] > MIN_SPREAD:
        r1, r2, r3, r4 = (points[:, i] for i in range(4))
    else:
        idx = best_triangle(ref) if P > 3 else (0, 1, 2)
        r1, r2, r3 = (points[:, i] for i in idx)
        r4 = auxiliary_point(r1, r2, r3)
    B = np.stack([r1 - r4, r2 - r4, r3 - r4], axis=2)
    return Basis(r4, B, "affine")


def affine_triangle(points: np.ndarray) -> tuple[int, int, int]:
    """The three points the closed forms use when the MTB basis is affine: the largest triangle."""
    return best_triangle(reference_shape(points)) if points.shape[1] > 3 else (0, 1, 2)


def rigid_basis(frames: RigidFrames) -> Basis:
    """A basis from a least-squares rigid frame (used for segments with more than four points)."""
    return Basis(frames.t, frames.R, "rigid")


def reference_shape(points: np.ndarray) -> np.ndarray:
    """Positions (P, 3) in the frame that sees most of the points (gaps 0-filled)."""
    seen = np.all(np.isfinite(points), axis=2)
    f = int(np.argmax(seen.sum(1)))
    return np.where(seen[f][:, None], points[f], np.nan)


def best_triangle(ref: np.ndarray) -> tuple[int, int, int]:
    """The three points spanning the largest triangle."""
    combos = np.array(list(itertools.combinations(range(len(ref)), 3)))
    a, b, c = ref[combos[:, 0]], ref[combos[:, 1]], ref[combos[:, 2]]
    area = np.linalg.norm(cross3(b - a, c - a), axis=1)
    area = np.where(np.isfinite(area), area, -1.0)
    return tuple(int(i) for i in combos[int(np.argmax(area))])  # type: ignore[return-value]


def cross3(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cross product along the last axis (np.cross without its per-call overhead)."""
    return np.stack([u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1], u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
                     u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]], axis=-1)


# --------------------------------------------------------------------------- costs
def jmv_cost(centre: np.ndarray, points: np.ndarray, alpha: float = 0.0) -> float:
    """Seed 000 Eq. 8: mean over points of [variance over frames of |c − r| + α · mean |c − r|].

    centre (F, 3), points (F, P, 3); frames where either is NaN are left out per point.
    """
    d = np.linalg.norm(points - centre[:, None, :], axis=2)
    seen = np.isfinite(d)
    n = seen.sum(0)
    use = n > 1
    d0 = np.where(seen, d, 0.0)
    mean = d0.sum(0) / np.maximum(n, 1)
    var = np.where(seen, (d - mean) ** 2, 0.0).sum(0) / np.maximum(n, 1)
    return float(np.mean((var + alpha * mean)[use])) if np.any(use) else math.nan


def jmv_rms(centre: np.ndarray, points: np.ndarray) -> float:
    d = np.linalg.norm(points - centre[:, None, :], axis=2)
    seen = np.isfinite(d)
    n = seen.sum(0)
    mean = np.where(seen, d, 0.0).sum(0) / np.maximum(n, 1)
    dev = np.where(seen, d - mean, 0.0)
    return float(np.sqrt(np.sum(dev**2) / max(int(seen.sum()), 1)))


def mtb_refine(basis: Basis, points: np.ndarray, lam0: np.ndarray, alpha: float = 0.0,
               fixed: np.ndarray | None = None, iterations: int = 30) -> tuple[np.ndarray, float, int]:
    """Minimise Eq. 8 over λ by damped Newton with the exact gradient and Hessian.

    points (F, P, 3) are the markers (and solved joints) of both segments.  `fixed` is a
    direction in λ-space that is not changed (a hinge's axis).  Returns λ, cost, iterations.
    """
    ok = np.all(np.isfinite(basis.B.reshape(len(basis.B), -1)), axis=1) & np.isfinite(basis.o[:, 0])
    o, B, r = basis.o[ok], basis.B[ok], points[ok]
    seen = np.all(np.isfinite(r), axis=2)  # (F, P)
    r = np.where(seen[..., None], r, 0.0)
    w = seen.astype(float)
    n = np.maximum(w.sum(0), 1.0)  # (P,)
    use = w.sum(0) > 1
    w[:, ~use] = 0.0
    P_used = max(int(use.sum()), 1)
    if fixed is not None:
        f = fixed / np.linalg.norm(fixed)
        N = np.linalg.svd(np.eye(3) - np.outer(f, f))[0][:, :2]
    else:
        N = np.eye(3)

    def evaluate(lam: np.ndarray, hessian: bool):
        c = o + B @ lam
        diff = c[:, None, :] - r  # (F, P, 3)
        d = np.sqrt(np.sum(diff**2, axis=2))
        d = np.where(w > 0, np.maximum(d, 1e-12), 1.0)
        mean = (w * d).sum(0) / n
        dev = w * (d - mean)
        cost = float(np.sum(((dev**2).sum(0) / n + alpha * mean)[use]) / P_used)
        if not hessian:
            return cost, None, None
        u = diff / d[..., None]
        g = np.matmul(u, B)  # ∂d/∂λ = Bᵀ u   (F, P, 3)
        gw = w[..., None] * g
        gbar = gw.sum(0) / n[:, None]  # (P, 3)
        grad = 2 * (dev[..., None] * g).sum(0) / n[:, None] + alpha * gbar
        grad = grad[use].sum(0) / P_used
        gc = w[..., None] * (g - gbar[None])
        H = 2 * np.matmul(gc.transpose(1, 2, 0), g.transpose(1, 0, 2)) / n[:, None, None]
        # second-order term: Σ (2 (d − d̄) + α) ∂²d / n, with ∂²d = Bᵀ (I − u uᵀ) B / d
        coef = (2 * dev + alpha * w) / d / n[None, :]
        coef[:, ~use] = 0.0
        BtB = np.matmul(np.swapaxes(B, 1, 2), B)
        Bu = g  # Bᵀu
        H2 = np.tensordot(coef.sum(1), BtB, 1) - (coef[..., None] * Bu).reshape(-1, 3).T @ Bu.reshape(-1, 3)
        H = H[use].sum(0) / P_used + H2 / P_used
        return cost, grad, H

    lam = np.array(lam0, dtype=float)
    cost, grad, H = evaluate(lam, True)
    mu = 0.0
    it = 0
    for it in range(1, iterations + 1):  # noqa: B007
        gN, HN = N.T @ grad, N.T @ H @ N
        scale = np.maximum(np.abs(np.diag(HN)), 1e-30)
        if cost <= 1e-28 * (1.0 + float(np.mean(np.sum(r**2, axis=2)))):
            break  # exact fit (noise-free data): nothing left to gain
        accepted = False
        for _ in range(20):
            try:
                step = -np.linalg.solve(HN + mu * np.diag(scale), gN)
            except np.linalg.LinAlgError:
                mu = max(mu * 10, 1e-6)
                continue
            if np.linalg.norm(step) <= 1e-13 * (1 + np.linalg.norm(lam)):
                break  # converged to rounding
            trial = lam + N @ step
            new = evaluate(trial, False)[0]
            if new <= cost:
                accepted = True
                break
            mu = max(mu * 10, 1e-6)
        if not accepted:
            break
        small = np.linalg.norm(step) <= 1e-12 * (1 + np.linalg.norm(lam))
        flat = cost - new <= 1e-15 * max(cost, 1e-300)
        lam, cost = trial, new
        mu = mu / 10 if mu > 1e-9 else 0.0
        if small or flat:
            break
        cost, grad, H = evaluate(lam, True)
    return lam, cost, it


def inv_sym3(A: np.ndarray) -> np.ndarray:
    """Inverses of symmetric 3x3 matrices (F, 3, 3) by cofactors (vectorised; no per-matrix LAPACK call)."""
    a, b, c = A[:, 0, 0], A[:, 0, 1], A[:, 0, 2]
    d, e, f = A[:, 1, 1], A[:, 1, 2], A[:, 2, 2]
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    inv = np.stack([c00, c01, c02, c01, c11, c12, c02, c12, c22], axis=1).reshape(-1, 3, 3)
    return inv / det[:, None, None]


def jmv_frames(points: np.ndarray, start: np.ndarray, iterations: int = 100) -> tuple[np.ndarray, np.ndarray, float]:
    """Condition-free JMV optimisation: a joint position in every frame (Kirk et al. 2005).

    Minimises Σ_f Σ_p (|c_f − r_fp| − ρ_p)² over the positions c_f (3 per frame) and the
    joint–point distances ρ_p (the variance part of Eq. 8, with α = 0), by
    Levenberg–Marquardt.  The normal equations are block-arrow (frames coupled only through
    ρ) and are solved by a Schur complement on ρ, so the cost is linear in the frames.
    Returns c (F, 3; NaN where fewer than 3 points are seen), ρ (P,), final RMS residual.
    """
    seen = np.all(np.isfinite(points), axis=2)
    ok = seen.sum(1) >= 3
    r = np.where(seen[..., None], points, 0.0)[ok]
    w = seen[ok].astype(float)
    c = np.array(start, dtype=float)[ok]
    c = np.where(np.isfinite(c), c, (w[..., None] * r).sum(1) / np.maximum(w.sum(1), 1)[:, None])

    def dist(c):
        diff = c[:, None, :] - r
        d = np.sqrt(np.sum(diff**2, axis=2))
        return diff, np.maximum(d, 1e-12)

    diff, d = dist(c)
    rho = (w * d).sum(0) / np.maximum(w.sum(0), 1)
    e = w * (d - rho)
    cost = float(np.sum(e**2))
    mu = 1e-3
    for _ in range(iterations):
        u = diff / d[..., None]
        A = np.matmul(np.swapaxes(u * w[..., None], 1, 2), u)
        gc = (e[..., None] * u).sum(1)
        grho = -e.sum(0)
        Dd = w.sum(0)
        accepted = False
        for _ in range(20):
            Ad = A + mu * (np.diagonal(A, axis1=1, axis2=2)[..., None] * np.eye(3) + 1e-12 * np.eye(3))
            Ainv = inv_sym3(Ad)
            C = -(w[..., None] * u)  # (F, P, 3): column p of C_f is C[f, p]
            AiC = np.matmul(C, Ainv)  # Ainv is symmetric
            S = np.diag(Dd * (1 + mu) + 1e-12) - np.tensordot(C, AiC, axes=([0, 2], [0, 2]))
            Aig = np.matmul(Ainv, gc[..., None])[..., 0]
            rhs = -grho + np.tensordot(C, Aig, axes=([0, 2], [0, 1]))
            try:
                drho = np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                mu *= 10
                continue
            dc = -Aig - np.tensordot(AiC, drho, axes=([1], [0]))
            c_new, rho_new = c + dc, rho + drho
            diff_n, d_n = dist(c_new)
            e_n = w * (d_n - rho_new)
            new = float(np.sum(e_n**2))
            if new <= cost:
                accepted = True
                break
            mu *= 10
        if not accepted:
            break
        done = cost - new <= 1e-10 * cost or new < 1e-28
        c, rho, diff, d, e, cost = c_new, rho_new, diff_n, d_n, e_n, new
        mu = max(mu / 10, 1e-12)
        if done:
            break
    out = np.full((len(points), 3), np.nan)
    out[ok] = c
    return out, rho, float(np.sqrt(cost / max(w.sum(), 1)))


def jmv_multistart(X: np.ndarray, ga: list[np.ndarray], gb: list[np.ndarray], F: int,
                    search: bool = True) -> np.ndarray:
    """Per-frame JMV from several starts (the cost has mirror-image and local minima); the lowest
    residual wins.

    Starts: the best few of a grid search over the joint's distances to three of the points
    (trilateration, see trilateration_starts), the midpoint of the two segments' centroids, each
    centroid, and, for a segment with two points p, q, the points beyond either end of pq.
    """
    ca, cb = centroid(ga, F), centroid(gb, F)
    starts = (trilateration_starts(X) if search else []) + [0.5 * (ca + cb), ca, cb]
    for g in (ga, gb):
        if len(g) == 2:
            p, q = g
            starts += [p + 1.5 * (q - p), q + 1.5 * (p - q)]
    best, best_rms = None, math.inf
    for start in starts:  # a few iterations from every start, then the most promising is finished
        if not np.any(np.isfinite(start)):
            continue
        with warnings.catch_warnings():  # a frame with no marker at all has no mean: it stays NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            fill = np.nanmean(X, axis=1)
        centre, _, rms = jmv_frames(X, np.where(np.isfinite(start), start, fill), iterations=8)
        if rms < best_rms:
            best, best_rms = centre, rms
        if best_rms < 1e-12:
            break
    if best is not None and best_rms >= 1e-12:
        best, _, _ = jmv_frames(X, best)
    return best if best is not None else np.full((F, 3), np.nan)


FD_STEP = float(np.finfo(float).eps) ** 0.5  # scipy's relative step for 2-point differences
TRILATERATION_TOLERANCE = 1e-8  # each start's polish stops at this relative change of (ρa, ρb, ρc) or of its cost:
# the starts only begin jmv_frames' iterations, and 1e-15 (to machine precision, 30-70 evaluations) and 1e-8 (16-42)
# gave the same seeds to the last bit on simulated gait and squats and the same calibrations on the real recordings


def trilateration_starts(X: np.ndarray, steps: int = 16, keep: int = 6, max_frames: int = 100) -> list[np.ndarray]:
    """Global starts for per-frame JMV: a joint keeps fixed distances (ρa, ρb, ρc) to three of the points
    around it, so on a grid of those three distances every frame's joint follows by trilateration (two
    mirror solutions; one side is kept for the whole trial).  Each grid point is scored by how much the
    joint's distances to the other points vary; the `keep` best become starts (trajectories (F, 3)).
    The search runs on at most `max_frames` evenly spaced frames; trilateration then fills all frames."""
    from scipy.optimize import least_squares  # here, not at the top: importing scipy costs every command 0.25 s

    F, P, _ = X.shape
    if P < 4:
        return []
    seen = np.all(np.isfinite(X), axis=2)
    full = np.flatnonzero(seen.all(1))
    if len(full) < MIN_FRAMES:
        return []
    # the three points spanning the largest triangle on average, the rest score
    ref = X[full[len(full) // 2]]
    a, b, c = best_triangle(ref)
    rest = [k for k in range(P) if k not in (a, b, c)]
    sub = full[np.linspace(0, len(full) - 1, min(max_frames, len(full))).astype(int)]
    span = np.nanmax(np.linalg.norm(X[sub][:, :, None] - X[sub][:, None, :], axis=3))
    grid = np.linspace(span / steps, span, steps)
    ra, rb, rc = (g.ravel() for g in np.meshgrid(grid, grid, grid, indexing="ij"))
    Xs, Xr = X[sub], X[sub][:, rest]
    spheres = Spheres(Xs[:, a], Xs[:, b], Xs[:, c])

    def candidates(r: np.ndarray, spheres: Spheres, Xrest: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per frame, the trilaterated joint on the side of the plane that fits the other points
        (the joint may cross the plane of the three during the trial): (G, f, 3), distances, misses."""
        up, down, miss = spheres.points(r[0], r[1], r[2])
        d = [np.linalg.norm(cen[:, :, None, :] - Xrest[None], axis=3) for cen in (up, down)]  # (G, f, R)
        med = [np.median(x, axis=1, keepdims=True) for x in d]
        one_side = [np.sum(np.var(x, axis=1), axis=1) for x in d]
        ref = np.where((one_side[0] <= one_side[1])[:, None, None], med[0], med[1])
        pick = np.sum((d[0] - ref) ** 2, axis=2) <= np.sum((d[1] - ref) ** 2, axis=2)  # (G, f)
        return np.where(pick[..., None], up, down), np.where(pick[..., None], d[0], d[1]), miss

    def score(r: np.ndarray) -> np.ndarray:
        _, d, bad = candidates(r, spheres, Xr)
        beyond = np.sum(np.maximum(np.abs(r - 0.5 * span) - 0.5 * span, 0.0) ** 2, axis=0)  # keep 0 < ρ < span
        return d.var(axis=1).sum(1) + bad.mean(1) + beyond

    def residuals_at(r: np.ndarray) -> np.ndarray:
        """The polish's residuals at G sets of distances r (3, G): (G, m)."""
        _, d, bad = candidates(r, spheres, Xr)
        beyond = np.maximum(np.abs(r - 0.5 * span) - 0.5 * span, 0.0)
        return np.concatenate([(d - d.mean(1, keepdims=True)).reshape(r.shape[1], -1) / math.sqrt(len(sub)),
                               np.sqrt(bad / len(sub)), beyond.T], axis=1)

    def residuals(r: np.ndarray) -> np.ndarray:
        return residuals_at(r[:, None])[0]

    def jacobian(r: np.ndarray) -> np.ndarray:
        """Forward differences as scipy's least_squares takes them by default (its steps, to the bit), the three
        steps and r itself in one batched evaluation: half the polish's time."""
        h = FD_STEP * ((r >= 0) * 2.0 - 1.0) * np.maximum(1.0, np.abs(r))
        moved = r[:, None] + np.diag(h)
        f = residuals_at(np.concatenate([r[:, None], moved], axis=1))
        return ((f[1:] - f[0]) / (np.diagonal(moved) - r)[:, None]).T

    sc = score(np.stack([ra, rb, rc]))
    best: list[tuple[float, np.ndarray]] = []
    picked: list[np.ndarray] = []
    for g in np.argsort(sc):  # the best distinct grid points, each polished by least squares in (ρa, ρb, ρc)
        r0 = np.array([ra[g], rb[g], rc[g]])
        if any(np.max(np.abs(r0 - q)) <= 1.5 * span / steps for q in picked):
            continue
        picked.append(r0)
        res = least_squares(residuals, r0, jac=jacobian, method="lm", xtol=TRILATERATION_TOLERANCE,
                            ftol=TRILATERATION_TOLERANCE, gtol=1e-15, max_nfev=200)
        best.append((float(2 * res.cost), res.x))
        if len(picked) == keep or res.cost < 1e-24:
            break
    best.sort(key=lambda item: item[0])
    whole, rest_all = Spheres(X[:, a], X[:, b], X[:, c]), X[:, rest]
    return [candidates(r[:, None], whole, rest_all)[0][0] for _, r in best]


class Spheres:
    """Trilateration's frame for three points p1, p2, p3 (f, 3), computed once: the points at any distances
    (r1, r2, r3) from them then cost a few products (the polish asks for thousands)."""

    def __init__(self, p1: np.ndarray, p2: np.ndarray, p3: np.ndarray):
        ex = p2 - p1
        self.dd = np.linalg.norm(ex, axis=1)
        self.ex = ex / self.dd[:, None]
        v = p3 - p1
        self.i = np.sum(self.ex * v, axis=1)
        ey = v - self.i[:, None] * self.ex
        self.j = np.linalg.norm(ey, axis=1)
        self.ey = ey / self.j[:, None]
        self.ez = cross3(self.ex, self.ey)
        self.p1 = p1

    def points(self, r1: np.ndarray, r2: np.ndarray, r3: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points at distances r1, r2, r3 (G,) from p1, p2, p3 on the + side of their plane and on its − side
        (G, f, 3 each), and how far (m²) the spheres miss each other where they do not meet (0 where they do)."""
        dd, i, j = self.dd, self.i, self.j
        r1, r2, r3 = r1[:, None], r2[:, None], r3[:, None]
        x = (r1**2 - r2**2 + dd**2) / (2 * dd)
        y = (r1**2 - r3**2 + i**2 + j**2) / (2 * j) - (i / j) * x
        z2 = r1**2 - x**2 - y**2
        in_plane = self.p1 + x[..., None] * self.ex + y[..., None] * self.ey
        off = np.sqrt(np.maximum(z2, 0.0))[..., None] * self.ez
        return in_plane + off, in_plane - off, np.maximum(-z2, 0.0)


def centroid(trajs: list[np.ndarray], F: int) -> np.ndarray:
    """Per-frame mean of the trajectories seen in that frame (NaN if none)."""
    if not trajs:
        return np.full((F, 3), np.nan)
    X = np.stack(trajs, axis=1)
    seen = np.all(np.isfinite(X), axis=2)
    n = seen.sum(1)
    out = np.where(seen[..., None], X, 0.0).sum(1) / np.maximum(n, 1)[:, None]
    out[n == 0] = np.nan
    return out


def solve_lambda(basis: Basis, c: np.ndarray) -> np.ndarray:
    """λ with o + B λ closest to the trajectory c (F, 3) over the frames where all are defined."""
    ok = np.isfinite(c[:, 0]) & np.all(np.isfinite(basis.B.reshape(len(c), -1)), axis=1)
    B, r = basis.B[ok], (c - basis.o)[ok]
    return np.linalg.solve(np.matmul(np.swapaxes(B, 1, 2), B).sum(0), np.matmul(r[:, None, :], B).sum((0, 1)))


def solve_direction(basis: Basis, frames: RigidFrames, axis_local: np.ndarray) -> np.ndarray:
    """A direction fixed in the rigid frame, expressed in λ-space of the basis."""
    ok = frames.valid & np.all(np.isfinite(basis.B.reshape(len(basis.B), -1)), axis=1)
    v = frames.R[ok] @ axis_local
    B = basis.B[ok]
    return np.linalg.solve(np.matmul(np.swapaxes(B, 1, 2), B).sum(0), np.matmul(v[:, None, :], B).sum((0, 1)))
