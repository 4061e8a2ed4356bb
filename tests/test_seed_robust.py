"""The MTB seed against swapped labels and spikes (issue 16, item 7): marker samples that break the
distances they keep to the other markers of their segment, or that jump away and back, are left
out of the seed, so a few frames of two labels exchanged no longer pull a shoulder centre
centimetres off.  Truths are the simulator's."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.calibration.evaluate import compare_to_truth
from calibrate.calibration.pipeline import calibrate
from calibrate.io.labels import map_labels
from calibrate.io.read import read_trial
from calibrate.io.trial import Trial
from calibrate.seed.seeding import broken_samples, jump_episodes, seed_parameters
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns

REAL = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real" / "pig_walk"
SWAP = slice(100, 112)  # frames whose C7 and LSHO labels are exchanged


@pytest.fixture(scope="module")
def squats(human):
    return simulate_squats(human, frames=300, noise_mm=1.0, seed=3)


@pytest.fixture(scope="module")
def clean_squats(human, squats):
    """The undamaged squats' calibration (the defaults), which the damaged trials' calibrations are held to."""
    return calibrate(human, squats.trial)


def _swapped(trial, a: str, b: str, frames: slice):
    X = np.array(trial.markers)
    i, j = trial.labels.index(a), trial.labels.index(b)
    X[frames, [i, j]] = X[frames, [j, i]]
    return replace(trial, markers=X)


def test_swapped_torso_labels_are_flagged_and_nothing_else(human, squats):
    trial = _swapped(squats.trial, "C7", "LSHO", SWAP)
    bad = broken_samples(human, trial)
    assert bad.shape == (trial.n_frames, len(human.markers))
    c7, lsho = human.marker_index("C7"), human.marker_index("LSHO")
    assert bad[SWAP, c7].all() and bad[SWAP, lsho].all()
    expected = np.zeros_like(bad)
    expected[SWAP, [[c7], [lsho]]] = True
    seen = np.all(np.isfinite(marker_columns(human, trial)), axis=2)
    assert (bad & ~expected).sum() <= 0.001 * seen.sum()
    # the unswapped trial: (almost) nothing flagged
    assert broken_samples(human, squats.trial).sum() <= 0.001 * seen.sum()


def test_simulated_swaps_and_spikes_are_caught(human):
    """The simulator's own corruptions (truth_corruptions) under 3 mm soft-tissue artefact, over six
    subjects: jump_episodes catches nearly all (a spike of under 100 mm next to a gap has no jump back), broken_samples
    many (not a spike along no pair, nor two markers of a two-marker segment swapped: every distance
    kept); few clean samples are lost."""
    caught = {"jump": 0, "rigid": 0}
    false = {"jump": 0, "rigid": 0}
    corrupted = seen = 0
    for seed in range(6):
        sim = simulate_squats(human, frames=300, seed=seed, sta_mm=3.0, swaps=3, spikes=5)
        order = [sim.trial.labels.index(n) for n in human.marker_names]
        found = {"jump": jump_episodes(sim.trial)[:, order], "rigid": broken_samples(human, sim.trial)}
        truth = np.zeros_like(found["rigid"])
        for c in sim.corruptions:
            truth[c.frame, human.marker_index(c.marker)] = True
        for k, bad in found.items():
            caught[k] += int((bad & truth).sum())
            false[k] += int((bad & ~truth).sum())
        corrupted += int(truth.sum())
        seen += int(np.all(np.isfinite(marker_columns(human, sim.trial)), axis=2).sum())
    assert corrupted > 200
    assert caught["jump"] >= 0.95 * corrupted, (caught, corrupted)
    assert false["jump"] <= 0.001 * seen, (false, seen)
    assert caught["rigid"] >= 0.6 * corrupted, (caught, corrupted)
    assert false["rigid"] <= 0.003 * seen, (false, seen)


def _shoulder_error(human, sim, trial) -> tuple[float, tuple[str, ...]]:
    """Median distance (m) of the seed's left-shoulder MTB trajectory from the true centre, and the notes."""
    seed = seed_parameters(human, trial)
    est = seed.joints["shoulder_l"]
    step = sim.trial.n_frames // est.centre.shape[0]
    truth = sim.clean_centres[::step][: est.centre.shape[0], human.joint_index("shoulder_l")]
    return float(np.nanmedian(np.linalg.norm(est.centre - truth, axis=1))), seed.notes


@pytest.fixture(scope="module")
def clean_shoulder(human, squats) -> float:
    return _shoulder_error(human, squats, squats.trial)[0]


@pytest.mark.parametrize("pair", [("C7", "LSHO"), ("LELB", "LUPA")])
def test_seeded_shoulder_ignores_swapped_labels(human, squats, clean_shoulder, pair):
    """Twelve frames of two labels exchanged (on the torso; on the upper arm, where every distance is
    kept) put the left shoulder's MTB centre 95 and 165 mm from the truth before the check (measured);
    with it, as close as on the unswapped trial."""
    swapped, notes = _shoulder_error(human, squats, _swapped(squats.trial, *pair, SWAP))
    assert clean_shoulder < 0.005
    assert swapped < 0.005, swapped
    assert any("left out of the seed" in n for n in notes)


def test_upper_arm_swap_is_a_jump_episode(human, squats):
    trial = _swapped(squats.trial, "LELB", "LUPA", SWAP)
    jumps = jump_episodes(trial)
    i, j = trial.labels.index("LELB"), trial.labels.index("LUPA")
    assert jumps[SWAP, i].all() and jumps[SWAP, j].all()
    assert jumps.sum() == 2 * (SWAP.stop - SWAP.start)
    assert not jump_episodes(squats.trial).any()


def test_labels_exchanged_for_longer_than_an_episode_are_found(human, squats, clean_squats):
    """RKNE and LELB exchanged for frames 60-199 of the squats (1.4 s, longer than an episode of SEED_EPISODE_S): at
    both ends the two jump by each other's separation in opposite ways, which no limb does, so the whole stretch is
    taken for both (seeding._exchanged_stretches) and nothing else, also from the trial's fourth frame on; one
    exchange with no second (the labels stay exchanged to the trial's end) is not judged.  The calibration then puts
    every joint centre as near the simulator's truth as on the undamaged trial, to 2 mm (before:
    scripts/damage_values.py's longswap copies of pig_walk moved a centre 93-370 mm in 7 of 16)."""
    frames = slice(60, 200)
    trial = _swapped(squats.trial, "RKNE", "LELB", frames)
    got = jump_episodes(trial)
    i, j = trial.labels.index("RKNE"), trial.labels.index("LELB")
    assert got[frames, i].all() and got[frames, j].all()
    assert got.sum() == 2 * (frames.stop - frames.start)
    assert not jump_episodes(_swapped(squats.trial, "RKNE", "LELB", slice(200, 300))).any()
    # from the trial's fourth frame: the three before are not a ghost at the trial's edge (the jump exchanges labels)
    early = jump_episodes(_swapped(squats.trial, "RKNE", "LELB", slice(3, 150)))
    assert early[3:150, [i, j]].all() and early.sum() == 2 * 147
    clean, cal = clean_squats, calibrate(human, trial)
    got, ref = compare_to_truth(cal, squats).centre_error, compare_to_truth(clean, squats).centre_error
    assert all(got[j] < ref[j] + 0.002 for j in ref), {j: (got[j], ref[j]) for j in ref if got[j] >= ref[j] + 0.002}


def test_a_ghost_at_a_gaps_edge_is_a_jump_episode(human, squats):
    """A ghost 0.8 m off just before a gap, and one of two frames just after another: no jump back bounds either, so
    the jump test left them in (the start race and the first solve then fitted them: a 2.5 m ghost before a gap moved
    pig_walk's right knee centre 70 mm).  A jump of 100 mm or more with at most three seen frames between it and a
    gap, and more on its other side, now marks those frames; a fast arm read at 50 Hz (steps of 50 mm, jumps of
    30-50 from the steps around them) keeps its frames.  (The simulator's truth: which samples were damaged.)"""
    t = squats.trial
    X = t.markers.copy()
    k, j = t.labels.index("LKNE"), t.labels.index("RWRA")
    X[100, k] += [0.8, 0.0, 0.0]
    X[101:110, k] = np.nan
    X[200:205, j] = np.nan
    X[205:207, j] += [0.0, 0.3, 0.0]
    jumps = jump_episodes(Trial(t.labels, X, t.rate))
    assert jumps[100, k] and jumps[205:207, j].all()
    assert jumps.sum() == 3
    X = t.markers.copy()
    X[101:110, k] = np.nan  # the gaps alone
    X[200:205, j] = np.nan
    assert not jump_episodes(Trial(t.labels, X, t.rate)).any()


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_real_walk_loses_no_samples(human):
    """A clean Vicon walk (pig_walk, 120 Hz): no jump episode and no broken segment distance."""
    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    assert not jump_episodes(trial).any()
    assert not broken_samples(human, trial).any()


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_a_one_marker_foot_in_stance_is_not_taken_for_a_fallen_marker(human):
    """pig_walk's walk without LHEE: LTOE, its foot's only marker, stands still through each stance while the shank's
    markers travel over it, as a fallen marker would; judged by the segments next to it alone, it is taken only where
    every one of their markers travels away (LANK barely moves in a stance) for a stay of 1 s or more
    (seeding.FALLEN_ALONE_S), and none of its 142 stance frames is left out."""
    from calibrate.seed.seeding import fallen_samples

    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names) and lab != "LHEE"])
    assert not fallen_samples(human, trial).any()


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_a_mates_ghost_does_not_make_a_marker_look_fallen(human):
    """pig_walk's walk with a ghost of LHEE 1.5 m off in frames 251-252 (a stance of the left foot): only the ghost's
    two positions are left out.  The check for fallen markers judges the trial without its jumps: the ghost, in a
    window's mean, had made the heel travel away from the toe standing beside it, and LTOE was left out for 83
    frames (`calibrate ik` then turned the left ankle 57 deg; scripts/damage_values.py --ik)."""
    from calibrate.seed.seeding import jumped_samples

    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    for v in ([0.9, 1.0, 0.6], [-0.5, 1.2, 0.4]):
        X = trial.markers.copy()
        X[251:253, trial.labels.index("LHEE")] += v
        out = jumped_samples(human, [Trial(trial.labels, X, trial.rate)])
        k = human.marker_index("LHEE")
        assert out[251:253, k].all() and out.sum() == 2, {human.marker_names[j]: int(out[:, j].sum())
                                                          for j in np.flatnonzero(out.any(axis=0))}


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_a_lone_label_exchange_is_judged_against_the_model(human):
    """pig_walk's first 300 frames with two labels exchanged once, to the trial's end or from its start (no jump back):
    the jumps alone cannot say which side is wrong, and take nothing; with the model, the side whose markers' distances
    to their segments' other markers fit the model's exchanged is taken, and nothing else (seeding.lone_exchanges).
    LHEE/LTOE and RASI/LASI so exchanged put centres 80-103 mm off."""
    from calibrate.seed.seeding import episodes, exchanged_back

    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    trial = Trial(trial.labels, np.array(trial.markers[:300]), trial.rate)
    assert not episodes(trial, model=human)[0].any()
    for a, b, f0, f1 in (("LHEE", "LTOE", 100, 300), ("RASI", "LASI", 0, 200), ("LBHD", "T10", 227, 300)):
        X = trial.markers.copy()
        i, j = trial.labels.index(a), trial.labels.index(b)
        X[f0:f1, [i, j]] = X[f0:f1, [j, i]]
        damaged = Trial(trial.labels, X, trial.rate)
        assert not jump_episodes(damaged).any()
        truth = np.zeros(X.shape[:2], dtype=bool)
        truth[f0:f1, [i, j]] = True
        assert np.array_equal(episodes(damaged, model=human)[0], truth), (a, b)
        back: list = []  # or, for the caller to exchange back: named, and not in the mask
        assert not episodes(damaged, model=human, back=back)[0].any()
        assert [(set(x.labels), x.start, x.stop) for x in back] == [({a, b}, f0, f1)]
        assert np.array_equal(exchanged_back(damaged, back).markers, trial.markers, equal_nan=True)


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_the_calibration_exchanges_a_lone_exchange_back(human):
    """pig_walk's first 300 frames with LASI and RPSI exchanged over the first 150 (no exchange back): the calibration
    exchanges them back there (Calibration.exchanged_back, an `exchanged` summary line, the report's
    `exchanged_back`) and fits the trial as recorded; left out instead, the pelvis had two markers in half the walk
    and the left hip ended 161 mm off (scripts/damage_values.py --kinds endswap)."""
    from calibrate.calibration.report import calibration_report, summary_text

    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    trial = Trial(trial.labels, np.array(trial.markers[:300]), trial.rate, 0, "walk.c3d")
    X = trial.markers.copy()
    i, j = trial.labels.index("LASI"), trial.labels.index("RPSI")
    X[:150, [i, j]] = X[:150, [j, i]]
    cal = calibrate(human, Trial(trial.labels, X, trial.rate, 0, "walk.c3d"))
    assert [(i, set(x.labels), x.start, x.stop) for i, x in cal.exchanged_back] == [(0, {"LASI", "RPSI"}, 0, 150)]
    assert np.array_equal(cal.trials[0].markers, trial.markers, equal_nan=True)
    assert "exchanged    walk.c3d: " in summary_text(cal)
    assert calibration_report(cal)["exchanged_back"][0]["frames"] == [0, 149]


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_a_lone_exchange_across_segments_is_read_on_each_markers_own_segment(human, tmp_path):
    """pig_walk's first 300 frames with RTHI and RFIN exchanged from frame 173 on, judged against the subject
    calibrated on its static and the walk as recorded (what `calibrate ik` judges a lab's other trials against): the
    exchange is named and exchanged back.  The finger keeps steady to the knee in this walk (its distance's spread
    under LONE_STEADY) but 80 mm or more from the subject's neutral pose's, a distance across the arm, hip and knee
    that says nothing of the labels; read with it, neither side was named and `calibrate ik` turned the right wrist
    81 deg (scripts/damage_values.py --ik --seed 7, copy 8).  Each position is now read against the references on the
    segment of the marker it is taken for (RTHI's: the femur's RKNE)."""
    from calibrate.model.model import load_model, write_model
    from calibrate.seed.seeding import LONE_STEADY, MAD_SD, episodes, exchanged_back

    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    trial = Trial(trial.labels, np.array(trial.markers[:300]), trial.rate, 0, "walk.c3d")
    static, _ = map_labels(read_trial(REAL / "static.c3d"), human.marker_names)
    cal = calibrate(human, [static, trial])
    subject = load_model(write_model(cal.model, tmp_path / "subject.urdf", cal.params))
    i, j, knee = (trial.labels.index(n) for n in ("RTHI", "RFIN", "RKNE"))
    d = np.linalg.norm(trial.markers[:173, j] - trial.markers[:173, knee], axis=1)
    neutral = np.linalg.norm(np.subtract(*subject.neutral_positions(["RFIN", "RKNE"])))
    assert MAD_SD * np.median(np.abs(d - np.median(d))) < LONE_STEADY and abs(np.median(d) - neutral) > 0.08
    X = trial.markers.copy()
    X[173:, [i, j]] = X[173:, [j, i]]
    damaged = Trial(trial.labels, X, trial.rate)
    back: list = []
    assert not episodes(damaged, model=subject, back=back)[0].any()
    assert [(set(x.labels), x.start, x.stop) for x in back] == [({"RTHI", "RFIN"}, 173, 300)]
    assert np.array_equal(exchanged_back(damaged, back).markers, trial.markers, equal_nan=True)


def test_a_marker_whose_mate_is_left_out_is_not_judged_alone(human):
    """A planted foot (heel and toe still, 0.5 mm of noise) under a shank travelling 0.8 m/s forward, with a ghost of
    the heel in two frames: the ghost is left out, and with it the toe has no mate seen through those windows; judged
    by the shank alone, travelling away from it, it had been taken for fallen over the whole trial.  A mate unseen
    in part of a window leaves the marker unjudged there."""
    from calibrate.seed.seeding import jumped_samples

    trial = simulate_squats(human, frames=300, noise_mm=0.5, seed=3).trial
    X = np.array(trial.markers)
    rng = np.random.default_rng(0)
    for lab in ("LHEE", "LTOE"):
        k = trial.labels.index(lab)
        X[:, k] = X[0, k] + rng.normal(scale=0.0005, size=(trial.n_frames, 3))
    for lab in ("LTIB", "LANK"):
        X[:, trial.labels.index(lab), 0] += 0.8 * np.arange(trial.n_frames) / trial.rate
    assert not jumped_samples(human, [Trial(trial.labels, X, trial.rate)]).any()
    X[150:152, trial.labels.index("LHEE")] += [0.9, 1.0, 0.6]
    out = jumped_samples(human, [Trial(trial.labels, X, trial.rate)])
    assert out[150:152, human.marker_index("LHEE")].all() and out.sum() == 2


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_a_hand_marker_or_a_late_tibia_marker_on_the_floor_is_taken(human):
    """pig_walk's first 300 frames with one marker put on the floor where it was (7 mm up) from a frame on:
    - LFIN, the left hand's only marker, from frame 83: 1.8 s on the floor, every wrist marker travelling away from it
      and back (it had been taken only after 2 s, and the calibration put the left wrist 618 mm off);
    - LTIB from frame 207: the 0.5 s blocks after the fall each held a stance, where LANK, its segment's other marker,
      stands still (knee_l 101 mm off); windows a quarter of a block apart find the swing between.
    Every fallen frame is taken, nothing else (scripts/damage_values.py's fallen kind found both)."""
    from calibrate.seed.seeding import fallen_samples

    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    trial = Trial(trial.labels, np.array(trial.markers[:300]), trial.rate)
    for label, f in (("LFIN", 83), ("LTIB", 207)):
        X = trial.markers.copy()
        k = trial.labels.index(label)
        X[f:, k] = [X[f, k, 0], X[f, k, 1], 0.007]
        out = fallen_samples(human, Trial(trial.labels, X, trial.rate))
        kk = human.marker_index(label)
        assert out[f:, kk].all() and not out[:f, kk].any(), (label, int(out[:, kk].sum()))
        assert out.sum() == out[:, kk].sum()


def test_a_heel_lying_elsewhere_leaves_its_toe_standing_in_a_stance(human):
    """pig_walk's walk with LHEE put 7 mm above the lab's floor plane from frame 175 on, late in a stance of the left
    foot (scripts/damage_values.py --ik's fallen kind, seed 112): every LHEE sample from there is taken, and of LTOE,
    its segment's other marker, only the samples where its distance to LHEE leaves the rigid one it keeps while both
    are on the foot (the windows before took LTOE from its stance's start, frame 106: 69 frames of it on its foot, and
    `calibrate ik` then turned the left ankle 25 deg on the heel alone)."""
    from calibrate.seed.seeding import fallen_samples

    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    X = np.array(trial.markers[:300])
    heel, toe = trial.labels.index("LHEE"), trial.labels.index("LTOE")
    X[175:, heel] = [X[175, heel, 0], X[175, heel, 1], 0.007]
    out = fallen_samples(human, Trial(trial.labels, X, trial.rate))
    h, t = human.marker_index("LHEE"), human.marker_index("LTOE")
    assert out[175:, h].all() and not out[:175, h].any(), int(out[:, h].sum())
    d = np.linalg.norm(X[:, toe] - X[:, heel], axis=1)
    rigid = np.median(d[:175])
    assert np.abs(d[:175] - rigid).max() < 0.010  # the foot's two markers 237 mm apart, within 7 mm, until the fall
    assert not out[:175, t].any(), np.flatnonzero(out[:, t])
    assert out.sum() == out[:, h].sum() + out[175:, t].sum()


def test_jumps_are_left_out_of_the_solve_and_reported(human):
    """Eight frames of LELB and LUPA exchanged: the calibration leaves all 16 positions out before the
    start and reports them as outliers, each with its error at the fit close to the distance the swap
    moved it (simulator truth); the left shoulder comes out as on the clean trial."""
    sim = simulate_squats(human, frames=150, noise_mm=1.0, seed=5)
    frames = slice(60, 68)
    cal = calibrate(human, _swapped(sim.trial, "LELB", "LUPA", frames))
    got = {(o.frame, o.marker): o.error for o in cal.outliers}
    i, j = human.marker_index("LELB"), human.marker_index("LUPA")
    moved = np.linalg.norm(sim.clean_markers[frames, i] - sim.clean_markers[frames, j], axis=1)
    for f, d in zip(range(frames.start, frames.stop), moved, strict=True):
        for m in ("LELB", "LUPA"):
            assert (f, m) in got
            assert abs(got[f, m] - d) < 0.01, (f, m, got[f, m], d)
    assert compare_to_truth(cal, sim).ball()["shoulder_l"] < 0.004


def test_a_marker_fallen_off_is_left_out_where_it_lies(human, squats, clean_squats):
    """Squats with the right knee marker fallen to the floor half-way through (it lies where it landed): its
    positions there are left out before the start (seeding.fallen_samples: it stays at one place while its distance
    to the thigh's other marker changes), so the calibration fits as on the trial without it; before, that one
    marker pulled the fit to 40+ mm RMS.  The squats' feet stand still too, with their markers: none of theirs is
    taken.  (The simulator's truth: which samples fell, and the clean trial's fit.)"""
    from calibrate.seed.seeding import fallen_samples

    sim = squats  # 300 frames, 1 mm, seed 3
    t = sim.trial
    k = t.labels.index("RKNE")
    X = t.markers.copy()
    X[150:, k] = X[150, k] * [1.0, 1.0, 0.0] + [0.0, 0.0, 0.007]  # on the floor, below where it fell from
    fell = Trial(t.labels, X, t.rate)
    flagged = fallen_samples(human, fell)
    assert flagged[:, human.marker_index("RKNE")].sum() >= 140 and not flagged[:150].any()
    assert flagged.sum() == flagged[:, human.marker_index("RKNE")].sum()  # nothing else (the still feet kept)
    assert not fallen_samples(human, t).any()
    # a segment's only marker (the forearm's RFRM) stuck where it was at the start: judged against the elbow's and
    # the wrist's markers, which travel away from it
    Y = t.markers.copy()
    j = t.labels.index("RFRM")
    Y[:, j] = Y[0, j]
    stuck = fallen_samples(human, Trial(t.labels, Y, t.rate))
    moving = np.linalg.norm(t.markers[:, j] - t.markers[0, j], axis=1) > 0.05  # where the true RFRM is 50 mm away
    assert stuck[:, human.marker_index("RFRM")][moving].mean() > 0.9
    assert stuck.sum() == stuck[:, human.marker_index("RFRM")].sum()
    clean = clean_squats  # the undamaged trial's calibration (the module's fixture)
    cal = calibrate(human, fell)
    assert sum(o.marker == "RKNE" and o.frame >= 150 for o in cal.outliers) >= 140
    assert cal.marker_rms < 1.2 * clean.marker_rms
    # every joint centre as near the truth as the clean trial's calibration puts it, to 2 mm
    got, ref = compare_to_truth(cal, sim).centre_error, compare_to_truth(clean, sim).centre_error
    assert all(got[j] < ref[j] + 0.002 for j in ref), {j: (got[j], ref[j]) for j in ref if got[j] >= ref[j] + 0.002}


def test_a_marker_dropped_in_a_static_is_left_out_of_it(human, squats):
    """A static (nothing turns) whose RTHI drops 0.4 m a third of the way through and lies there: it moves alone
    while its segment's and its neighbours' markers stay put, and the trial cannot say which of its places was the
    thigh's, so all its positions in the static are left out (seeding.fallen_samples).  Before, the fit took both
    places: pig_walk's static with a thigh marker dropped put the right knee centre 361 mm off.  The calibration now
    ends where the undamaged static's does.  (The simulator's truth: which marker dropped.)"""
    from calibrate.seed.seeding import fallen_samples
    from calibrate.simulation.simulate import simulate_static

    st = simulate_static(human, squats.truth, frames=240, noise_mm=1.0, seed=7).trial
    X = st.markers.copy()
    k = st.labels.index("RTHI")
    X[80:, k] = X[80, k] + [0.1, -0.3, -0.25]
    dropped = Trial(st.labels, X, st.rate)
    flagged = fallen_samples(human, dropped)
    assert flagged[:, human.marker_index("RTHI")].all() and flagged.sum() == st.n_frames
    assert not fallen_samples(human, st).any()
    clean, cal = calibrate(human, st), calibrate(human, dropped)
    shift = np.linalg.norm(np.array(cal.params.centre) - np.array(clean.params.centre), axis=1)
    assert shift.max() < 0.010, dict(zip([j.name for j in human.joints], np.round(1e3 * shift, 1), strict=True))


def test_a_marker_fallen_off_the_body_in_a_static_keeps_its_frames_on_it(human, squats):
    """A static whose T10 falls to the floor below it 40 % of the way through and lies there for the rest (the
    majority of the frames): it moved alone, and where it lies it is five times further from the torso's other
    markers than the base model puts it, where before the fall it sat among them at the subject's size
    (seeding._where_modelled).  Its frames on the body are kept, those on the floor left out, and the calibration ends
    where the same static's does with the fallen positions unseen (T10's outliers those alone); before, every T10
    position was left out (the trial could not say which place was the torso's), and in pig_walk's static the left
    shoulder moved 14 mm so (scripts/damage_values.py --trial static, seed 11).  pig_walk's static itself: the same
    for the torso's, head's, pelvis's and arms' markers; a heel on the floor lies too near the toe to tell, and is
    left out whole as before.  (The simulator's truth: which samples fell.)"""
    from calibrate.seed.seeding import fallen_samples
    from calibrate.simulation.simulate import simulate_static

    st = simulate_static(human, squats.truth, frames=240, noise_mm=1.0, seed=7).trial
    X = st.markers.copy()
    k = st.labels.index("T10")
    X[96:, k] = [X[96, k, 0], X[96, k, 1], 0.007]
    fell = Trial(st.labels, X, st.rate)
    flagged = fallen_samples(human, fell)
    kk = human.marker_index("T10")
    assert flagged[96:, kk].all() and not flagged[:96, kk].any(), int(flagged[:, kk].sum())
    assert flagged.sum() == flagged[:, kk].sum()
    unseen = X.copy()
    unseen[96:, k] = np.nan
    cal, ref = calibrate(human, fell), calibrate(human, Trial(st.labels, unseen, st.rate))
    shift = np.linalg.norm(np.array(cal.params.centre) - np.array(ref.params.centre), axis=1)
    # (within the solve's own spread on a static's unplaced centres: the forearms 1-3 mm between these runs)
    assert shift.max() < 0.003, dict(zip([j.name for j in human.joints], np.round(1e3 * shift, 2), strict=True))
    assert {o.frame for o in cal.outliers if o.marker == "T10"} == set(range(96, 240))
    if not (REAL / "static.c3d").exists():
        return
    trial, _ = map_labels(read_trial(REAL / "static.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    for label in ("T10", "CLAV", "LFHD", "RASI", "LWRA", "RUPA", "LHEE"):
        X = np.array(trial.markers[:300])
        j = trial.labels.index(label)
        X[141:, j] = [X[141, j, 0], X[141, j, 1], 0.007]
        out = fallen_samples(human, Trial(trial.labels, X, trial.rate))
        m = human.marker_index(label)
        assert out[141:, m].all() and out[:141, m].any() == (label == "LHEE") and out.sum() == out[:, m].sum(), label


def test_a_marker_fallen_in_a_static_whose_arms_drift_is_taken():
    """Rajagopal's static_walk_1 (OpenSim's example, Rajagopal2016.osim with the lab's marker set): the arms drift
    40-50 mm through it.  R.Biceps on the floor from frame 179: its segment drifted, yet its two mates (R.Elbow,
    R.MElbow) keep their distance to each other and break theirs with it, and it moved the most: its fallen
    positions are taken (its others, among its mates as the base model places them, kept) and nothing else.  L.Wrist,
    its segment's only marker, on the floor from frame 139: its distance to the forearm's marker, itself drifting,
    ranges over a metre: all its positions are taken.  Before, neither was (the segment moved, or no neighbour stood
    still), and the static's forearm pronation centres ended 0.7 and 1.4 m off (scripts/damage_values.py --case
    rajagopal --trial static, seed 23)."""
    from calibrate.seed.seeding import fallen_samples

    model, trial = _rajagopal("static_walk_1.trc")
    assert not fallen_samples(model, trial).any()
    for label, f, kept in (("R.Biceps", 179, True), ("L.Wrist", 139, False)):
        X = np.array(trial.markers)
        j = trial.labels.index(label)
        X[f:, j] = [X[f, j, 0], 0.007, X[f, j, 2]]  # y up
        out = fallen_samples(model, Trial(trial.labels, X, trial.rate))
        m = model.marker_index(label)
        assert out[f:, m].all() and out[:f, m].any() != kept and out.sum() == out[:, m].sum(), (label, out.sum())
    # R.Biceps stuck at its first frame's place: its mates drift away from it, and it moved less than they did
    # (the first version raised an IndexError here: scripts/damage_values.py found it)
    X = np.array(trial.markers)
    X[:, trial.labels.index("R.Biceps")] = X[0, trial.labels.index("R.Biceps")]
    assert not fallen_samples(model, Trial(trial.labels, X, trial.rate)).any()


def test_a_lone_exchange_of_two_segments_is_judged_by_rigidity():
    """Rajagopal's walk (OpenSim's example, Rajagopal2016.osim with the lab's marker set) with R.Knee and R.Wrist
    exchanged from its start to frame 104: the generic model's distances from the knee marker to its thigh cluster
    are not this lab's, and they had named the labelled side (frames 105-237) exchanged: exchanged back there, the
    knee's centre ended 188 mm off (scripts/damage_values.py --case rajagopal, seed 21).  On the exchanged side each
    position keeps its distances to the other segment's markers, on the other side to its own's: frames 0-104 are
    named, by rigidity, and exchanged back to the trial as recorded."""
    from calibrate.seed.seeding import episodes, exchanged_back

    model, trial = _rajagopal("motion_capture_walk.trc")
    i, j = trial.labels.index("R.Knee"), trial.labels.index("R.Wrist")
    X = np.array(trial.markers)
    X[:105, [i, j]] = X[:105, [j, i]]
    damaged = Trial(trial.labels, X, trial.rate)
    back: list = []
    episodes(damaged, model=model, back=back)
    assert [(set(x.labels), x.start, x.stop, x.by) for x in back] == [({"R.Knee", "R.Wrist"}, 0, 105, "rigidity")]
    assert back[0].exchanged < 0.005 < 0.02 < back[0].labelled  # steady to skin's mm exchanged, not as labelled
    assert np.array_equal(exchanged_back(damaged, back).markers, trial.markers, equal_nan=True)


def _rajagopal(trial_name: str):
    """Rajagopal2016.osim with the lab's marker set, and one of its example trials with the labels the model knows
    (skipped where the real trials are not present)."""
    from calibrate.model.model import load_model

    raj = REAL.parent / "rajagopal_walk"
    if not (raj / trial_name).exists():
        pytest.skip("real Rajagopal trials not present")
    model = load_model(raj / "Rajagopal2016.osim", raj / "markerset_walk_preScale.xml")
    trial = read_trial(raj / trial_name)
    return model, trial.select([lab for lab in trial.labels if lab in set(model.marker_names)])


def _gait2392_walk():
    """gait2392.osim with its scale marker set, and OpenSim's example walk with the labels the model knows (skipped
    where the real trials are not present)."""
    from calibrate.model.model import load_model

    g = REAL.parent / "gait2392"
    if not (g / "subject01_walk1.trc").exists():
        pytest.skip("real gait2392 trials not present")
    model = load_model(g / "gait2392.osim", g / "gait2392_Scale_MarkerSet.xml")
    trial = read_trial(g / "subject01_walk1.trc")
    return model, trial.select([lab for lab in trial.labels if lab in set(model.marker_names)])


def test_a_segments_only_marker_fallen_for_under_a_second_far_from_its_neighbours_is_taken():
    """Rajagopal's walk with L.Forearm (the ulna's only marker) on the floor for its last 0.67 s (frames 171-237 at
    100 Hz): judged by its neighbours alone, a one-marker segment was taken only where it lay 1 s or more (a foot's
    only marker stands still through a stance), and the fit pulled the left arm's centres 340 mm off
    (scripts/damage_values.py --case rajagopal, seed 26, copy 47).  There it lies 5-9x further from the elbow's and
    the wrist's markers than elsewhere in the trial: every fallen frame is taken and nothing else; on the floor for
    0.53 s (a window is 0.5 s), the same; and for its last 0.40, 0.33 and 0.18 s, judged in the trial's last three,
    two and one steps of a window (whole windows missed them, and the left arm's centres ended 258 and 506 mm off);
    frozen in the air where it was (still, but not far), nothing."""
    from calibrate.seed.seeding import fallen_samples

    model, trial = _rajagopal("motion_capture_walk.trc")
    assert not fallen_samples(model, trial).any()
    j, m = trial.labels.index("L.Forearm"), model.marker_index("L.Forearm")
    X0 = np.array(trial.markers)
    for first in (171, 185, 198, 205, 220):
        X = X0.copy()
        X[first:, j] = [X[first, j, 0], 0.007, X[first, j, 2]]  # y up
        out = fallen_samples(model, Trial(trial.labels, X, trial.rate))
        assert out[first:, m].all() and not out[:first, m].any() and out.sum() == out[:, m].sum(), first
    X = X0.copy()
    X[171:, j] = X[171, j]  # frozen in the air where it was: still, yet near the arm
    out = fallen_samples(model, Trial(trial.labels, X, trial.rate))
    assert not out[:, m].any()


def test_a_segments_only_marker_next_to_segments_with_one_is_judged_by_the_next_ones_too():
    """Rajagopal's R.Wrist, the radius's only marker, next to the ulna whose only marker is R.Forearm: judged by the
    markers next to it alone, it had one, under the two the check needs, and was never judged -- on the floor from
    frame 100 (1.4 s) none of its positions was taken and the refit ended with the right forearm's centres 1.1 m off;
    on the floor for the walk's last 0.37 s, 377 mm (scripts/damage_values.py --case rajagopal --kinds latefall
    --seed 1174, copy 1).  The humerus's markers, next to the ulna's, now judge it too; and over a window too short
    for a marker a metre away to change its distances to them by FALLEN_TURN (21-29 mm here), a still marker is taken
    where it lies FALLEN_FAR times further from them than elsewhere (R.Forearm in the last 13 frames too, copy 19:
    the right elbow 315 mm off).  Every fallen frame is taken, nothing else."""
    from calibrate.seed.seeding import fallen_samples

    model, trial = _rajagopal("motion_capture_walk.trc")
    X0 = np.array(trial.markers)
    for label, first in (("R.Wrist", 100), ("R.Wrist", 201), ("R.Forearm", 225)):
        j, m = trial.labels.index(label), model.marker_index(label)
        X = X0.copy()
        X[first:, j] = [X[first, j, 0], 0.007, X[first, j, 2]]  # y up
        out = fallen_samples(model, Trial(trial.labels, X, trial.rate))
        assert out[first:, m].all() and not out[:first, m].any() and out.sum() == out[:, m].sum(), (label, first)


def test_a_ghost_before_a_gap_at_the_trials_start_is_left_out_before_the_solve():
    """Rajagopal's walk with L.Ankle 2 m off in frame 3 and unseen for the 17 frames after (scripts/damage_values.py
    --case rajagopal --seed 1171, copy 28): the jumps misread it (the trial's start and the gap leave the frame
    before it alone on its side, and that frame was taken), and broken_samples did not judge the tibia at all -- the
    model carries 14 markers there, over SEED_BROKEN_GROUP, where the trial shows 5.  The ghost, kept into the solve,
    was rejected there only after it had drawn hip_l 66 mm from the calibration with it unseen.  Judged on the
    markers the trial shows, its distances to the shank's markers broken by 2 m (over GHOST_BREAK), it is left out
    before the solve: the calibration equals the one with it unseen."""
    from calibrate.seed.seeding import broken_samples, jumped_samples

    model, trial = _rajagopal("motion_capture_walk.trc")
    j, m = trial.labels.index("L.Ankle"), model.marker_index("L.Ankle")
    X = np.array(trial.markers)
    X[3, j] += [1.7848, -0.4086, -0.7992]
    X[4:21, j] = np.nan
    damaged = Trial(trial.labels, X, trial.rate)
    assert broken_samples(model, damaged)[3, m] and jumped_samples(model, [damaged])[3, m]
    assert not jumped_samples(model, [trial]).any()
    U = X.copy()
    U[3, j] = np.nan
    cal, unseen = calibrate(model, damaged), calibrate(model, Trial(trial.labels, U, trial.rate))
    assert any(o.marker == "L.Ankle" and o.frame == 3 and o.before for o in cal.outliers)
    shift = np.linalg.norm(np.array(cal.params.centre) - np.array(unseen.params.centre), axis=1)
    assert shift.max() < 2e-3, shift.max()


def test_a_marker_rejected_in_bulk_far_from_its_place_is_calibrated_again_without(monkeypatch):
    """The outlier test's safety net: gait2392's walk with R.Thigh.Rear on the floor for its last 41 of 151 frames,
    with seeding.fallen_samples made to miss it (as it did before FALLEN_MATES), and the ghost check too
    (GHOST_BREAK).  The fit smears the marker's place (its residuals 140-470 mm in every frame): the test, its noise
    floor per marker capped at NOISE_CAP, rejects exactly the 41, yet the solve from the distorted geometry ended
    with the hips 44-70 mm from the calibration with them unseen (3 posterior SDs 3.6 mm).  Calibrated again from
    the start without them (pipeline.refit_outliers), it equals that calibration and reports the 41 as outliers."""
    import calibrate.seed.seeding as seeding
    from calibrate.calibration.pipeline import refit_outliers

    model, trial = _gait2392_walk()
    X = np.array(trial.markers)
    j = trial.labels.index("R.Thigh.Rear")
    X[110:, j] = [X[110, j, 0], 0.007, X[110, j, 2]]  # y up
    U = X.copy()
    U[110:, j] = np.nan
    unseen = calibrate(model, Trial(trial.labels, U, trial.rate))
    assert not refit_outliers(unseen)
    monkeypatch.setattr(seeding, "fallen_samples", lambda m, t: np.zeros((t.n_frames, len(m.markers)), dtype=bool))
    monkeypatch.setattr(seeding, "GHOST_BREAK", np.inf)  # (its distances to the thigh's markers broken: a ghost's)
    cal = calibrate(model, Trial(trial.labels, X, trial.rate))
    assert "first run" in cal.times
    fallen = sorted(o.frame for o in cal.outliers if o.marker == "R.Thigh.Rear")
    assert fallen == list(range(110, 151))
    shift = np.linalg.norm(np.array(cal.params.centre) - np.array(unseen.params.centre), axis=1)
    assert shift.max() < 1e-3, shift.max()


@pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")
def test_a_fallen_marker_leaves_the_subjects_size_as_if_unseen(human):
    """pig_walk's walk (300 frames) with RFRM on the floor from frame 88: every fallen position is left out of the
    seed and the solve, but the subject's size was read from the trial as recorded -- the right arm's from the floor
    for most of its frames (0.72 against 0.86) -- and the right shoulder ended 49 mm from the calibration with those
    positions unseen (scripts/damage_values.py --kinds fallen --seed 30, copy 2; its posterior SD 12 mm).  Read from
    the cleaned trial, every centre is within one posterior SD of that calibration's (0.0 mm where the two arrays share
    a memory layout; the wrists 10 mm, SD 25, where not: a flat valley's end follows the arithmetic)."""
    trial, _ = map_labels(read_trial(REAL / "walk.c3d"), human.marker_names)
    trial = trial.select([lab for lab in trial.labels if lab in set(human.marker_names)])
    X = np.array(trial.markers[:300])
    j = trial.labels.index("RFRM")
    X[88:, j] = [X[88, j, 0], X[88, j, 1], 0.007]  # z up
    U = X.copy()
    U[88:, j] = np.nan
    fallen = calibrate(human, Trial(trial.labels, X, trial.rate))
    unseen = calibrate(human, Trial(trial.labels, U, trial.rate))
    assert sorted(o.frame for o in fallen.outliers if o.marker == "RFRM") == list(range(88, 300))
    assert all(o.before for o in fallen.outliers if o.marker == "RFRM")
    shift = np.linalg.norm(np.array(fallen.params.centre) - np.array(unseen.params.centre), axis=1)
    sd = {c.item: 1e-3 * float(np.linalg.norm(c.std)) for c in unseen.changes if c.group == "centre"}
    within = [shift[i] <= sd.get(j.name, 1e-3) for i, j in enumerate(human.joints)]
    assert all(within), {j.name: round(1e3 * shift[i], 1) for i, j in enumerate(human.joints) if not within[i]}


def test_a_thigh_marker_fallen_late_in_a_slowing_walk_is_taken():
    """gait2392's walk (OpenSim's example, its .osim and marker set) with R.Thigh.Rear on the floor for its last 0.68 s
    (frames 110-150 at 60 Hz), where the subject slows: the thigh's other markers travel 67-125 mm per half window,
    yet the floor point lies 0.5 m below them and their distances to it range only 24-27 mm.  Its own markers'
    distances are judged at FALLEN_MATES (20 mm; a rigid turn about it keeps them to the skin's few mm): every fallen
    frame is taken and nothing else (with 30 mm none was, and the fit ended 48.7 mm RMS: scripts/damage_values.py
    --case gait2392, seed 28)."""
    from calibrate.seed.seeding import fallen_samples

    model, trial = _gait2392_walk()
    assert not fallen_samples(model, trial).any()
    X = np.array(trial.markers)
    j = trial.labels.index("R.Thigh.Rear")
    X[110:, j] = [X[110, j, 0], 0.007, X[110, j, 2]]  # y up
    out = fallen_samples(model, Trial(trial.labels, X, trial.rate))
    m = model.marker_index("R.Thigh.Rear")
    assert out[110:, m].all() and not out[:110, m].any() and out.sum() == out[:, m].sum(), int(out.sum())
