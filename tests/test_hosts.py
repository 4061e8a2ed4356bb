"""New labels placed by the model's poses (calibrate.calibration.hosts) where seed 002's rigidity cannot: a cluster
whose skin moves it more than the trial's noise (Camargo et al.'s 2021 walk: every thigh and shank cluster marker
left out on human.urdf)."""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate.calibration.hosts import HOST_SPREAD, kinematic_hosts
from calibrate.calibration.pipeline import calibrate
from calibrate.model.model import load_model
from calibrate.problem.settings import Settings
from calibrate.seed.association import associate_to_model
from calibrate.simulation import simulate_gait, simulate_squats

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
CLUSTER = {"LSH1": (0.03, 0.06, -0.12), "LSH2": (0.05, 0.03, -0.16), "LSH3": (0.01, 0.07, -0.19)}  # tibia_l, m


def _clustered(cluster: dict = CLUSTER, segment: str = "tibia_l"):
    """models/human.urdf with the markers `cluster` (name -> place, m) on `segment` (by default the shank cluster
    CLUSTER on tibia_l): the subject the simulator draws from."""
    extra = "".join(
        f'  <link name="{n}"><visual><geometry><sphere radius="0.007"/></geometry></visual></link>\n'
        f'  <joint name="{n}_marker" type="fixed"><parent link="{segment}"/><child link="{n}"/>'
        f'<origin xyz="{x} {y} {z}" rpy="0 0 0"/></joint>\n' for n, (x, y, z) in cluster.items())
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "clustered.urdf"
        path.write_text(HUMAN.read_text().replace("</robot>", extra + "</robot>"))
        return load_model(path)


def _session():
    """Squats of a subject carrying a shank cluster the base model (models/human.urdf) does not know, the
    cluster's markers moved by 4 mm of independent skin motion per frame and axis (the rest: 1 mm noise), and a
    label that rides on nothing (a marker on the ground, moved by 4 mm per frame)."""
    truth = _clustered()
    sim = simulate_squats(truth, frames=200, noise_mm=1.0, seed=5)
    rng = np.random.default_rng(5)
    X = sim.trial.markers.copy()
    k = [sim.trial.labels.index(n) for n in CLUSTER]
    X[:, k] += rng.normal(0.0, 0.004, (X.shape[0], len(k), 3))
    ground = np.array([0.5, 0.5, 0.0]) + rng.normal(0.0, 0.004, (X.shape[0], 1, 3))
    trial = replace(sim.trial, labels=(*sim.trial.labels, "FLOOR"), markers=np.concatenate([X, ground], axis=1))
    s = sim.truth.scale[truth.segment_index("tibia_l")]
    return trial, {n: s * sim.truth.marker[truth.marker_index(n)] for n in CLUSTER}


def test_a_skin_moved_cluster_is_placed_by_the_models_poses_where_rigidity_leaves_it_out():
    """Rigidity (threshold set by the 1 mm noise of the rest) leaves the cluster out; on the base model's poses its
    places spread a few mm on tibia_l and several times more on any other segment, so it goes there, and the
    calibration fits it there (the femur and the foot as runners-up are the joints' neighbours).  The floor marker
    spreads on every segment and stays out."""
    base = load_model(HUMAN)
    trial, true_places = _session()
    labels = [*CLUSTER, "FLOOR"]
    assoc = associate_to_model(base, trial)
    assert all(assoc[n].segment is None for n in labels), [assoc[n].reason for n in labels]
    hosts = kinematic_hosts(base, [trial], labels)
    for n in CLUSTER:
        h = hosts[n]
        assert h.segment == "tibia_l", h
        assert h.spread < HOST_SPREAD and h.runner_up_spread > 2 * h.spread, h
        assert h.reason().startswith(f"on the model's poses its place on tibia_l spreads {1e3 * h.spread:.1f} mm")
    floor = hosts["FLOOR"]
    assert floor.segment is None and floor.spread > HOST_SPREAD
    assert f"mm RMS on {floor.best} at best" in floor.reason()

    cal = calibrate(base, trial, Settings())
    placed = {m.label: m for m in cal.new_markers}
    assert {n for n in CLUSTER if placed[n].segment == "tibia_l"} == set(CLUSTER)
    assert placed["FLOOR"].segment is None and "FLOOR" in cal.ignored_labels
    # Placed where the simulator put them: their distances to each other within 3 mm of the subject's.
    P = {n: cal.params.scale[base.segment_index("tibia_l")] * cal.params.marker[cal.model.marker_index(n)]
         for n in CLUSTER}
    for a, b in (("LSH1", "LSH2"), ("LSH1", "LSH3"), ("LSH2", "LSH3")):
        truth = np.linalg.norm(true_places[a] - true_places[b])
        assert abs(np.linalg.norm(P[a] - P[b]) - truth) < 0.003


def test_a_static_alone_places_no_new_label():
    """The same subject standing still (simulate_static), its shank cluster's labels unknown to the base model: no
    trial moves, so neither rigidity nor the poses can tell the tibia from any other segment (they had put a BTS
    static's hip centre on the tibia); every new label is left out, said so, and the subject has none of them.  With
    the squats beside the static the cluster goes on tibia_l again, as above."""
    from calibrate.simulation.simulate import simulate_static

    base = load_model(HUMAN)
    truth = _clustered()
    squats = simulate_squats(truth, frames=200, noise_mm=1.0, seed=5)
    static = simulate_static(truth, squats.truth, frames=120, noise_mm=1.0, seed=2).trial
    cal = calibrate(base, static, Settings())
    placed = {m.label: m for m in cal.new_markers}
    for n in CLUSTER:
        assert placed[n].segment is None and "seen only in still trials" in placed[n].reason, placed[n]
        assert n in cal.ignored_labels and n not in cal.model.marker_names
    both = calibrate(base, [static, squats.trial], Settings())
    assert {m.label: m.segment for m in both.new_markers if m.label in CLUSTER} == dict.fromkeys(CLUSTER, "tibia_l")


def test_forearm_labels_past_an_unposed_elbow_are_left_out_not_put_on_the_humerus(tmp_path, capsys):
    """Treadmill gait (the elbows hardly move) whose forearm, wrist and hand markers carry names the base model does not
    know (a lab's own set), and two markers on the left upper arm that it has no counterpart for, through the command
    line.  No known marker moves the elbows, so on the base model's poses the forearm labels turn with the humeri and
    keep their distances to the humeri's markers: the tests had put 8 of 8 on the humeri, which then carried the
    shoulder centres 70 and 104 mm from the truth's (elbows 53 and 59).  They sit where the base model's forearm and
    hand markers come over the joints below the elbow, so they are left out, each with the model marker it sits by
    (the report's `sits_by`, the warning's hint at a marker map); the upper-arm markers stay on humerus_l; the written
    subject's shoulder centres end within 20 mm of the truth's (3 and 14 mm)."""
    import json

    from calibrate.cli import main
    from calibrate.io.c3d import write_c3d

    arm = {"LARM1": (0.03, 0.05, -0.10), "LARM2": (-0.03, 0.045, -0.20)}  # mid and distal upper arm, humerus_l
    truth = _clustered(arm, "humerus_l")
    sim = simulate_gait(truth, frames=300, noise_mm=1.0, seed=0)
    renamed = {f"{s}{k}": f"{s}{v}" for s in "LR"
               for k, v in (("FRM", "Forearm1"), ("WRA", "WristIn"), ("WRB", "WristOut"), ("FIN", "HandOut"))}
    labels = tuple(renamed.get(lab, lab) for lab in sim.trial.labels)
    write_c3d(tmp_path / "gait.c3d", replace(sim.trial, labels=labels))
    assert main([str(tmp_path / "gait.c3d"), str(HUMAN), "-o", str(tmp_path / "subject.urdf"), "-q"]) == 0
    warning = next(x for x in capsys.readouterr().err.splitlines() if x.startswith("warning: 8 trial labels"))
    report = json.loads(next(tmp_path.glob("*_report.json")).read_text())["marker_set"]
    assert {x["label"]: x["segment"] for x in report["new"]} == dict.fromkeys(arm, "humerus_l")
    left = {x["label"]: x for x in report["left_out"]}
    forearm = {side: {f"{side}{k}" for k in ("FRM", "WRA", "WRB", "FIN")} for side in "LR"}
    for old, new in renamed.items():
        side = old[0].lower()
        assert f"joints below humerus_{side}" in left[new]["reason"], left[new]
        assert left[new]["sits_by"] and set(left[new]["sits_by"]) <= forearm[old[0]], left[new]
        assert f"{new} near {' or '.join(left[new]['sits_by'])}" in warning and "--markers" in warning
    base, subject = load_model(HUMAN), load_model(tmp_path / "subject.urdf")
    for name in ("shoulder_l", "shoulder_r"):
        k = [j.name for j in base.joints].index(name)
        ours = subject.parameters().centre[[j.name for j in subject.joints].index(name)]
        true = sim.truth.scale[base.segment_index(base.joints[k].parent)] * sim.truth.centre[
            [j.name for j in truth.joints].index(name)]
        assert np.linalg.norm(ours - true) < 0.020, (name, np.linalg.norm(ours - true))


def test_past_joints_leaves_a_wrist_marker_on_the_ulna_and_takes_the_hand_and_heel_off():
    """hosts.past_joints on simulated gait whose left wrist, hand, heel and toe markers carry unknown names, each
    label given on the segment a test could put it on (the ulna, the tibia): the hand marker sits by the base model's
    LFIN, past the wrist, and the heel by LHEE, past the ankle (across the markerless talus), so both are taken off;
    the wrist markers lie along the radius's pronation axis seen from its centre, which leaves them where they are,
    so they stay on the ulna."""
    from calibrate.calibration.hosts import past_joints

    sim = simulate_gait(load_model(HUMAN), frames=200, noise_mm=1.0, seed=0)
    renamed = {"LWRA": "LWristIn", "LWRB": "LWristOut", "LFIN": "LHandOut", "LHEE": "LHeelBack", "LTOE": "LToeTip"}
    trial = replace(sim.trial, labels=tuple(renamed.get(lab, lab) for lab in sim.trial.labels))
    base = load_model(HUMAN)
    placed = {"LWristIn": "ulna_l", "LWristOut": "ulna_l", "LHandOut": "ulna_l", "LHeelBack": "tibia_l"}
    past = past_joints(base, [trial], placed)
    assert set(past) == {"LHandOut", "LHeelBack"}, past
    assert (past["LHandOut"].by, past["LHandOut"].segment) == ("LFIN", "hand_l")
    assert past["LHeelBack"].segment == "calcn_l" and past["LHeelBack"].by in ("LHEE", "LTOE")
    assert past["LHeelBack"].distance < past["LHeelBack"].own


def test_the_base_models_poses_are_fitted_once_per_frames_and_kept_apart_by_model_and_frames():
    """An association's host tests share one BasePoses: kinematic_hosts' first round and past_joints pose the base
    model on the same picked frames, and the fit is made once (the same IKResult), its poses equal to a fit made
    afresh (calibrate.solve.ik run here) and its hosts equal to those found without the cache; other frames or a
    model with more markers get their own fit."""
    from calibrate.calibration.hosts import HOST_FRAMES, BasePoses, _posed, past_joints, pick_frames
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import add_markers
    from calibrate.solve.ik import DECISION_TOLERANCE, inverse_kinematics

    base = load_model(HUMAN)
    trial, _ = _session()
    labels = [*CLUSTER, "FLOOR"]
    cache = BasePoses()
    picked = pick_frames([trial], HOST_FRAMES)
    (t1, fit1), = _posed(base, picked, labels, cache=cache)
    (t2, fit2), = _posed(base, pick_frames([trial], HOST_FRAMES), ["LSH1"], cache=cache)
    assert fit2 is fit1  # the same frames and model: found again, not fitted again
    fresh = inverse_kinematics(build_kinematics(base), picked[0], base.parameters(), tolerance=DECISION_TOLERANCE)
    np.testing.assert_array_equal(fit1.motion.angles, fresh.motion.angles)
    np.testing.assert_array_equal(fit1.residuals, fresh.residuals)
    # other frames, or the model with a label placed on it: fitted anew
    (_, other), = _posed(base, pick_frames([trial], HOST_FRAMES // 2), labels, cache=cache)
    assert other is not fit1 and other.motion.angles.shape[0] != fit1.motion.angles.shape[0]
    more = add_markers(base, {"LSH1": ("tibia_l", np.array(CLUSTER["LSH1"]))})
    (_, moved), = _posed(more, picked, ["LSH2"], cache=cache)
    assert moved is not fit1
    # a start given: fitted from it, not taken from the cache
    (_, started), = _posed(base, picked, labels, {0: fit1.motion}, cache=cache)
    assert started is not fit1
    # the hosts the tests find with a shared cache are those found without one
    with_cache = kinematic_hosts(base, [trial], labels, cache=cache)
    without = kinematic_hosts(base, [trial], labels)
    assert {n: (h.segment, h.spread) for n, h in with_cache.items()} == {n: (h.segment, h.spread)
                                                                         for n, h in without.items()}
    placed = {n: h.segment for n, h in without.items() if h.segment}
    assert past_joints(base, [trial], placed, cache=cache) == past_joints(base, [trial], placed)
