"""Rigidity against a segment the trial shows by one marker (calibrate.seed.association.associate_to_model): a marker
across a joint keeps its distance to a marker beside that joint, so one marker cannot say which side a label rides on
(AddBiomechanics' stairdown: six forearm markers put on the humeri, rigid with the lateral elbow marker alone, the
upper arm's own markers unlabelled for the model).  Such a label is left to the model's poses."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate.calibration.pipeline import calibrate
from calibrate.model.model import load_model
from calibrate.problem.settings import Settings
from calibrate.seed.association import associate_to_model
from calibrate.simulation import simulate_squats

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
REACH = 0.10  # m: XFRM's constant distance from LELB


def _session():
    """Squats of a human.urdf subject whose left humerus the trial shows by LELB alone (LUPA dropped), and a label
    XFRM that keeps 100 mm from LELB while turning about it (as a forearm marker does about a marker on the elbow's
    axis), with 0.5 mm of noise: rigid with humerus_l by its one marker, on no segment."""
    base = load_model(HUMAN)
    sim = simulate_squats(base, frames=200, noise_mm=0.5, seed=3)
    t = sim.trial
    keep = [k for k, lab in enumerate(t.labels) if lab != "LUPA"]
    rng = np.random.default_rng(3)
    phase = np.linspace(0.0, 2.0, t.n_frames)
    turn = np.stack([np.cos(phase), np.zeros_like(phase), -np.sin(phase)], axis=1)  # a unit vector turning 115 deg
    xfrm = t.markers[:, t.labels.index("LELB")] + REACH * turn + rng.normal(0.0, 0.0005, (t.n_frames, 3))
    return base, replace(t, labels=(*[t.labels[k] for k in keep], "XFRM"),
                         markers=np.concatenate([t.markers[:, keep], xfrm[:, None]], axis=1))


def test_a_label_rigid_with_one_marker_beside_a_joint_is_not_put_on_that_segment():
    """XFRM's distance to LELB keeps within the trial's rigidity threshold (computed here from the positions), as a
    humerus marker's would; with humerus_l shown by LELB alone, rigidity does not place it there and says why, and
    calibrate does not put it on the humerus."""
    base, trial = _session()
    i, j = trial.labels.index("XFRM"), trial.labels.index("LELB")
    spread = np.std(np.linalg.norm(trial.markers[:, i] - trial.markers[:, j], axis=1))
    a = associate_to_model(base, trial)
    assert spread ** 2 <= a.threshold, (spread, a.threshold)
    assert a["XFRM"].segment is None, a["XFRM"]
    assert a["XFRM"].reason.startswith("rigid only with the one marker of humerus_l (LELB)"), a["XFRM"].reason
    cal = calibrate(base, trial, Settings())
    placed = {m.label: m for m in cal.new_markers}
    assert placed["XFRM"].segment != "humerus_l", placed["XFRM"]
