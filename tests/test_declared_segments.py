"""The marker map's ``[segments]`` table: new labels put on the segment the lab names, without the hosts' tests
(calibrate.io.labels.declared_segments, pipeline._declared_doubts); CAST sessions, whose movement trials show the
clusters alone (pipeline._bare_trials, _bare_exchanges).  Simulated subjects carrying a shank cluster the base model
does not know (tests/test_hosts.py's) or a CAST protocol's clusters (scripts/bench_cast.py's); truth from the
simulator."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d
from test_beyond_joints import assert_lumbar_fitted, walk_with_renamed_trunk
from test_hosts import CLUSTER, _clustered

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from bench_cast import cast_subject, world_centres  # noqa: E402  (the CAST subject, shared with the benchmark)

from calibrate.calibration.pipeline import _assign_new_markers, calibrate
from calibrate.calibration.regression import harrington
from calibrate.calibration.report import summary_text
from calibrate.cli import main
from calibrate.errors import CalibrateError
from calibrate.io.c3d import write_c3d
from calibrate.io.labels import declared_segments, load_marker_map, map_labels
from calibrate.problem.settings import Settings
from calibrate.simulation import simulate_squats
from calibrate.simulation.simulate import simulate_static

SHANK = {"segments": {"tibia_l": list(CLUSTER)}}


def _map(tmp_path, text: str):
    path = tmp_path / "map.toml"
    path.write_text(text)
    return path


def test_the_segments_table_is_read_and_checked(tmp_path, human):
    """After the model labels, `[segments]` lists new labels by segment; a mapping's "segments" entry reads the same.
    Each mistake is refused in one line naming the file, the label or segment, and what to do."""
    m = load_marker_map(_map(tmp_path, 'RASI = ["R.ASIS"]\n[segments]\nfemur_l = ["LTH1", "LTH2"]\ntibia_l = "LSH1"\n'))
    assert dict(m) == {"RASI": ["R.ASIS"]} and m.segments == {"femur_l": ["LTH1", "LTH2"], "tibia_l": ["LSH1"]}
    assert declared_segments(m) == {"LTH1": "femur_l", "LTH2": "femur_l", "LSH1": "tibia_l"}
    assert declared_segments({"RASI": ["R.ASIS"], "segments": {"femur_l": ["LTH1"]}}) == {"LTH1": "femur_l"}
    assert declared_segments({"RASI": ["R.ASIS"]}) == {} and declared_segments(None) == {}
    bad = {
        '[segments]\nfemur_l = ["LTH1"]\ntibia_l = ["LTH1"]\n': "listed under both femur_l and tibia_l",
        'RASI = ["LTH1"]\n[segments]\nfemur_l = ["LTH1"]\n': "under model label RASI and under [segments] femur_l",
        'segments = "femur_l"\n': "is not a table",
        '[segments]\nfemur_l = [1, 2]\n': "is not a list of trial labels",
        '[segments]\nfemur_l = []\n': "lists no trial label",
    }
    for text, what in bad.items():
        with pytest.raises(CalibrateError) as e:
            load_marker_map(_map(tmp_path, text))
        assert what in str(e.value) and "map.toml" in str(e.value) and "\n" not in str(e.value), str(e.value)
    # A declared label is kept as it is (L_Thigh is an alias of LTHI), and one that is the model's own is refused.
    trial = simulate_squats(human, frames=5, seed=0).trial
    trial = replace(trial, labels=tuple("L_Thigh" if lab == "LTHI" else lab for lab in trial.labels))
    relabelled, mapping = map_labels(trial, human.marker_names, {"segments": {"femur_l": ["L_Thigh"]}})
    assert "L_Thigh" in relabelled.labels and "LTHI" not in relabelled.labels
    assert mapping.renamed["L_Thigh"] == "L_Thigh" and "on femur_l ([segments])" in \
        next(m.note for m in mapping if m.trial_label == "L_Thigh")
    assert map_labels(trial, human.marker_names)[0].labels.count("LTHI") == 1  # (the alias, undeclared)
    with pytest.raises(CalibrateError, match="lists 'LKNE', which is a marker of human.urdf"):
        calibrate(human, trial, Settings(), marker_map={"segments": {"femur_l": ["LKNE"]}})
    # (map_labels reads it as the model's own: a subject calibrated with the map carries its new labels)
    assert map_labels(trial, human.marker_names, {"segments": {"femur_l": ["LKNE"]}})[1].renamed["LKNE"] == "LKNE"


def test_a_static_alone_places_the_declared_cluster(human):
    """Standing still, no test can tell which segment a new label rides on, and the shank cluster is left out
    (test_hosts.test_a_static_alone_places_no_new_label); declared on tibia_l it is placed and fitted there, its
    markers' distances to each other within 3 mm of the simulated subject's.  A segment the model lacks is refused."""
    truth = _clustered()
    squats = simulate_squats(truth, frames=200, noise_mm=1.0, seed=5)
    static = simulate_static(truth, squats.truth, frames=120, noise_mm=1.0, seed=2).trial
    cal = calibrate(human, static, Settings(), marker_map=SHANK)
    placed = {m.label: m for m in cal.new_markers}
    assert all(placed[n].segment == "tibia_l" and placed[n].declared and "[segments]" in placed[n].reason
               for n in CLUSTER)
    assert "(3 new: 3 on the segments the marker map's [segments] names)" in summary_text(cal)
    assert not cal.ignored_labels and all(n in cal.model.marker_names for n in CLUSTER)
    s = cal.params.scale[human.segment_index("tibia_l")]
    got = {n: s * cal.params.marker[cal.model.marker_index(n)] for n in CLUSTER}
    s0 = squats.truth.scale[truth.segment_index("tibia_l")]
    want = {n: s0 * squats.truth.marker[truth.marker_index(n)] for n in CLUSTER}
    for a, b in (("LSH1", "LSH2"), ("LSH1", "LSH3"), ("LSH2", "LSH3")):
        assert abs(np.linalg.norm(got[a] - got[b]) - np.linalg.norm(want[a] - want[b])) < 0.003
    with pytest.warns(UserWarning, match=r"\[segments\] lists 1 label no trial shows \(LSH9\)"):
        calibrate(human, static, Settings(), marker_map={"segments": {"tibia_l": [*CLUSTER, "LSH9"]}})
    with pytest.raises(CalibrateError, match="names 'shin_l', which is not a segment of human.urdf"):
        calibrate(human, static, Settings(), marker_map={"segments": {"shin_l": list(CLUSTER)}})


def _skin_moved():
    """Squats of the clustered subject, the cluster's markers moved by 15 mm (SD per axis) of smooth skin motion
    (white noise filtered over 0.1 s): more than the hosts' tests take (spread over 20 mm RMS on the tibia)."""
    truth = _clustered()
    sim = simulate_squats(truth, frames=200, noise_mm=1.0, seed=5)
    k = [sim.trial.labels.index(n) for n in CLUSTER]
    w = gaussian_filter1d(np.random.default_rng(5).normal(0.0, 1.0, (sim.trial.n_frames, len(k), 3)), 10, axis=0)
    X = sim.trial.markers.copy()
    X[:, k] += 0.015 * w / w.std()
    return replace(sim.trial, markers=X)


def test_declared_labels_on_skin_are_placed_and_a_wrong_segment_is_questioned(human, tmp_path, capsys):
    """Skin moves the cluster past what the tests take: left out by default, placed on tibia_l when declared there,
    with no question; declared on femur_l, each gets a `check label` line naming tibia_l (its place spreads there
    less than half as much as on the femur on the base model's poses), in the summary, the report and the HTML."""
    trial = _skin_moved()
    assert all(m.segment is None for m in _assign_new_markers(human, [trial], list(CLUSTER), [0.0]))
    right = calibrate(human, trial, Settings(), marker_map=SHANK)
    assert all(m.segment == "tibia_l" and not m.check for m in right.new_markers if m.label in CLUSTER)
    assert "check label" not in summary_text(right)

    write_c3d(tmp_path / "t.c3d", trial)
    (tmp_path / "map.toml").write_text('[segments]\nfemur_l = ["LSH1", "LSH2", "LSH3"]\n')
    code = main([str(tmp_path / "t.c3d"), str(human.path), "-o", str(tmp_path / "s.urdf"), "--markers",
                 str(tmp_path / "map.toml"), "--report", str(tmp_path / "s.json"), "--html", str(tmp_path / "s.html"),
                 "--no-hip-regression", "-q"])  # (the shank on the femur puts the hips outside the pelvis: not redone)
    out = capsys.readouterr().out
    assert code == 0
    checks = [line for line in out.splitlines() if line.startswith("  check label  LSH")]
    assert len(checks) == 3 and all("puts it on femur_l, yet" in c and "does it ride on tibia_l?" in c for c in checks)
    report = json.loads((tmp_path / "s.json").read_text())
    new = {m["label"]: m for m in report["marker_set"]["new"]}
    assert all(new[n]["segment"] == "femur_l" and "tibia_l" in new[n]["check"] for n in CLUSTER)
    page = (tmp_path / "s.html").read_text()
    assert page.count("check label LSH") == 3 and page.count("placed on femur_l (the marker map's [segments])") == 3
    # The same map beside the subject it made (which carries its new labels): calibrate ik reads them as its own
    (tmp_path / "ik").mkdir()
    assert main(["ik", str(tmp_path / "t.c3d"), str(tmp_path / "s.urdf"), "--markers", str(tmp_path / "map.toml"),
                 "-o", str(tmp_path / "ik"), "-q"]) == 0
    ik = json.loads((tmp_path / "ik" / "t_ik_report.json").read_text())
    assert {"LSH1", "LSH2", "LSH3"} <= set(json.dumps(ik).split('"'))
    # The spread figures it quotes: tibia_l's under half femur_l's.
    for c in checks:
        tib, fem = (float(x) for x in c.split("spreads ")[1].split(" on femur_l")[0].replace(" mm RMS on tibia_l,", "")
                    .split())
        assert tib < 0.5 * fem


def test_a_bad_segment_on_the_command_line_is_one_line_and_exit_2(human, tmp_path, capsys):
    trial = simulate_squats(human, frames=40, seed=1).trial
    write_c3d(tmp_path / "t.c3d", trial)
    (tmp_path / "map.toml").write_text('[segments]\nshank_l = ["LSH1"]\n')
    code = main([str(tmp_path / "t.c3d"), str(human.path), "-o", str(tmp_path / "s.urdf"), "--markers",
                 str(tmp_path / "map.toml"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "map.toml: [segments] names 'shank_l'" in err[0], err
    assert not (tmp_path / "s.urdf").exists()
    # calibrate inspect, which shows what the labels become, says so too
    code = main(["inspect", str(tmp_path / "t.c3d"), "--model", str(human.path), "--markers",
                 str(tmp_path / "map.toml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "[segments] names 'shank_l', which is not a segment of human.urdf" in err[0]


def test_declaring_a_label_changes_that_label_only(human):
    """The rest are judged as without the map (the rigidity threshold is set by every label's pairs, the declared
    ones' too): test_hosts' session, its cluster placed on tibia_l by the model's poses and its floor marker left
    out; the floor marker declared on the pelvis changes nothing else, to the reasons' figures."""
    from test_hosts import _session

    trial, _ = _session()
    labels = [*CLUSTER, "FLOOR"]
    plain = {m.label: m for m in _assign_new_markers(human, [trial], labels, [0.0])}
    said = {m.label: m for m in _assign_new_markers(human, [trial], labels, [0.0], {"FLOOR": "pelvis"})}
    assert plain["FLOOR"].segment is None and said["FLOOR"].segment == "pelvis"
    assert all(said[n] == plain[n] and plain[n].segment == "tibia_l" for n in CLUSTER)


def test_a_cast_session_calibrates_its_trials_of_clusters_alone(human, tmp_path):
    """A CAST session: a static showing the model's landmarks and the clusters, squats showing the clusters only (none
    of the model's markers: refused before, after a crash).  Calibrated together, the clusters declared, the clusters
    are placed from the static's poses and then pose the squats, whose motion places the joints: in the squats each hip
    centre ends within 3 mm of the simulated subject's and each knee within 12 mm, and every hip, knee and ankle angle
    follows the truth to 3 deg SD.  The way that worked before, the static calibrated alone and the squats posed on it
    (`calibrate ik`), leaves the hips where the priors put them, 10 mm or more off, and the hip flexion 5 deg SD or
    more from the truth."""
    from calibrate.model.kinematics import build_kinematics
    from calibrate.solve.ik import inverse_kinematics

    truth, segments = cast_subject(human)
    sim = simulate_squats(truth, frames=200, noise_mm=1.0, seed=3)
    static = simulate_static(truth, sim.truth, frames=100, noise_mm=1.0, seed=4).trial
    clusters = [lab for labs in segments.values() for lab in labs]
    only = replace(sim.trial.select(clusters), source="squats.c3d")
    cal = calibrate(human, [static, only], Settings(), marker_map={"segments": segments})
    assert {m.label: m.segment for m in cal.new_markers} == {lab: s for s, labs in segments.items() for lab in labs}
    legs = ("hip_l", "hip_r", "knee_l", "knee_r")
    want = sim.clean_centres[:, [[j.name for j in truth.joints].index(n) for n in legs]]
    off = np.median(np.linalg.norm(world_centres(cal.model, cal.params, cal.motions[1], legs) - want, axis=2), axis=0)
    assert np.all(off[:2] < 0.003) and np.all(off[2:] < 0.012), off
    dofs = [k for k, n in enumerate(human.dof_names) if n.split("_")[0] in ("hip", "knee", "ankle")]
    sd = np.degrees(np.std(cal.motions[1].angles[:, dofs] - sim.motion.angles[:, dofs], axis=0))
    assert sd.max() < 3.0, dict(zip([human.dof_names[k] for k in dofs], sd.round(1), strict=True))

    # --hip-regression: Harrington's hips from the static's pelvis landmarks (the squats show none: their virtual
    # markers unseen there, not refused before the fit), which then draw the hip centres from where the squats put them.
    reg = calibrate(human, [static, only], Settings(hip_regression=True), marker_map={"segments": segments})
    rasi, lasi, rpsi, lpsi = (static.marker(x) for x in ("RASI", "LASI", "RPSI", "LPSI"))
    want_reg = np.median(np.stack(harrington(rasi, lasi, 0.5 * (rpsi + lpsi)), axis=1), axis=0)
    before, after = (np.linalg.norm(np.median(world_centres(c.model, c.params, c.motions[0], ("hip_r", "hip_l")),
                                              axis=0) - want_reg, axis=1) for c in (cal, reg))
    assert np.all(after < before - 0.001), (after, before)  # (the squats place the hips: they move a little)

    alone = calibrate(human, static, Settings(), marker_map={"segments": segments})
    posed = inverse_kinematics(build_kinematics(alone.model), only, alone.params).motion
    off2 = np.median(np.linalg.norm(world_centres(alone.model, alone.params, posed, legs) - want, axis=2), axis=0)
    assert np.all(off2[:2] > 0.010), off2
    k = human.dof_index("hip_l_flexion")
    assert np.degrees(np.std(posed.angles[:, k] - sim.motion.angles[:, k])) > 5.0


def test_a_trial_of_clusters_alone_needs_them_declared_and_shown_beside_the_models_markers(human, tmp_path):
    """Refused in one line, naming the trial and what to do: the clusters not declared, or declared but shown only in
    the trial that shows none of the model's markers (nothing reads their places)."""
    truth, segments = cast_subject(human)
    sim = simulate_squats(truth, frames=60, noise_mm=1.0, seed=3)
    static = simulate_static(truth, sim.truth, frames=30, noise_mm=1.0, seed=4).trial
    clusters = [lab for labs in segments.values() for lab in labs]
    only = replace(sim.trial.select(clusters), source="squats.c3d")
    bare_static = static.select([lab for lab in static.labels if lab not in clusters])
    for trials, given in (([static, only], None), ([bare_static, only], {"segments": segments})):
        with pytest.raises(CalibrateError) as e:
            calibrate(human, trials, Settings(), marker_map=given)
        assert str(e.value).startswith("squats.c3d: shows none of human.urdf's markers in any frame"), str(e.value)
        assert "[segments]" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(CalibrateError) as e:  # (alone: none of its labels the model's; the way that works named)
        calibrate(human, only, Settings())
    assert "only 0 of its labels match" in str(e.value) and "beside a static" in str(e.value)
    def refused(limbs: dict[str, list[str]], few: list[str]) -> tuple[str, set[str]]:
        """The one line refusing the static and the squats showing the clusters of `limbs` (declared there) and the
        model's markers `few`, and the segments its [segments] clause names."""
        worn = [lab for labs in limbs.values() for lab in labs]
        trials = [static.select([*worn, *few]), replace(sim.trial.select([*worn, *few]), source="squats.c3d")]
        with pytest.raises(CalibrateError) as e:
            calibrate(human, trials, Settings(), marker_map={"segments": limbs})
        line = str(e.value)
        assert "\n" not in line and f"the {len(worn)} labels the marker map's [segments] puts on " in line, line
        said = line.split("the marker map's [segments] puts on ")[1].split(" take their places")[0]
        return line, set(said.split(", "))

    # Declared, with no marker on the pelvis, and every trial shows them with a few of the model's markers that pose
    # no segment (kineticstoolkit's wheelchair trials: clusters on the limbs, the sternum and the epicondyles): the
    # line says the declared labels wait for a trial whose model markers pose their segments, and which segments.
    left = {seg: labs for seg, labs in segments.items() if seg.endswith("_l")}
    line, named = refused(left, ["STRN", "LELB", "RELB"])
    assert "cannot place the pelvis" in line and named == set(left), line
    # Both legs' clusters count for the pelvis (two posed femurs place it) but nothing places them: their places would
    # come from start poses nothing fixes, and the run ended with knee axes 47-89 deg off and a shank scaled 0.69.
    # Refused, the same clause naming them; with the pelvis cluster shown as well, calibrated as above.
    legs = {seg: labs for seg, labs in segments.items() if seg != "pelvis"}
    line, named = refused(legs, ["LKNE", "RKNE", "STRN"])
    assert line.startswith("trial, squats.c3d: the model's markers the trials show (3) and the new labels placed "
                           "cannot place the pelvis without the marker map's [segments] labels"), line
    assert named == set(legs), line


def test_a_plate_the_static_names_turned_is_read_as_the_trials_of_clusters_alone_name_it(human, tmp_path):
    """The static names the left thigh's plate turned 180 deg (AddBiomechanics' Expert1 does): its distances are the
    same either way, the plate's places read from the static pose the squats' femur turned, and nothing later reads
    the labels again (the squats' places come from the poses they set; the checks after the solve had left the
    static's plate out as moved instead).  Of the relabellings that keep the plate's distances, the one that poses the
    squats best is taken: said and listed as the other exchanges are (`relabelled`), and the hips end within 5 mm of
    the truth (1.1 and 4.1 mm)."""
    truth, segments = cast_subject(human, plate=True)
    sim = simulate_squats(truth, frames=150, noise_mm=1.0, seed=3)
    static = simulate_static(truth, sim.truth, frames=60, noise_mm=1.0, seed=4).trial
    turn = {"LTH1": "LTH3", "LTH3": "LTH1", "LTH2": "LTH4", "LTH4": "LTH2"}
    swapped = replace(static, labels=tuple(turn.get(x, x) for x in static.labels), source="static.c3d")
    only = sim.trial.select([lab for labs in segments.values() for lab in labs])
    cal = calibrate(human, [swapped, only], Settings(), marker_map={"segments": segments})
    (x,) = [x for x in cal.relabelled if x.trial == 0]
    assert (x.segment, dict(zip(x.labels, x.read_as, strict=True))) == ("femur_l", turn)
    assert min(x.own) > 3 * max(x.exchanged)
    want = sim.clean_centres[:, [[j.name for j in truth.joints].index(n) for n in ("hip_l", "hip_r")]]
    off = np.median(np.linalg.norm(world_centres(cal.model, cal.params, cal.motions[1], ("hip_l", "hip_r")) - want,
                                   axis=2), axis=0)
    assert np.all(off < 0.005), off


def test_a_segment_carrying_only_declared_labels_is_posed_by_them(human):
    """A lower-body model's torso with no marker of its own (pyCGM2's gait2392): the lab declares its trunk markers
    there.  Judged at their segment's origin (the lumbar centre) before their places are read, they placed none of its
    turns, and the lumbar was locked, the markers riding with the pelvis.  Now judged at provisional places: a
    simulated walk whose torso markers are renamed and declared keeps the lumbar free, and its three angles follow the
    truth's within 0.5 deg (about their means: the torso's frame is the priors'), where held at 0 they missed its
    0.8-2.0 deg of motion; no `unresolved` torso."""
    sim, trial, trunk = walk_with_renamed_trunk(human)
    cal = calibrate(human, trial, Settings(), marker_map={"segments": {"torso": [f"TR_{lab}" for lab in trunk]}})
    assert all(m.declared for m in cal.new_markers)
    assert_lumbar_fitted(cal, sim)


def test_a_trial_showing_fewer_labels_is_judged_at_the_provisional_places(human):
    """Two trials, the second without one thigh marker the first shows: each trial's own markers are judged for the
    segments they place, and the torso, carried by declared trunk markers with no place read yet, is judged at their
    provisional places as the calibration's markers are.  At the torso's origin they had placed none of its turns, so
    the second trial's lumbar was held at 0 (a clinical lab's walk without its static's medial knee and ankle
    markers: AUC's trunk markers 300 mm off the fit)."""
    sim, trial, trunk = walk_with_renamed_trunk(human)
    fewer = trial.select([lab for lab in trial.labels if lab != "RTHI"])
    cal = calibrate(human, [trial, fewer], Settings(max_iterations=30),
                    marker_map={"segments": {"torso": [f"TR_{lab}" for lab in trunk]}})
    assert all(m.declared and m.segment == "torso" for m in cal.new_markers)
    assert cal.unplaced_in_trial == (), cal.unplaced_in_trial
    assert not {"lumbar_flexion", "lumbar_bending", "lumbar_rotation"} & set(cal.locked)
