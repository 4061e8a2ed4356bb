"""Tests for calibrate.io.trial: reading and writing C3D/TRC trials, gaps, units, bad files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from calibrate.errors import CalibrateError, TrialError
from calibrate.io.c3d import read_c3d, write_c3d
from calibrate.io.read import read_trial
from calibrate.io.trc import read_trc, write_trc
from calibrate.io.trial import Trial, strip_subject_prefix

ATOL = 1e-6  # metres: float32 C3D storage in mm or m is good to well below a micrometre


def make_trial(n_frames: int = 40, n_markers: int = 5, *, first_frame: int = 12, rate: float = 200.0) -> Trial:
    """A trial with known positions (metres, a few metres from the origin) and some gaps."""
    rng = np.random.default_rng(7)
    markers = rng.uniform(-2.5, 2.5, size=(n_frames, n_markers, 3))
    if n_frames > 20 and n_markers > 2:
        markers[3, 1] = np.nan  # a one-frame gap
        markers[10:20, 2] = np.nan  # a longer gap
    markers[0, 0] = np.nan  # gap on the first frame
    markers[-1, -1] = np.nan  # gap on the last frame
    labels = tuple(f"M{i}" for i in range(n_markers - 1)) + ("R.ASIS",)
    return Trial(labels=labels, markers=markers, rate=rate, first_frame=first_frame)


def assert_same_trial(got: Trial, want: Trial) -> None:
    assert got.labels == want.labels
    assert got.rate == pytest.approx(want.rate)
    assert got.first_frame == want.first_frame
    assert got.markers.shape == want.markers.shape
    np.testing.assert_array_equal(np.isnan(got.markers), np.isnan(want.markers))
    np.testing.assert_allclose(got.markers, want.markers, rtol=0, atol=ATOL, equal_nan=True)


def assert_one_line_error(excinfo: pytest.ExceptionInfo[TrialError], path: Path) -> None:
    message = str(excinfo.value)
    assert path.name in message
    assert "\n" not in message and "\r" not in message
    assert isinstance(excinfo.value, CalibrateError)


# ---------------------------------------------------------------------------
# Trial
# ---------------------------------------------------------------------------


def test_trial_properties_and_accessors() -> None:
    trial = make_trial(n_frames=40, first_frame=12, rate=200.0)
    assert trial.n_frames == 40
    assert trial.n_markers == 5
    assert trial.markers.dtype == np.float64
    np.testing.assert_allclose(trial.times, (12 + np.arange(40)) / 200.0)
    np.testing.assert_array_equal(trial.marker("M2"), trial.markers[:, 2, :])
    gaps = trial.gap_fraction()
    np.testing.assert_allclose(gaps, [1 / 40, 1 / 40, 10 / 40, 0.0, 1 / 40])


def test_trial_markers_are_a_read_only_copy() -> None:
    markers = np.zeros((2, 1, 3))
    markers[0, 0] = [0.1, 0.2, 0.3]
    trial = Trial(("A",), markers, 100.0)
    markers[0, 0, 0] = 9.0
    assert trial.markers[0, 0, 0] == 0.1
    with pytest.raises(ValueError):
        trial.markers[0, 0, 0] = 1.0


def test_partial_or_infinite_coordinates_make_a_whole_gap() -> None:
    markers = np.ones((3, 2, 3))
    markers[0, 0, 1] = np.nan
    markers[2, 1, 2] = np.inf
    trial = Trial(("A", "B"), markers, 100.0)
    assert np.isnan(trial.markers[0, 0]).all()
    assert np.isnan(trial.markers[2, 1]).all()
    assert np.isfinite(trial.markers[1]).all()


def test_unknown_marker_names_the_label_and_some_known_ones() -> None:
    trial = make_trial()
    with pytest.raises(TrialError) as excinfo:
        trial.marker("LHEE")
    message = str(excinfo.value)
    assert "LHEE" in message and "M0" in message and "\n" not in message


def test_select_reorders_and_subsets() -> None:
    trial = make_trial()
    sub = trial.select(["R.ASIS", "M0"])
    assert sub.labels == ("R.ASIS", "M0")
    np.testing.assert_array_equal(sub.markers[:, 0], trial.marker("R.ASIS"))
    np.testing.assert_array_equal(sub.markers[:, 1], trial.marker("M0"))
    assert sub.rate == trial.rate and sub.first_frame == trial.first_frame
    assert trial.select("M1").labels == ("M1",)
    with pytest.raises(TrialError, match="nope"):
        trial.select(["M0", "nope"])


def test_frames_slices_and_adjusts_first_frame() -> None:
    trial = make_trial(first_frame=12)
    part = trial.frames(5, 15)
    assert part.n_frames == 10
    assert part.first_frame == 17
    np.testing.assert_array_equal(part.markers, trial.markers[5:15])
    np.testing.assert_allclose(part.times, trial.times[5:15])
    assert trial.frames(3, 3).n_frames == 0
    for start, stop in [(-1, 4), (5, 4), (0, 41)]:
        with pytest.raises(TrialError):
            trial.frames(start, stop)


@pytest.mark.parametrize(
    ("labels", "markers", "rate", "first_frame", "match"),
    [
        (("A", "B"), np.zeros((4, 3, 3)), 100.0, 0, "shape"),
        (("A",), np.zeros((4, 1, 2)), 100.0, 0, "shape"),
        (("A",), np.zeros((4, 3)), 100.0, 0, "shape"),
        (("A", "A"), np.zeros((4, 2, 3)), 100.0, 0, "unique"),
        (("A", ""), np.zeros((4, 2, 3)), 100.0, 0, "non-empty"),
        (("A", "  "), np.zeros((4, 2, 3)), 100.0, 0, "non-empty"),
        (("A", " B"), np.zeros((4, 2, 3)), 100.0, 0, "whitespace"),
        (("A", 7), np.zeros((4, 2, 3)), 100.0, 0, "label"),
        ("AB", np.zeros((4, 2, 3)), 100.0, 0, "sequence"),
        (("A",), np.zeros((4, 1, 3)), 0.0, 0, "rate"),
        (("A",), np.zeros((4, 1, 3)), -50.0, 0, "rate"),
        (("A",), np.zeros((4, 1, 3)), float("nan"), 0, "rate"),
        (("A",), np.zeros((4, 1, 3)), float("inf"), 0, "rate"),
        (("A",), np.zeros((4, 1, 3)), 100.0, -1, "first frame"),
        (("A",), np.zeros((4, 1, 3)), 100.0, 1.5, "first frame"),
    ],
)
def test_trial_validation(labels, markers, rate, first_frame, match) -> None:  # noqa: ANN001
    with pytest.raises(TrialError, match=match) as excinfo:
        Trial(labels, markers, rate, first_frame=first_frame, source="walk01.c3d")
    assert "\n" not in str(excinfo.value)
    assert "walk01.c3d" in str(excinfo.value)


# ---------------------------------------------------------------------------
# Round trips
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("units", ["mm", "m", "cm"])
def test_c3d_round_trip(tmp_path: Path, units: str) -> None:
    trial = make_trial()
    path = tmp_path / f"walk_{units}.c3d"
    write_c3d(path, trial, units=units)
    back = read_c3d(path)
    assert_same_trial(back, trial)
    assert back.source == str(path)
    assert ezc3d.c3d(str(path))["parameters"]["POINT"]["UNITS"]["value"] == [units]


@pytest.mark.parametrize("units", ["mm", "m", "cm"])
def test_trc_round_trip(tmp_path: Path, units: str) -> None:
    trial = make_trial()
    path = tmp_path / f"walk_{units}.trc"
    write_trc(path, trial, units=units)
    back = read_trc(path)
    assert_same_trial(back, trial)
    np.testing.assert_allclose(back.markers, trial.markers, rtol=0, atol=1e-9, equal_nan=True)


def test_c3d_round_trip_with_more_than_255_markers(tmp_path: Path) -> None:
    trial = make_trial(n_frames=4, n_markers=300)
    path = tmp_path / "many.c3d"
    write_c3d(path, trial, units="m")
    assert_same_trial(read_c3d(path), trial)


def test_c3d_gaps_are_stored_as_invalid_points(tmp_path: Path) -> None:
    """Gaps go into the file as the standard invalid point: residual -1 (ezc3d reads them as NaN)."""
    trial = make_trial()
    path = tmp_path / "gaps.c3d"
    write_c3d(path, trial)
    raw = ezc3d.c3d(str(path))
    residuals = raw["data"]["meta_points"]["residuals"][0]  # (markers, frames)
    gap = np.isnan(trial.markers).any(axis=2).T
    assert (residuals[gap] < 0).all()
    assert (residuals[~gap] >= 0).all()


def test_c3d_first_frame_is_stored_one_based_in_the_header(tmp_path: Path) -> None:
    trial = make_trial(first_frame=12)
    path = tmp_path / "ff.c3d"
    write_c3d(path, trial)
    header = path.read_bytes()[:512]
    assert int.from_bytes(header[6:8], "little") == 13  # C3D header word 4: first frame, 1-based
    assert ezc3d.c3d(str(path))["header"]["points"]["first_frame"] == 12  # ezc3d: 0-based


def test_trc_written_in_opensim_layout(tmp_path: Path) -> None:
    trial = make_trial(n_frames=3, n_markers=2, first_frame=4, rate=100.0)
    path = tmp_path / "layout.trc"
    write_trc(path, trial, units="mm")
    lines = path.read_text().splitlines()
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\tlayout.trc"
    assert lines[1].split("\t") == [
        "DataRate",
        "CameraRate",
        "NumFrames",
        "NumMarkers",
        "Units",
        "OrigDataRate",
        "OrigDataStartFrame",
        "OrigNumFrames",
    ]
    assert lines[2].split("\t") == ["100", "100", "3", "2", "mm", "100", "5", "3"]
    assert lines[3] == "Frame#\tTime\tM0\t\t\tR.ASIS\t\t\t"
    assert lines[4] == "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\t"
    first_row = lines[6].split("\t")
    assert first_row[:2] == ["5", "0.04"]
    assert first_row[2:5] == ["", "", ""]  # M0 is a gap on the first frame
    assert float(first_row[5]) == pytest.approx(trial.markers[0, 1, 0] * 1000, abs=1e-6)


def test_writers_replace_existing_files_and_leave_no_temporaries(tmp_path: Path) -> None:
    trial = make_trial()
    for name, write, read in [("t.c3d", write_c3d, read_c3d), ("t.trc", write_trc, read_trc)]:
        path = tmp_path / name
        path.write_text("old contents")
        write(path, trial)
        assert_same_trial(read(path), trial)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.c3d", "t.trc"]


def test_writer_missing_directory_is_named(tmp_path: Path) -> None:
    trial = make_trial()
    missing = tmp_path / "no_such_dir"
    for name, write in [("t.c3d", write_c3d), ("t.trc", write_trc)]:
        with pytest.raises(TrialError) as excinfo:
            write(missing / name, trial)
        assert "no_such_dir" in str(excinfo.value)
        assert "\n" not in str(excinfo.value)
    assert not missing.exists()


def test_writer_rejects_unknown_units(tmp_path: Path) -> None:
    trial = make_trial()
    for name, write in [("t.c3d", write_c3d), ("t.trc", write_trc)]:
        with pytest.raises(TrialError, match="inch"):
            write(tmp_path / name, trial, units="inch")
    assert list(tmp_path.iterdir()) == []


def test_writers_reject_empty_trial(tmp_path: Path) -> None:
    empty = make_trial().frames(0, 0)
    for name, write in [("t.c3d", write_c3d), ("t.trc", write_trc)]:
        with pytest.raises(TrialError):
            write(tmp_path / name, empty)
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------
# C3D written directly with ezc3d
# ---------------------------------------------------------------------------


def test_read_c3d_from_ezc3d_with_invalid_points_cm_and_many_labels(tmp_path: Path) -> None:
    n_points, n_frames = 300, 6
    rng = np.random.default_rng(3)
    positions_cm = rng.uniform(-150.0, 150.0, size=(n_frames, n_points, 3))
    labels = [f"P{i:03d}" for i in range(n_points)]
    labels[7] = ""  # an unlabelled point
    labels[9] = "P008"  # a duplicate label
    labels[260] = "  Spaced  "  # surrounding whitespace

    points = np.ones((4, n_points, n_frames))
    points[:3] = positions_cm.transpose(2, 1, 0)
    residuals = np.zeros((1, n_points, n_frames))
    residuals[0, 5, 2] = -1.0  # invalid point by residual
    points[:3, 6, 4] = 0.0  # exactly-zero point, residual 0
    points[:3, 270, 1] = 0.0  # exactly-zero point past the first 255

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [250.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels[:255]
    c3d.add_parameter("POINT", "LABELS2", labels[255:])
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["cm"]
    c3d["header"]["points"]["first_frame"] = 99
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals}
    path = tmp_path / "direct.c3d"
    c3d.write(str(path))
    params = ezc3d.c3d(str(path))["parameters"]["POINT"]
    assert len(params["LABELS"]["value"]) == 255 and len(params["LABELS2"]["value"]) == 45

    trial = read_c3d(path)
    assert trial.n_markers == n_points and trial.n_frames == n_frames
    assert trial.rate == 250.0
    assert trial.first_frame == 99
    assert trial.labels[7] == "unlabelled_8"
    assert trial.labels[8] == "P008" and trial.labels[9] == "P008_2"
    assert trial.labels[260] == "Spaced"
    assert trial.labels[299] == "P299"
    assert len(set(trial.labels)) == n_points

    want = positions_cm / 100.0
    want[2, 5] = np.nan
    want[4, 6] = np.nan
    want[1, 270] = np.nan
    np.testing.assert_array_equal(np.isnan(trial.markers), np.isnan(want))
    np.testing.assert_allclose(trial.markers, want, rtol=0, atol=ATOL, equal_nan=True)


def _ezc3d_file(path: Path, *, units: list[str] | None, n_points: int = 2, n_frames: int = 3) -> Path:
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = [f"M{i}" for i in range(n_points)]
    if units is not None:
        c3d["parameters"]["POINT"]["UNITS"]["value"] = units
    c3d["data"]["points"] = np.full((4, n_points, n_frames), 10.0)
    if n_frames == 0:
        del c3d["data"]["rotations"]  # ezc3d's writer divides by the frame count when rotations are present
    c3d.write(str(path))
    return path


def test_read_c3d_units(tmp_path: Path) -> None:
    assert read_c3d(_ezc3d_file(tmp_path / "a.c3d", units=[" MM "])).markers[0, 0, 0] == pytest.approx(0.01)
    assert read_c3d(_ezc3d_file(tmp_path / "b.c3d", units=["M"])).markers[0, 0, 0] == pytest.approx(10.0)
    assert read_c3d(_ezc3d_file(tmp_path / "c.c3d", units=None)).markers[0, 0, 0] == pytest.approx(0.01)
    bad = _ezc3d_file(tmp_path / "inches.c3d", units=["in"])
    with pytest.raises(TrialError, match="units") as excinfo:
        read_c3d(bad)
    assert_one_line_error(excinfo, bad)


def test_read_c3d_without_points_or_frames(tmp_path: Path) -> None:
    no_points = _ezc3d_file(tmp_path / "nopoints.c3d", units=["mm"], n_points=0)
    with pytest.raises(TrialError, match="no marker") as excinfo:
        read_c3d(no_points)
    assert_one_line_error(excinfo, no_points)
    no_frames = _ezc3d_file(tmp_path / "noframes.c3d", units=["mm"], n_frames=0)
    with pytest.raises(TrialError, match="no frames") as excinfo:
        read_c3d(no_frames)
    assert_one_line_error(excinfo, no_frames)


# ---------------------------------------------------------------------------
# TRC reading tolerance
# ---------------------------------------------------------------------------

TRC_HEADER = (
    "PathFileType\t4\t(X/Y/Z)\thand.trc\n"
    "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n"
    "{rate}\t{rate}\t{frames}\t2\t{units}\t{rate}\t1\t{frames}\n"
    "Frame#\tTime\tA\t\t\tB\n"
    "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
)


def test_read_trc_hand_written_with_gaps_and_ragged_rows(tmp_path: Path) -> None:
    path = tmp_path / "hand.trc"
    path.write_text(
        TRC_HEADER.format(rate=60, frames=4, units="m")
        + "1\t0\t1\t2\t3\t4\t5\t6\t\t\n"  # trailing tabs
        + "2\t0.0167\t1.5\t2.5\t3.5\n"  # missing trailing cells: B is a gap
        + "3\t0.0333\t\t\t\t4\t5\t6\n"  # blank cells: A is a gap
        + "4\t0.05\t1\t\t3\t4\t5\t6\n"  # one blank coordinate: A is a gap
        + "\n\n"  # blank lines at the end
    )
    trial = read_trc(path)
    assert trial.labels == ("A", "B")
    assert trial.rate == 60.0 and trial.first_frame == 0
    want = np.array(
        [
            [[1, 2, 3], [4, 5, 6]],
            [[1.5, 2.5, 3.5], [np.nan] * 3],
            [[np.nan] * 3, [4, 5, 6]],
            [[np.nan] * 3, [4, 5, 6]],
        ]
    )
    np.testing.assert_allclose(trial.markers, want, equal_nan=True)


def test_read_trc_units_and_crlf(tmp_path: Path) -> None:
    path = tmp_path / "crlf.trc"
    text = TRC_HEADER.format(rate=100, frames=1, units="cm") + "11\t0.1\t1\t2\t3\t4\t5\t6\n"
    path.write_bytes(text.replace("\n", "\r\n").encode())
    trial = read_trc(path)
    np.testing.assert_allclose(trial.markers[0], [[0.01, 0.02, 0.03], [0.04, 0.05, 0.06]])
    assert trial.first_frame == 10


def _opensim_trc(name: str, labels: list[str], rows: list[list[str]], units: str, blank_line: bool) -> str:
    """A TRC file laid out as OpenSim's example files are (tabs, a blank 6th line in gait2392's subject01)."""
    n = len(labels)
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"60.00\t60.00\t{len(rows)}\t{n}\t{units}\t60.00\t1\t{len(rows)}",
        "Frame#\tTime\t" + "\t\t\t".join(labels),
        "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, n + 1)),
    ]
    if blank_line:
        lines.append("")
    lines += ["\t".join(row) for row in rows]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(("units", "blank_line"), [("mm", True), ("m", False), ("Millimeters", True)])
def test_read_trc_opensim_example_layout(tmp_path: Path, units: str, blank_line: bool) -> None:
    """Dots and spaces in names, empty and NaN cells, Units mm or m, with or without the blank 6th line."""
    labels = ["R.ASIS", "L.ASIS", "V.Sacral", "R Knee Lat", "R.Toe.Tip"]
    first = np.array([[120.5, 980.25, -40], [118, 975.5, 210.75], [-60, 1005, 85.5], [140, 500, -90], [300, 40, -80]])
    values = first + np.array([0.0, 1.0, 2.0])[:, None, None] * [1.0, 1.0, -1.0]  # (3 frames, 5 markers, 3) mm
    if units == "m":
        values = values / 1000.0
    cells = [[f"{v:.6f}" for v in frame.ravel()] for frame in values]
    cells[0][3:6] = ["", "", ""]  # L.ASIS missing: empty cells
    cells[1][9:12] = ["NaN", "NaN", "NaN"]  # R Knee Lat missing: NaN
    cells[2] = cells[2][:12]  # R.Toe.Tip missing: the row ends early
    rows = [[str(i + 1), f"{i / 60:.5f}", *c] for i, c in enumerate(cells)]
    path = tmp_path / "subject01_walk1.trc"
    path.write_text(_opensim_trc(path.name, labels, rows, units, blank_line))

    trial = read_trc(path)
    assert trial.labels == tuple(labels)
    assert trial.rate == 60.0 and trial.first_frame == 0 and trial.n_frames == 3
    want = values * (1.0 if units == "m" else 1e-3)
    want[0, 1] = want[1, 3] = want[2, 4] = np.nan
    np.testing.assert_allclose(trial.markers, want, rtol=0, atol=1e-9, equal_nan=True)

    # A marker written as exactly 0, 0, 0 is a gap too, as C3D's convention has it (the Hamner running trial of
    # OpenSim's models repository holds L.Bicep so in every frame); one coordinate at 0 is a position.
    cells[1][0:3] = ["0", "0", "0"]
    cells[2][6:9] = ["0.000000", "-0.000000", "0"]
    cells[0][12:15] = ["0", "5", "0"]
    rows = [[str(i + 1), f"{i / 60:.5f}", *c] for i, c in enumerate(cells)]
    path.write_text(_opensim_trc(path.name, labels, rows, units, blank_line))
    trial = read_trc(path)
    want[1, 0] = want[2, 2] = np.nan
    want[0, 4] = np.array([0.0, 5.0, 0.0]) * (1.0 if units == "m" else 1e-3)
    np.testing.assert_allclose(trial.markers, want, rtol=0, atol=1e-9, equal_nan=True)


def test_read_trc_subject_prefix(tmp_path: Path) -> None:
    labels = ["Sub01:RASI", "Sub01:LASI", "C7"]
    rows = [["1", "0", *["1"] * 9]]
    path = tmp_path / "prefixed.trc"
    path.write_text(_opensim_trc(path.name, labels, rows, "mm", blank_line=False))
    assert read_trc(path).labels == ("RASI", "LASI", "C7")
    assert read_trial(path, strip_prefix=False).labels == tuple(labels)


@pytest.mark.parametrize(
    ("labels", "want", "prefix"),
    [
        (["Sub01:RASI", "Sub01:LASI", "*12", ""], ["RASI", "LASI", "*12", ""], "Sub01"),
        (["Sub 01 : RASI", " Sub 01 :LASI"], ["RASI", "LASI"], "Sub 01"),
        (["Sub01:RASI", "Sub02:RASI"], ["Sub01:RASI", "Sub02:RASI"], None),  # two subjects
        (["Sub01:RASI", "RASI"], ["Sub01:RASI", "RASI"], None),  # would repeat RASI
        (["Sub01:RASI", "Sub01:"], ["Sub01:RASI", "Sub01:"], None),  # would leave a label empty
        ([":RASI", ":LASI"], [":RASI", ":LASI"], None),  # blank prefix
        (["RASI", "LASI"], ["RASI", "LASI"], None),
        (["A:B:C", "A:D"], ["B:C", "D"], "A"),  # the prefix ends at the first colon
    ],
)
def test_strip_subject_prefix(labels: list[str], want: list[str], prefix: str | None) -> None:
    assert strip_subject_prefix(labels) == (want, prefix)


def test_write_c3d_refuses_more_frames_than_ezc3d_reads_back(tmp_path: Path) -> None:
    trial = Trial(("A",), np.ones((65_536, 1, 3)), 100.0)
    path = tmp_path / "long.c3d"
    with pytest.raises(TrialError, match="65536 frames") as excinfo:
        write_c3d(path, trial)
    assert_one_line_error(excinfo, path)
    assert list(tmp_path.iterdir()) == []
    write_c3d(path, trial.frames(0, 65_535))
    assert read_c3d(path).n_frames == 65_535


def test_read_trc_labels_one_tab_apart_and_a_times_column(tmp_path: Path) -> None:
    """AddBiomechanics' stair-descent trial (server/engine/tests/data/stairdown) writes "Times" and its labels one tab
    apart ("Frame#  Times  <tab> LFHD <tab> LBHD ..."), its rows 2 + 3 x NumMarkers wide: read as OpenSim's reader takes
    labels (the non-empty ones in order, as many as NumMarkers), every value where it belongs."""
    path = tmp_path / "stairs.trc"
    path.write_text(TRC_HEADER.replace("Frame#\tTime\tA\t\t\tB", "Frame#\tTimes\t\tA\t\tB")
                    .replace("\t\tX1", "\t\t\tX1").format(rate=100, frames=2, units="m")
                    + "1\t0.01\t1\t2\t3\t4\t5\t6\n2\t0.02\t7\t8\t9\t10\t11\t12\n")
    trial = read_trc(path)
    assert trial.labels == ("A", "B") and trial.n_frames == 2
    np.testing.assert_array_equal(trial.markers[1], [[7, 8, 9], [10, 11, 12]])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (TRC_HEADER.format(rate=100, frames=1, units="mm") + "1\t0\t1\t2\tabc\t4\t5\t6\n", "abc"),
        (TRC_HEADER.format(rate=100, frames=1, units="furlong") + "1\t0\t1\t2\t3\t4\t5\t6\n", "furlong"),
        (TRC_HEADER.format(rate="fast", frames=1, units="mm") + "1\t0\t1\t2\t3\t4\t5\t6\n", "DataRate"),
        (TRC_HEADER.format(rate=100, frames=5, units="mm") + "1\t0\t1\t2\t3\t4\t5\t6\n", "NumFrames"),
        (TRC_HEADER.format(rate=100, frames=1, units="mm") + "1\t0\t1\t2\t3\t4\t5\t6\t7\n", "more values"),
        (TRC_HEADER.format(rate=100, frames=0, units="mm"), "no frames"),
        ("Frame#\tTime\tA\n1\t0\t1\t2\t3\n", "TRC"),
        (TRC_HEADER.replace("PathFileType", "Hello").format(rate=100, frames=0, units="mm") + "1\t0\n", "PathFileType"),
        # labels one tab apart with a third one the header does not count: out of step, not guessed
        (TRC_HEADER.replace("A\t\t\tB", "A\tB\tC").format(rate=100, frames=1, units="mm") + "1\t0\t1\t2\t3\t4\t5\t6\n",
         "out of step"),
    ],
)
def test_read_trc_malformed(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "bad.trc"
    path.write_text(text)
    with pytest.raises(TrialError, match=match) as excinfo:
        read_trc(path)
    assert_one_line_error(excinfo, path)


# ---------------------------------------------------------------------------
# Bad files and dispatch
# ---------------------------------------------------------------------------


def _valid_c3d_bytes(tmp_path: Path) -> bytes:
    path = tmp_path / "valid.c3d"
    write_c3d(path, make_trial(n_frames=60, n_markers=8))
    return path.read_bytes()


@pytest.mark.parametrize("suffix", [".c3d", ".trc"])
def test_missing_file(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"missing{suffix}"
    with pytest.raises(TrialError, match="no such file") as excinfo:
        read_trial(path)
    assert_one_line_error(excinfo, path)


@pytest.mark.parametrize("suffix", [".c3d", ".trc"])
def test_empty_file(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    with pytest.raises(TrialError, match="empty") as excinfo:
        read_trial(path)
    assert_one_line_error(excinfo, path)


def test_directory(tmp_path: Path) -> None:
    path = tmp_path / "folder.c3d"
    path.mkdir()
    for reader in (read_c3d, read_trc, read_trial):
        with pytest.raises(TrialError, match="directory") as excinfo:
            reader(path)
        assert_one_line_error(excinfo, path)


def test_truncated_c3d(tmp_path: Path) -> None:
    data = _valid_c3d_bytes(tmp_path)
    for cut in (len(data) // 2, 1024, 600, 300):
        path = tmp_path / f"cut_{cut}.c3d"
        path.write_bytes(data[:cut])
        with pytest.raises(TrialError, match="C3D") as excinfo:
            read_c3d(path)
        assert_one_line_error(excinfo, path)


def test_c3d_missing_last_frame_bytes(tmp_path: Path) -> None:
    data = _valid_c3d_bytes(tmp_path)
    path = tmp_path / "short.c3d"
    path.write_bytes(data[: len(data) - 8 * 16 - 512])  # lose the padding block and most of the last frame
    with pytest.raises(TrialError, match="truncated") as excinfo:
        read_c3d(path)
    assert_one_line_error(excinfo, path)


def test_garbage_c3d(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    for name, data in [
        ("noise.c3d", rng.integers(0, 256, 4096, dtype=np.uint8).tobytes()),
        ("text.c3d", b"this is not a c3d file\n" * 50),
        ("sig.c3d", bytes([2, 0x50]) + rng.integers(0, 256, 2046, dtype=np.uint8).tobytes()),
    ]:
        path = tmp_path / name
        path.write_bytes(data)
        with pytest.raises(TrialError, match="C3D") as excinfo:
            read_trial(path)
        assert_one_line_error(excinfo, path)


def test_binary_trc(tmp_path: Path) -> None:
    path = tmp_path / "binary.trc"
    path.write_bytes(_valid_c3d_bytes(tmp_path))
    with pytest.raises(TrialError) as excinfo:
        read_trc(path)
    assert_one_line_error(excinfo, path)


def test_read_trial_dispatch(tmp_path: Path) -> None:
    trial = make_trial()
    upper_c3d = tmp_path / "WALK.C3D"
    write_c3d(upper_c3d, trial)
    mixed_trc = tmp_path / "walk.Trc"
    write_trc(mixed_trc, trial)
    assert_same_trial(read_trial(upper_c3d), trial)
    assert_same_trial(read_trial(mixed_trc), trial)
    assert read_trial(str(upper_c3d)).source == str(upper_c3d)
    for name in ("walk.csv", "walk"):
        path = tmp_path / name
        path.write_text("x")
        with pytest.raises(TrialError, match=r"\.c3d or \.trc") as excinfo:
            read_trial(path)
        assert_one_line_error(excinfo, path)


def _c3d_with_analogs(path: Path) -> bytes:
    """A C3D with 2 markers and 2 analog channels at 10 samples per frame, written by ezc3d."""
    n_frames = 8
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = ["LHEE", "RHEE"]
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["ANALOG"]["RATE"]["value"] = [1000.0]
    c3d["parameters"]["ANALOG"]["LABELS"]["value"] = ["Fz1", "Fz2"]
    c3d["data"]["points"] = np.full((4, 2, n_frames), 250.0)
    c3d["data"]["analogs"] = np.ones((1, 2, 10 * n_frames))
    c3d.write(str(path))
    return path.read_bytes()


def _record(data: bytes, group_id: int, name: bytes) -> int:
    """Offset of the parameter record GROUP_ID:NAME in a C3D file (unlocked or locked)."""
    for n_chars in (len(name), 256 - len(name)):
        at = data.find(bytes([n_chars, group_id]) + name, 512)
        if at >= 0:
            return at
    raise AssertionError(f"no parameter {name!r} in group {group_id}")


def test_read_c3d_with_analog_channels(tmp_path: Path) -> None:
    path = tmp_path / "analogs.c3d"
    _c3d_with_analogs(path)
    trial = read_c3d(path)
    assert trial.labels == ("LHEE", "RHEE")
    np.testing.assert_allclose(trial.markers, 0.25)


def test_c3d_with_incomplete_analog_parameters(tmp_path: Path) -> None:
    """ezc3d crashes the interpreter when ANALOG:SCALE is missing: it is given a copy telling it of no analog
    channels, and the markers are read as the header lays them out (in a child process, so that a crash fails the
    test rather than the run)."""
    data = bytearray(_c3d_with_analogs(tmp_path / "analogs.c3d"))
    at = _record(bytes(data), 2, b"SCALE")  # ezc3d writes POINT as group 1, ANALOG as group 2
    data[at + 2 : at + 7] = b"SCALX"
    path = tmp_path / "noscale.c3d"
    path.write_bytes(bytes(data))
    code = ("import sys, numpy as np; from calibrate.io.c3d import read_c3d; t = read_c3d(sys.argv[1]); "
            "print(t.labels, t.n_frames, float(np.nanmin(t.markers)), float(np.nanmax(t.markers)))")
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-300:]
    assert run.stdout.split() == ["('LHEE',", "'RHEE')", "8", "0.25", "0.25"]


def test_c3d_with_damaged_parameter_record(tmp_path: Path) -> None:
    data = bytearray(_valid_c3d_bytes(tmp_path))
    at = _record(bytes(data), 1, b"LABELS")
    data[at + 2 + 6 + 2 + 1] = 200  # number of dimensions of POINT:LABELS
    path = tmp_path / "damaged.c3d"
    path.write_bytes(bytes(data))
    with pytest.raises(TrialError, match="parameter section") as excinfo:
        read_c3d(path)
    assert_one_line_error(excinfo, path)


def test_failed_write_leaves_the_old_file_alone(tmp_path: Path) -> None:
    tabbed = Trial(("A\tB",), np.ones((2, 1, 3)), 100.0)
    path = tmp_path / "keep.trc"
    path.write_text("old contents")
    with pytest.raises(TrialError, match="tab"):
        write_trc(path, tabbed)
    with pytest.raises(TrialError, match="units"):
        write_trc(path, make_trial(), units="feet")
    assert path.read_text() == "old contents"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.trc"]


def test_trc_header_values_padded_with_empty_fields(tmp_path):
    """Some exporters pad line 3 (the header values) with empty tab fields between the values, as
    Rajagopal's motion_capture_walk.trc does: the values are still matched to their keys."""
    from calibrate.io.trc import read_trc, write_trc
    from calibrate.io.trial import Trial

    rng = np.random.default_rng(0)
    trial = Trial(("A", "B"), rng.normal(size=(4, 2, 3)), 100.0)
    write_trc(tmp_path / "t.trc", trial)
    lines = (tmp_path / "t.trc").read_text().split("\n")
    lines[2] = "\t\t".join(lines[2].split("\t"))
    (tmp_path / "p.trc").write_text("\n".join(lines))
    back = read_trc(tmp_path / "p.trc")
    assert back.rate == 100.0 and back.labels == ("A", "B")
    assert np.allclose(back.markers, trial.markers, atol=1e-6)


def test_columns_put_trials_side_by_side_over_the_labels_of_all():
    """Trial.columns: the markers of the labels given, in their order, NaN for a label the trial does not show."""
    rng = np.random.default_rng(0)
    t = Trial(("A", "B", "C"), rng.normal(size=(5, 3, 3)), 100.0)
    cols = t.columns(["C", "X", "A"])
    assert cols.shape == (5, 3, 3)
    np.testing.assert_array_equal(cols[:, 0], t.marker("C"))
    np.testing.assert_array_equal(cols[:, 2], t.marker("A"))
    assert np.isnan(cols[:, 1]).all()
