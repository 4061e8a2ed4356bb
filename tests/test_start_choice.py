"""choose_start: of several start geometries, the one whose basin ends at the lowest cost on the
subsample starts the calibration; one that already fits to the stated noise is taken at once."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.start import choose_start, start_poses
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import Parameters, load_model
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns
from calibrate.solve.lm import levenberg_marquardt


@pytest.fixture(scope="module")
def human():
    from pathlib import Path

    return load_model(Path(__file__).resolve().parents[1] / "models" / "human.urdf")


@pytest.fixture(scope="module")
def human_kin(human):
    return build_kinematics(human)


def _wrong(p: Parameters) -> Parameters:
    """A start far from the subject: every segment 30 % too large."""
    return Parameters(p.scale * 1.3, p.centre.copy(), p.axis.copy(), p.marker.copy())


def test_the_lower_cost_start_is_chosen(human, human_kin):
    sim = simulate_squats(human, frames=200, noise_mm=1.0, seed=11)
    obs = marker_columns(human, sim.trial)
    loose = Settings(noise=0.0005)  # half the simulated noise: no start fits to it, so the costs decide
    problem = Problem(human, obs, loose, human_kin)
    truth = sim.truth
    said: list[str] = []
    # the wrong start first, so that the good-fit shortcut cannot decide
    chosen, note = choose_start(problem, obs, [slice(0, len(obs))], {"a wrong start": _wrong(truth),
                                                                     "the truth": truth}, said.append)
    assert np.allclose(chosen.vector(), truth.vector())
    assert note.startswith("started from the truth: of a wrong start (cost ")
    # the costs in the note are the ones each start reaches: recompute the truth's independently
    # (the same subsample, poses and 30 iterations) and compare with the note's figure
    costs = [float(x.split(")")[0]) for x in note.split("(cost ")[1:]]
    assert costs[1] < costs[0]
    seen = np.all(np.isfinite(obs), axis=2)
    from calibrate.calibration.start import START_FRAMES, START_ITERATIONS, coarse_frames
    coarse = coarse_frames(seen, START_FRAMES)
    sub = Problem(human, obs[coarse], loose, human_kin)
    st = start_poses(human_kin, obs[coarse], truth, stride=1, evaluator=sub.frame_evaluator(truth.vector()))
    _, summary = levenberg_marquardt(sub, st, max_iterations=START_ITERATIONS)
    assert summary.final_cost == pytest.approx(costs[1], rel=1e-3)


def test_a_start_at_the_noise_is_taken_at_once(human, human_kin):
    sim = simulate_squats(human, frames=200, noise_mm=1.0, seed=12)
    obs = marker_columns(human, sim.trial)
    problem = Problem(human, obs, Settings(), human_kin)
    said: list[str] = []
    chosen, note = choose_start(problem, obs, [slice(0, len(obs))], {"the truth": sim.truth,
                                                                     "a wrong start": _wrong(sim.truth)}, said.append)
    assert np.allclose(chosen.vector(), sim.truth.vector())
    assert "no other start was tried" in note
    assert not any("a wrong start" in s for s in said)  # never solved


def test_calibration_reports_its_start(human, human_kin):
    sim = simulate_squats(human, frames=150, noise_mm=1.0, seed=13)
    cal = calibrate(human, sim.trial, kinematics=human_kin)
    assert sum(n.startswith("started from ") for n in cal.seed.notes) == 1


def test_a_run_advanced_in_parts_takes_the_steps_of_one_run(human, human_kin):
    """lm.Run, which choose_start's race pauses after START_CHECK steps: advanced 3, then 4 steps, then to
    its end, suspended (every frame block and buffer let go) between the parts, it reaches the very point
    (bit for bit) and summary that one levenberg_marquardt call does."""
    from calibrate.solve.lm import Run

    sim = simulate_squats(human, frames=40, noise_mm=1.0, seed=14)
    obs = marker_columns(human, sim.trial)
    problem = Problem(human, obs, Settings(), human_kin)
    start = _wrong(sim.truth)
    st = start_poses(human_kin, obs, start, stride=1, evaluator=problem.frame_evaluator(start.vector()))
    st = replace(st, p=start.vector())
    whole, s1 = levenberg_marquardt(problem, st, max_iterations=15)
    run = Run(Problem(human, obs, Settings(), human_kin), st, max_iterations=15)
    assert run.advance(3).summary.iterations == 3 and not run.done
    assert run.cost == run.summary.cost_history[-1] < s1.initial_cost
    run.suspend()
    assert run._steps.blocks is None and not run._steps.work  # nothing of the frames' blocks held
    run.advance(7)
    assert run.summary.iterations == 7
    run.suspend()
    parts, s2 = run.finish()
    assert run.done and s2.iterations == s1.iterations > 7
    assert np.array_equal(parts.p, whole.p) and np.array_equal(parts.Z, whole.Z)
    assert s2.cost_history == s1.cost_history and s2.termination == s1.termination


def test_a_start_far_ahead_after_the_check_is_taken_there(human, human_kin):
    """The race: the truth against a start twice the subject's size; after START_CHECK steps each the
    truth's cost is under START_LEAD times the other's, so neither is solved further, and the note's
    costs are those of START_CHECK steps (recomputed here)."""
    from calibrate.calibration.start import START_CHECK, START_FRAMES, coarse_frames

    sim = simulate_squats(human, frames=200, noise_mm=1.0, seed=15)
    obs = marker_columns(human, sim.trial)
    loose = Settings(noise=0.0005)  # no start fits to half the simulated noise: the race decides
    far = Parameters(sim.truth.scale * 2.0, sim.truth.centre.copy(), sim.truth.axis.copy(), sim.truth.marker.copy())
    problem = Problem(human, obs, loose, human_kin)
    chosen, note = choose_start(problem, obs, [slice(0, len(obs))], {"a far start": far, "the truth": sim.truth},
                                lambda s: None)
    assert np.allclose(chosen.vector(), sim.truth.vector())
    assert f"({START_CHECK} iterations each: one far ahead)" in note
    costs = [float(x.split(")")[0]) for x in note.split("(cost ")[1:]]
    coarse = coarse_frames(np.all(np.isfinite(obs), axis=2), START_FRAMES)
    for params, cost in zip((far, sim.truth), costs, strict=True):
        sub = Problem(human, obs[coarse], loose, human_kin)
        st = start_poses(human_kin, obs[coarse], params, stride=1, evaluator=sub.frame_evaluator(params.vector()))
        _, summary = levenberg_marquardt(sub, replace(st, p=params.vector()), max_iterations=START_CHECK)
        assert summary.final_cost == pytest.approx(cost, rel=1e-3)
    assert costs[1] < 0.75 * costs[0]


def test_the_local_start_from_the_default_pose_is_taken_only_when_it_fits_better(human, human_kin):
    """FrameSolver.global_start(local=True): the better fit of the joint-by-joint search and a local solve from
    the default pose, each solved to convergence; on a simulated subject's frames (its true geometry) it fits
    to the noise and never worse than the joint-by-joint start alone."""
    from calibrate.solve.ik import FrameSolver

    sim = simulate_squats(human, frames=60, noise_mm=1.0, seed=4)
    obs = marker_columns(human, sim.trial)
    fs = FrameSolver(human_kin, sim.truth.vector())
    every = np.arange(human.nz)
    for f in (0, 25, 50):
        seen = np.isfinite(obs[f, :, 0])
        idx = np.flatnonzero(seen)
        zj, qj = fs.global_start(obs[f], seen)
        cost_j = fs.solve(zj, qj, obs[f], idx, every, 200)[2]
        zl, ql = fs.global_start(obs[f], seen, local=True)
        cost_l = fs.solve(zl, ql, obs[f], idx, every, 200)[2]
        assert cost_l <= cost_j * (1 + 1e-9) + 1e-15
        assert np.sqrt(cost_l / (3 * idx.size)) < 2e-3  # per coordinate: the 1 mm noise, not another basin
