"""A rigid cluster of new labels placed on a segment whose model markers the trial never shows
(calibrate.calibration.hosts.cluster_hosts): a head band the model spells otherwise (AddBiomechanics'
initial_off_treadmill: LHEAD, RHEAD, FHEAD, THEAD against human.urdf's LFHD, RFHD, LBHD, RBHD; the head was left
unresolved, its neck locked, and the four labels ignored)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate.calibration.hosts import CLUSTER_REACH, cluster_hosts
from calibrate.calibration.pipeline import calibrate
from calibrate.model.model import load_model
from calibrate.problem.settings import Settings
from calibrate.seed.association import associate_to_model
from calibrate.simulation import simulate_squats

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
BAND = {"LFHD": "HB1", "RFHD": "HB2", "LBHD": "HB3", "RBHD": "HB4"}  # the model's head markers, relabelled
FLOOR = ("F1", "F2", "F3")  # a rigid triad on the floor


def _session():
    """Squats of a human.urdf subject with its head markers relabelled (the model no longer knows them) and a
    rigid triad lying on the floor; returns the trial and the subject's head-marker places on the head (m)."""
    base = load_model(HUMAN)
    sim = simulate_squats(base, frames=200, noise_mm=0.5, seed=11)
    rng = np.random.default_rng(11)
    labels = tuple(BAND.get(lab, lab) for lab in sim.trial.labels)
    tri = np.array([[0.6, 0.8, 0.0], [0.7, 0.8, 0.0], [0.6, 0.9, 0.0]])
    floor = tri[None] + rng.normal(0.0, 0.0005, (sim.trial.n_frames, 3, 3))
    trial = replace(sim.trial, labels=(*labels, *FLOOR), markers=np.concatenate([sim.trial.markers, floor], axis=1))
    s = sim.truth.scale[base.segment_index("head")]
    return trial, {BAND[n]: s * sim.truth.marker[base.marker_index(n)] for n in BAND}


def test_a_head_band_goes_on_the_head_whose_model_markers_the_trial_does_not_show():
    """The relabelled head markers are rigid with each other and with no segment's known markers (the head's are
    unseen); their centroid keeps the distances to the trunk's markers that the head's model markers' centroid has in
    the base model (the one unseen segment), within CLUSTER_REACH, though the subject's neck turns; the floor triad is
    rigid too, but placed nothing like the head, and stays out."""
    base = load_model(HUMAN)
    trial, _ = _session()
    assoc = associate_to_model(base, trial)
    labels = [*BAND.values(), *FLOOR]
    assert all(assoc[n].segment is None for n in labels), [assoc[n].reason for n in labels]
    hosts = cluster_hosts(base, [trial], labels, assoc.threshold)
    for n in BAND.values():
        h = hosts[n]
        assert h.segment == "head" and set(h.labels) == set(BAND.values()), h
        assert h.distance < CLUSTER_REACH and h.runner_up_distance > 2 * h.distance, h
        assert h.reason(n).startswith("rigid with ") and "markers of head" in h.reason(n)
    for n in FLOOR:
        assert hosts[n].segment is None and hosts[n].distance > CLUSTER_REACH, hosts[n]


def test_the_calibration_fits_the_head_band_and_turns_the_neck():
    """calibrate puts the band on the head, the head no longer unresolved (its neck turns, its centre held at the
    base model's), and fits the band's markers where the simulator put the head's: their distances to each other
    within 3 mm of the subject's."""
    base = load_model(HUMAN)
    trial, places = _session()
    cal = calibrate(base, trial, Settings())
    placed = {m.label: m.segment for m in cal.new_markers}
    assert all(placed[n] == "head" for n in BAND.values()), placed
    assert all(placed[n] is None for n in FLOOR), placed
    assert not cal.unresolved and not any(d.startswith("neck") for d in cal.locked), (cal.unresolved, cal.locked)
    assert "neck" in cal.settings.hold_centres  # the band's places and the neck's centre would trade: centre held
    s = cal.params.scale[base.segment_index("head")]
    fitted = {n: s * cal.params.marker[cal.model.marker_index(n)] for n in places}
    names = list(places)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            truth = np.linalg.norm(places[a] - places[b])
            assert abs(np.linalg.norm(fitted[a] - fitted[b]) - truth) < 0.003, (a, b, truth)
