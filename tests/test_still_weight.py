"""A still trial counted as a few frames (Settings.still_weight; Problem.frame_weight).

A frame of weight w must count exactly as w copies of itself in the cost and the normal equations; the
pipeline must give a static trial beside a moving one the stated total weight (its subsample too), leave
everything as it was when the option is off, and still calibrate the simulated subject."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.calibration import pipeline as pipeline_module
from calibrate.calibration.html import report_html
from calibrate.calibration.pipeline import _still_lengths, _trial_motion, calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.calibration.start import spread_frames, subsample_weight
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.problem.state import State
from calibrate.simulation.simulate import simulate_squats, simulate_static
from calibrate.solve.ik import marker_columns


@pytest.fixture(scope="module")
def copies(human, human_kin):
    """12 squat frames with frame f repeated count[f] times, and each once with weight count[f]; the
    geometry moved off the truth."""
    sim = simulate_squats(human, frames=12, noise_mm=1.0, seed=4)
    obs = marker_columns(human, sim.trial)
    obs[5, 3] = np.nan  # a gap
    count = np.array([3, 1, 2, 1, 4, 1, 1, 2, 1, 1, 5, 1])
    m = sim.motion
    Z = np.column_stack([m.root_translation, np.zeros((m.times.size, 3)), m.angles])
    Q = m.root_quaternion.copy()
    whole = Problem(human, obs, Settings(), human_kin)
    p = whole.retract_parameters(sim.truth.vector(), 0.002 * np.random.default_rng(0).normal(size=whole.n_free))
    weighted = whole.with_frame_weight(count.astype(float))
    copied = Problem(human, np.repeat(obs, count, axis=0), Settings(), human_kin)
    Zc, Qc = np.repeat(Z, count, axis=0), np.repeat(Q, count, axis=0)
    return (weighted, State(Z, Q, p)), (copied, State(Zc, Qc, p)), count


def test_a_weighted_frame_counts_as_its_copies_in_the_cost_and_normal_equations(copies):
    (weighted, s_w), (copied, s_c), count = copies
    assert weighted.cost(s_w) == pytest.approx(copied.cost(s_c), rel=1e-12)
    lw, lc = weighted.linearize(s_w), copied.linearize(s_c)
    assert np.allclose(lw.C, lc.C, rtol=1e-10, atol=1e-9 * np.abs(lc.C).max())
    assert np.allclose(lw.gp, lc.gp, rtol=1e-10, atol=1e-9 * np.abs(lc.gp).max())
    first = np.concatenate([[0], np.cumsum(count)[:-1]])  # each frame's first copy
    assert np.allclose(lw.A, count[:, None, None] * lc.A[first], rtol=1e-10, atol=1e-12 * np.abs(lc.A).max())
    assert np.allclose(lw.B, count[:, None, None] * lc.B[first], rtol=1e-10, atol=1e-12 * np.abs(lc.B).max())


def test_frame_weights_are_checked_and_carried(human, human_kin):
    sim = simulate_squats(human, frames=6, noise_mm=1.0, seed=1)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(), human_kin)
    with pytest.raises(ValueError, match="frame weights"):
        problem.with_frame_weight(np.array([1.0, 0.0, 2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="frame weights"):
        problem.subset(np.arange(3), np.ones(2))
    assert problem.with_frame_weight(np.ones(6)).frame_weight is None  # every frame once: no weights
    w = problem.with_frame_weight(np.arange(1.0, 7.0))
    assert np.array_equal(w.subset(np.array([1, 4])).frame_weight, [2.0, 5.0])
    assert np.array_equal(w.with_noise(np.full(len(human.markers), 0.002)).frame_weight, np.arange(1.0, 7.0))
    held = w.with_settings(Settings(hold_axes=("knee_r",)), sigma=w.sigma)
    assert np.array_equal(held.frame_weight, np.arange(1.0, 7.0))


@pytest.fixture(scope="module")
def static_and_squats(human):
    squats = simulate_squats(human, frames=300, noise_mm=1.0, seed=5)
    static = simulate_static(human, squats.truth, frames=400, noise_mm=1.0, seed=5)
    return squats, static


def test_a_static_trial_counts_as_the_stated_frames_and_keeps_that_share_of_the_subsample(human, static_and_squats):
    squats, static = static_and_squats
    trials = [static.trial, squats.trial]
    motion = _trial_motion(human, trials)
    assert motion[0] < pipeline_module.STILL_MOTION <= motion[1]
    assert _still_lengths(trials, motion, 16.0) == [16.0, 300.0]
    assert _still_lengths(trials, motion, 0.0) is None  # off
    assert _still_lengths([static.trial, static.trial], [motion[0]] * 2, 16.0) is None  # nothing moves
    obs = np.concatenate([marker_columns(human, t) for t in trials])
    spans = [slice(0, 400), slice(400, 700)]
    seen = np.all(np.isfinite(obs), axis=2)
    frames = spread_frames(seen, spans, 120, [16.0, 300.0])
    weight = subsample_weight(frames, spans, [16.0, 300.0])
    in_static = frames < 400
    # The static's share of the subsample's weight is its share of the whole problem's: 16 of 316 frames.
    share = weight[in_static].sum() / weight.sum()
    assert share == pytest.approx(16 / 316, rel=0.05)
    assert np.all(weight[~in_static] == 1.0) and in_static.sum() < 12
    assert subsample_weight(frames, spans, None) is None


def test_a_calibration_with_the_static_weighted_finds_the_simulated_subject(human, static_and_squats):
    """The hips' and knees' centres (scaled, in their parents' frames) as near the simulator's truth as the
    run with every frame counted once (the simulator's static has no skin artefact to down-weigh)."""
    squats, static = static_and_squats
    said: list[str] = []
    runs = {w: calibrate(human, [static.trial, squats.trial], Settings(still_weight=w, outliers=0.0),
                         progress=lambda p: said.append(str(p)))
            for w in (16.0, 0.0)}
    assert sum("count as 16 frames in all" in s for s in said) == 1  # said once: by the weighted run

    def error(cal) -> np.ndarray:
        parent = [cal.model.segment_index(j.parent) for j in cal.model.joints]
        ours = cal.params.scale[parent][:, None] * cal.params.centre
        true = squats.truth.scale[parent][:, None] * squats.truth.centre
        legs = [j.name.startswith(("hip", "knee")) for j in human.joints]
        return np.linalg.norm(ours - true, axis=1)[legs]

    assert runs[16.0].converged
    assert runs[16.0].trial_weights == (16.0, 300.0) and runs[0.0].trial_weights == ()
    report = calibration_report(runs[16.0])
    assert report["trials"][0]["counted_as_frames"] == 16.0 and "counted_as_frames" not in report["trials"][1]
    assert "its frames count as 16 in all" in summary_text(runs[16.0])
    assert "400 (counted as 16)" in report_html(report)
    assert "count as" not in summary_text(runs[0.0])
    assert np.median(error(runs[16.0])) < np.median(error(runs[0.0])) + 0.001, (error(runs[16.0]), error(runs[0.0]))
    assert np.max(error(runs[16.0])) < 0.02


def test_still_weight_is_validated():
    with pytest.raises(ValueError, match="still_weight"):
        Settings(still_weight=-1.0)
