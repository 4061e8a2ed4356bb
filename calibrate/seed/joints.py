"""Joint-centre trajectories from marker trajectories alone: the MTB framework (seed 000)
with closed-form centres and axes of rotation (seed 002, Gamage & Lasenby 2002).

A joint connects two segments.  If one of them (the *anchor*) carries three or more
non-collinear points — its markers, plus joint centres already solved on it — the joint
is fixed in the anchor's frame, so its trajectory is a linear combination of the
anchor's point trajectories (marker-trajectory bases, MTB): only three numbers λ are
unknown, whatever the number of frames.  λ starts from the closed-form centre of
rotation of the other segment's points seen from the anchor (Gamage & Lasenby) and is
refined by Newton's method on the joint–marker-variance (JMV) cost of seed 000 Eq. 8,
with an analytic gradient and Hessian evaluated over all frames at once.

A hinge has no unique centre: every point of its axis keeps a constant distance to both
segments.  For a hinge (declared, or detected because the other segment's points move
in planes only) the axis is the direction in which those points do not move, and the
centre is the point of the axis nearest a prior: the base model's joint centre carried
into the anchor's frame, else the middle of the two segments' points.

A solved joint becomes a point of both its segments (solvability propagation), which
can give a segment with one or two markers a frame.  The loop runs until nothing
changes; if joints remain, the one with most points around it is solved by per-frame
JMV optimisation (joint position free in every frame; the hybrid scheme of seed 000
Section III-C) and propagation resumes.  A segment with no markers at all (the talus)
is seen through: its joints are estimated against the segments beyond it, and flagged.

Entry points: :func:`estimate_joints` (trajectories + groups + topology) and
:func:`estimate_model_joints` (a model and a trial).
"""

from __future__ import annotations

import itertools
import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.optimize import least_squares
from scipy.signal import butter, filtfilt

from ..io.text import atomic_write_text
from ..io.trial import Trial
from ..model.model import Model
from .geometry import MIN_SPREAD, RigidFrames, rigid_fit, similarity_fit, sphere_fit, spread, triad_frames

HINGE_RATIO = 0.01  # smallest/middle eigenvalue of the rotation fit below this: the joint moved as a hinge
MIN_MOTION = 0.005  # m: RMS relative motion below this means the joint did not move enough to locate it
MIN_FRAMES = 10  # fewer usable frames than this: no estimate
MIN_WIDTH = 0.005  # m: a segment's points must lie this far (RMS) from their best-fit line to give it a frame
KINDS = ("ball", "hinge", "universal")


@dataclass(frozen=True)
class JointSpec:
    """One joint of the topology: the segments (marker groups) it connects."""

    name: str
    parent: str
    child: str
    kind: str | None = None  # 'ball', 'hinge', 'universal' (treated as ball) or None: decide from the data


@dataclass(frozen=True)
class JointEstimate:
    """The estimated trajectory of one joint centre, and how it was found."""

    name: str
    parent: str
    child: str
    kind: str  # 'ball' or 'hinge' as estimated (a declared ball that moved about one axis becomes 'hinge')
    method: str  # 'MTB', 'MTB (propagated)', 'JMV' or 'failed'
    centre: np.ndarray  # (F, 3) m, world; NaN where not estimated
    axis: np.ndarray | None  # (F, 3) unit hinge axis in the world per frame; None unless kind == 'hinge'
    anchor: str | None  # segment whose frame holds the centre fixed (None for JMV)
    rms: float  # m: RMS over frames and points of (joint–point distance − its mean): the JMV residual
    frames: int  # frames with an estimate
    ok: bool
    reason: str = ""  # why not ok
    note: str = ""  # caveats of an ok estimate (e.g. seen through a markerless segment)
    axis_local: np.ndarray | None = field(default=None, repr=False)  # hinge axis in the anchor frame
    centre_local: np.ndarray | None = field(default=None, repr=False)  # centre in the anchor frame

    @property
    def mtb(self) -> bool:
        """Estimated by the MTB framework (directly or propagated), not by JMV alone."""
        return self.method in ("MTB", "MTB (propagated)")


@dataclass(frozen=True)
class JointEstimates:
    """All joints of a trial, in the order of the topology, plus the solve order and time."""

    joints: tuple[JointEstimate, ...]
    order: tuple[str, ...]  # names in the order they were solved
    seconds: float
    times: np.ndarray | None = None  # (F,) s, if known

    def __getitem__(self, name: str) -> JointEstimate:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"no joint named '{name}'; joints are: {', '.join(self.names)}")

    def __iter__(self):
        return iter(self.joints)

    def __len__(self) -> int:
        return len(self.joints)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def centres(self) -> np.ndarray:
        """(F, n_joints, 3) every joint's trajectory (NaN where not estimated)."""
        return np.stack([j.centre for j in self.joints], axis=1)

    def table(self) -> str:
        """A plain-text table: joint, segments, kind, method, frames, JMV residual, axis."""
        rows = [("joint", "parent -> child", "kind", "method", "frames", "resid mm", "axis (anchor frame)", "note")]
        for j in self.joints:
            if j.axis_local is not None:
                ax = "[" + " ".join(f"{v:+.3f}" for v in j.axis_local) + "]"
            else:
                ax = "-"
            rows.append((j.name, f"{j.parent} -> {j.child}", j.kind, j.method, str(j.frames),
                         f"{1000 * j.rms:.2f}" if math.isfinite(j.rms) else "-", ax,
                         j.reason if not j.ok else j.note))
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r[:-1], widths, strict=True)) + ("  " + r[-1] if r[-1] else "")
                 for r in rows]
        lines.insert(1, "-" * len(lines[0]))
        return "\n".join(line.rstrip() for line in lines)


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
    return r3 + _cross(r1 - r3, r2 - r3)


def affine_basis(points: np.ndarray, names: Sequence[str] | None = None) -> Basis:
    """The MTB basis of seed 000 from 3 non-collinear or 4 non-coplanar trajectories (F, P, 3).

    With four non-coplanar points the basis vectors are a_i = r_i − r_4; with three (or
    four nearly coplanar ones) the auxiliary point of Eq. 9 replaces the fourth.
    """
    P = points.shape[1]
    ref = _reference_shape(points)
    if P == 4 and spread(ref)[1] > MIN_SPREAD:
        r1, r2, r3, r4 = (points[:, i] for i in range(4))
    else:
        idx = _best_triangle(ref) if P > 3 else (0, 1, 2)
        r1, r2, r3 = (points[:, i] for i in idx)
        r4 = auxiliary_point(r1, r2, r3)
    B = np.stack([r1 - r4, r2 - r4, r3 - r4], axis=2)
    return Basis(r4, B, "affine")


def _affine_triangle(points: np.ndarray) -> tuple[int, int, int]:
    """The three points the closed forms use when the MTB basis is affine: the largest triangle."""
    return _best_triangle(_reference_shape(points)) if points.shape[1] > 3 else (0, 1, 2)


def rigid_basis(frames: RigidFrames) -> Basis:
    """A basis from a least-squares rigid frame (used for segments with more than four points)."""
    return Basis(frames.t, frames.R, "rigid")


def _reference_shape(points: np.ndarray) -> np.ndarray:
    """Positions (P, 3) in the frame that sees most of the points (gaps 0-filled)."""
    seen = np.all(np.isfinite(points), axis=2)
    f = int(np.argmax(seen.sum(1)))
    return np.where(seen[f][:, None], points[f], np.nan)


def _best_triangle(ref: np.ndarray) -> tuple[int, int, int]:
    """The three points spanning the largest triangle."""
    combos = np.array(list(itertools.combinations(range(len(ref)), 3)))
    a, b, c = ref[combos[:, 0]], ref[combos[:, 1]], ref[combos[:, 2]]
    area = np.linalg.norm(_cross(b - a, c - a), axis=1)
    area = np.where(np.isfinite(area), area, -1.0)
    return tuple(int(i) for i in combos[int(np.argmax(area))])  # type: ignore[return-value]


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
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


def _jmv_rms(centre: np.ndarray, points: np.ndarray) -> float:
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


def _inv_sym3(A: np.ndarray) -> np.ndarray:
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
            Ainv = _inv_sym3(Ad)
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


# --------------------------------------------------------------------------- framework
@dataclass
class _Point:
    name: str
    traj: np.ndarray  # (F, 3)
    is_joint: bool


class _Framework:
    """The system state of seed 000 Section III: points per segment, solved joints, the loop."""

    def __init__(self, points: Mapping[str, np.ndarray], groups: Mapping[str, Sequence[str]],
                 specs: Sequence[JointSpec], alpha: float, geometry: Mapping[str, Mapping[str, np.ndarray]] | None,
                 basis: str):
        self.alpha = alpha
        self.basis = basis
        self.geometry = geometry or {}
        self.specs = list(specs)
        self.F = _n_frames(points)
        self.seg: dict[str, list[_Point]] = {s: [] for s in groups}
        for spec in self.specs:
            for s in (spec.parent, spec.child):
                self.seg.setdefault(s, [])
        for s, labels in groups.items():
            for lab in labels:
                self.seg[s].append(_Point(lab, np.asarray(points[lab], dtype=float), False))
        self.joints_of: dict[str, list[JointSpec]] = {s: [] for s in self.seg}
        for spec in self.specs:
            self.joints_of[spec.parent].append(spec)
            self.joints_of[spec.child].append(spec)
        self.solved: dict[str, JointEstimate] = {}
        self.order: list[str] = []
        self.n_markers = {s: sum(not p.is_joint for p in pts) for s, pts in self.seg.items()}

    # --- state helpers
    def other(self, spec: JointSpec, s: str) -> str:
        return spec.child if s == spec.parent else spec.parent

    def has_frame(self, s: str, without: str = "") -> bool:
        """Whether the segment's points (less `without`) span a frame: 3 or more, not (nearly) collinear."""
        pts = [p for p in self.seg[s] if p.name != without]
        return len(pts) >= 3 and _frame_width(_reference_shape(np.stack([p.traj for p in pts], axis=1))) > MIN_WIDTH

    def other_points(self, spec: JointSpec, anchor: str) -> tuple[list[_Point], str]:
        """Points that move with the far side of the joint; looks through a markerless segment."""
        o = self.other(spec, anchor)
        pts = [p for p in self.seg[o] if p.name != spec.name]
        note = ""
        if self.n_markers[o] == 0:
            beyond = [j for j in self.joints_of[o] if j.name != spec.name]
            names = {p.name for p in pts}
            for j in beyond:
                far = self.other(j, o)
                pts += [p for p in self.seg[far] if p.name not in names and p.name != spec.name]
            if beyond:
                note = f"{o} carries no markers: estimated against " + ", ".join(self.other(j, o) for j in beyond)
        return pts, note

    def add_solution(self, est: JointEstimate, spec: JointSpec) -> None:
        self.solved[spec.name] = est
        if spec.name not in self.order:  # a joint solved again (polish) keeps its place
            self.order.append(spec.name)
        for s in (spec.parent, spec.child):
            self.seg[s] = [p for p in self.seg[s] if p.name != spec.name]
            if est.ok:
                self.seg[s].append(_Point(spec.name, est.centre, True))

    def polish(self) -> None:
        """Joints found by per-frame JMV are solved again by MTB once one of their segments has a frame
        without them (propagation from the other side gave it one): a hinge then gets its axis."""
        for spec in self.specs:
            est = self.solved.get(spec.name)
            if est is None or est.method != "JMV":
                continue
            sides = [s for s in (spec.parent, spec.child) if self.has_frame(s, without=spec.name)]
            if not sides:
                continue
            anchor = max(sides, key=lambda s: len(self.seg[s]))
            new = self.solve_mtb(spec, anchor)
            if new is not None and new.ok:
                note = "; ".join(filter(None, [new.note, "started from per-frame JMV (hybrid scheme)"]))
                self.add_solution(replace(new, note=note), spec)

    # --- solvers
    def solve_mtb(self, spec: JointSpec, anchor: str) -> JointEstimate | None:
        apts = [p for p in self.seg[anchor] if p.name != spec.name]
        opts, note = self.other_points(spec, anchor)
        if not opts:
            return None
        A = np.stack([p.traj for p in apts], axis=1)
        O = np.stack([p.traj for p in opts], axis=1)
        paper = self.basis == "affine" and len(apts) <= 4
        frames = triad_frames(A, _affine_triangle(A)) if paper else rigid_fit(A)
        Q = frames.to_local(O)
        Q[~frames.valid] = np.nan
        usable = frames.valid & np.any(np.all(np.isfinite(O), axis=2), axis=1)
        if usable.sum() < MIN_FRAMES:
            return self._fail(spec, f"only {int(usable.sum())} frames see {anchor}'s frame and a point of "
                              f"{self.other(spec, anchor)}; need {MIN_FRAMES}")
        try:
            fit = sphere_fit(Q)
        except ValueError:
            return self._fail(spec, f"no point of {self.other(spec, anchor)} seen in enough frames")
        motion = math.sqrt(fit.eigenvalues[-1] / max(fit.n_samples, 1))
        if motion < MIN_MOTION:
            return self._fail(spec, f"{self.other(spec, anchor)} barely moves relative to {anchor} "
                              f"({1000 * motion:.1f} mm RMS); record a trial that moves this joint")
        declared = spec.kind if not note else None  # seen through a markerless segment: two joints in one
        hinge = declared == "hinge" or fit.hinge_ratio < HINGE_RATIO
        if hinge and declared != "hinge":
            note = "; ".join(filter(None, [note, f"moved about one axis only (eigenvalue ratio {fit.hinge_ratio:.1e}): "
                                                 "centre placed on that axis"]))
        near = self.prior_local(spec, anchor, apts, frames)
        if near is None:
            near = np.nanmean(np.concatenate([frames.local, Q.reshape(-1, 3)]), axis=0)
        if hinge:
            fit = sphere_fit(Q, hinge=True, near=near)
        # MTB refinement (Eq. 8) in the paper's basis of at most four points, else the rigid frame
        basis = affine_basis(A) if paper else rigid_basis(frames)
        c_world = frames.to_world(fit.centre)
        lam0 = _solve_lambda(basis, c_world)
        allpts = np.concatenate([A, O], axis=1)
        fixed = None
        if hinge:
            fixed = _solve_direction(basis, frames, fit.axis)
        lam, _, _ = mtb_refine(basis, allpts, lam0, self.alpha, fixed=fixed)
        centre = basis.point(lam)
        centre[~usable] = np.nan
        axis_world = None
        if hinge:
            axis_world = frames.R @ fit.axis
            axis_world[~usable] = np.nan
        propagated = any(p.is_joint for p in apts)

        c_local = np.nanmean(frames.to_local(centre[:, None, :])[:, 0], axis=0)
        return JointEstimate(
            spec.name, spec.parent, spec.child, "hinge" if hinge else "ball",
            "MTB (propagated)" if propagated else "MTB", centre, axis_world, anchor,
            _jmv_rms(centre, allpts), int(np.isfinite(centre[:, 0]).sum()), True, "", note,
            axis_local=fit.axis if hinge else None, centre_local=c_local)

    def prior_local(self, spec: JointSpec, anchor: str, apts: list[_Point], frames: RigidFrames) -> np.ndarray | None:
        """The base model's joint centre in the anchor's rigid frame (similarity fit on the points both know)."""
        geo = self.geometry.get(anchor)
        if not geo or spec.name not in geo:
            return None
        idx = [i for i, p in enumerate(apts) if p.name in geo]
        if len(idx) < 3:
            return None
        src = np.array([geo[apts[i].name] for i in idx])
        dst = frames.local[idx]
        if _frame_width(src) <= MIN_WIDTH:
            return None
        s, R, t = similarity_fit(src, dst)
        if not 0.7 <= s <= 1.4:  # an implausible size change means the fit is ill-conditioned: the prior is unknown
            return None
        return s * R @ np.asarray(geo[spec.name]) + t

    def solve_jmv(self, spec: JointSpec, markers_only: bool = False) -> JointEstimate:
        a, b = spec.parent, spec.child
        pts = [p for s in (a, b) for p in self.seg[s] if p.name != spec.name and not (markers_only and p.is_joint)]
        note = ""
        for s in (a, b):
            if self.n_markers[s] == 0 and not markers_only:
                extra, note = self.other_points(spec, self.other(spec, s))
                names = {p.name for p in pts}
                pts += [p for p in extra if p.name not in names]
        if len(pts) < 4:
            return self._fail(spec, f"JMV needs 4 or more points around the joint; {a} and {b} have {len(pts)}")
        X = np.stack([p.traj for p in pts], axis=1)
        ga = [p.traj for p in self.seg[a] if p.name != spec.name]
        gb = [p.traj for p in self.seg[b] if p.name != spec.name]
        # a hinge's JMV optimum is a whole line, so the global search for the one true point is skipped
        centre = _jmv_multistart(X, ga, gb, self.F, search=spec.kind != "hinge")
        n = int(np.isfinite(centre[:, 0]).sum())
        if n < MIN_FRAMES:
            return self._fail(spec, f"only {n} frames see 3 or more points around the joint; need {MIN_FRAMES}")
        if spec.kind == "hinge":
            note = "; ".join(filter(None, [note, "a hinge solved by per-frame JMV: where the centre lies along the "
                                                  "axis is not determined by the data"]))
        return JointEstimate(spec.name, a, b, spec.kind or "ball", "JMV", centre, None, None, _jmv_rms(centre, X),
                             n, True, "", note)

    def _fail(self, spec: JointSpec, reason: str) -> JointEstimate:
        return JointEstimate(spec.name, spec.parent, spec.child, spec.kind or "ball", "failed",
                             np.full((self.F, 3), np.nan), None, None, math.nan, 0, False, reason)

    # --- the loop
    def run(self, mode: str) -> None:
        if mode == "jmv":
            for spec in self.specs:
                self.add_solution(self.solve_jmv(spec, markers_only=True), spec)
            return
        while True:
            self.propagate()
            pending = [s for s in self.specs if s.name not in self.solved]
            if not pending:
                self.polish()
                return
            # hybrid scheme: JMV for the pending joint with most points around it, then propagate again
            def n_points(spec: JointSpec) -> int:
                return len(self.seg[spec.parent]) + len(self.seg[spec.child])

            spec = max(pending, key=n_points)
            self.add_solution(self.solve_jmv(spec), spec)  # solved or failed with a reason: one fewer pending

    def propagate(self) -> None:
        """Joint solvability and its propagation, until the system state stops changing."""
        changed = True
        while changed:
            changed = False
            segments = sorted(self.seg, key=lambda s: (-len(self.seg[s]), s))
            for s in segments:
                pending = [j for j in self.joints_of[s] if j.name not in self.solved]
                if not pending or not self.has_frame(s):
                    continue
                for spec in pending:
                    other = self.other(spec, s)
                    if self.has_frame(other) and len(self.seg[other]) > len(self.seg[s]):
                        continue  # the better-marked side anchors it
                    est = self.solve_mtb(spec, s)
                    if est is not None:
                        self.add_solution(est, spec)
                        changed = True
                if changed:
                    break


def _jmv_multistart(X: np.ndarray, ga: list[np.ndarray], gb: list[np.ndarray], F: int,
                    search: bool = True) -> np.ndarray:
    """Per-frame JMV from several starts (the cost has mirror-image and local minima); the lowest
    residual wins.

    Starts: the best few of a grid search over the joint's distances to three of the points
    (trilateration, see _trilateration_starts), the midpoint of the two segments' centroids, each
    centroid, and, for a segment with two points p, q, the points beyond either end of pq.
    """
    ca, cb = _centroid(ga, F), _centroid(gb, F)
    starts = (_trilateration_starts(X) if search else []) + [0.5 * (ca + cb), ca, cb]
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


def _trilateration_starts(X: np.ndarray, steps: int = 16, keep: int = 6, max_frames: int = 100) -> list[np.ndarray]:
    """Global starts for per-frame JMV: a joint keeps fixed distances (ρa, ρb, ρc) to three of the points
    around it, so on a grid of those three distances every frame's joint follows by trilateration (two
    mirror solutions; one side is kept for the whole trial).  Each grid point is scored by how much the
    joint's distances to the other points vary; the `keep` best become starts (trajectories (F, 3)).
    The search runs on at most `max_frames` evenly spaced frames; trilateration then fills all frames."""
    F, P, _ = X.shape
    if P < 4:
        return []
    seen = np.all(np.isfinite(X), axis=2)
    full = np.flatnonzero(seen.all(1))
    if len(full) < MIN_FRAMES:
        return []
    # the three points spanning the largest triangle on average, the rest score
    ref = X[full[len(full) // 2]]
    a, b, c = _best_triangle(ref)
    rest = [k for k in range(P) if k not in (a, b, c)]
    sub = full[np.linspace(0, len(full) - 1, min(max_frames, len(full))).astype(int)]
    span = np.nanmax(np.linalg.norm(X[sub][:, :, None] - X[sub][:, None, :], axis=3))
    grid = np.linspace(span / steps, span, steps)
    ra, rb, rc = (g.ravel() for g in np.meshgrid(grid, grid, grid, indexing="ij"))
    Xs, Xr = X[sub], X[sub][:, rest]

    def candidates(r: np.ndarray, Xa, Xb, Xc, Xrest) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per frame, the trilaterated joint on the side of the plane that fits the other points
        (the joint may cross the plane of the three during the trial): (G, f, 3), distances, misses."""
        both = [_trilaterate(Xa, Xb, Xc, r[0], r[1], r[2], sign) for sign in (1.0, -1.0)]
        d = [np.linalg.norm(cen[:, :, None, :] - Xrest[None], axis=3) for cen, _ in both]  # (G, f, R)
        med = [np.median(x, axis=1, keepdims=True) for x in d]
        one_side = [np.sum(np.var(x, axis=1), axis=1) for x in d]
        ref = np.where((one_side[0] <= one_side[1])[:, None, None], med[0], med[1])
        pick = np.sum((d[0] - ref) ** 2, axis=2) <= np.sum((d[1] - ref) ** 2, axis=2)  # (G, f)
        cen = np.where(pick[..., None], both[0][0], both[1][0])
        return cen, np.where(pick[..., None], d[0], d[1]), np.where(pick, both[0][1], both[1][1])

    def score(r: np.ndarray) -> np.ndarray:
        _, d, bad = candidates(r, Xs[:, a], Xs[:, b], Xs[:, c], Xr)
        beyond = np.sum(np.maximum(np.abs(r - 0.5 * span) - 0.5 * span, 0.0) ** 2, axis=0)  # keep 0 < ρ < span
        return d.var(axis=1).sum(1) + bad.mean(1) + beyond

    def residuals(r: np.ndarray) -> np.ndarray:
        _, d, bad = candidates(r[:, None], Xs[:, a], Xs[:, b], Xs[:, c], Xr)
        beyond = np.maximum(np.abs(r - 0.5 * span) - 0.5 * span, 0.0)
        return np.concatenate([(d[0] - d[0].mean(0)).ravel() / math.sqrt(len(sub)), np.sqrt(bad[0] / len(sub)),
                               beyond])

    sc = score(np.stack([ra, rb, rc]))
    best: list[tuple[float, np.ndarray]] = []
    picked: list[np.ndarray] = []
    for g in np.argsort(sc):  # the best distinct grid points, each polished by least squares in (ρa, ρb, ρc)
        r0 = np.array([ra[g], rb[g], rc[g]])
        if any(np.max(np.abs(r0 - q)) <= 1.5 * span / steps for q in picked):
            continue
        picked.append(r0)
        res = least_squares(residuals, r0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)
        best.append((float(2 * res.cost), res.x))
        if len(picked) == keep or res.cost < 1e-24:
            break
    best.sort(key=lambda item: item[0])
    rest_all = X[:, rest]
    return [candidates(r[:, None], X[:, a], X[:, b], X[:, c], rest_all)[0][0] for _, r in best]


def _trilaterate(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray, r1: np.ndarray, r2: np.ndarray,
                 r3: np.ndarray, sign: float) -> tuple[np.ndarray, np.ndarray]:
    """Points at distances r1, r2, r3 (G,) from p1, p2, p3 (f, 3) on the `sign` side of their plane:
    (G, f, 3), and how far (m²) the spheres miss each other where they do not meet (0 where they do)."""
    ex = p2 - p1
    dd = np.linalg.norm(ex, axis=1)
    ex = ex / dd[:, None]
    v = p3 - p1
    i = np.sum(ex * v, axis=1)
    ey = v - i[:, None] * ex
    j = np.linalg.norm(ey, axis=1)
    ey = ey / j[:, None]
    ez = _cross(ex, ey)
    r1, r2, r3 = r1[:, None], r2[:, None], r3[:, None]
    x = (r1**2 - r2**2 + dd**2) / (2 * dd)
    y = (r1**2 - r3**2 + i**2 + j**2) / (2 * j) - (i / j) * x
    z2 = r1**2 - x**2 - y**2
    z = sign * np.sqrt(np.maximum(z2, 0.0))
    pts = p1 + x[..., None] * ex + y[..., None] * ey + z[..., None] * ez
    return pts, np.maximum(-z2, 0.0)


def _frame_width(ref: np.ndarray) -> float:
    """RMS distance (m) of points (P, 3) from their best-fit line; 0 if fewer than 3 are seen."""
    pts = ref[np.all(np.isfinite(ref), axis=1)]
    if len(pts) < 3:
        return 0.0
    sv = np.linalg.svd(pts - pts.mean(0), compute_uv=False)
    return float(np.sqrt(np.sum(sv[1:] ** 2) / len(pts)))


def _centroid(trajs: list[np.ndarray], F: int) -> np.ndarray:
    """Per-frame mean of the trajectories seen in that frame (NaN if none)."""
    if not trajs:
        return np.full((F, 3), np.nan)
    X = np.stack(trajs, axis=1)
    seen = np.all(np.isfinite(X), axis=2)
    n = seen.sum(1)
    out = np.where(seen[..., None], X, 0.0).sum(1) / np.maximum(n, 1)[:, None]
    out[n == 0] = np.nan
    return out


def _solve_lambda(basis: Basis, c: np.ndarray) -> np.ndarray:
    """λ with o + B λ closest to the trajectory c (F, 3) over the frames where all are defined."""
    ok = np.isfinite(c[:, 0]) & np.all(np.isfinite(basis.B.reshape(len(c), -1)), axis=1)
    B, r = basis.B[ok], (c - basis.o)[ok]
    return np.linalg.solve(np.matmul(np.swapaxes(B, 1, 2), B).sum(0), np.matmul(r[:, None, :], B).sum((0, 1)))


def _solve_direction(basis: Basis, frames: RigidFrames, axis_local: np.ndarray) -> np.ndarray:
    """A direction fixed in the rigid frame, expressed in λ-space of the basis."""
    ok = frames.valid & np.all(np.isfinite(basis.B.reshape(len(basis.B), -1)), axis=1)
    v = frames.R[ok] @ axis_local
    B = basis.B[ok]
    return np.linalg.solve(np.matmul(np.swapaxes(B, 1, 2), B).sum(0), np.matmul(v[:, None, :], B).sum((0, 1)))


def _n_frames(points: Mapping[str, np.ndarray]) -> int:
    sizes = {np.asarray(v).shape[0] for v in points.values()}
    if len(sizes) != 1:
        raise ValueError(f"points: every trajectory needs the same number of frames, got {sorted(sizes)}")
    return sizes.pop()


def _check(points: Mapping[str, np.ndarray], groups: Mapping[str, Sequence[str]], specs: Sequence[JointSpec],
           mode: str, alpha: float) -> None:
    if mode not in ("framework", "jmv"):
        raise ValueError(f"mode: expected 'framework' or 'jmv', got {mode!r}")
    if not (alpha >= 0 and math.isfinite(alpha)):
        raise ValueError(f"alpha: must be a finite number >= 0, got {alpha}")
    for name, traj in points.items():
        if np.ndim(traj) != 2 or np.shape(traj)[1] != 3:
            raise ValueError(f"points['{name}']: expected an (F, 3) trajectory, got shape {np.shape(traj)}")
    owner: dict[str, str] = {}
    for s, labels in groups.items():
        for lab in labels:
            if lab not in points:
                raise ValueError(f"groups['{s}']: marker '{lab}' has no trajectory in points")
            if lab in owner:
                raise ValueError(f"marker '{lab}' is in two groups ('{owner[lab]}' and '{s}'); a marker rides on "
                                 "one segment")
            owner[lab] = s
    seen: set[str] = set()
    for spec in specs:
        if spec.name in seen:
            raise ValueError(f"joints: the name '{spec.name}' is used twice")
        seen.add(spec.name)
        if spec.kind is not None and spec.kind not in KINDS:
            raise ValueError(f"joint '{spec.name}': kind must be one of {KINDS} or None, got {spec.kind!r}")
        if spec.parent == spec.child:
            raise ValueError(f"joint '{spec.name}': parent and child are the same segment '{spec.parent}'")


def estimate_joints(points: Mapping[str, np.ndarray], groups: Mapping[str, Sequence[str]],
                    joints: Sequence[JointSpec], *, mode: str = "framework", alpha: float = 0.0,
                    basis: str = "rigid", geometry: Mapping[str, Mapping[str, np.ndarray]] | None = None,
                    rate: float | None = None, cutoff_hz: float | None = None,
                    times: np.ndarray | None = None) -> JointEstimates:
    """Estimate every joint-centre trajectory of a topology from marker trajectories.

    points: marker label -> (F, 3) trajectory (m; NaN in gaps).
    groups: segment -> the labels of the markers riding on it (a segment may have none).
    joints: the topology, one JointSpec per joint (parent and child are segment names).
    mode: 'framework' (MTB, propagation, hybrid JMV; seed 000) or 'jmv' (every joint by
      per-frame JMV from its two segments' markers only: the baseline the paper compares with).
    alpha: weight of the mean joint–marker distance in Eq. 8 (0: pure variance, unbiased).
    basis: 'rigid' (default) writes a point fixed on the anchor as t_f + R_f λ with the anchor's
      least-squares rigid frame (all its points); 'affine' uses seed 000's basis of four points
      (or three plus Eq. 9's auxiliary point), r4 + Σ λ_i (r_i − r4).  Both are exact without
      noise; with marker noise the rigid frame is measurably more accurate (docs/benchmarks.md).
    rate, cutoff_hz: if both are given, markers are low-passed first (zero-lag 4th-order
      Butterworth, each gap-free run separately), as is usual for marker data.
    geometry: optional base-model positions, segment -> {marker label or joint name -> (3,)
      position in that segment's frame}; it places a hinge's centre on its axis (nearest the
      model's centre).  Without it the hinge centre is the point of the axis nearest the middle
      of the two segments' points.
    """
    _check(points, groups, joints, mode, alpha)
    if basis not in ("rigid", "affine"):
        raise ValueError(f"basis: expected 'rigid' or 'affine', got {basis!r}")
    t0 = time.perf_counter()
    if cutoff_hz is not None:
        if rate is None or not (0 < cutoff_hz < rate / 2):
            raise ValueError(f"cutoff_hz: needs the sampling rate and 0 < cutoff_hz < rate/2; got {cutoff_hz} at "
                             f"rate {rate}")
        points = {k: lowpass(np.asarray(v, dtype=float), rate, cutoff_hz) for k, v in points.items()}
    fw = _Framework(points, groups, joints, alpha, geometry, basis)
    fw.run(mode)
    out = tuple(fw.solved[s.name] for s in joints)
    return JointEstimates(out, tuple(fw.order), time.perf_counter() - t0, times)


def lowpass(traj: np.ndarray, rate: float, cutoff_hz: float, order: int = 4) -> np.ndarray:
    """Zero-lag Butterworth low-pass of a trajectory (F, ...) along frames; each gap-free run is
    filtered on its own, runs too short to filter are kept as they are, gaps stay NaN."""
    b, a = butter(order, cutoff_hz / (rate / 2))
    pad = 3 * max(len(a), len(b))
    out = np.array(traj, dtype=float)
    flat = out.reshape(len(out), -1)
    ok = np.all(np.isfinite(flat), axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if stop - start > pad:
            flat[start:stop] = filtfilt(b, a, flat[start:stop], axis=0)
    return out


# --------------------------------------------------------------------------- models and trials
def model_geometry(model: Model) -> dict[str, dict[str, np.ndarray]]:
    """Base-model positions of markers and joint centres in each segment's frame (neutral pose)."""
    pm = model.pin
    data = pm.createData()
    pin.framesForwardKinematics(pm, data, pin.neutral(pm))
    place = {}
    for s in model.segments:
        place[s.name] = data.oMf[pm.getFrameId(s.name)]
    geo: dict[str, dict[str, np.ndarray]] = {s.name: {} for s in model.segments}
    for m in model.markers:
        geo[m.segment][m.name] = np.asarray(m.offset, dtype=float)
    for j in model.joints:
        world = data.oMf[pm.getFrameId(j.urdf_joints[0])].translation
        for s in (j.parent, j.child):
            geo[s][j.name] = place[s].actInv(world).copy()
    return geo


def estimate_model_joints(model: Model, trial: Trial, *, mode: str = "framework", alpha: float = 0.0,
                          basis: str = "rigid", cutoff_hz: float | None = 6.0,
                          extra_markers: Mapping[str, str] | None = None) -> JointEstimates:
    """Every joint of `model` from a trial: groups are the model's markers per segment (those the
    trial has), the topology is the model's joint tree, hinges come from the model, and the base
    model's centres choose the point on each hinge axis.  Markers are low-passed at `cutoff_hz`
    (None: raw) unless the trial's rate is too low for it.  `extra_markers` (trial label ->
    segment, e.g. from calibrate.seed.association.associate_to_model) adds markers the model does not
    know to the segments they ride on."""
    if cutoff_hz is not None and not cutoff_hz < trial.rate / 2:
        cutoff_hz = None
    labels = set(trial.labels)
    known = {m.name for m in model.markers}
    points = {lab: trial.marker(lab) for lab in trial.labels if lab in known}
    groups = {s.name: [m for m in s.markers if m in labels] for s in model.segments}
    for lab, seg in (extra_markers or {}).items():
        if lab in known or lab not in labels:
            continue
        if seg not in groups:
            raise ValueError(f"extra_markers['{lab}']: '{seg}' is not a segment of {model.path}")
        points[lab] = trial.marker(lab)
        groups[seg].append(lab)
    kinds = {"hinge": "hinge", "ball": "ball", "universal": "universal"}
    specs = [JointSpec(j.name, j.parent, j.child, kinds.get(j.kind)) for j in model.joints if j.kind != "fixed"]
    est = estimate_joints(points, groups, specs, mode=mode, alpha=alpha, basis=basis,
                          geometry=model_geometry(model), rate=trial.rate, cutoff_hz=cutoff_hz, times=trial.times)
    return est


def write_centres_csv(path: str | Path, est: JointEstimates, overwrite: bool = True) -> Path:
    """Joint-centre trajectories as CSV: time, then <joint>_x, _y, _z (m) per joint; hinges add
    <joint>_axis_x, _y, _z (unit, world).  Empty cells where a joint is not estimated."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists; pass overwrite=True (CLI: --overwrite) to replace it")
    F = len(est.joints[0].centre) if est.joints else 0
    times = est.times if est.times is not None else np.arange(F, dtype=float)
    header = ["time"]
    cols = [np.asarray(times, dtype=float)[:, None]]
    for j in est.joints:
        header += [f"{j.name}_{c}" for c in "xyz"]
        cols.append(j.centre)
        if j.axis is not None:
            header += [f"{j.name}_axis_{c}" for c in "xyz"]
            cols.append(j.axis)
    data = np.hstack(cols) if cols else np.zeros((0, 1))
    lines = [",".join(header)]
    for row in data:
        lines.append(",".join("" if not np.isfinite(v) else f"{v:.6f}" if k else f"{v:.6g}" for k, v in enumerate(row)))
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
