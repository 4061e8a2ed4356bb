"""Robust losses (Huber, Cauchy): ρ, ρ′ and the IRLS row weights against values computed by hand,
and the robust cost's gradient (what the solver steps along) against finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibrate.problem.problem import Problem, _robust
from calibrate.problem.settings import Settings
from calibrate.problem.state import State
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns


def huber_by_hand(s: float, c: float) -> tuple[float, float]:
    """Huber on the squared, noise-normalised residual norm s = |d|²/σ² with threshold c (in σ):
    |d|/σ ≤ c: ρ = s; beyond: ρ = 2c|d|/σ − c² (linear in |d|); ρ′ = dρ/ds."""
    r = math.sqrt(s)
    return (s, 1.0) if r <= c else (2 * c * r - c * c, c / r)


def cauchy_by_hand(s: float, c: float) -> tuple[float, float]:
    """Cauchy: ρ = c² ln(1 + s/c²), ρ′ = 1/(1 + s/c²)."""
    return c * c * math.log(1 + s / (c * c)), 1 / (1 + s / (c * c))


# Values written out for c = 2 (c² = 4), so that a wrong formula in the helpers above is caught too.
@pytest.mark.parametrize("loss, s, rho, drho", [
    ("huber", 1.0, 1.0, 1.0),                      # inside: least squares
    ("huber", 4.0, 4.0, 1.0),                      # on the threshold |d| = 2σ: both branches agree
    ("huber", 9.0, 2 * 2 * 3 - 4, 2 / 3),          # |d| = 3σ: 8, weight c/|d| = 2/3
    ("huber", 100.0, 2 * 2 * 10 - 4, 0.2),         # |d| = 10σ: 36, weight 0.2
    ("cauchy", 4.0, 4 * math.log(2), 0.5),         # s = c²: half weight
    ("cauchy", 12.0, 4 * math.log(4), 0.25),
    ("cauchy", 0.0, 0.0, 1.0),
    ("linear", 9.0, 9.0, 1.0),
])
def test_rho_and_derivative_by_hand(loss, s, rho, drho):
    r, dr = _robust(np.array([s]), loss, 4.0)
    assert r[0] == pytest.approx(rho, rel=1e-14, abs=1e-15)
    assert dr[0] == pytest.approx(drho, rel=1e-14)
    if loss == "huber":
        assert (r[0], dr[0]) == pytest.approx(huber_by_hand(s, 2.0), rel=1e-14)
    if loss == "cauchy":
        assert (r[0], dr[0]) == pytest.approx(cauchy_by_hand(s, 2.0), rel=1e-14, abs=1e-15)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_derivative_is_that_of_rho(loss):
    """ρ′ against central differences of ρ, away from Huber's kink (where ρ is C¹ but not C²)."""
    s = np.array([0.3, 2.0, 3.5, 5.0, 9.0, 40.0, 400.0])
    h = 1e-6 * s
    up, _ = _robust(s + h, loss, 4.0)
    down, _ = _robust(s - h, loss, 4.0)
    _, d = _robust(s, loss, 4.0)
    assert np.allclose((up - down) / (2 * h), d, rtol=1e-7, atol=0)


@pytest.fixture(scope="module")
def frames(human):
    sim = simulate_squats(human, frames=4, noise_mm=1.0, seed=3)
    return sim, marker_columns(human, sim.trial)


def _state(problem: Problem, sim, offset: float) -> State:
    """The true poses and geometry, every coordinate moved by `offset`: residuals of a few mm to a few
    cm, so some markers lie inside the loss's threshold (3σ = 3 mm) and some far beyond it."""
    m = sim.motion
    Z = np.column_stack([m.root_translation, np.zeros((4, 3)), m.angles]) + offset
    rng = np.random.default_rng(5)
    return State(Z, m.root_quaternion.copy(),
                 problem.retract_parameters(sim.truth.vector(), offset * rng.normal(size=problem.n_free)))


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_cost_and_irls_weights_by_hand(human, human_kin, frames, loss):
    """Problem's data cost ½ Σ ρ(|d|²/σ²) and row weights √ρ′/σ, with ρ and ρ′ written out by hand
    per marker, for per-marker noise SDs; plus the priors' and limits' plain squares."""
    sim, obs = frames
    obs = obs.copy()
    obs[1, 5] = np.nan  # a gap: no residual, weight 0
    noise = {"RTHI": 0.004, "LHEE": 0.0005}
    problem = Problem(human, obs, Settings(loss=loss, marker_noise=noise), human_kin)
    state = _state(problem, sim, 0.001)
    d = problem.marker_residuals(state)  # (F, n_markers, 3), NaN in the gap
    sigma = np.array([noise.get(n, 0.001) for n in human.marker_names])
    c = 3.0  # Settings.loss_scale's default
    hand = huber_by_hand if loss == "huber" else cauchy_by_hand
    cost, w = 0.0, np.zeros(d.shape[:2])
    n_out = 0
    for f in range(d.shape[0]):
        for k in range(d.shape[1]):
            if np.isnan(d[f, k, 0]):
                continue
            s = float(d[f, k] @ d[f, k]) / sigma[k] ** 2
            rho, drho = hand(s, c)
            n_out += s > c * c
            cost += 0.5 * rho
            w[f, k] = math.sqrt(drho) / sigma[k]
    assert 10 < n_out < d.shape[0] * d.shape[1] - 10  # both sides of the threshold are exercised
    got_cost, got_w = problem._weights(np.nan_to_num(d).reshape(d.shape[0], -1))
    assert got_cost == pytest.approx(cost, rel=1e-12)
    assert np.allclose(got_w, w, rtol=1e-12, atol=0)
    assert got_w[1, 5] == 0
    r, _ = problem.prior(state.p, jacobian=False)
    lim = problem.limits(state.Z)
    assert problem.cost(state) == pytest.approx(cost + 0.5 * r @ r + 0.5 * np.sum(lim**2), rel=1e-12)
    assert problem.linearize(state).cost == pytest.approx(problem.cost(state), rel=1e-12)


@pytest.mark.parametrize("loss", ["huber", "cauchy"])
def test_robust_gradient_against_finite_differences(human, human_kin, frames, loss):
    """The gradient the solver steps along (Linearization.gz, gp: J′ of the IRLS-weighted residuals)
    is the derivative of the robust cost Problem.cost: central differences along random directions
    in the poses and in the free parameters.  A weight of ρ′ instead of √ρ′, or a wrong ρ′, fails
    by tens of per cent."""
    sim, obs = frames
    problem = Problem(human, obs, Settings(loss=loss), human_kin)
    state = _state(problem, sim, 0.001)
    lin = problem.linearize(state)
    T = problem.tangent_map(state.p)
    rng = np.random.default_rng(2)
    h = 1e-6
    for _ in range(3):
        dz = rng.normal(size=state.Z.shape)
        dp = rng.normal(size=problem.n_free)

        def at(t, dz=dz, dp=dp):
            return problem.cost(State(state.Z + t * dz, state.Q, state.p + T @ (t * dp)))

        fd = (at(h) - at(-h)) / (2 * h)
        analytic = float(np.sum(lin.gz * dz) + lin.gp @ dp)
        assert fd == pytest.approx(analytic, rel=1e-5)
        # Poses and parameters separately, so that one cannot hide an error in the other.
        fd_z = (at(h, dp=0 * dp) - at(-h, dp=0 * dp)) / (2 * h)
        assert fd_z == pytest.approx(float(np.sum(lin.gz * dz)), rel=1e-5)
        fd_p = (at(h, dz=0 * dz) - at(-h, dz=0 * dz)) / (2 * h)
        assert fd_p == pytest.approx(float(lin.gp @ dp), rel=1e-5)
