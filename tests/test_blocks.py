"""Named parameter blocks (calibrate.model.blocks), the immutable Problem and the solver's options.

The layout is checked against the model's own numbers (each block's entries hold the base model's
joint centre, axis, marker offset, scale), the tangent map against finite differences of the
retraction, and each Problem copy against the original left unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.model.blocks import FrameLayout, ParameterLayout, perpendicular_bases, perpendicular_basis
from calibrate.problem.options import SolverOptions
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns
from calibrate.solve.lm import State, levenberg_marquardt


def test_blocks_hold_the_model_numbers(human):
    L = ParameterLayout(human)
    P = human.parameters()
    p = P.vector()
    assert L.n_full == p.size
    for j, joint in enumerate(human.joints):
        assert np.array_equal(p[L.centre(j)], joint.centre)
        assert L.block("centre", j).label == f"centre[{joint.name}]"
    for d, dof in enumerate(human.dofs):
        assert np.array_equal(p[L.axis(d)], dof.axis)
    for k, mk in enumerate(human.markers):
        assert np.array_equal(p[L.marker(k)], mk.offset)
    assert np.array_equal(p[L.scales], np.ones(len(human.segments)))
    # Every entry of p in exactly one block, in order.
    covered = np.concatenate([np.arange(b.offset, b.offset + b.size) for b in L.blocks])
    assert np.array_equal(covered, np.arange(p.size))
    # The free columns: 1 per scale, 3 per centre and marker, 2 per hinge/universal axis, none per ball axis.
    hinge_axes = sum(len(j.dofs) for j in human.joints if j.kind in ("hinge", "universal"))
    assert L.n_free == len(human.segments) + 3 * len(human.joints) + 2 * hinge_axes + 3 * len(human.markers)
    assert len(L.free_names) == L.n_free == len(set(L.free_names))


def test_held_blocks_have_no_columns(human):
    knee = human.dof_index("knee_r")
    L = ParameterLayout(human, free=("centre", "axis"), held_axes=("knee_r",), held_segments=("hand_r",))
    assert L.block("axis", knee).held and L.axis_cols(knee).size == 0
    assert all(L.block("scale", i).held for i in range(len(human.segments)))
    assert all(L.block("marker", k).held for k in range(len(human.markers)))
    for j, joint in enumerate(human.joints):
        assert L.block("centre", j).held == (joint.parent == "hand_r")
    cols = np.concatenate([b.cols for b in L.free_blocks])
    assert np.array_equal(cols, np.arange(L.n_free))


def test_tangent_map_is_the_retraction_derivative(human):
    """Column k of T(p) against the central difference of retract(p, ±h e_k)."""
    L = ParameterLayout(human)
    rng = np.random.default_rng(1)
    P = human.parameters()
    P.scale[:] = 1 + 0.1 * rng.normal(size=P.scale.shape)
    p = P.vector()
    T = L.tangent_map(p)
    h = 1e-6
    for k in rng.choice(L.n_free, 40, replace=False):
        e = np.zeros(L.n_free)
        e[k] = h
        fd = (L.retract(p, e) - L.retract(p, -e)) / (2 * h)
        assert np.allclose(fd, T[:, k], atol=1e-7), L.free_names[k]
    # Axes stay unit after any step.
    q = L.retract(p, rng.normal(size=L.n_free))
    for d in L.axis_dofs:
        assert np.linalg.norm(q[L.axis(d)]) == pytest.approx(1.0, abs=1e-14)


def test_tangent_pattern_holds_every_tangent_map(human, human_kin):
    """T(p)'s nonzeros lie in tangent_pattern() at every p: at the base model's (offsets with exact zeros,
    axes along frame axes) and at random ones whose axes' tangent bases use other components; and the
    normal equations gathered on that one pattern (Problem.parameter_layout, built once) equal those
    gathered on T(p)'s own nonzeros."""
    from calibrate.solve.assembly import assemble, parameter_layout

    L = ParameterLayout(human)
    pattern = L.tangent_pattern()
    rng = np.random.default_rng(4)
    base = human.parameters().vector()
    bases_used = set()
    for trial in range(30):
        p = base.copy() if trial == 0 else base + 0.05 * rng.normal(size=base.size)
        T = L.tangent_map(p)
        assert not np.any((T != 0) & ~pattern)
        bases_used.add(np.packbits(T != 0).tobytes())
    assert len(bases_used) > 2  # T's own nonzeros changed with p; the pattern did not need to
    sim = simulate_squats(human, frames=12, noise_mm=1.0, seed=6)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(), human_kin)
    m = sim.motion
    p = sim.truth.vector() + 0.02 * rng.normal(size=base.size)
    state = State(np.column_stack([m.root_translation, np.zeros((12, 3)), m.angles]), m.root_quaternion.copy(), p)
    lin = problem.linearize(state)
    d, jz, jp, wrow, _ = lin.jacobian[:5]
    F, nz, n = lin.B.shape
    A, B, gz = np.empty((F, nz, nz)), np.empty((F, nz, n)), np.empty((F, nz))
    C, gp = assemble(d, wrow, jz, jp, problem._layout_z, parameter_layout(problem.groups, problem.tangent_map(p)),
                     A, B, gz, n)
    prior = lin.jacobian[5]
    r = problem.prior(p)[0]
    assert np.allclose(lin.A, A, rtol=1e-13, atol=0) and np.allclose(lin.B, B, rtol=1e-13, atol=1e-300)
    assert np.allclose(lin.C, C + prior.T @ prior, rtol=1e-12, atol=1e-12 * np.abs(C).max())
    assert np.allclose(lin.gp, gp + prior.T @ r, rtol=1e-12, atol=1e-12 * np.abs(gp).max())


def test_frame_layout(human):
    F = FrameLayout(human.n_dofs)
    Z = np.arange(3 * human.nz, dtype=float).reshape(3, human.nz)
    assert F.nz == human.nz
    assert np.array_equal(F.angles(Z)[:, 4], Z[:, F.angle(4)])
    assert F.dof(F.angle(7)) == 7
    t, a = np.ones((3, 3)), np.full((3, human.n_dofs), 2.0)
    W = F.coordinates(t, a)
    assert np.array_equal(W[:, F.translation], t) and not W[:, F.rotation].any() and np.array_equal(F.angles(W), a)


def test_problem_copies_leave_the_original_unchanged(human, human_kin):
    sim = simulate_squats(human, frames=4, noise_mm=1.0, seed=0)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(loss="huber"), human_kin)
    with pytest.raises(AttributeError):
        problem.loss = "linear"
    with pytest.raises(AttributeError):
        problem.base = human.parameters()
    linear = problem.with_loss("linear")
    assert linear.loss == "linear" and problem.loss == "huber" and linear.settings.loss_scale == 3.0
    mask = np.zeros(problem.seen.shape, dtype=bool)
    mask[1, 2] = True
    fewer = problem.without(mask)
    assert fewer.n_obs == problem.n_obs - 1 and problem.seen[1, 2] and not fewer.seen[1, 2]
    moved = human.parameters()
    moved.marker[0] += 0.01
    based = problem.with_base(moved)
    assert based.base is moved and problem.base is not moved
    # The prior sees the new base: its first marker residual is the 1 cm move over the prior SD.
    p = human.parameters().vector()
    r0 = problem.prior(p, jacobian=False)[0]
    r1 = based.prior(p, jacobian=False)[0]
    assert np.allclose(r1[:3] - r0[:3], -0.01 / problem.settings.priors.marker)


def test_solver_options(human, human_kin):
    s = Settings(max_iterations=7, ftol=1e-3, atol=0.1, xtol=1e-5, gtol=1e-4, geodesic=False)
    assert s.solver == SolverOptions(7, 1e-3, 0.1, 1e-5, 1e-4, False)
    assert Settings().solver == SolverOptions()
    with pytest.raises(ValueError):
        SolverOptions(ftol=0.0)
    sim = simulate_squats(human, frames=4, noise_mm=1.0, seed=0)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(free=()), human_kin)
    m = sim.motion
    state = State(FrameLayout.coordinates(m.root_translation, m.angles) + 0.05, m.root_quaternion.copy(),
                  sim.truth.vector())
    _, one = levenberg_marquardt(problem, state, SolverOptions(max_iterations=1), pose_only=True)
    assert one.iterations == 1 and not one.converged and "max_iterations (1)" in one.termination


def test_gauge_constraints_and_axis_bases_match_their_definitions(human, human_kin):
    """The gathered gauge constraints (Problem.gauge_constraints) against the definition written out
    segment by segment: for each gauged segment and turn axis w, the row Σ weight · (w × x) over the
    positions x it holds (at the subject's scale) and, through each axis's tangent basis, its axes;
    the root's shift rows; each hinge centre's slide along its axis.  And the tangent bases: unit,
    perpendicular to their axis and to each other."""
    sim = simulate_squats(human, frames=4, noise_mm=1.0, seed=0)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(), human_kin)
    L, m, pr = problem.layout, human, problem.settings.priors
    rng = np.random.default_rng(4)
    p = problem.retract_parameters(human.parameters().vector(), 0.05 * rng.normal(size=problem.n_free))
    rows = []
    for si, kind in problem._gauges:
        items = []
        s = p[L.scale(si)]
        for k in np.flatnonzero((problem.marker_segment == si) & ~problem.unseen):
            items.append((s * p[L.marker(k)], L.cols("marker", k), 1 / pr.marker**2, None))
        for ji in np.flatnonzero(problem.centre_segment == si):
            items.append((s * p[L.centre(ji)], L.cols("centre", ji), 1 / pr.centre**2, None))
            for name in m.joints[ji].dofs:
                d = m.dof_index(name)
                if d in problem.axis_dofs:
                    a = p[L.axis(d)] / np.linalg.norm(p[L.axis(d)])
                    items.append((a, L.axis_cols(d), 1 / pr.axis**2, perpendicular_basis(a)))
        if kind == "axis":
            j = next(j for j in m.joints if j.child == m.segments[si].name)
            a = p[L.axis(m.dof_index(j.dofs[-1]))]
            omegas = [a / np.linalg.norm(a)]
        else:
            omegas = list(np.eye(3))
        for w in omegas:
            r = np.zeros(problem.n_free)
            for x, cols, wt, B in items:
                v = wt * np.cross(w, x)
                r[cols] += v if B is None else v @ B
            rows.append(r)
        if kind == "rigid":
            for c in range(3):
                r = np.zeros(problem.n_free)
                for _, cols, wt, B in items:
                    if B is None:
                        r[cols[c]] += wt
                rows.append(r)
    kinds = {kind for _, kind in problem._gauges}
    assert {"rigid", "rotation", "axis"} <= kinds
    K = problem.gauge_constraints(p, slides=False)
    assert K.shape == (len(rows), problem.n_free)
    assert np.allclose(K, np.array(rows), rtol=1e-12, atol=1e-9)
    slides = problem.gauge_constraints(p)[len(rows):]
    assert slides.shape[0] == len(problem._slides) > 0
    for r, ji in zip(slides, problem._slides, strict=True):
        j = m.joints[ji]
        a = p[L.axis(m.dof_index(j.dofs[0]))]
        want = np.zeros(problem.n_free)
        want[L.cols("centre", ji)] = problem._urdf[j.urdf_joints[0]].rotation @ (a / np.linalg.norm(a))
        assert np.allclose(r, want, rtol=1e-12, atol=1e-15)
    A = L.axis_directions(p)
    B = perpendicular_bases(A)
    assert np.allclose(np.einsum("nij,nik->njk", B, B), np.eye(2), atol=1e-14)
    assert np.allclose(np.einsum("ni,nij->nj", A, B), 0.0, atol=1e-14)


def test_hinge_centres_slide_along_their_axes_without_moving_a_marker(human, human_kin):
    """Problem.slide_centres: every marker in every frame where it was (the problem's CasADi residuals, to
    1e-12 m), the priors' cost lower, no slide left that lowers it further (the
    priors' gradient along each hinge's slide is zero), and a second slide changes nothing."""
    sim = simulate_squats(human, frames=4, noise_mm=1.0, seed=0)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(), human_kin)
    rng = np.random.default_rng(7)
    p = problem.retract_parameters(sim.truth.vector(), 0.03 * rng.normal(size=problem.n_free))
    m = sim.motion
    state = State(FrameLayout.coordinates(m.root_translation, m.angles), m.root_quaternion.copy(), p)
    slid = State(state.Z, state.Q, problem.slide_centres(p))
    assert np.abs(slid.p - p).max() > 1e-3  # the random geometry had hinge centres off along their axes
    before = problem.marker_residuals(state)
    after = problem.marker_residuals(slid)
    assert np.nanmax(np.abs(after - before)) < 1e-12
    r0, _ = problem.prior(p, jacobian=False)
    r1, J1 = problem.prior(slid.p)
    assert r1 @ r1 < r0 @ r0
    # The slide directions at the slid point (centre along the axis, the child's contents back), as written out.
    L = problem.layout
    for ji in problem._slides:
        j = human.joints[ji]
        a = L.axis_direction(slid.p, human.dof_index(j.dofs[0]))
        g = np.zeros(problem.n_free)
        g[L.cols("centre", ji)] = problem._urdf[j.urdf_joints[0]].rotation @ a
        child = human.segment_index(j.child)
        for k in np.flatnonzero(problem.marker_segment == child):
            g[L.cols("marker", k)] = -a
        for jk in np.flatnonzero(problem.centre_segment == child):
            g[L.cols("centre", jk)] = -a
        assert abs(g @ (J1.T @ r1)) < 1e-8 * np.linalg.norm(J1.T @ r1), j.name
    assert np.abs(problem.slide_centres(slid.p) - slid.p).max() < 1e-9


def test_sparse_gram_and_dense_sum_repeated_nonzeros_as_the_dense_products():
    """The priors' Jacobian from its nonzeros (priors._dense, np.add.at) is the matrix np.bincount
    builds, bit for bit; its Gram matrix from the nonzeros (priors.sparse_gram: each row's products, a
    position repeated within a row and rows without any) equals JᵀJ of the dense matrix."""
    from calibrate.problem.priors import _dense, sparse_gram

    rng = np.random.default_rng(11)
    m, n = 40, 25
    rows = np.sort(rng.integers(0, m, 150))
    cols = rng.integers(0, n, 150)
    cols[1] = cols[0]
    rows[1] = rows[0]  # one position given twice
    vals = rng.standard_normal(150)
    J = _dense(rows, cols, vals, (m, n))
    ref = np.bincount(rows * n + cols, weights=vals, minlength=m * n).reshape(m, n)
    assert np.array_equal(J, ref)
    assert np.any(~J.any(axis=1))  # some rows without nonzeros
    np.testing.assert_allclose(sparse_gram(rows, cols, vals, n), J.T @ J, rtol=1e-13, atol=1e-13)
