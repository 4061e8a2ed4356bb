"""Points from camera rays: weighted least-squares triangulation, its reprojection error, and the
compromise between a prediction and one ray (seed 002, Section 2, step 3).

A detection is a ray from the camera centre c along the unit direction d.  The squared distance of a
point X from it is ‖P (X − c)‖² with P = I − d dᵀ; divided by the depth and times the focal length it is,
to first order, the reprojection error in pixels.  Triangulation minimises Σ w ‖P (X − c)‖² with
w = (f / depth)², i.e. the pixel reprojection error (to first order; exact for noise-free rays).
"""

from __future__ import annotations

import numpy as np


def ray_terms(centres: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per ray (n): P = I − d dᵀ (n, 3, 3), P c (n, 3) and cᵀ P c (n,)."""
    P = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]
    Pc = np.einsum("nij,nj->ni", P, centres)
    return P, Pc, np.einsum("ni,ni->n", centres, Pc)


def solve_points(A: np.ndarray, b: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points X (h, 3) minimising Xᵀ A X − 2 bᵀ X + s and that minimum (h,) (the weighted squared ray
    distances), for A (h, 3, 3) positive definite."""
    X = np.linalg.solve(A, b[..., None])[..., 0]
    r = s - np.einsum("hi,hi->h", b, X)
    return X, np.maximum(r, 0.0)


def triangulate(centres: np.ndarray, dirs: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """The point (3,) nearest (weighted least squares) to two or more rays, and the weighted sum of
    squared distances.  `weights` (n,) default 1."""
    w = np.ones(len(centres)) if weights is None else np.asarray(weights, float)
    P, Pc, s = ray_terms(np.asarray(centres, float), np.asarray(dirs, float))
    X, r = solve_points((w[:, None, None] * P).sum(0)[None], (w[:, None] * Pc).sum(0)[None], np.array([w @ s]))
    return X[0], float(r[0])


def ray_compromise(prediction: np.ndarray, centre: np.ndarray, direction: np.ndarray, w_prediction: float,
                   w_ray: float) -> np.ndarray:
    """The point minimising w_prediction ‖X − ŷ‖² + w_ray ‖P (X − c)‖²: between the prediction ŷ and the
    ray (the paper's compromise when only one camera saw the marker)."""
    P = np.eye(3) - np.outer(direction, direction)
    A = w_prediction * np.eye(3) + w_ray * P
    return np.linalg.solve(A, w_prediction * prediction + w_ray * P @ centre)
