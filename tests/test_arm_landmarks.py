"""Named landmarks a lab's moving trials carry: the forearm's styloids read as Plug-in Gait's wrist markers
(``R_wrist_radius`` -> RWRA), a medial epicondyle put on the segment its hinge hangs from by its name whatever the
trial (on the hinge's axis neither rigidity nor the poses tell the two segments apart), its place started across the
axis from the lateral marker where the start's poses leave it elsewhere, and a lab's joint-centre label (R_HJC) kept
on its joint's segments.  Trials from the simulator, renamed as AddBiomechanics' and OpenCap's labs name them."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import with_medial_markers

from calibrate.calibration.hosts import centre_labels, centre_segments, kinematic_hosts, medial_host
from calibrate.calibration.pipeline import _across_hinge, _off_its_joint, calibrate
from calibrate.calibration.result import NewMarker
from calibrate.io.labels import map_labels
from calibrate.problem.priors import straddle
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_gait, simulate_static


def test_the_styloids_names_read_as_the_wrist_markers(human):
    """Expert1's and OpenCap's styloid labels become human.urdf's wrist markers (radial: WRA, ulnar: WRB), as an alias;
    the elbow's lateral label becomes ELB and the medial one stays unknown (no Plug-in Gait marker)."""
    renamed = {"RWRA": "R_wrist_radius", "RWRB": "R_wrist_ulna", "LWRA": "L_wrist_radius", "LWRB": "L_wrist_ulna",
               "RELB": "R_elbow_lat", "LELB": "R_elbow_med"}
    labels = list(renamed.values())
    trial = simulate_static(human, human.parameters(), frames=3).trial
    trial = replace(trial, labels=[renamed.get(n, n) for n in trial.labels])
    _, mapping = map_labels(trial, human.marker_names, None, aliases=True)
    got = {m.trial_label: (m.label, m.how) for m in mapping.matches if m.trial_label in labels}
    assert got == {"R_wrist_radius": ("RWRA", "alias"), "R_wrist_ulna": ("RWRB", "alias"),
                   "L_wrist_radius": ("LWRA", "alias"), "L_wrist_ulna": ("LWRB", "alias"),
                   "R_elbow_lat": ("RELB", "alias"), "R_elbow_med": ("R_elbow_med", "unknown")}


def test_a_joint_centre_label_names_its_joints_two_segments(human):
    """R_HJC, L_HJC_reg, RHJC and OpenCap's augmented spelling name the hip's pelvis and femur on their side; a name
    without a side, or not a centre's, names none."""
    assert centre_segments(human, "R_HJC") == ("pelvis", "femur_r")
    assert centre_segments(human, "L_HJC_reg") == ("pelvis", "femur_l")
    assert centre_segments(human, "RHJC") == ("pelvis", "femur_r")
    assert centre_segments(human, "r_HJC_study") == ("pelvis", "femur_r")
    assert centre_segments(human, "L.Elbow.JC") == ("humerus_l", "ulna_l")
    assert [centre_segments(human, x) for x in ("HJC", "R_HJCX", "RASI", "R_elbow_med")] == [None] * 4
    # a test that put it on a third segment leaves it out; on its joint's, it stays
    torso = NewMarker("L_HJC", "torso", None, "on the model's poses its place on torso spreads 19.6 mm RMS")
    out = _off_its_joint(human, torso)
    assert out.segment is None and "named as the centre of the joint between pelvis and femur_l" in out.reason
    pelvis = replace(torso, segment="pelvis")
    assert _off_its_joint(human, pelvis) is pelvis


def test_the_plainest_label_of_each_centre_is_the_one_tied(human):
    """centre_labels: per joint one label the model lacks, the plainest of those naming its centre (R_HJC before its
    regression's R_HJC_reg); none for a joint skipped (the hips under --hip-regression) or a label the model has."""
    got = centre_labels(human, ["RASI", "R_HJC_reg", "R_HJC", "L_HJC_reg", "L.Knee.JC", "R_elbow_med", "R_HJC"])
    assert {lab: j.name for lab, j in got.items()} == {"R_HJC": "hip_r", "L_HJC_reg": "hip_l", "L.Knee.JC": "knee_l"}
    assert got["R_HJC"].child == "femur_r"
    assert set(centre_labels(human, ["R_HJC", "L_HJC"], skip=("hip_r",))) == {"L_HJC"}
    assert centre_labels(human, ["RASI", "LKNE"]) == {}


def test_a_hip_centre_label_rides_on_the_pelvis_or_the_femur(human):
    """A label at the right hip's centre in a simulated walk (the lab's computed R_HJC, 1 mm noise) is judged by the
    model's poses on the hip's two segments only, and placed on one of them."""
    sim = simulate_gait(human, frames=120, noise_mm=1.0, seed=3)
    centres = sim.clean_centres[:, human.joint_index("hip_r")]
    rng = np.random.default_rng(0)
    X = np.concatenate([sim.trial.markers, (centres + rng.normal(0, 0.001, centres.shape))[:, None]], axis=1)
    trial = replace(sim.trial, labels=[*sim.trial.labels, "R_HJC"], markers=X)
    host = kinematic_hosts(human, [trial], ["R_HJC"])["R_HJC"]
    assert host.segment in ("pelvis", "femur_r") and {host.best, host.runner_up} <= {"pelvis", "femur_r"}


@pytest.fixture(scope="module")
def elbows(human):
    """human.urdf with a medial elbow marker on each humerus: the lateral one (LELB, RELB) reflected through the plane
    across the elbow axis at its centre, then 5 mm further out (a 76 mm elbow)."""
    return with_medial_markers(human, "elbow", "ELB", "MEL", 0.005)


def test_a_medial_place_off_the_axis_starts_across_it(human, elbows):
    """Where the start's poses put a medial elbow marker 90 mm behind the humerus (off the line through the lateral
    marker along the axis), its place starts across the axis from the lateral one: the two then straddle the centre
    along the axis; a place that straddles already is kept, and a hinge without a lateral marker gives none."""
    p = human.parameters()
    ji = human.joint_index("elbow_r")
    c = p.centre[ji]
    R = next(u.rotation for u in human.urdf_joints if u.name == human.joints[ji].urdf_joints[0])
    a = R @ (p.axis[human.dof_index("elbow_r")] / np.linalg.norm(p.axis[human.dof_index("elbow_r")]))
    lateral = p.marker[human.marker_index("RELB")]
    behind = np.array([-0.093, -0.012, -0.315])
    mirrored, name, moved = _across_hinge(human, p, "elbow_r", behind)
    assert name == "RELB" and moved == pytest.approx(float(np.linalg.norm(mirrored - behind)))
    assert straddle(c, a, lateral, behind) is None and straddle(c, a, lateral, mirrored) is not None
    # the mirror: as far from the centre along the axis as the lateral marker, on the other side, and as far off it
    assert float(a @ (mirrored - c)) == pytest.approx(-float(a @ (lateral - c)), abs=1e-12)
    assert np.allclose(mirrored - c - (a @ (mirrored - c)) * a, lateral - c - (a @ (lateral - c)) * a, atol=1e-12)
    true_place = elbows.parameters().marker[elbows.marker_index("RMEL")]
    assert _across_hinge(human, p, "elbow_r", true_place) is None
    assert _across_hinge(human, p, "radioulnar_r", behind) is None
    # a lateral marker the start put 40 mm off the axis's line (past PAIR_OFF): its mirror would pass as far from the
    # centre, so the medial place starts on the axis, across the centre from it, and the two straddle the centre
    off = np.cross(a, [0.0, 0.0, 1.0])
    off /= np.linalg.norm(off)
    far = c + float(a @ (lateral - c)) * a + 0.040 * off
    q = replace(p, marker=p.marker.copy())
    q.marker[human.marker_index("RELB")] = far
    assert straddle(c, a, far, far - 2.0 * float(a @ (far - c)) * a) is None
    on_axis, _, _ = _across_hinge(human, q, "elbow_r", behind)
    assert np.allclose(on_axis, c - float(a @ (far - c)) * a, atol=1e-12)
    assert straddle(c, a, far, on_axis) is not None


def test_medial_elbow_markers_in_a_moving_trial_go_on_the_humerus_by_name(human, elbows):
    """A lab's medial elbow labels (R_elbow_med, L_elbow_med: unknown to human.urdf) in a static and a walk are put on
    the humeri by their names (hosts.medial_host), whatever rigidity and the poses say; each pairs with the lateral
    marker, and the calibrated elbow is as wide as the simulated subject's to 3 mm."""
    gait = simulate_gait(elbows, frames=150, noise_mm=1.0, seed=5)
    static = simulate_static(elbows, gait.truth, frames=40, noise_mm=1.0, seed=2)
    renamed = {"LMEL": "L_elbow_med", "RMEL": "R_elbow_med"}
    trials = [replace(t, labels=[renamed.get(n, n) for n in t.labels]) for t in (static.trial, gait.trial)]
    assert medial_host(human, "R_elbow_med") == ("humerus_r", "elbow_r")
    cal = calibrate(human, trials, Settings())
    placed = {m.label: m for m in cal.new_markers}
    for name, lab in renamed.items():
        side = lab[0].lower()
        assert placed[lab].segment == f"humerus_{side}" and placed[lab].hinge == f"elbow_{side}"
        assert "on its hinge's axis" in placed[lab].reason
        seg, lateral = elbows.segment_index(f"humerus_{side}"), f"{side.upper()}ELB"
        k, t = cal.model.marker_index(lab), elbows.marker_index(name)
        span = cal.params.scale[seg] * np.linalg.norm(cal.params.marker[k]
                                                      - cal.params.marker[cal.model.marker_index(lateral)])
        truth = gait.truth.scale[seg] * np.linalg.norm(gait.truth.marker[t]
                                                       - gait.truth.marker[elbows.marker_index(lateral)])
        assert span == pytest.approx(truth, abs=0.003)
    assert {(j, a, b) for j, a, b in cal.axis_pairs if j.startswith("elbow")} \
        == {("elbow_l", "LELB", "L_elbow_med"), ("elbow_r", "RELB", "R_elbow_med")}
