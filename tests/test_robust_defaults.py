"""Robust defaults on real-looking data: the noise learnt from the residuals, spikes and label swaps
rejected, the left/right symmetry prior, and a start that fits the subject's size."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import prior_jacobian_by_differences

from calibrate.calibration.noise import NOISE_TAU_SECONDS, learned_noise, leverage, tau_cap
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.result import rms
from calibrate.calibration.start import start_poses
from calibrate.errors import CalibrateError
from calibrate.io.config import settings_from_dict
from calibrate.io.trial import Trial
from calibrate.model.model import Parameters
from calibrate.problem.priors import symmetry_pairs
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Priors, Settings
from calibrate.problem.state import State
from calibrate.seed.seeding import seed_parameters, size_from_markers
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns
from calibrate.solve.lm import covariance, levenberg_marquardt


def _with_markers(sim, markers: np.ndarray) -> Trial:
    return Trial(sim.trial.labels, markers, sim.trial.rate, 0, None)


def _truth_state(sim) -> tuple[np.ndarray, np.ndarray]:
    m = sim.motion
    return np.column_stack([m.root_translation, np.zeros((m.times.size, 3)), m.angles]), m.root_quaternion.copy()


# ---------------------------------------------------------------------- settings
def test_noise_is_learnt_unless_given():
    assert Settings().learns_noise
    assert not Settings(noise=0.003).learns_noise  # a noise stated in Python is the user's
    assert Settings(noise=0.003, learn_noise=True).learns_noise
    assert not Settings(learn_noise=False).learns_noise
    assert not settings_from_dict({"noise_mm": 1.0}).learns_noise  # stated in a config / --noise-mm: kept
    assert settings_from_dict({"noise_mm": 2.0, "learn_noise": True}).learns_noise
    s = settings_from_dict({"priors": {"symmetry_scale": 0.05, "symmetry_centre_mm": 4.0}})
    assert s.priors.symmetry_scale == 0.05 and math.isclose(s.priors.symmetry_centre, 0.004)
    with pytest.raises(CalibrateError, match="symmetry_centre"):
        settings_from_dict({"priors": {"symmetry_centre_mm": -1.0}})
    with pytest.raises(CalibrateError, match="learn_noise"):
        settings_from_dict({"learn_noise": "yes"})


# ---------------------------------------------------------------------- symmetry prior
def test_symmetry_pairs_mirror_the_sagittal_plane(human):
    segs, joints, mirror = symmetry_pairs(human, human.parameters().centre)
    names = {(human.joints[a].name, human.joints[b].name) for a, b in joints}
    assert ("hip_l", "hip_r") in names and ("shoulder_l", "shoulder_r") in names and len(joints) == 8
    assert len(segs) == 8
    np.testing.assert_array_equal(mirror, [1.0, -1.0, 1.0])  # y is left in models/human.urdf
    c = human.parameters().centre
    for a, b in joints:  # the base model is symmetric: each left centre is its right partner mirrored
        np.testing.assert_allclose(c[a], mirror * c[b], atol=1e-12)


def test_symmetry_prior_jacobian_matches_finite_differences(human, human_kin):
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    obs = marker_columns(human, sim.trial)
    pri = Priors(symmetry_scale=0.02, symmetry_centre=0.01)
    problem = Problem(human, obs, Settings(priors=pri), human_kin)
    off = Problem(human, obs, Settings(priors=Priors(symmetry_scale=0.0, symmetry_centre=0.0)), human_kin)
    rng = np.random.default_rng(1)
    p = problem.retract_parameters(sim.truth.vector(), 0.02 * rng.normal(size=problem.n_free))
    r, J = problem.prior(p)
    n_sym = r.size - off.prior(p)[0].size
    assert n_sym == 8 + 3 * 8  # 8 segment pairs, 8 joint pairs
    rows = slice(r.size - n_sym, r.size)
    # the rows before the symmetry block are the old priors, unchanged
    np.testing.assert_array_equal(r[: r.size - n_sym], off.prior(p)[0])
    fd = prior_jacobian_by_differences(problem, p)[rows]
    np.testing.assert_allclose(J[rows], fd, atol=1e-5 * max(1.0, np.abs(fd).max()))
    # symmetric geometry costs nothing: the base model itself
    assert np.allclose(problem.prior(human.parameters().vector(), jacobian=False)[0][rows], 0.0)



@pytest.mark.parametrize("free", [("scale", "centre", "axis", "marker"), ("centre", "axis")])
def test_every_prior_row_jacobian_matches_finite_differences(human, human_kin, free):
    """The whole prior Jacobian (built from its nonzeros), every row and free column, against central
    differences through the parameters' retraction; with a marker no frame shows (held)."""
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    obs = marker_columns(human, sim.trial)
    obs[:, human.marker_index("RFIN")] = np.nan
    problem = Problem(human, obs, Settings(free=free, priors=Priors(symmetry_scale=0.02, symmetry_centre=0.01)),
                      human_kin)
    rng = np.random.default_rng(2)
    p = problem.retract_parameters(sim.truth.vector(), 0.02 * rng.normal(size=problem.n_free))
    r, J = problem.prior(p)
    assert J.shape == (r.size, problem.n_free)
    fd = prior_jacobian_by_differences(problem, p)
    np.testing.assert_allclose(J, fd, atol=1e-5 * max(1.0, np.abs(fd).max()))

def test_symmetry_prior_pulls_as_a_gaussian_observation_predicts(human, human_kin):
    """Scales of an asymmetric subject (left leg 6 % longer than the right), every other parameter
    known: the symmetry prior moves the left/right differences by what conditioning the posterior
    without it on 'difference = 0 +- SD' gives (exact for a linear problem)."""
    sim0 = simulate_squats(human, frames=40, noise_mm=0.0, seed=4)
    t = sim0.truth
    scale = t.scale.copy()
    for name, f in (("femur_l", 1.03), ("tibia_l", 1.03), ("femur_r", 0.97), ("tibia_r", 0.97)):
        scale[human.segment_index(name)] *= f
    truth = Parameters(scale, t.centre, t.axis, t.marker)
    Z, Q = _truth_state(sim0)
    M, _ = human_kin.batch(Z, Q, truth)
    M = M + np.random.default_rng(2).normal(0.0, 0.001, M.shape)
    base = Parameters(np.ones_like(scale), t.centre, t.axis, t.marker)  # only the scales are unknown

    def solve(sd: float):
        st = Settings(free=("scale",), learn_noise=False, priors=Priors(symmetry_scale=sd))
        problem = Problem(human, M, st, human_kin, base=base)
        state, summary = levenberg_marquardt(problem, State(Z.copy(), Q.copy(), base.vector()))
        assert summary.converged
        return problem, state

    p0, s0 = solve(0.0)
    C0 = covariance(p0, s0).matrix  # the free parameters are the segment scales, in order
    segs, _, _ = symmetry_pairs(human, base.centre)
    A = np.zeros((len(segs), C0.shape[0]))
    for i, (a, b) in enumerate(segs):
        A[i, a], A[i, b] = 1.0, -1.0
    fl, fr = human.segment_index("femur_l"), human.segment_index("femur_r")
    sd = 0.3 * math.sqrt(C0[fl, fl] + C0[fr, fr])  # stronger than the data alone on this pair
    m0 = s0.p[: C0.shape[0]]
    d = m0 - 1.0
    pred = m0 - C0 @ A.T @ np.linalg.solve(A @ C0 @ A.T + sd**2 * np.eye(len(segs)), A @ d)
    _, s1 = solve(sd)
    diff0, diff1, want = m0[fl] - m0[fr], s1.p[fl] - s1.p[fr], pred[fl] - pred[fr]
    assert diff0 > 0.04  # the data see the asymmetry
    assert abs(diff1 - want) < 0.05 * diff0, (diff0, diff1, want)
    assert 0.1 < diff1 / diff0 < 0.9, (diff0, diff1)  # pulled towards symmetry, not all the way


# ---------------------------------------------------------------------- noise learnt
def _sta(sim, names: tuple[str, ...], amp: float) -> np.ndarray:
    """Skin-motion-like displacements (F, markers, 3): smooth functions of the hip and knee angles."""
    out = np.zeros_like(sim.clean_markers)
    ang = sim.motion.angles
    dof = sim.model.dof_index
    for name in names:
        side = name[0].lower()
        hip, knee = ang[:, dof(f"hip_{side}_flexion")], ang[:, dof(f"knee_{side}")]
        d = amp * np.column_stack([np.sin(2 * knee), np.cos(1.5 * hip + knee), np.sin(hip - 2 * knee)])
        out[:, sim.model.marker_index(name)] = d - d.mean(axis=0)
    return out


@pytest.fixture(scope="module")
def sta_run(human):
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=1)
    thigh = ("LTHI", "RTHI", "LKNE", "RKNE")
    trial = _with_markers(sim, sim.trial.markers + _sta(sim, thigh, 0.006))
    return sim, thigh, calibrate(human, trial)


def test_learnt_noise_is_the_white_noise_sd(human):
    """1 mm white noise: each marker's learnt SD is 1 mm (the leverage correction matters: the raw
    residual RMS per coordinate is ~0.8 mm, one frame's 38 coordinates absorbing a third of it)."""
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=1)
    cal = calibrate(human, sim.trial)
    sd = 1000 * np.array(list(cal.noise.values()))
    assert cal.noise_learnt
    assert 0.95 < np.median(sd) < 1.05
    assert sd.min() > 0.8 and sd.max() < 1.25
    raw = 1000 * rms(cal.residuals) / math.sqrt(3)
    assert raw < 0.9  # what a learnt SD without the correction would have been
    rep = json.loads(json.dumps(cal.report()))
    assert rep["noise"]["learnt"] and set(rep["noise"]["per_marker_mm"]) == set(human.marker_names)
    assert "noise SD (mm)" in cal.text() and "learnt" in cal.text()


def test_learnt_noise_is_larger_for_skin_motion(sta_run):
    sim, thigh, cal = sta_run
    sd = {k: 1000 * v for k, v in cal.noise.items()}
    rest = [v for k, v in sd.items() if k not in thigh]
    assert 0.9 < np.median(rest) < 1.15
    for name in thigh:  # white 1 mm: 0.9-1.1 mm, correlation time ~1 (test above); here 1.6-2.6 mm, 2-17 frames
        assert sd[name] > 1.4, (name, sd[name])
        assert 1000 * cal.noise_weight[name] > 1.3 * sd[name]  # smooth skin motion: correlated over frames
    assert np.median([cal.noise_weight[k] / cal.noise[k] for k in cal.noise if k not in thigh]) < 1.1
    assert len(cal.outliers) < 0.005 * cal.residuals.shape[0] * cal.residuals.shape[1]


def test_a_correlation_time_counts_up_to_the_same_seconds_at_any_rate(human):
    """Four thigh and knee markers drift on the skin (8 mm, periods of 2.5-3.5 s): their residuals stay correlated
    for longer than the cap, so each weighs as one frame in NOISE_TAU_SECONDS' worth of frames (the weight's SD over
    the noise SD, squared): 13.3 frames at 100 Hz and 3.3 when the same trial is read at 25 Hz (every fourth frame),
    so that a second of the trial weighs the same against the priors at either rate (a cap of 16 frames at every
    rate made a 25 Hz frame count 1/16).  The white-noise markers stay near 1."""
    sim = simulate_squats(human, frames=400, noise_mm=1.0, seed=1)
    drift = ("LTHI", "RTHI", "LKNE", "RKNE")
    X, t = sim.trial.markers.copy(), sim.trial.times
    for i, name in enumerate(drift):
        X[:, human.marker_index(name)] += 0.008 * np.column_stack(
            [np.sin(2 * np.pi * t / 3 + 1.3 * i), np.cos(2 * np.pi * t / 2.5 + 1.3 * i),
             np.sin(2 * np.pi * t / 3.5 + 2.6 * i)])
    for step in (1, 4):
        trial = Trial(sim.trial.labels, X[::step], sim.trial.rate / step, 0, None)
        cal = calibrate(human, trial)
        frames = {k: (cal.noise_weight[k] / cal.noise[k]) ** 2 for k in cal.noise}
        cap = NOISE_TAU_SECONDS * trial.rate
        assert cap == pytest.approx(tau_cap(np.array([trial.rate]), np.array([trial.n_frames])))
        for name in drift:
            # (within 15 %: LKNE and RKNE also hold their knees' centres, Priors.knee_landmark, and the fit turns a
            # part of their drift into the knee's; 2.9 of 3.3 frames at 25 Hz; a 25 Hz frame once counted 1/16)
            assert abs(frames[name] / cap - 1) < 0.15, (trial.rate, name, frames[name], cap)
        assert np.median([v for k, v in frames.items() if k not in drift]) < 1.1
        noise = json.loads(json.dumps(cal.report()))["noise"]  # the report states the cap, in seconds and frames
        assert noise["correlation_cap_s"] == NOISE_TAU_SECONDS and noise["correlation_cap_frames"] == pytest.approx(cap)
    # Trials at different rates: the cap at their mean rate, each weighted by its frames.
    assert tau_cap(np.array([120.0, 60.0]), np.array([300, 100])) == pytest.approx(NOISE_TAU_SECONDS * 105.0)


def test_learned_noise_keeps_fixed_markers(human, human_kin):
    sim = simulate_squats(human, frames=60, noise_mm=1.0, seed=3)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(noise=0.004), human_kin)
    Z, Q = _truth_state(sim)
    state, _ = levenberg_marquardt(problem, State(Z, Q, sim.truth.vector()), pose_only=True, max_iterations=10)
    fixed = np.zeros(len(human.markers), dtype=bool)
    fixed[3] = True
    sd = learned_noise(problem, state, fixed)
    assert sd[3] == 0.004
    assert 0.0009 < np.median(sd[~fixed]) < 0.0011 and np.all((sd[~fixed] > 0.0007) & (sd[~fixed] < 0.0013))


def test_spikes_and_swaps_rejected_skin_motion_kept(human):
    """50 mm spikes at single frames and two labels swapped for a few frames, on a trial with thigh
    skin motion: at least 95 % of the corrupted positions rejected, under 0.5 % of the others."""
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=2)
    X = sim.trial.markers + _sta(sim, ("LTHI", "RTHI"), 0.006)
    rng = np.random.default_rng(7)
    bad = set()
    for _ in range(30):
        f, k = int(rng.integers(300)), int(rng.integers(len(human.markers)))
        v = rng.normal(size=3)
        X[f, k] += 0.05 * v / np.linalg.norm(v)
        bad.add((f, human.marker_names[k]))
    a, b = human.marker_index("LKNE"), human.marker_index("LANK")
    for f in range(100, 106):  # LKNE and LANK swapped for 6 frames
        X[f, [a, b]] = X[f, [b, a]]
        bad |= {(f, "LKNE"), (f, "LANK")}
    cal = calibrate(human, _with_markers(sim, X))
    got = {(o.frame, o.marker) for o in cal.outliers}
    caught = len(bad & got) / len(bad)
    false = len(got - bad) / (300 * len(human.markers))
    assert caught >= 0.95, sorted(bad - got)
    assert false < 0.005


# ---------------------------------------------------------------------- size
# a 1.5 m and a 2.0 m subject of a 1.75 m base model, and a 1.0 m child (its seeded scales were clipped at 0.7 of the
# base model's: 23 % too large)
@pytest.mark.parametrize("k", [0.86, 1.14, 0.57])
def test_start_fits_the_subjects_size(human, human_kin, k):
    sim = simulate_squats(human, frames=200, noise_mm=1.0, seed=2)
    t = sim.truth
    Z, Q = _truth_state(sim)

    def subject(f: float) -> tuple[Parameters, Trial]:
        truth = Parameters(np.full_like(t.scale, f), t.centre, t.axis, t.marker)
        Zf = Z.copy()
        Zf[:, :3] *= f
        M, _ = human_kin.batch(Zf, Q, truth)
        M = M + np.random.default_rng(0).normal(0, 0.001, M.shape)
        return truth, Trial(human.marker_names, M, 100.0, 0, None)

    _, same = subject(1.0)
    ref = size_from_markers(human, [same])  # the subject's own proportions (markers and centres moved)
    truth, trial = subject(k)
    size = size_from_markers(human, [trial])
    assert size is not None and size.pairs >= 20
    for limb, f in size.limbs.items():
        assert abs(ref.limbs[limb] - 1) < 0.07, (limb, ref.limbs[limb])  # markers +-10 mm, centres +-15 mm
        assert abs(f / ref.limbs[limb] / k - 1) < 0.01, (limb, f)  # the same subject k times as large
    seed = seed_parameters(human, trial, size=size)
    carried = [i for i, s in enumerate(human.segments) if s.markers]
    err = seed.params.scale[carried] / k - 1
    # (the child's joint centres from the markers alone are placed to the same millimetres on segments 0.57 times as
    # long: its seeded scales' median error 4.3 %, the adults' 1-3 %; clipped at 0.7 they had been 23 % off)
    assert np.median(np.abs(err)) < (0.03 if k > 0.7 else 0.05) and np.abs(err).max() < 0.12
    obs = marker_columns(human, trial)
    st = start_poses(human_kin, obs, seed.params)  # with the balls' reference rotations (State.B)
    assert rms(Problem(human, obs, Settings(), human_kin).marker_residuals(st)) < 0.015


def test_leverage_is_the_hat_matrix_diagonal(human, human_kin):
    """leverage(): per marker, the trace of its three rows of the hat matrix J (J'J)⁻¹ J' of its frame's
    coordinates (weighted rows), / 3 — checked against that matrix formed densely from the sparse Jacobian."""
    sim = simulate_squats(human, frames=12, noise_mm=1.0, seed=5)
    obs = marker_columns(human, sim.trial)
    obs[4, 7] = np.nan  # a gap: no leverage there
    problem = Problem(human, obs, Settings(noise=0.002, marker_noise={"LTHI": 0.005}), human_kin)
    Z, Q = _truth_state(sim)
    state, _ = levenberg_marquardt(problem, State(Z, Q, sim.truth.vector()), pose_only=True, max_iterations=5)
    h, _ = leverage(problem, state)
    _, J = problem.full_jacobian(state)
    J = J.toarray()
    nm, nz = len(human.markers), human.nz
    for f in (0, 4, 11):
        Jf = J[f * 3 * nm:(f + 1) * 3 * nm, f * nz:(f + 1) * nz]
        hat = Jf @ np.linalg.pinv(Jf.T @ Jf) @ Jf.T
        expect = np.diag(hat).reshape(nm, 3).sum(axis=1) / 3
        np.testing.assert_allclose(h[f], np.where(problem.seen[f], expect, 0.0), atol=1e-9)
    assert h[4, 7] == 0.0 and 0.0 < h.max() < 1.0
