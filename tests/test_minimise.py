"""The one Levenberg–Marquardt loop (calibrate.solve.lm.minimise) on problems with known minima, and the
one Kabsch (calibrate.seed.geometry.kabsch_rotation) against scipy's independent implementation."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calibrate.problem.options import SolverOptions
from calibrate.seed.geometry import kabsch_batch, kabsch_rotation
from calibrate.solve.lm import minimise


class Rosenbrock:
    """Residuals r = (10 (y − x²), 1 − x): cost |r|², minimum 0 at (1, 1), a curved valley."""

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])
        J = np.array([[-20 * x[0], 10.0], [-1.0, 0.0]])
        return r, J

    def linearize(self, x: np.ndarray, lam: float) -> float:
        r, J = self.residuals(x)
        self.g, self.A = J.T @ r, J.T @ J
        return float(r @ r)

    def gradient_max(self) -> float:
        return 2 * float(np.abs(self.g).max())

    def step(self, x: np.ndarray, lam: float):
        D = np.maximum(np.diag(self.A), 1e-9)
        s = -np.linalg.solve(self.A + lam * np.diag(D), self.g)
        return x + s, -(2 * float(self.g @ s) + float(s @ self.A @ s)), float(np.linalg.norm(s))

    def cost(self, x: np.ndarray) -> float:
        r, _ = self.residuals(x)
        return float(r @ r)

    def norm(self, x: np.ndarray) -> float:
        return float(np.linalg.norm(x))


def test_minimise_finds_the_rosenbrock_minimum():
    options = SolverOptions(max_iterations=200, ftol=1e-15, atol=1e-300, xtol=1e-15, gtol=1e-20, geodesic=False)
    x, summary = minimise(Rosenbrock(), np.array([-1.2, 1.0]), options)
    assert summary.converged, summary.termination
    assert np.allclose(x, [1.0, 1.0], atol=1e-8)
    assert summary.final_cost < 1e-16 < summary.initial_cost
    history = np.array(summary.cost_history)
    assert np.all(np.diff(history) < 0)  # only accepted steps are recorded, each lowering the cost
    assert summary.accepted == len(history) - 1 <= summary.iterations


def test_minimise_stops_at_its_iteration_limit():
    options = SolverOptions(max_iterations=3, ftol=1e-15, atol=1e-300, xtol=1e-15, gtol=1e-20, geodesic=False)
    _, summary = minimise(Rosenbrock(), np.array([-1.2, 1.0]), options)
    assert summary.iterations == 3 and not summary.converged
    assert "max_iterations" in summary.termination


def test_kabsch_matches_scipy_align_vectors():
    rng = np.random.default_rng(3)
    R_true = Rotation.random(5, random_state=4).as_matrix()
    a = rng.normal(size=(7, 3))
    a -= a.mean(0)
    b = np.einsum("fij,pj->fpi", R_true, a) + 1e-3 * rng.normal(size=(5, 7, 3))
    b -= b.mean(1, keepdims=True)
    H = np.einsum("pi,fpj->fij", a, b)  # Σ a_p b_pᵀ per frame
    R, S, D = kabsch_rotation(H)  # batched
    for f in range(5):
        ref, _ = Rotation.align_vectors(b[f], a)  # scipy: the rotation taking a onto b
        assert np.allclose(R[f], ref.as_matrix(), atol=1e-12)
        one, _, _ = kabsch_rotation(H[f])  # one matrix at a time: the same
        assert np.allclose(one, R[f], atol=1e-14)
    assert np.allclose(np.linalg.det(R), 1.0) and np.all(D == 1.0)
    Rb, t = kabsch_batch(a, b + 0.5, np.ones((5, 7)))
    assert np.allclose(Rb, R, atol=1e-12) and np.allclose(t, 0.5, atol=1e-12)


def test_kabsch_never_returns_a_reflection():
    a = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [-1, -1, -1]])
    a -= a.mean(0)
    b = a * np.array([1.0, 1.0, -1.0])  # the mirror image: the best orthogonal matrix is a reflection
    R, _, D = kabsch_rotation(a.T @ b)
    assert np.isclose(np.linalg.det(R), 1.0) and D[2] == -1.0


def test_fit_least_squares_reaches_scipys_minimum_of_a_curve_fit():
    # The OpenSim import's small fits (calibrate.io.osim: a hinge over a knee's range) run on it, not on scipy's
    # least_squares: on a noisy exponential decay the two reach the same minimum, and it stops at its tolerances.
    from scipy.optimize import least_squares

    from calibrate.solve.lm import fit_least_squares

    rng = np.random.default_rng(5)
    t = np.linspace(0.0, 4.0, 80)
    y = 2.5 * np.exp(-1.3 * t) + 0.4 * np.sin(3.0 * t + 0.2) + rng.normal(0.0, 0.02, t.size)

    def residual(x: np.ndarray) -> np.ndarray:
        return x[0] * np.exp(-x[1] * t) + x[2] * np.sin(x[3] * t + x[4]) - y

    x0 = np.array([1.0, 1.0, 0.3, 2.8, 0.0])
    ours, summary = fit_least_squares(residual, x0, ftol=1e-14, xtol=1e-14)
    theirs = least_squares(residual, x0, method="trf", xtol=1e-14, ftol=1e-14, gtol=1e-14).x
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-8)
    assert summary.converged and summary.final_cost <= float(residual(theirs) @ residual(theirs)) * (1 + 1e-12)
    assert abs(ours[1] - 1.3) < 0.05 and abs(ours[3] - 3.0) < 0.05  # the decay and the wave the data were made of
    loose, loose_summary = fit_least_squares(residual, x0, ftol=1e-3, xtol=1e-14)
    assert loose_summary.iterations < summary.iterations and "ftol" in loose_summary.termination
