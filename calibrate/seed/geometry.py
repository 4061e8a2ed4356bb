"""Closed-form geometry on marker trajectories, vectorised over frames.

Everything here works on stacks of frames at once (no per-frame Python loop) and
treats NaN as a gap: a sample that is NaN is left out of that frame's fit.

- rigid_fit: a segment's pose in every frame from its points (weighted Kabsch), with the
  points' local coordinates found by generalised Procrustes.
- sphere_fit: Gamage & Lasenby's (2002) closed-form least-squares centre of rotation of
  points moving about a fixed point, and, for a hinge, the axis of rotation (the
  direction in which the points do not move).
- similarity_fit: scale, rotation and translation between two point sets (Umeyama),
  used to carry a base model's joint centre into a segment's local frame.
- kabsch / kabsch_rotation: the rigid motion between two point sets, and the rotation
  nearest to a cross-covariance (one point set; kabsch_batch: weighted, every frame at once).
- marker_rms, marker_max: RMS and largest 3-D marker error of a residual array.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

MIN_SPREAD = 0.02  # a point set is collinear when its 2nd singular value < MIN_SPREAD * its 1st


@dataclass(frozen=True)
class RigidFrames:
    """A segment's pose in every frame: world = R[f] @ local + t[f]."""

    R: np.ndarray  # (F, 3, 3); NaN in frames where fewer than 3 non-collinear points are seen
    t: np.ndarray  # (F, 3)
    local: np.ndarray  # (P, 3) the points in the segment's own frame (centroid at the origin)
    rms: np.ndarray  # (F,) RMS distance of the points from their rigid fit (m); NaN where invalid

    @property
    def valid(self) -> np.ndarray:
        """(F,) frames in which the pose is defined."""
        return np.isfinite(self.t[:, 0])

    def to_local(self, world: np.ndarray) -> np.ndarray:
        """World trajectories (F, ..., 3) in the segment frame (NaN where the pose or point is missing)."""
        shape = world.shape
        w = world.reshape(shape[0], -1, 3) - self.t[:, None, :]
        return np.matmul(w, self.R).reshape(shape)

    def to_world(self, local: np.ndarray) -> np.ndarray:
        """A fixed local point (3,) or points (P, 3) as world trajectories (F, 3) or (F, P, 3)."""
        loc = np.atleast_2d(local)
        out = np.matmul(loc, np.swapaxes(self.R, 1, 2)) + self.t[:, None, :]
        return out[:, 0] if np.ndim(local) == 1 else out


def spread(points: np.ndarray) -> tuple[float, float]:
    """(s2/s1, s3/s1): singular-value ratios of a centred point set (P, 3); small s2/s1 = collinear,
    small s3/s1 = coplanar."""
    pts = points[np.all(np.isfinite(points), axis=1)]
    if len(pts) < 2:
        return 0.0, 0.0
    s = np.linalg.svd(pts - pts.mean(0), compute_uv=False)
    s = np.concatenate([s, np.zeros(3 - len(s))])
    return (float(s[1] / s[0]), float(s[2] / s[0])) if s[0] > 0 else (0.0, 0.0)


def kabsch_batch(local: np.ndarray, world: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, R, t minimising Σ_p w[f,p] |R local[p] + t − world[f,p]|².

    local (P, 3), world (F, P, 3) with no NaN where w > 0, w (F, P) >= 0.  Frames whose
    weighted points are collinear (or fewer than 3) get NaN.
    """
    wsum = w.sum(1)
    safe = np.where(wsum > 0, wsum, 1.0)
    lc = (w @ local) / safe[:, None]  # (F, 3) weighted local centroid
    wc = np.matmul(w[:, None, :], world)[:, 0] / safe[:, None]
    a = local[None, :, :] - lc[:, None, :]
    b = world - wc[:, None, :]
    H = np.matmul(np.swapaxes(a * w[..., None], 1, 2), b)
    R, S, _ = kabsch_rotation(H)
    t = wc - np.einsum("fij,fj->fi", R, lc)
    # H's singular values are products of spreads: a collinear set leaves S[1] ~ (ratio)^2 S[0].
    bad = (np.count_nonzero(w > 0, axis=1) < 3) | ~(S[:, 1] > MIN_SPREAD**2 * S[:, 0])
    R[bad] = np.nan
    t[bad] = np.nan
    return R, t


def rigid_fit(world: np.ndarray, iterations: int = 2) -> RigidFrames:
    """The rigid motion of points (F, P, 3) that move together (gaps NaN).

    The local shape starts from the frame that sees the most points and is refined by
    generalised Procrustes (average of every frame's points carried back into the
    segment frame), so no single frame's noise defines the segment.
    """
    world = np.asarray(world, dtype=float)
    F, P, _ = world.shape
    seen = np.all(np.isfinite(world), axis=2)
    w = seen.astype(float)
    filled = np.where(seen[..., None], world, 0.0)
    if P < 3:
        raise ValueError(f"rigid_fit: need at least 3 points, got {P}")
    counts = seen.sum(1)
    f0 = int(np.argmax(counts))
    local = world[f0] - np.nanmean(world[f0], axis=0)
    local = np.where(np.isfinite(local), local, 0.0)
    w_ref = w.copy()
    if counts[f0] < P:  # points unseen in the reference frame take no part until estimated
        w_ref[:, ~seen[f0]] = 0.0
    R, t = kabsch_batch(local, filled, w_ref)
    size = max(float(np.sqrt(np.mean(np.sum(local**2, axis=1)))), 1e-300)
    for _ in range(iterations):
        loc = np.matmul(filled - t[:, None, :], R)  # R^T (x - t)
        ok = seen & np.isfinite(t[:, :1])
        n = ok.sum(0)
        if np.any(n == 0):
            break
        new = np.einsum("fp,fpi->pi", ok.astype(float), np.where(ok[..., None], loc, 0.0)) / n[:, None]
        new -= new.mean(0)
        if np.max(np.abs(new - local)) <= 1e-12 * size and counts[f0] == P:
            break  # the shape no longer changes (noise-free data): the poses stand
        local = new
        R, t = kabsch_batch(local, filled, w)
    fit = np.matmul(local, np.swapaxes(R, 1, 2)) + t[:, None, :]
    err = np.where(seen, np.sum((fit - filled) ** 2, axis=2), 0.0)
    rms = np.sqrt(err.sum(1) / np.maximum(seen.sum(1), 1))
    rms[~np.isfinite(t[:, 0])] = np.nan
    return RigidFrames(R, t, local, rms)


def triad_frames(world: np.ndarray, triangle: tuple[int, int, int] = (0, 1, 2)) -> RigidFrames:
    """A segment frame from three of its points by Gram–Schmidt: origin at the first, x towards the
    second, the third in the xy-plane.  Exact for rigid noise-free points and needs no per-frame
    decomposition (the seed 000 setting); frames missing one of the three points are NaN."""
    world = np.asarray(world, dtype=float)
    i, j, k = triangle
    o = world[:, i]
    e1 = world[:, j] - o
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    v = world[:, k] - o
    e2 = v - np.sum(v * e1, axis=1, keepdims=True) * e1
    n2 = np.linalg.norm(e2, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        e2 = np.where(n2 > MIN_SPREAD * np.linalg.norm(v, axis=1, keepdims=True), e2 / n2, np.nan)
    e3 = np.stack([e1[:, 1] * e2[:, 2] - e1[:, 2] * e2[:, 1], e1[:, 2] * e2[:, 0] - e1[:, 0] * e2[:, 2],
                   e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]], axis=1)
    R = np.stack([e1, e2, e3], axis=2)
    frames = RigidFrames(R, o, np.zeros((world.shape[1], 3)), np.zeros(len(world)))
    loc = frames.to_local(world)
    seen = np.all(np.isfinite(loc), axis=2)
    n = np.maximum(seen.sum(0), 1)
    local = np.where(seen[..., None], loc, 0.0).sum(0) / n[:, None]
    fit = frames.to_world(local)
    err = np.where(seen, np.sum((fit - np.where(seen[..., None], world, 0.0)) ** 2, axis=2), 0.0)
    rms = np.sqrt(err.sum(1) / np.maximum(seen.sum(1), 1))
    rms[~np.isfinite(o[:, 0] + R[:, 0, 0])] = np.nan
    return RigidFrames(R, o, local, rms)


@dataclass(frozen=True)
class SphereFit:
    """Gamage & Lasenby's closed-form fit of points rotating about a centre (or a hinge axis)."""

    centre: np.ndarray  # (3,) least-squares centre (for a hinge: the point on the axis nearest `near`)
    axis: np.ndarray  # (3,) direction in which the points move least (the hinge axis, if a hinge)
    eigenvalues: np.ndarray  # (3,) of the fit matrix, ascending: how well each direction is determined
    radii: np.ndarray  # (P,) sphere radius per point (m)
    rms: float  # RMS of |point − centre| − radius over all samples (m)
    n_samples: int

    @property
    def hinge_ratio(self) -> float:
        """Smallest over middle eigenvalue: near 0 when the points only move in planes (a hinge)."""
        return float(self.eigenvalues[0] / self.eigenvalues[1]) if self.eigenvalues[1] > 0 else 1.0


def sphere_fit(points: np.ndarray, hinge: bool = False, near: np.ndarray | None = None) -> SphereFit:
    """Centre of rotation of points (F, P, 3) expressed in the frame of the segment they rotate about.

    Minimises Σ_p Σ_f (|v_pf − c|² − r_p²)² in closed form (Gamage & Lasenby 2002): with
    centred positions ṽ and centred squared norms s, c = ½ (Σ ṽᵀṽ)⁻¹ Σ ṽᵀ s.  For a hinge
    the matrix is singular along the axis: the axis is its smallest eigenvector and the
    centre is the point on the axis nearest `near` (default: the points' centroid).
    """
    pts = np.asarray(points, dtype=float)
    seen = np.all(np.isfinite(pts), axis=2)
    n = seen.sum(0)
    use = n >= 3
    if not np.any(use):
        raise ValueError("sphere_fit: no point seen in 3 or more frames")
    pts, seen, n = pts[:, use], seen[:, use], n[use]
    flat = pts.reshape(-1, 3)
    origin = flat[np.all(np.isfinite(flat), axis=1)].mean(0)  # shift for conditioning
    v = np.where(seen[..., None], pts - origin, 0.0)
    mean = v.sum(0) / n[:, None]
    vt = np.where(seen[..., None], v - mean, 0.0)
    sq = np.sum(v**2, axis=2)
    st = np.where(seen, sq - sq.sum(0) / n, 0.0)
    A = vt.reshape(-1, 3).T @ vt.reshape(-1, 3)
    b = vt.reshape(-1, 3).T @ st.reshape(-1)
    evals, evecs = np.linalg.eigh(A)
    axis = evecs[:, 0]
    ref = (origin if near is None else np.asarray(near, float)) - origin
    if hinge:
        E = evecs[:, 1:]
        c = 0.5 * E @ ((E.T @ b) / evals[1:])
        c = c + axis * (axis @ (ref - c))
    else:
        c = 0.5 * np.linalg.solve(A, b)
    d = np.linalg.norm(v - c, axis=2)
    radii = np.where(seen, d, 0.0).sum(0) / n
    res = np.where(seen, d - radii, 0.0)
    rms = float(np.sqrt(np.sum(res**2) / seen.sum()))
    radii_full = np.full(use.size, np.nan)
    radii_full[use] = radii
    return SphereFit(c + origin, axis, evals, radii_full, rms, int(seen.sum()))


def kabsch_rotation(H: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rotation R maximising trace(R H) for a cross-covariance H = Σ w_i a_i b_iᵀ (3, 3) of
    centred point sets (so R a_i ≈ b_i), or for each of a stack of them (..., 3, 3): R, H's singular
    values S and the signs D (the last -1 where the best orthogonal matrix would be a reflection).
    The one Kabsch of the package: rigid fits, frame alignments and chordal means of rotations
    (the mean of R_f is kabsch_rotation(Σ R_fᵀ)) all come here."""
    U, S, Vt = np.linalg.svd(H)
    D = np.ones(S.shape)
    D[..., 2] = np.sign(np.linalg.det(np.einsum("...ji,...kj->...ik", Vt, U)))  # det(V Uᵀ)
    return np.einsum("...ji,...j,...kj->...ik", Vt, D, U), S, D  # V diag(D) Uᵀ


def kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R, t minimising Σ |R a_i + t − b_i|² (rows are points)."""
    ca, cb = a.mean(0), b.mean(0)
    R = kabsch_rotation((a - ca).T @ (b - cb))[0]
    return R, cb - R @ ca


def marker_rms(residuals: np.ndarray, axis: int | None = None) -> float | np.ndarray:
    """RMS 3-D marker error of residuals (F, M, 3) (m; NaN where a marker is not seen): over every
    observed marker in every frame, or along `axis` only (1: per frame, 0: per marker); NaN where
    nothing is seen.  The one RMS of marker errors in the package."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        rms = np.sqrt(np.nanmean(np.sum(residuals**2, axis=-1), axis=axis))
    return float(rms) if axis is None else rms


def per_marker(residuals: np.ndarray, names: Sequence[str]) -> dict[str, tuple[float, float, int]]:
    """Each seen marker of residuals (F, M, 3) (m; NaN where not seen), named by `names` -> (its RMS 3-D error m,
    its largest m, the frames it is seen in): a calibration's and a `calibrate ik` fit's per-marker table."""
    seen = np.isfinite(residuals[..., 0]).sum(axis=0)
    rms = marker_rms(residuals, axis=0)
    worst = np.nanmax(np.where(seen[None] > 0, np.linalg.norm(residuals, axis=2), 0.0), axis=0)
    return {name: (float(rms[k]), float(worst[k]), int(seen[k])) for k, name in enumerate(names) if seen[k]}


def marker_max(residuals: np.ndarray) -> float:
    """Largest 3-D marker error in residuals (F, M, 3) (m), NaN where a marker is not seen."""
    return float(np.nanmax(np.linalg.norm(residuals, axis=2)))


def similarity_fit(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """s, R, t minimising Σ |s R src_i + t − dst_i|² (Umeyama 1991); rows are points."""
    ms, md = src.mean(0), dst.mean(0)
    a, b = src - ms, dst - md
    R, S, D = kabsch_rotation(a.T @ b)
    var = np.sum(a**2)
    s = float(np.sum(S * D) / var) if var > 0 else 1.0
    return s, R, md - s * R @ ms


Transform = tuple[np.ndarray, np.ndarray]  # a rigid transform (R (3, 3), t (3,)): x -> R x + t


def compose(a: Transform, b: Transform) -> Transform:
    """a ∘ b: first b, then a."""
    return a[0] @ b[0], a[0] @ b[1] + a[1]


def invert(a: Transform) -> Transform:
    """The inverse rigid transform."""
    return a[0].T, -a[0].T @ a[1]


def identity_transform() -> Transform:
    return np.eye(3), np.zeros(3)


def apply(X: Transform, x: np.ndarray) -> np.ndarray:
    """X applied to a point x (3,)."""
    return X[0] @ x + X[1]
