"""Marker-to-segment association (Ringer & Lasenby, Section 3) on the project's simulated squats."""

from __future__ import annotations

from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from calibrate.io.trial import Trial
from calibrate.model.model import load_model
from calibrate.seed.association import (
    associate,
    associate_to_model,
    group_adjacency,
    misplaced_labels,
    tied_hypotheses,
)
from calibrate.seed.jitter import jittery_samples
from calibrate.seed.rigidity import RIGID_FLOOR, distance_variance, group_markers, pair_distance_level, rigid_threshold
from calibrate.simulation.simulate import simulate_squats

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
FRAMES = 300


@cache
def _sim(seed: int, noise_mm: float, gaps: bool):
    return simulate_squats(_human(), frames=FRAMES, noise_mm=noise_mm, seed=seed, gaps=gaps)


@cache
def _human():
    return load_model(HUMAN)


def true_groups(model) -> set[frozenset[int]]:
    """Marker indices grouped by their model segment (segments with markers only)."""
    by_seg: dict[str, set[int]] = {}
    for k, m in enumerate(model.markers):
        by_seg.setdefault(m.segment, set()).add(k)
    return {frozenset(g) for g in by_seg.values()}


def contracted_adjacency(model) -> set[frozenset[str]]:
    """Model joints between segments that carry markers; a segment without markers (the talus)
    is contracted, so its parent and child (tibia and calcaneus) count as adjacent."""
    parent = {j.child: j.parent for j in model.joints}
    has = {s.name: bool(s.markers) for s in model.segments}
    out = set()
    for s in model.segments:
        if not s.markers or s.name not in parent:
            continue
        p = parent[s.name]
        while not has[p]:
            p = parent[p]
        out.add(frozenset((s.name, p)))
    return out


# ------------------------------------------------------------------ distance variance, threshold, greedy
def test_distance_variance_matches_direct_computation():
    rng = np.random.default_rng(3)
    F, N = 60, 5
    X = rng.normal(size=(F, N, 3))
    X[rng.random((F, N)) < 0.2] = np.nan  # gaps
    X[5:, 4] = np.nan  # marker 4 seen in only 5 frames
    D = distance_variance(X)
    for i in range(N):
        for j in range(N):
            both = np.isfinite(X[:, i, 0]) & np.isfinite(X[:, j, 0])
            if i == j:
                assert D[i, j] == 0.0
            elif both.sum() < 10:
                assert D[i, j] == np.inf
            else:
                d = np.linalg.norm(X[both, i] - X[both, j], axis=1)
                assert D[i, j] == pytest.approx(np.var(d, ddof=1), rel=1e-10)


def test_noise_level_and_threshold_from_the_data():
    sim = _sim(0, 1.0, False)
    D = distance_variance(sim.trial.markers)
    # A rigid pair's distance varies by the noise projected on the pair's line: variance 2σ², σ = 1 mm.
    assert pair_distance_level(D) == pytest.approx(2e-6, rel=0.05)
    thr = rigid_threshold(D, FRAMES)
    assert 1.2 * 2e-6 < thr < 1.6 * 2e-6
    assert rigid_threshold(D) == pytest.approx(9 * pair_distance_level(D))  # frame count unknown: 3x in std
    clean = distance_variance(sim.clean_markers)
    assert rigid_threshold(clean, FRAMES) == RIGID_FLOOR


def test_greedy_complete_linkage_and_planted_inconsistency():
    big = 100.0
    D = np.full((6, 6), big)
    np.fill_diagonal(D, 0.0)
    for (i, j), v in {(0, 1): 1.0, (0, 2): 2.0, (1, 2): 3.0, (3, 4): 1.5, (2, 3): 0.5}.items():
        D[i, j] = D[j, i] = v
    g = group_markers(D, threshold=5.0)
    # (2, 3) is the smallest entry: a new group; 4 may not join it (D[2, 4] is large: complete
    # linkage), so (3, 4) is an inconsistency, and so are (0, 2) and (1, 2) once {0, 1} exists.
    assert g.groups == ((0, 1), (2, 3), (4,), (5,))
    assert {(i, j) for i, j, _ in g.inconsistencies} == {(3, 4), (0, 2), (1, 2)}
    assert {v for *_, v in g.inconsistencies} == {1.5, 2.0, 3.0}
    # Without the planted pair the true groups come out and nothing is inconsistent.
    D[2, 3] = D[3, 2] = big
    g = group_markers(D, threshold=5.0)
    assert g.groups == ((0, 1, 2), (3, 4), (5,)) and g.inconsistencies == ()


# ------------------------------------------------------------------ unlabelled trajectories
EXACT = [(1.0, False, s) for s in (0, 2, 3)] + [(0.0, False, s) for s in range(4)] + [(1.0, True, s) for s in (0, 2, 3)]


@pytest.mark.parametrize("noise_mm,gaps,seed", EXACT)
def test_unlabelled_markers_grouped_by_segment(human, noise_mm, gaps, seed):
    sim = _sim(seed, noise_mm, gaps)
    res = associate(sim.trial.markers)  # labels are not used
    assert {frozenset(g) for g in res.best.groups} == true_groups(human)
    assert res.best.admissible
    # The tree of presumed joints: one edge per model joint between segments with markers.
    seg_of_group = [human.markers[g[0]].segment for g in res.best.groups]
    got = {frozenset((seg_of_group[e.a], seg_of_group[e.b])) for e in res.adjacency.tree}
    assert got == contracted_adjacency(human)


@pytest.mark.parametrize("gaps", [False, True])
def test_marker_on_hinge_axis_is_reported_when_undecidable(human, gaps):
    """Seed 1: the left elbow marker lies on the elbow axis to within ~0.2 mm, so its distance to
    the forearm marker varies as little as its distance to the upper-arm marker (1.38 vs 1.40 mm
    std at 1 mm noise).  Its segment cannot be told from the data; it must be flagged."""
    sim = _sim(1, 1.0, gaps)
    names = human.marker_names
    res = associate(sim.trial.markers, names)
    truth = true_groups(human)
    tied = tied_hypotheses(res.hypotheses, res.sigma)
    assert any({frozenset(g) for g in h.groups} == truth for h in tied)
    flagged = {names[i] for i in res.ambiguous}
    assert "LELB" in flagged
    best = res.best.label(len(names))
    for i, name in enumerate(names):
        if name not in flagged:
            assert frozenset(res.best.groups[best[i]]) in truth, name


def test_paper_tree_and_joint_tests(human):
    """On the true groups: the paper's greedy on mean centroid distance alone joins the two feet
    in some seeds; the joint-aware tree does not, and the ball joints pass the sphere test."""
    groups = [tuple(human.marker_index(k) for k in s.markers) for s in human.segments if s.markers]
    names = [s.name for s in human.segments if s.markers]
    expected = contracted_adjacency(human)
    paper_wrong = 0
    for seed in range(4):
        adj = group_adjacency(_sim(seed, 1.0, False).trial.markers, groups)
        tree = {frozenset((names[e.a], names[e.b])): e for e in adj.tree}
        assert set(tree) == expected
        paper_wrong += len({frozenset((names[e.a], names[e.b])) for e in adj.greedy_tree} - expected)
        for a, b in [("pelvis", "femur_l"), ("pelvis", "torso"), ("torso", "head"), ("torso", "humerus_r")]:
            assert tree[frozenset((a, b))].joint_rms < 2.0e-3  # noise 1 mm; a wrong pair is centimetres
        assert np.isnan(tree[frozenset(("femur_l", "tibia_l"))].joint_rms)  # two 2-marker groups: untestable
    assert paper_wrong > 0


# ------------------------------------------------------------------ against the model
def _tibia_point(sim, model, offset: float, rng, noise: float = 1e-3) -> np.ndarray:
    """A point fixed on the right tibia: built from the knee and ankle centres and RTIB (all fixed on it), with
    `noise` (m SD) added."""
    C = sim.clean_centres
    knee, ankle = C[:, model.joint_index("knee_r")], C[:, model.joint_index("ankle_r")]
    tib = sim.clean_markers[:, model.marker_index("RTIB")]
    e1 = (ankle - knee) / np.linalg.norm(ankle - knee, axis=1, keepdims=True)
    v = tib - knee
    v -= np.sum(v * e1, axis=1, keepdims=True) * e1
    e2 = v / np.linalg.norm(v, axis=1, keepdims=True)
    e3 = np.cross(e1, e2)
    p = knee + 0.6 * (ankle - knee) + offset * e3
    return p + rng.normal(0.0, noise, p.shape)


def test_associate_to_model_places_unknown_markers(human):
    sim = _sim(0, 1.0, False)
    rng = np.random.default_rng(7)
    renamed = {"RTHI": "X1", "LWRA": "X2", "C7": "X3"}
    labels = [renamed.get(lab, lab) for lab in sim.trial.labels]
    tibia_point = _tibia_point(sim, human, 0.05, rng)
    start = sim.clean_markers[0, human.marker_index("LASI")]
    walk = start + np.cumsum(rng.normal(0.0, 3e-3, (FRAMES, 3)), axis=0)  # moves on its own
    markers = np.concatenate([sim.trial.markers, tibia_point[:, None], walk[:, None]], axis=1)
    trial = Trial(labels=(*labels, "X4", "X5"), markers=markers, rate=sim.trial.rate)
    res = associate_to_model(human, trial)

    expected = {"X3": "torso", "X4": "tibia_r"}
    for lab, seg in expected.items():
        assert res[lab].segment == seg and res[lab].status == "assigned", (lab, res[lab].reason)
    # Renamed away, RTHI and LWRA leave femur_r and radius_l one marker each the trial shows (RKNE, LWRB): a marker
    # across the joint beside it would keep its distance to it too, so rigidity leaves them to the model's poses.
    for lab, (seg, ref) in {"X1": ("femur_r", "RKNE"), "X2": ("radius_l", "LWRB")}.items():
        assert res[lab].segment is None, (lab, res[lab].reason)
        assert res[lab].reason.startswith(f"rigid only with the one marker of {seg} ({ref})"), (lab, res[lab].reason)
    assert res["X5"].segment is None and res["X5"].status == "unassigned"
    assert "varies by" in res["X5"].reason and "talus" in res["X5"].reason
    # The reported figure is the smallest worst-pair std over segments, recomputed here directly.
    D = distance_variance(markers)
    k = len(labels) + 1
    per_segment = [max(D[k, labels.index(m)] for m in s.markers if m in labels)
                   for s in human.segments if any(m in labels for m in s.markers)]
    assert res["X5"].spread == pytest.approx(np.sqrt(min(per_segment)))
    assert res["X5"].spread > np.sqrt(res.threshold)
    for lab in labels:
        if lab not in (*expected, "X1", "X2"):
            assert res[lab].status == "known" and res[lab].segment == human.markers[human.marker_index(lab)].segment
    assert res.suspects == [] and res.unassigned == ["X1", "X2", "X5"]


def test_model_markers_the_trial_never_shows_neither_check_nor_place_others(human):
    """The pipeline hands every model marker to associate_to_model, seen or not: a model marker with no sample
    (gait models' virtual joint-centre markers, a marker written as zeros throughout) must not make its segment's
    seen markers 'suspect', nor hide a trial marker's rigidity with the segment behind a NaN ('never seen long
    enough' for the Hamner running trial's head markers, seen in every frame)."""
    sim = _sim(0, 1.0, False)
    labels = list(sim.trial.labels)
    markers = sim.trial.markers.copy()
    for lab in ("C7", "T10", "CLAV", "LKNE"):  # in the trial, never seen
        markers[:, labels.index(lab)] = np.nan
    labels[labels.index("STRN")] = "X3"  # the torso's sternum marker, unknown to the model
    res = associate_to_model(human, Trial(labels=tuple(labels), markers=markers, rate=sim.trial.rate))
    assert res["X3"].segment == "torso" and res["X3"].status == "assigned", res["X3"].reason
    assert res.suspects == []
    for lab in ("C7", "T10", "CLAV", "LKNE"):
        assert res[lab].status == "known" and "not in the trial" in res[lab].reason
    assert res["LTHI"].status == "known"  # its only partner never seen: nothing to check it against
    # A trial marker rigid with no segment gets the figure that ruled it out, not 'never seen'.
    walk = markers[:, labels.index("LASI")] + np.cumsum(np.random.default_rng(3).normal(0, 3e-3, (FRAMES, 3)), 0)
    res = associate_to_model(human, Trial(labels=(*labels, "X5"), markers=np.concatenate([markers, walk[:, None]], 1),
                                          rate=sim.trial.rate))
    assert res["X5"].status == "unassigned" and res["X5"].reason.startswith("varies by"), res["X5"].reason
    # A trial label with no position at all (a marker set's label the session did not use: BTKData's FunctionalWalk
    # lists its arms and medial markers, empty) says so, not 'never seen long enough together with any model marker'.
    empty = np.full((FRAMES, 1, 3), np.nan)
    res = associate_to_model(human, Trial(labels=(*labels, "LKNEin"), markers=np.concatenate([markers, empty], 1),
                                          rate=sim.trial.rate))
    assert res["LKNEin"].status == "unassigned" and res["LKNEin"].reason == "no position in any frame of the trial"


def test_associate_to_model_reports_mislabelled_markers(human):
    sim = _sim(2, 1.0, True)
    labels = list(sim.trial.labels)
    i, j = labels.index("T10"), labels.index("LPSI")
    labels[i], labels[j] = labels[j], labels[i]  # swapped labels: each sits on the other's segment
    res = associate_to_model(human, replace(sim.trial, labels=tuple(labels)))
    assert sorted(res.suspects) == ["LPSI", "T10"]
    assert res["T10"].segment == "torso"  # reported, not moved
    assert all(m in res["LPSI"].reason for m in ("LASI", "RASI", "RPSI"))
    assert all(res[lab].status == "known" for lab in labels if lab not in ("T10", "LPSI"))


PIG = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real" / "pig_walk"


@pytest.mark.parametrize("sta_mm", [3.0, 10.0])
def test_a_label_exchanged_across_segments_for_the_whole_trial_is_named(sta_mm):
    """Squats with soft-tissue artefact: the true labels ride with their segments; a knee label exchanged with
    the ankle's for the whole trial rides with the foot's markers, and is named with the segment it moves with.
    (The simulator's truth: which marker is on which segment.)"""
    human = _human()
    trial = simulate_squats(human, frames=300, noise_mm=0.5, sta_mm=sta_mm, seed=2).trial
    assert misplaced_labels(human, [trial]) == ()
    labels = list(trial.labels)
    i, j = labels.index("RKNE"), labels.index("RANK")
    labels[i], labels[j] = labels[j], labels[i]
    found = {m.label: m for m in misplaced_labels(human, [Trial(labels, trial.markers, trial.rate)])}
    assert "RKNE" in found and found["RKNE"].segment == "femur_r"
    assert found["RKNE"].rides_with in ("tibia_r", "talus_r", "calcn_r")  # the shank or the foot: the ankle marker's
    assert found["RKNE"].sd_own > 3 * found["RKNE"].sd_other
    # the exchange that puts every label back on its segment is proposed (with the thigh and shank wands', which
    # rigidity cannot tell from it: both segments carry two markers)
    assert ("RKNE", "RANK") in found["RKNE"].exchanges and ("RTHI", "RTIB") in found["RKNE"].exchanges
    # within one segment an exchange cannot be seen by rigidity (and only moves the two markers' offsets)
    labels = list(trial.labels)
    i, j = labels.index("RHEE"), labels.index("RTOE")
    labels[i], labels[j] = labels[j], labels[i]
    assert misplaced_labels(human, [Trial(labels, trial.markers, trial.rate)]) == ()


def test_a_ghost_spike_does_not_make_a_label_look_misplaced():
    """One frame of a marker a metre off (a ghost: a wrong ray match), alone or at the edge of a gap (which no jump
    bounds), set the SD of every distance of its marker: a correct label then rode "with another segment" and a
    partner was named (a 400 mm spike in one of 150 frames read as 33 mm).  The samples that jump away and back or
    break their segment's distances are now left out first (seeding.without_broken); a label exchanged for the whole
    trial is still named with the spikes there.
    (The simulator's truth: every label on its segment.)"""
    human = _human()
    trial = simulate_squats(human, frames=300, noise_mm=0.5, sta_mm=3.0, seed=2).trial
    X = np.array(trial.markers)
    k, j, h = (trial.labels.index(n) for n in ("RKNE", "LTHI", "RELB"))
    X[100, k] += [1.0, 0.0, 0.0]  # a ghost in one frame
    X[150, j] += [0.0, -0.8, 0.0]  # ... and one before a gap
    X[151:160, j] = np.nan
    X[40, h] += [0.0, 0.0, 2.0]
    X[41, h] += [0.0, 0.0, 2.0]  # two frames running
    spiked = Trial(trial.labels, X, trial.rate)
    assert np.sqrt(distance_variance(X[::2, [k, trial.labels.index("RTHI")]]))[0, 1] > 0.05  # the plain SD: 50+ mm
    assert misplaced_labels(human, [spiked]) == ()
    labels = list(trial.labels)
    labels[k], labels[trial.labels.index("RANK")] = "RANK", "RKNE"
    found = {m.label for m in misplaced_labels(human, [Trial(labels, X, trial.rate)])}
    assert "RKNE" in found


def test_the_real_plug_in_gait_trials_raise_no_label_to_check():
    if not (PIG / "walk.c3d").exists():
        pytest.skip("pig_walk is not in ../shared/data/real")
    from calibrate.io.read import read_trial

    for name in ("static.c3d", "walk.c3d"):
        assert misplaced_labels(_human(), [read_trial(PIG / name)]) == (), name


def test_a_static_places_a_new_marker_on_the_nearest_of_the_segments_it_is_rigid_with(human):
    """A static moves no segment against another, so a new marker is rigid with many segments to within the noise;
    it goes on the nearest of them, not on the one whose distance variance the noise made the smallest (BTKData's
    FunctionalStatic put the left shank's cluster marker on tibia_r, 150 mm off in the walk fitted after it).  Six
    markers 3 cm off a marker of six segments, a 1 mm noise static of the simulated subject: each on its own
    segment, on every one of three draws."""
    from calibrate.model.model import add_markers
    from calibrate.simulation.simulate import simulate_static

    hosts = {"N1": ("tibia_l", "LTIB"), "N2": ("tibia_r", "RTIB"), "N3": ("femur_l", "LTHI"),
             "N4": ("femur_r", "RTHI"), "N5": ("humerus_l", "LUPA"), "N6": ("radius_r", "RWRA")}
    p = human.parameters()
    extra = {name: (seg, p.marker[human.marker_index(ref)] + np.array([0.03, 0.0, 0.0]))
             for name, (seg, ref) in hosts.items()}
    marked = add_markers(human, extra)
    truth = simulate_squats(human, frames=10, noise_mm=0.0, seed=1).truth
    tp = marked.parameters()
    tp.scale[:] = truth.scale
    for seed in (1, 2, 3):
        static = simulate_static(marked, tp, frames=100, noise_mm=1.0, seed=seed)
        res = associate_to_model(human, static.trial)
        for name, (seg, _) in hosts.items():
            assert res[name].segment == seg and res[name].status == "assigned", (seed, name, res[name].reason)


def _only_the_walk_judged(human, static: Trial, walk) -> None:
    """Calibrated with `walk`'s trial with LKNE and LANK exchanged: only the walk's labels are named, the exchange
    among them."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.problem.settings import Settings

    swapped = list(walk.trial.labels)
    a, b = swapped.index("LKNE"), swapped.index("LANK")
    swapped[a], swapped[b] = swapped[b], swapped[a]
    moving = Trial(tuple(swapped), walk.trial.markers, 100.0, 0, "walk.c3d")
    cal = calibrate(human, [static, moving], Settings(max_iterations=5))
    assert {i for i, _ in cal.misplaced} == {1}
    assert {m.label for _, m in cal.misplaced} & {"LKNE", "LANK"}


def test_a_still_trial_is_not_judged_for_misplaced_labels():
    """In a still trial every label keeps its distance to every segment's markers, so the rigidity test weighs only
    their noise: a static whose torso markers wander 8 mm (filtered video keypoints: smooth, so not jitter, which
    seed.jitter would take out) but T10 names T10 (and more) "riding with" a thigh.  The pipeline judges only the
    trials that move; the static's labels are not flagged, the walk's still are."""
    from calibrate.simulation.simulate import simulate_gait, simulate_static

    human = _human()
    walk = simulate_gait(human, frames=60, noise_mm=0.3, seed=2)
    static = simulate_static(human, walk.truth, frames=60, noise_mm=0.3, seed=2)
    X = static.trial.markers.copy()
    rng = np.random.default_rng(0)
    t = np.arange(X.shape[0])[:, None, None] / 100.0
    for m in human.markers:
        if m.segment == "torso" and m.name != "T10":  # three sines of 1-3 Hz per coordinate, 8 mm SD in all
            wave = np.sin(2 * np.pi * rng.uniform(1.0, 3.0, (1, 3, 3)) * t + rng.uniform(0, 2 * np.pi, (1, 3, 3)))
            X[:, human.marker_index(m.name)] += 0.008 * np.sqrt(2.0 / 3.0) * wave.sum(axis=2)
    jittery = Trial(static.trial.labels, X, 100.0, 0, "static.c3d")
    assert not jittery_samples(jittery)[0].any()
    assert "T10" in [m.label for m in misplaced_labels(human, [jittery])]  # the test alone is fooled
    _only_the_walk_judged(human, jittery, walk)


def test_a_trial_whose_segments_jitter_as_much_as_they_move_is_not_judged():
    """Augmented keypoints (Pose2Sim's LSTM static) move against each other on one segment nearly as much as across the
    joints, and the rigidity test then weighs their jitter: here every segment's markers jitter 8 mm but the left
    shank's, and LKNE rides with the shank: alone the test names LKNE, and the static moves more than a still
    trial does (relative_motion past STILL_MOTION).  The pipeline judges a trial only where its markers on different
    segments move MISPLACED_MOTION times as much as those on one segment: the static is not judged, a walk with LKNE
    and LANK exchanged still is."""
    from calibrate.calibration.pipeline import (
        MISPLACED_MOTION,
        STILL_MOTION,
        relative_motion,
        segment_jitter,
    )
    from calibrate.simulation.simulate import simulate_gait, simulate_static

    human = _human()
    walk = simulate_gait(human, frames=60, noise_mm=0.3, seed=2)
    static = simulate_static(human, walk.truth, frames=60, noise_mm=0.3, seed=2)
    X = static.trial.markers.copy()
    rng = np.random.default_rng(0)
    shank = [human.marker_index(m.name) for m in human.markers if m.segment == "tibia_l"]
    for m in human.markers:
        k = human.marker_index(m.name)
        if m.segment != "tibia_l" and m.name != "LKNE":
            X[:, k] += rng.normal(0.0, 0.008, (X.shape[0], 3))
    X[:, human.marker_index("LKNE")] = X[:, human.marker_index("LKNE")] + (X[:, shank] - static.trial.markers[:, shank]
                                                                           ).mean(axis=1)
    jittery = Trial(static.trial.labels, X, 100.0, 0, "static.c3d")
    assert "LKNE" in [m.label for m in misplaced_labels(human, [jittery])]  # the test alone is fooled
    assert relative_motion(jittery, human) >= STILL_MOTION
    assert relative_motion(jittery, human) < MISPLACED_MOTION * segment_jitter(jittery, human)
    assert relative_motion(walk.trial, human) > MISPLACED_MOTION * segment_jitter(walk.trial, human)
    _only_the_walk_judged(human, jittery, walk)


def test_landmarks_reconstructed_from_one_cluster_ride_on_its_segment(human):
    """A lab's anatomical landmarks reconstructed from one cluster keep their distances to each other exactly
    (MOtoNMS's UNIPD walks: the greater trochanter 0.01 mm SD from the lateral epicondyle).  With the femur showing its
    knee marker alone, a trochanter so reconstructed rides on femur_r, and with the shank showing its ankle marker
    alone, a point on the shank rides on tibia_r: their distances to the markers across the segment's joints vary many
    times as much (association.ACROSS_EXACT, ACROSS_FLOOR).  The same points as skin markers, noisy on their own, are
    left to the model's poses as any label rigid with one marker of a segment is; and the shank's point with the thigh
    showing its knee marker alone too stays out: on the knee's axis, that marker keeps within 2 mm of it.  Truth: the
    simulator's clean centres and markers."""
    sim = _sim(0, 1.0, False)
    rng = np.random.default_rng(11)
    C, clean = sim.clean_centres, sim.clean_markers
    hip, knee = C[:, human.joint_index("hip_r")], C[:, human.joint_index("knee_r")]
    kne = clean[:, human.marker_index("RKNE")]
    side = (kne - knee) / np.linalg.norm(kne - knee, axis=1, keepdims=True)
    points = {"RGT": (hip + 0.06 * side, "RKNE", "femur_r", "RTHI"),  # 60 mm lateral of the hip centre
              "RTT": (_tibia_point(sim, human, 0.03, rng, noise=0.0), "RANK", "tibia_r", "RTIB")}

    def judged(lab: str, drop: tuple[str, ...], exact: bool):
        point, ref, _, _ = points[lab]
        keep = [k for k, name in enumerate(sim.trial.labels) if name not in drop]
        labels = tuple(sim.trial.labels[k] for k in keep)
        noisy = sim.trial.markers[:, keep]
        at = noisy[:, labels.index(ref)] + (point - clean[:, human.marker_index(ref)]) if exact else \
            point + rng.normal(0.0, 1e-3, point.shape)
        return associate_to_model(human, Trial((*labels, lab), np.concatenate([noisy, at[:, None]], axis=1),
                                               sim.trial.rate))[lab]

    for lab, (_, ref, seg, other) in points.items():
        got = judged(lab, (other,), exact=True)
        assert got.segment == seg and got.status == "assigned", (lab, got.reason)
        assert got.reason.startswith(f"rigid with {ref}, the one marker of {seg} the trial shows"), got.reason
        assert got.spread < 1e-6
        got = judged(lab, (other,), exact=False)
        # (the shank's point may be rigid with RKNE too: the simulator keeps it on the knee's axis)
        assert got.segment is None and got.reason.startswith("rigid only with the one marker of") and \
            f"{seg} ({ref})" in got.reason.split(" the trial shows")[0], (lab, got.reason)
    got = judged("RTT", ("RTIB", "RTHI"), exact=True)
    assert got.segment is None and got.reason.startswith("rigid only with the one marker of") and \
        "tibia_r (RANK)" in got.reason.split(" the trial shows")[0], got.reason
