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


def test_the_calibration_fits_the_head_band_and_turns_the_neck(tmp_path):
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
    # ... and said so, not as the user's --hold-centres
    assert cal.cluster_centres == ("neck",) and cal.report()["cluster_centres"] == ["neck"]
    text = cal.text().splitlines()
    line = next(ln for ln in text if ln.startswith("  centres held") and "neck" in ln)
    assert "only a cluster of new labels" in line and "--hold-centres" not in line, line
    assert any(ln.strip().startswith("neck") and "(held: a cluster of new labels below" in ln for ln in text)
    cal.write(report=tmp_path / "s.json", html=tmp_path / "s.html")
    assert "carrying only a cluster of new labels: neck</li>" in (tmp_path / "s.html").read_text()
    s = cal.params.scale[base.segment_index("head")]
    fitted = {n: s * cal.params.marker[cal.model.marker_index(n)] for n in places}
    names = list(places)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            truth = np.linalg.norm(places[a] - places[b])
            assert abs(np.linalg.norm(fitted[a] - fitted[b]) - truth) < 0.003, (a, b, truth)


def test_a_cluster_by_the_hip_is_not_put_on_an_unseen_hand():
    """A rigid triad beside the left hip (following it, turning with nothing) while the trial shows none of the
    left forearm's and hand's markers: a hanging hand's place in the neutral pose lies there, but a hand goes anywhere
    three joints below the trunk, so only segments one joint below their references are candidates
    (hosts.CLUSTER_JOINTS; before, the triad went on radius_l at 72 mm RMS).  The head band is still placed."""
    base = load_model(HUMAN)
    trial, _ = _session()
    trial = trial.select([lab for lab in trial.labels if lab not in ("LFIN", "LWRA", "LWRB")])
    las, ras = trial.markers[:, trial.labels.index("LASI")], trial.markers[:, trial.labels.index("RASI")]
    side = (las - ras) / np.linalg.norm(las - ras, axis=1)[:, None]
    tri = np.array([[0.0, 0.0, 0.0], [0.08, 0.0, 0.0], [0.0, 0.08, 0.0]])
    at = las + 0.12 * side + np.array([0.0, 0.0, -0.1])
    hip = at[:, None] + tri[None] + np.random.default_rng(0).normal(0.0, 0.0005, (trial.n_frames, 3, 3))
    trial = replace(trial, labels=(*trial.labels, "H1", "H2", "H3"),
                    markers=np.concatenate([trial.markers, hip], axis=1))
    assoc = associate_to_model(base, trial)
    labels = ["H1", "H2", "H3", *BAND.values()]
    assert all(assoc[n].segment is None for n in labels)
    hosts = cluster_hosts(base, [trial], labels, assoc.threshold)
    assert all(hosts[n].segment is None and hosts[n].best not in ("radius_l", "hand_l") for n in ("H1", "H2", "H3"))
    assert all(hosts[n].segment == "head" for n in BAND.values())
