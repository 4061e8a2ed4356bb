"""A cluster's labels exchanged between the static and the moving trials (calibrate.calibration.moved.
exchanged_clusters, read back by relabel_columns before the fit).

AddBiomechanics' Expert1 labels its left thigh plate the other way round in the static: L_thigh1 sits where the walk
puts L_thigh3, L_thigh2 where it puts L_thigh4, and back.  A rectangular plate keeps every distance under that
exchange, so rigidity and the distance tests cannot see it; on the segment, where the other markers fix its frame,
each label of the static sits 90-140 mm from its place in the walk.  Fitted as labelled, the plate bent the left leg
(models/human_girdle.urdf: 11.4 mm RMS, the knee's axis 84 deg off).  Here the simulator's subject carries such a
plate on its left thigh, and its static names the plate mirrored."""

from __future__ import annotations

import json
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.calibration.moved import EXCHANGE_GAIN, EXCHANGE_OWN, exchanged_clusters, relabel_columns
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.calibration.subject_ik import fit_trial
from calibrate.cli import main
from calibrate.io.c3d import write_c3d
from calibrate.model.model import load_model, write_model
from calibrate.problem.settings import Settings
from calibrate.simulation import simulate_squats
from calibrate.simulation.simulate import simulate_static

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
# A plate on the left thigh's lateral side (femur_l's frame, m): two columns 100 mm apart, two rows 120 mm apart.
PLATE = {"TH1": (0.03, 0.08, -0.12), "TH2": (0.03, 0.08, -0.24), "TH3": (-0.07, 0.075, -0.12),
         "TH4": (-0.07, 0.075, -0.24)}
MIRRORED = {"TH1": "TH3", "TH3": "TH1", "TH2": "TH4", "TH4": "TH2"}  # the static's label -> the squats' label


def _plated(markers: dict | None = None):
    """models/human.urdf with the plate PLATE (or `markers`: name -> place) on femur_l: the subject the simulator
    draws from."""
    extra = "".join(
        f'  <link name="{n}"><visual><geometry><sphere radius="0.007"/></geometry></visual></link>\n'
        f'  <joint name="{n}_marker" type="fixed"><parent link="femur_l"/><child link="{n}"/>'
        f'<origin xyz="{x} {y} {z}" rpy="0 0 0"/></joint>\n' for n, (x, y, z) in (markers or PLATE).items())
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "plated.urdf"
        path.write_text(HUMAN.read_text().replace("</robot>", extra + "</robot>"))
        return load_model(path)


def _halves(squats):
    """The squats cut in two moving trials, first.c3d and second.c3d, the second naming the plate mirrored."""
    half = squats.trial.n_frames // 2
    first = replace(squats.trial.frames(0, half), source="first.c3d")
    second = squats.trial.frames(half, squats.trial.n_frames)
    return first, replace(second, labels=tuple(MIRRORED.get(n, n) for n in second.labels), source="second.c3d")


@pytest.fixture(scope="module")
def session():
    """Squats of the plated subject, its static with the plate's labels mirrored, and models/human.urdf."""
    truth = _plated()
    squats = simulate_squats(truth, frames=200, noise_mm=1.0, seed=11)
    static = simulate_static(truth, squats.truth, frames=100, noise_mm=1.0, seed=11)
    mirrored = replace(static.trial, labels=tuple(MIRRORED.get(n, n) for n in static.trial.labels))
    true_places = {n: squats.truth.scale[truth.segment_index("femur_l")] * squats.truth.marker[truth.marker_index(n)]
                   for n in PLATE}
    return load_model(HUMAN), squats, static, mirrored, true_places


def test_the_mirrored_static_is_read_back_and_places_the_plate(session):
    """The static's four labels are read as the squats name them (one exchange on femur_l, each label's place 100 mm
    or more from its own and within the start poses' error of the one it is read as); the plate is then placed where
    the subject carries it, the static's positions kept in the fit and fitted to the noise, nothing named moved."""
    base, squats, _, mirrored, true_places = session
    cal = calibrate(base, [mirrored, squats.trial], Settings())
    assert len(cal.relabelled) == 1
    x = cal.relabelled[0]
    assert (x.trial, x.segment) == (0, "femur_l")
    assert dict(zip(x.labels, x.read_as, strict=True)) == MIRRORED
    # Each label's own place in the squats is the plate's column (100 mm) away; the one it is read as within the start
    # poses' error (the seeded geometry's, not the subject's: 15-19 mm).
    assert min(x.own) > 0.09 and max(x.exchanged) < 0.025, x
    assert not cal.moved and not [m for m in cal.moved_kept if m.marker in PLATE]
    F0 = mirrored.n_frames
    for n in PLATE:
        k = cal.model.marker_index(n)
        err = np.linalg.norm(cal.residuals[:F0, k], axis=1)
        assert np.isfinite(err).all() and np.median(err) < 0.003, (n, np.median(err))
    placed = {n: cal.params.scale[cal.model.segment_index("femur_l")] * cal.params.marker[cal.model.marker_index(n)]
              for n in PLATE}
    for a in PLATE:  # the plate's shape as the subject carries it: its distances within 2 mm of the truth's
        for b in PLATE:
            assert abs(np.linalg.norm(placed[a] - placed[b]) - np.linalg.norm(true_places[a] - true_places[b])) < 0.002
    report = calibration_report(cal)
    assert report["relabelled"][0]["read_as"] == list(x.read_as) and report["relabelled"][0]["segment"] == "femur_l"
    line = next(ln for ln in summary_text(cal).splitlines() if ln.startswith("  relabelled   "))
    assert "names the markers of femur_l otherwise than the moving trials: read TH" in line
    assert f"{1e3 * x.own[0]:.0f}" in line


def test_a_static_labelled_as_the_squats_is_left_alone(session):
    """The same static named as the squats name the plate: nothing read otherwise, and its fit alike."""
    base, squats, static, _, _ = session
    cal = calibrate(base, [static.trial, squats.trial], Settings())
    assert cal.relabelled == () and calibration_report(cal)["relabelled"] == []
    assert not any(ln.startswith("  relabelled") for ln in summary_text(cal).splitlines())


def test_the_match_needs_far_own_places_and_near_exchanged_ones():
    """exchanged_clusters on places given directly: two markers 15 mm apart whose still places drift by 12 mm (skin,
    a pose) are not read exchanged however the match falls (EXCHANGE_OWN); two 100 mm apart, exchanged, are; and an
    exchange whose read places lie over EXCHANGE_GAIN of their own distance is not."""
    rng = np.random.default_rng(0)

    def places(still_at: np.ndarray, moving_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        F_still, F_moving = 10, 40
        P = np.concatenate([np.broadcast_to(still_at, (F_still, *still_at.shape)),
                            np.broadcast_to(moving_at, (F_moving, *moving_at.shape))]) + rng.normal(0, 1e-3, (
                                F_still + F_moving, *still_at.shape))
        return P, np.r_[np.zeros(F_still, int), np.ones(F_moving, int)]

    a, b = np.array([0.0, 0.08, -0.12]), np.array([0.1, 0.08, -0.12])
    P, trial_of = places(np.array([b, a]), np.array([a, b]))  # exchanged
    found = exchanged_clusters(P, trial_of, [True, False], ["A", "B"], ["femur_l", "femur_l"])
    assert len(found) == 1 and found[0].labels == ("A", "B") and found[0].read_as == ("B", "A")
    assert min(found[0].own) >= EXCHANGE_OWN and sum(found[0].exchanged) <= EXCHANGE_GAIN * sum(found[0].own)
    # The columns read back: the still trial's A column holds what B's did.
    obs = np.arange(2 * 2 * 3, dtype=float).reshape(2, 2, 3)
    back = relabel_columns(obs, [slice(0, 1), slice(1, 2)], found, ["A", "B"])
    assert np.array_equal(back[0, 1], obs[0, 0]) and np.array_equal(back[0, 0], obs[0, 1])
    assert np.array_equal(back[1], obs[1])
    near = a + np.array([0.015, 0.0, 0.0])  # 15 mm apart, the still places drifted 12 mm towards each other's
    P, trial_of = places(np.array([a + [0.012, 0, 0], near - [0.012, 0, 0]]), np.array([a, near]))
    assert exchanged_clusters(P, trial_of, [True, False], ["A", "B"], ["femur_l", "femur_l"]) == []
    half = (a + b) / 2  # far from their own, but no nearer the other's than half as far
    P, trial_of = places(np.array([half + [0.005, 0, 0], half - [0.005, 0, 0]]), np.array([a, b]))
    assert exchanged_clusters(P, trial_of, [True, False], ["A", "B"], ["femur_l", "femur_l"]) == []
    # Every trial moving, or every one still: nothing to compare against.
    assert exchanged_clusters(P, trial_of, [False, False], ["A", "B"], ["femur_l", "femur_l"]) == []


def test_the_command_line_warns_and_reports_it(session, tmp_path, capsys):
    """`calibrate STATIC SQUATS MODEL`: the summary's `relabelled` line, one warning naming the labels read, the
    report's `relabelled` entry with the static's file name, and the HTML report's note."""
    base, squats, _, mirrored, _ = session
    write_c3d(tmp_path / "static.c3d", mirrored)
    write_c3d(tmp_path / "squats.c3d", squats.trial)
    code = main([str(tmp_path / "static.c3d"), str(tmp_path / "squats.c3d"), str(base.path), "-o",
                 str(tmp_path / "subject.urdf"), "--report", str(tmp_path / "report.json"), "--html",
                 str(tmp_path / "report.html")])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "  relabelled   " in out and f"{tmp_path / 'static.c3d'} (still) names the markers of femur_l" in out
    warning = [ln for ln in err.splitlines() if "cluster labels a trial names otherwise than the others" in ln]
    assert len(warning) == 1 and all(f"{a} as {b}" in warning[0] for a, b in MIRRORED.items())
    rep = json.loads((tmp_path / "report.json").read_text())
    (entry,) = rep["relabelled"]
    assert entry["trial"].endswith("static.c3d")
    assert dict(zip(entry["labels"], entry["read_as"], strict=True)) == MIRRORED
    assert "relabelled: " in (tmp_path / "report.html").read_text()


def test_a_models_own_cluster_markers_are_read_back_after_the_first_solve():
    """The plate's markers in the base model itself (a lab's OpenSim model carrying its marker set, as Expert1's
    generic.osim): they set the start's poses, so they are judged at the first subsample solution
    (moved.exchanged_after_solve: the static's thigh posed again without its markers) and read back there.  As in
    Expert1's static, a medial knee marker there (static only) fixes that pose's turn about the femur's length: the
    places read lie 5-12 mm from the squats' (without it, 31-40 mm: at EXCHANGE_OWN's edge).  The plate's model places
    then end at the subject's, the static's positions kept and fitted to the noise."""
    truth = _plated({**PLATE, "LMKNE": (0.0, -0.057, -0.424)})
    squats = simulate_squats(truth, frames=200, noise_mm=1.0, seed=11)
    static = simulate_static(truth, squats.truth, frames=100, noise_mm=1.0, seed=11)
    mirrored = replace(static.trial, labels=tuple(MIRRORED.get(n, n) for n in static.trial.labels))
    walk = squats.trial.select([n for n in squats.trial.labels if n != "LMKNE"])
    cal = calibrate(truth, [mirrored, walk], Settings())
    assert len(cal.relabelled) == 1
    x = cal.relabelled[0]
    assert (x.trial, x.segment) == (0, "femur_l") and dict(zip(x.labels, x.read_as, strict=True)) == MIRRORED
    assert min(x.own) > 0.05 and sum(x.exchanged) < EXCHANGE_GAIN * sum(x.own), x
    assert not cal.moved
    F0 = mirrored.n_frames
    seg = cal.model.segment_index("femur_l")
    for n in PLATE:
        k = cal.model.marker_index(n)
        assert np.median(np.linalg.norm(cal.residuals[:F0, k], axis=1)) < 0.003
        true_place = squats.truth.scale[seg] * squats.truth.marker[truth.marker_index(n)]
        assert np.linalg.norm(cal.params.scale[seg] * cal.params.marker[k] - true_place) < 0.01


def test_two_moving_trials_that_name_the_plate_otherwise_are_read_as_one(session):
    """The squats cut in two moving trials, the second naming the plate mirrored (Expert1's walkingTO1 against its
    walking1): pooled, each label's place would jump between the trials.  Each trial's labels are hosted alone
    (hosts.trial_exchanges), the second's read as the first names them (the reference: of two that disagree, the
    first), and the plate is placed in the shape the subject carries it and fitted in both to the noise."""
    base, squats, _, _, true_places = session
    first, second = _halves(squats)
    cal = calibrate(base, [first, second], Settings())
    (x,) = cal.relabelled
    assert (x.trial, x.reference, x.segment) == (1, 0, "femur_l")
    assert dict(zip(x.labels, x.read_as, strict=True)) == MIRRORED
    assert cal.trials[1].labels == first.labels  # the second trial's labels as the first names them
    seg = cal.model.segment_index("femur_l")
    placed = {n: cal.params.scale[seg] * cal.params.marker[cal.model.marker_index(n)] for n in PLATE}
    for a in PLATE:  # the plate's shape as the subject carries it: its distances within 2 mm of the truth's
        for b in PLATE:
            assert abs(np.linalg.norm(placed[a] - placed[b]) - np.linalg.norm(true_places[a] - true_places[b])) < 0.002
    assert np.median(np.linalg.norm(cal.residuals[:, cal.model.marker_index("TH1")], axis=1)) < 0.003
    line = next(ln for ln in summary_text(cal).splitlines() if ln.startswith("  relabelled   "))
    assert "second.c3d names the markers of femur_l otherwise than first.c3d: read TH" in line
    assert calibration_report(cal)["relabelled"][0]["reference"] == "first.c3d"


def test_a_models_placeholder_plate_named_otherwise_by_the_trials_is_read_as_one(session):
    """The plate as the base model's own markers, all four at one point (placeholders, as Expert1's generic.osim carries
    its thigh plates for OpenSim's marker placer to fill): trials that name it otherwise are found before the fit,
    each hosting the placeholders as new labels on the model posed without them (hosts.trial_exchanges).  The squats
    cut in two moving trials, the second naming the plate mirrored, and the static mirrored too: both read as the
    first moving trial names them (on Expert1's generic.osim, walking1 with DJ1 had fitted walking1 to 27.7 mm), the
    plate placed in the subject's shape and every trial fitted to the noise."""
    _, squats, static, mirrored, true_places = session
    base = _plated({n: (-0.02, 0.078, -0.18) for n in PLATE})
    first, second = _halves(squats)
    cal = calibrate(base, [replace(mirrored, source="static.c3d"), first, second], Settings())
    read = {(x.trial, x.reference, x.segment): dict(zip(x.labels, x.read_as, strict=True)) for x in cal.relabelled}
    assert read == {(2, 1, "femur_l"): MIRRORED, (0, 1, "femur_l"): MIRRORED}
    assert cal.trials[0].labels == static.trial.labels and cal.trials[2].labels == first.labels
    assert not cal.moved
    seg = cal.model.segment_index("femur_l")
    placed = {n: cal.params.scale[seg] * cal.params.marker[cal.model.marker_index(n)] for n in PLATE}
    for a in PLATE:
        for b in PLATE:
            assert abs(np.linalg.norm(placed[a] - placed[b]) - np.linalg.norm(true_places[a] - true_places[b])) < 0.002
    for n in PLATE:
        assert np.median(np.linalg.norm(cal.residuals[:, cal.model.marker_index(n)], axis=1)) < 0.003


def test_calibrate_ik_reads_a_plate_the_trial_names_otherwise_than_the_subject(session, tmp_path, capsys):
    """`calibrate ik` of another trial on a subject already calibrated (subject_ik.fit_trial): the trial names the
    plate mirrored (22 of Expert1's 24 other trials name its left plate otherwise than walking1 does, fitted as labelled
    at 33-36 mm RMS).  The segment's two or more badly fitted markers are read on poses without them, matched to the
    subject's places and read back; the trial then fits as the unmirrored one does, to the frame.  The same trial as
    labelled is left alone, and the command line names what it read."""
    _, squats, _, _, _ = session
    truth = _plated()
    subject = load_model(write_model(truth, tmp_path / "subject.urdf", squats.truth))
    trial = squats.trial.frames(0, 120)
    mirrored = replace(trial, labels=tuple(MIRRORED.get(n, n) for n in trial.labels))
    plain = fit_trial(subject, trial, subject.parameters(), {})
    read = fit_trial(subject, mirrored, subject.parameters(), {})
    assert plain.relabelled == () and plain.fit.rms < 0.002
    (x,) = read.relabelled
    assert x.segment == "femur_l" and dict(zip(x.labels, x.read_as, strict=True)) == MIRRORED
    assert min(x.own) > EXCHANGE_OWN and max(x.exchanged) < 0.01
    assert np.allclose(read.fit.motion.angles, plain.fit.motion.angles, atol=1e-6)
    assert fit_trial(subject, mirrored, subject.parameters(), {}, keep_damaged=True).fit.rms > 0.02  # as labelled
    path = tmp_path / "mirrored.c3d"
    write_c3d(path, mirrored)
    assert main(["ik", str(path), str(tmp_path / "subject.urdf"), "-o", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert "mirrored.c3d names the markers of femur_l otherwise than subject.urdf: read TH" in err
    # the trial's report says the same for a lab's batch: what was read as what, and the note
    report = json.loads((tmp_path / "mirrored_ik_report.json").read_text())
    (got,) = report["relabelled"]
    assert got["segment"] == "femur_l" and dict(zip(got["labels"], got["read_as"], strict=True)) == MIRRORED
    assert [n for n in report["notes"] if "otherwise than subject.urdf" in n] == [
        line[len("note: "):] for line in err.splitlines() if "otherwise than subject.urdf" in line]


def test_two_moving_trials_that_name_a_models_own_plate_otherwise_are_read_as_one(session):
    """The plate as the base model's own markers at their places (a lab's marker set after OpenSim's Scale, as the
    expert's hand_scaled.osim carries Expert1's plates): the squats cut in two moving trials, the second naming it
    mirrored.  Each trial posed by the base model, the plate's markers fit the second trial 25 mm or more worse than the
    first, so both are posed again without them and the places read matched trial against trial
    (hosts.trial_exchanges); the second is read as the first names them and both fit to the noise."""
    _, squats, _, _, _ = session
    base = _plated()
    first, second = _halves(squats)
    cal = calibrate(base, [first, second], Settings())
    (x,) = cal.relabelled
    assert (x.trial, x.reference, x.segment) == (1, 0, "femur_l")
    assert dict(zip(x.labels, x.read_as, strict=True)) == MIRRORED
    for n in PLATE:
        assert np.median(np.linalg.norm(cal.residuals[:, cal.model.marker_index(n)], axis=1)) < 0.003
