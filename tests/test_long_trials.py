"""Long trials in bounded memory (issue 22): the frame blocks formed chunk by chunk give the same
solve, covariance and leverage as the whole trial's blocks held at once; the products that replace
B_f in the later passes equal B_f's; readers hand their one marker array to the trial; the simulator
writes a TRC where a C3D cannot hold the frames; progress estimates the time left."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibrate.calibration.noise import leverage
from calibrate.calibration.records import IterationClock
from calibrate.io.read import read_trial
from calibrate.io.trial import Trial
from calibrate.problem.options import SolverOptions
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats, write_simulation
from calibrate.solve import chunks
from calibrate.solve.ik import marker_columns
from calibrate.solve.lm import State, covariance, levenberg_marquardt

F = 30


@pytest.fixture(scope="module")
def squats(human, human_kin):
    sim = simulate_squats(human, frames=F, noise_mm=1.0, seed=3)
    obs = marker_columns(human, sim.trial)
    obs[4, 7] = np.nan  # a gap
    problem = Problem(human, obs, Settings(), human_kin)
    m = sim.motion
    Z = np.column_stack([m.root_translation, np.zeros((F, 3)), m.angles]) + 0.02
    return problem, State(Z, m.root_quaternion.copy(), human.parameters().vector())


def _budget(problem: Problem, frames: float) -> Problem:
    """The problem with a memory budget of `frames` frames' blocks (ProblemOptions.memory_mb)."""
    mb = chunks.frame_bytes(problem, True) * frames / 1e6
    return problem.with_settings(replace(problem.settings, memory_mb=mb))


def test_the_budget_counts_the_eliminations_packed_y(squats):
    """frame_bytes counts a frame's Y by its nonzeros (Problem.y_entries): the elimination's packed buffer
    holds exactly that many per frame, at a point other than the one y_entries was built at."""
    from calibrate.solve.schur import eliminate

    problem, state = squats
    lin = problem.linearize(replace(state, p=state.p * 1.01))
    el = eliminate(lin, np.full(lin.gz.shape, 1e-3))
    nz, n = lin.B.shape[1:]
    assert el.Y.layout.size == F * problem.y_entries() < F * nz * n
    assert chunks.frame_bytes(problem, True) - chunks.frame_bytes(problem, False) == \
        8 * (nz * n + problem.y_entries() + problem.output_sizes[2])


@pytest.mark.parametrize("kept", [0, 2], ids=["none-kept", "two-kept"])
def test_chunked_solve_equals_the_whole(squats, monkeypatch, kept):
    """Levenberg-Marquardt (with its geodesic acceleration) on blocks formed chunk by chunk, none or two
    chunks kept, takes the same steps as on the whole trial's blocks: the same iterations, and the
    solution and cost to the last digits (the sums only run in another order)."""
    problem, state = squats
    monkeypatch.setattr(chunks, "CHUNK_FRAMES", 7)
    whole, s_whole = levenberg_marquardt(problem, state, SolverOptions(max_iterations=12))
    chunked = _budget(problem, 7 * (kept + chunks.SCRATCH_CHUNKS) + 0.5)
    blocks = chunks.FrameBlocks(chunked, state, True, chunked.settings.memory_mb * 1e6)
    assert len(blocks.slices) == 5 and blocks.n_kept == kept
    part, s_part = levenberg_marquardt(chunked, state, SolverOptions(max_iterations=12))
    assert s_part.iterations == s_whole.iterations and s_part.accepted == s_whole.accepted
    assert s_part.final_cost == pytest.approx(s_whole.final_cost, rel=1e-12)
    assert np.abs(part.Z - whole.Z).max() < 1e-9 and np.abs(part.p - whole.p).max() < 1e-9
    # Pose-only runs go through the same passes.
    pz, _ = levenberg_marquardt(chunked, state, pose_only=True, max_iterations=3)
    wz, _ = levenberg_marquardt(problem, state, pose_only=True, max_iterations=3)
    assert np.abs(pz.Z - wz.Z).max() < 1e-9


def test_blocks_eliminated_as_they_are_formed(squats, monkeypatch):
    """The first step after each linearization uses the elimination made while the blocks were formed:
    a chunk not kept is formed with its coupling block again only for the steps after a rejected one."""
    problem, state = squats
    monkeypatch.setattr(chunks, "CHUNK_FRAMES", 7)
    chunked = _budget(problem, 7 * chunks.SCRATCH_CHUNKS + 0.5)  # five chunks, none kept
    formed: list[str] = []
    linearize = Problem.linearize

    def counting(self, *args, **kwargs):
        formed.append(kwargs.get("parts", "all"))
        return linearize(self, *args, **kwargs)

    monkeypatch.setattr(Problem, "linearize", counting)
    _, s = levenberg_marquardt(chunked, state, SolverOptions(max_iterations=12))
    assert s.accepted >= 3
    assert formed.count("coupling") == 5 * (s.iterations - s.accepted)  # pass 1 of the steps after a rejection
    # Every linearization, eliminated as formed: the start and each accepted point but the last if the
    # run ended on its convergence test.
    assert formed.count("all") in (5 * s.accepted, 5 * (s.accepted + 1))


def test_chunked_covariance_and_leverage_equal_the_whole(squats, monkeypatch):
    problem, state = squats
    monkeypatch.setattr(chunks, "CHUNK_FRAMES", 4)
    chunked = _budget(problem, 0.5)
    a, b = covariance(problem, state), covariance(chunked, state)
    # on the scale of the SDs (each entry over sqrt(C_ii C_jj)): the matrix is the inverse of a Schur
    # complement of condition ~1e20, whose smallest entries carry the sums' order at 1e-7 relative
    sd = np.sqrt(np.outer(np.diag(a.matrix), np.diag(a.matrix)))
    assert np.max(np.abs(b.matrix - a.matrix) / sd) < 1e-7
    assert np.allclose(b.prior_only, a.prior_only)
    (h1, d1), (h2, d2) = leverage(problem, state), leverage(chunked, state)
    assert np.allclose(h1, h2, rtol=1e-10, atol=1e-12) and np.array_equal(d1, d2)
    assert 0.0 < h1[problem.seen].mean() < 1.0


def test_cost_in_pieces_equals_the_residuals_summed(squats, monkeypatch):
    """Problem.cost, formed a few frames at a time, equals ½ Σ (|r| / σ)² over every marker position
    (the residuals of all frames at once) plus the priors and joint limits."""
    import calibrate.problem.problem as problem_module

    problem, state = squats
    monkeypatch.setattr(problem_module, "COST_FRAMES", 7)  # 30 frames: four whole pieces and a short one
    r = problem.marker_residuals(state)
    data = 0.5 * np.nansum(np.sum(r**2, axis=2) / problem.sigma**2)
    prior, _ = problem.prior(state.p, jacobian=False)
    expect = data + 0.5 * float(prior @ prior) + 0.5 * float(np.sum(problem.limits(state.Z) ** 2))
    assert problem.loss == "linear" and data > 0
    assert problem.cost(state) == pytest.approx(expect, rel=1e-12)


def test_coupling_products_equal_the_coupling_blocks(squats):
    """B_f dp and Σ_f B_f' u_f from the Jacobian alone (the passes that do not form B_f) equal the
    products with the assembled B_f."""
    problem, state = squats
    lin = problem.linearize(state)
    frames = problem.linearize(state, parts="frames")
    assert frames.B.shape[2] == 0 and np.array_equal(frames.A, lin.A) and np.array_equal(frames.gz, lin.gz)
    rng = np.random.default_rng(0)
    dp = rng.normal(size=problem.n_free)
    u = rng.normal(size=(F, problem.model.nz))
    ref = np.matmul(lin.B, dp)
    got = problem.coupling_times(frames, problem.tangent_map(state.p) @ dp)
    assert np.allclose(got, ref, rtol=1e-10, atol=1e-10 * np.abs(ref).max())
    ref_t = np.einsum("fij,fi->j", lin.B, u)
    assert np.allclose(problem.coupling_transpose(frames, u), ref_t, rtol=1e-10, atol=1e-10 * np.abs(ref_t).max())
    # Without B, the linearization's C and g_p are those of the full one ('no_coupling').
    nc = problem.linearize(state, parts="no_coupling")
    assert nc.B.shape[2] == 0 and np.allclose(nc.C, lin.C) and np.allclose(nc.gp, lin.gp)


def test_trial_takes_a_readers_array_without_copying(tmp_path):
    """A read-only float64 array that owns its memory becomes the trial's own (the readers' one copy);
    anything else is copied, so the trial never changes under its caller."""
    a = np.zeros((5, 2, 3))
    a.flags.writeable = False
    t = Trial(labels=("A", "B"), markers=a, rate=100.0)
    assert t.markers is a
    b = np.zeros((5, 2, 3))
    t = Trial(labels=("A", "B"), markers=b, rate=100.0)
    assert not np.shares_memory(t.markers, b) and not t.markers.flags.writeable
    c = np.zeros((5, 2, 3))
    c[1, 0, 2] = np.inf
    c.flags.writeable = False
    t = Trial(labels=("A", "B"), markers=c, rate=100.0)  # an infinite coordinate: a gap, in a copy
    assert np.isnan(t.markers[1, 0]).all() and c[1, 0, 2] == np.inf


def test_long_simulation_written_as_trc_and_read_back(human, tmp_path, monkeypatch):
    """More frames than a C3D file holds: the simulator writes trial.trc, read back in metres as the
    one (read-only) marker array of the trial."""
    import calibrate.simulation.simulate as simulate

    monkeypatch.setattr(simulate, "C3D_MAX_FRAMES", 40)
    sim = simulate_squats(human, frames=50, noise_mm=1.0, seed=1)
    paths = write_simulation(sim, tmp_path)
    assert paths["trial"].name == "trial.trc" and not (tmp_path / "trial.c3d").exists()
    back = read_trial(paths["trial"])
    assert back.markers.base is None and not back.markers.flags.writeable
    assert np.allclose(back.markers, sim.trial.markers, atol=1e-6, equal_nan=True)


def test_iteration_clock_estimates_the_iterations_left():
    """Decreases halving (50, 25) with atol 0.5: log(0.5/25)/log(0.5) = 5.6, so 6 more iterations."""
    said = []
    clock = IterationClock(said.append, "all frames, ", atol=0.5, ftol=1e-12)
    for it, cost in enumerate((100.0, 50.0, 25.0), start=1):
        clock(it, cost, 1e-3)
    assert "about" not in str(said[1]) and "about 6 more" in str(said[2])
    assert said[2].stage == "solve" and str(said[2]).startswith("solve: all frames, iteration   3")


def test_nanmedian_first_is_numpys():
    """The jump detector's median over a few frames' steps (seed.seeding.nanmedian_first) is numpy's
    nanmedian, gaps (NaN) and all-NaN columns included."""
    import warnings

    from calibrate.seed.seeding import nanmedian_first

    rng = np.random.default_rng(2)
    for shape in [(6, 500, 3), (5, 40, 3), (1, 7, 2)]:
        a = rng.normal(size=shape)
        a[rng.random(shape) < 0.3] = np.nan
        a[:, 3] = np.nan
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            ref = np.nanmedian(a, axis=0)
        assert np.array_equal(np.isnan(ref), np.isnan(nanmedian_first(a)))
        assert np.allclose(nanmedian_first(a), ref, equal_nan=True)


def test_larger_subsamples_reach_the_same_minimum(human, monkeypatch):
    """A long trial passes through larger evenly spaced subsamples before every frame (pipeline
    LEVEL_GROWTH, LEVEL_ROOM; here scaled down to a 600-frame trial): the report lists them, and the
    result is the minimum of the whole problem all the same — the geometry and the cost those of
    the run without them, to the solver's tolerances."""
    from calibrate.calibration import pipeline
    from calibrate.calibration.pipeline import calibrate
    from calibrate.calibration.report import calibration_report

    sim = simulate_squats(human, frames=600, noise_mm=1.0, seed=2)
    settings = Settings(learn_noise=False, outliers=0.0)
    monkeypatch.setattr(pipeline, "LEVEL_GROWTH", 2)
    monkeypatch.setattr(pipeline, "LEVEL_ROOM", 2)
    with_levels = calibrate(human, sim.trial, settings)
    monkeypatch.setattr(pipeline, "LEVEL_ROOM", 10**9)
    without = calibrate(human, sim.trial, settings)
    levels = with_levels.summary.levels
    assert len(levels) == 1 and 200 <= levels[0][0] <= 320 and levels[0][1] >= 1, levels
    assert without.summary.levels == []
    assert calibration_report(with_levels)["solver"]["levels"] == [{"frames": levels[0][0], "iterations": levels[0][1]}]
    assert with_levels.summary.converged and without.summary.converged
    cost_a, cost_b = with_levels.summary.final_cost, without.summary.final_cost
    assert abs(cost_a - cost_b) < 1e-4 * cost_b, (cost_a, cost_b)
    def centres(cal):  # every joint centre in its parent segment's frame, scaled (m)
        parent = [cal.model.segment_index(j.parent) for j in cal.model.joints]
        return cal.params.scale[parent][:, None] * cal.params.centre

    d = np.linalg.norm(centres(with_levels) - centres(without), axis=1)
    foot = np.array([j.name.startswith(("ankle", "subtalar", "wrist")) for j in human.joints])
    knee = np.array([j.name.startswith("knee") for j in human.joints])
    # 0.1 mm (the ball centres' noise here is about 0.7 mm).  The foot hinges' centres, which squats
    # hardly identify (docs/benchmarks.md: the foot axes' Cramér-Rao table), and the wrists' lie on flat
    # valleys where either run stops within the tolerances: measured 0.3-1.9 mm apart (subtalar), 0.22 mm
    # (wrist_l), the costs equal to 0.12 (χ² 0.25, under the solver's atol).  A knee centre's place along
    # its axis is where the priors want it (Problem.slide_centres), weighed against the shank's contents,
    # the ankle centre among them: measured 0.11 / 0.34 mm apart.
    assert d[~foot & ~knee].max() < 1e-4, d[~foot & ~knee].max()
    assert d[knee].max() < 5e-4, d[knee].max()
    assert d[foot].max() < 3e-3, d[foot].max()


def test_motion_csv_reports_progress_and_reads_back_exactly(tmp_path, monkeypatch):
    """The motion CSV is formatted a block of frames at a time, reporting the share done after each
    block; every number reads back bit for bit (shortest round-trip repr), NaN included."""
    from calibrate.io import motion as motion_io

    monkeypatch.setattr(motion_io, "CSV_ROWS", 5)
    rng = np.random.default_rng(1)
    q = rng.normal(size=(12, 4))
    angles = rng.normal(size=(12, 3)) * 10.0 ** rng.integers(-9, 3, size=(12, 3))
    angles[3, 1] = np.nan
    m = motion_io.Motion(np.arange(12) / 100.0, rng.normal(size=(12, 3)), q / np.linalg.norm(q, axis=1)[:, None],
                         angles, ("a", "b", "c"))
    shares: list[float] = []
    (tmp_path / "m.csv").write_text(motion_io.motion_csv_text(m, shares.append))
    assert shares == [5 / 12, 10 / 12, 1.0]
    back = motion_io.read_motion_csv(tmp_path / "m.csv")
    for a, b in ((back.times, m.times), (back.root_translation, m.root_translation),
                 (back.root_quaternion, m.root_quaternion), (back.angles, m.angles)):
        assert np.array_equal(a, b, equal_nan=True)
    assert back.dof_names == m.dof_names
