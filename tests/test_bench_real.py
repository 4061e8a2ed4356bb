"""scripts/bench_real.py recomputes its figures from the files a calibration writes (Pinocchio on the
subject URDF and motion CSV): they must agree with the calibration's own on a simulated trial."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.calibration.evaluate import compare_to_truth
from calibrate.calibration.pipeline import calibrate
from calibrate.io.measurements import SubjectMeasurements
from calibrate.io.read import read_trial
from calibrate.simulation.simulate import simulate_squats, write_simulation

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
import bench_real  # noqa: E402


@pytest.fixture(scope="module")
def written(human, tmp_path_factory):
    """A short 1 mm-noise squat trial, calibrated, with every output written."""
    d = tmp_path_factory.mktemp("bench_real")
    sim = simulate_squats(human, frames=60, noise_mm=1.0, seed=11)
    # With a session's measurements in the C3D (PROCESSING), as Plug-in Gait trials carry them.
    widths = {"knee_l": 0.105, "knee_r": 0.102, "ankle_l": 0.072, "ankle_r": 0.07, "elbow_l": 0.07, "elbow_r": 0.068}
    sim = replace(sim, trial=replace(sim.trial, measurements=SubjectMeasurements(mass=71.0, widths=widths)))
    paths = write_simulation(sim, d)
    cal = calibrate(human, read_trial(paths["trial"]))
    cal.write(urdf=d / "subject.urdf", motion=d / "trial_motion.csv", report=d / "report.json")
    return sim, cal, d


def test_marker_rms_recomputed_from_the_files_equals_the_calibrations(written):
    _, cal, d = written
    assert not cal.outliers  # every position is in both figures
    report = json.loads((d / "report.json").read_text())
    kin = bench_real.UrdfKinematics(d / "subject.urdf")
    fit = bench_real.marker_fit(kin, [(d / "trial.c3d", d / "trial_motion.csv")], report)
    assert fit["positions"] == int(np.isfinite(cal.residuals[..., 0]).sum())
    assert fit["rms_mm"] == pytest.approx(1e3 * cal.marker_rms, abs=1e-6)


def test_truth_errors_from_the_files_equal_compare_to_truth(written):
    sim, cal, d = written
    kin = bench_real.UrdfKinematics(d / "subject.urdf")
    ours = bench_real.truth_errors(kin, d / "trial_motion.csv", bench_real.UrdfKinematics(d / "truth.urdf"),
                                   d / "truth_motion.csv", [])
    ref = compare_to_truth(cal, sim, floor=0.0)
    for j, v in ref.centre_error.items():
        assert ours["centre_mm"][j] == pytest.approx(1e3 * v, abs=1e-6), j
    for j, v in ref.axis_error_deg.items():
        assert ours["axis_deg"][j] == pytest.approx(v, abs=1e-5), j


def test_lateral_distances_from_the_files_equal_the_reports(written):
    """The lateral markers' distances from the joint centres along the hinge axes, recomputed with Pinocchio from
    the subject URDF against the widths read with ezc3d, equal the report's; every width used (the elbows' too,
    beside a movement trial: io.measurements.WIDTH_JOINTS)."""
    _, cal, d = written
    report = json.loads((d / "report.json").read_text())
    ours = bench_real.lateral_figures(bench_real.UrdfKinematics(d / "subject.urdf"), d / "trial.c3d", report)
    rep = report["measurements"]["lateral_mm"]
    assert set(ours) == set(rep) == {"knee_l", "knee_r", "ankle_l", "ankle_r", "elbow_l", "elbow_r"}
    for j, v in ours.items():
        assert v["ours_mm"] == pytest.approx(rep[j]["calibrated_mm"], abs=1e-6), j
        assert v["measured_mm"] == pytest.approx(rep[j]["measured_mm"], abs=1e-9), j
        assert v["used"] and rep[j]["used"], j
    assert report["mass"]["subject_kg"] == 71.0


def test_joint_shifts_and_lengths_of_the_base_model_itself():
    """The base model against itself: no shift; left and right segments of equal length."""
    kin = bench_real.UrdfKinematics(bench_real.MODEL)
    shifts = bench_real.joint_shifts(kin, bench_real.MODEL, {"parameters": []})
    assert max(shifts["shift_mm"].values()) < 1e-9
    lengths = bench_real.segment_lengths(kin)
    assert len(lengths["lengths"]) == 4 and lengths["asymmetry_pct"] < 1e-9
    thigh = lengths["lengths"]["thigh (hip-knee)"]["left_mm"]
    assert thigh == pytest.approx(1e3 * np.linalg.norm(kin.origin["knee_l"]), abs=1e-9)


def test_sliced_c3d_keeps_the_frames(written, tmp_path):
    _, _, d = written
    cut = bench_real.slice_c3d(d / "trial.c3d", tmp_path / "cut.c3d", 10, 35)
    a, b = read_trial(d / "trial.c3d"), read_trial(cut)
    assert b.n_frames == 25 and b.labels == a.labels and b.first_frame == a.first_frame + 10
    np.testing.assert_array_equal(b.markers, a.markers[10:35])


def test_perturbed_c3d_adds_the_noise_and_keeps_the_rest(written, tmp_path):
    _, _, d = written
    noisy = bench_real.perturb_c3d(d / "trial.c3d", tmp_path / "noisy.c3d", 0.1, seed=1)
    a, b = read_trial(d / "trial.c3d"), read_trial(noisy)
    assert b.labels == a.labels and b.measurements.widths == a.measurements.widths
    np.testing.assert_array_equal(np.isnan(b.markers), np.isnan(a.markers))  # gaps stay gaps
    diff = 1000 * (b.markers - a.markers)[np.isfinite(a.markers)]  # mm
    assert abs(diff.std() - 0.1) < 0.005 and abs(diff.mean()) < 0.005


def test_corruptions_caught_matches_frame_and_marker(tmp_path):
    (tmp_path / "truth_corruptions.csv").write_text("kind,frame,marker\nspike,3,LKNE\nswap,7,LASI\nswap,7,RASI\n")
    report = {"outliers": {"count": 3, "rejected": [{"trial": 0, "frame": 3, "marker": "LKNE"},
                                                     {"trial": 0, "frame": 7, "marker": "LASI"},
                                                     {"trial": 0, "frame": 8, "marker": "RASI"}]}}
    c = bench_real.corruptions_caught(tmp_path, report)
    assert (c["corruptions"], c["caught"]) == (3, 2) and c["per_kind"]["swap"] == {"n": 2, "caught": 1}
    assert "note" not in c  # every rejected position is listed
    report["outliers"]["count"] = 500
    assert "lower bound" in bench_real.corruptions_caught(tmp_path, report)["note"]
