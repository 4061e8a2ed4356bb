"""The still test's "one frame's SD" (calibrate.calibration.identifiability.coordinate_spreads on the blocks
pipeline._frame_blocks forms) against Monte Carlo: one pose seen through many frames of white noise, each frame's
pose fitted at the true geometry; the SD of a coordinate's estimate over those frames is what one frame's markers
fix it to."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.calibration.identifiability import coordinate_spreads
from calibrate.calibration.pipeline import _frame_blocks
from calibrate.calibration.start import absolute
from calibrate.model.blocks import FrameLayout
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.problem.state import State
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns
from calibrate.solve.lm import levenberg_marquardt

FRAMES = 400
NOISE = 0.001  # m, white
TAU = 16.0  # frames: a correlation time the learnt noise can reach (its weights' SD NOISE * sqrt(TAU))
STILL_WEIGHT = 0.05  # a static's frame counted as a twentieth of one beside a walk (Settings.still_weight)


def test_one_frames_sd_is_what_one_frames_markers_fix(human, human_kin):
    """Weighted as the solver weighs a static beside a walk (a correlation time of 16 frames, each frame counted
    0.05 times), the blocks put one frame's SD sqrt(16 / 0.05) = 18 times wider than the frames' own scatter
    shows; the still test's blocks (the markers' scatter, every frame once) put it where the scatter is.  Read
    from the solver's weights, pig_walk's ankles (17 deg SD over its walk, 2.2 deg one frame) were called still."""
    sim = simulate_squats(human, frames=2, noise_mm=0.0, seed=11)
    clean = marker_columns(human, sim.trial)[:1]
    rng = np.random.default_rng(4)
    obs = np.repeat(clean, FRAMES, axis=0) + rng.normal(0.0, NOISE, (FRAMES, *clean.shape[1:]))
    m = sim.motion
    Z = np.repeat(np.column_stack([m.root_translation, np.zeros((2, 3)), m.angles])[:1], FRAMES, axis=0)
    state = State(Z, np.repeat(m.root_quaternion[:1], FRAMES, axis=0), sim.truth.vector())
    n_markers = len(human.markers)
    problem = Problem(human, obs, Settings(), human_kin).with_noise(np.full(n_markers, NOISE * np.sqrt(TAU)))
    problem = problem.with_frame_weight(np.full(FRAMES, STILL_WEIGHT))
    fitted, _ = levenberg_marquardt(problem, state, pose_only=True, max_iterations=30)
    angles = FrameLayout.angles(absolute(problem.kin, fitted)[0])
    hinges = [d for j in human.joints if j.kind == "hinge" for d in j.dofs]
    empirical = {d: float(np.std(angles[:, human.dof_index(d)])) for d in hinges}

    ours = coordinate_spreads(human, angles, _frame_blocks(problem, fitted, np.full(n_markers, NOISE)), Settings())
    ratio = np.array([ours[d][1] / empirical[d] for d in hinges])
    assert np.median(ratio) == pytest.approx(1.0, abs=0.1), dict(zip(hinges, ratio.round(2), strict=True))
    assert ratio.min() > 0.8 and ratio.max() < 1.25, dict(zip(hinges, ratio.round(2), strict=True))
    # Each spread is the Monte Carlo's own figure (the same angles), so the still test compares like with like.
    assert all(ours[d][0] == pytest.approx(empirical[d], rel=1e-12) for d in hinges)

    solver = coordinate_spreads(human, angles, problem.linearize(fitted, with_parameters=False).A, Settings())
    wide = np.median([solver[d][1] / empirical[d] for d in hinges])
    assert wide == pytest.approx(np.sqrt(TAU / STILL_WEIGHT), rel=0.1)


def test_a_trade_that_turned_the_axes_locks_the_joint_beyond_the_bare_segment(human):
    """trading_locks' second rule (the pair's axes carried past the limit, neither joint still): the trials cannot
    say which of the ankle and the subtalar turns, so the one beyond the markerless talus (the subtalar) is locked,
    whichever one frame's markers fix less well.  Expert1's drop jump, right foot, at the start: ankle 0.86 deg per
    frame, subtalar 0.83 (by that alone the ankle was locked, and the subtalar's axis turned 48 deg to do its
    work).  Under the limit, nothing."""
    from calibrate.calibration.identifiability import trading_locks

    deg = np.radians
    at_start = {"ankle_r": (deg(15.17), deg(0.86)), "subtalar_r": (deg(10.23), deg(0.83))}
    solved = {"ankle_r": (deg(22.06), deg(0.54)), "subtalar_r": (deg(15.49), deg(0.65))}
    turns = {"ankle_r": deg(31.9), "subtalar_r": deg(18.1)}
    for start in (at_start, {**at_start, "subtalar_r": (deg(10.23), deg(0.9))}):
        (lock,) = trading_locks(human, solved, None, (), turns, start, deg(20.0))
        assert (lock.coordinate, lock.bare, lock.neighbours, lock.value) == ("subtalar_r", "talus_r", ("ankle_r",), 0.0)
        assert (lock.per_frame, lock.neighbour_per_frame, lock.turned) == (start["subtalar_r"][1], (deg(0.86),),
                                                                           turns["ankle_r"])
        assert "the one beyond talus_r (of joints on one side of it, the less-seen) is held" in lock.text()
    assert trading_locks(human, solved, None, (), turns, at_start, deg(40.0)) == ()
