"""Qualisys QTM's .tsv and OptiTrack Motive's .csv exports (calibrate.io.tables): files written here in the
vendors' layouts, read back against the positions written; their bad forms refused in one line; and a simulated
squat through the command line from each, against the same squat as C3D."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from calibrate.cli import main
from calibrate.errors import TrialError
from calibrate.io.c3d import write_c3d
from calibrate.io.labels import UNLABELLED
from calibrate.io.read import read_trial
from calibrate.io.tables import read_motive_csv, read_qtm_tsv
from calibrate.io.trial import Trial
from calibrate.simulation.simulate import simulate_squats


def make_trial(n_frames: int = 30, n_markers: int = 4, rate: float = 150.0) -> Trial:
    """Known positions (metres, within 2.5 m of the origin), with gaps at the ends and inside."""
    rng = np.random.default_rng(11)
    markers = rng.uniform(-2.5, 2.5, size=(n_frames, n_markers, 3))
    markers[0, 0] = np.nan
    markers[5:9, 2] = np.nan
    markers[-1, -1] = np.nan
    return Trial(tuple(f"M{k}" for k in range(n_markers - 1)) + ("L ASIS",), markers, rate, first_frame=7)


def qtm_text(trial: Trial, *, header: bool = True, column_row: bool = True, frame_time: bool = True,
             gap: str = "0.000", freq: str | None = None, kind: str = "3D", frames: int | None = None) -> str:
    """QTM's 3D TSV export as its manual lays it out: KEY<tab>value lines, the Frame/Time/NAME X... row, one row
    a frame (1-based frame numbers, time in s, mm to 3 decimals); a gap written as `gap` three times."""
    n = trial.n_markers
    lines = []
    if header:
        lines += ["FILE_VERSION\t2.0.0", f"NO_OF_FRAMES\t{trial.n_frames if frames is None else frames}",
                  "NO_OF_CAMERAS\t8", f"NO_OF_MARKERS\t{n}", f"FREQUENCY\t{freq or f'{trial.rate:g}'}",
                  "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0", "DESCRIPTION\t--",
                  "TIME_STAMP\t2024-03-01, 10:00:00.000\t1234.5", f"DATA_INCLUDED\t{kind}",
                  "MARKER_NAMES\t" + "\t".join(trial.labels), "TRAJECTORY_TYPES\t" + "\t".join(["Measured"] * n)]
    if column_row:
        lines.append(("Frame\tTime\t" if frame_time else "") + "\t".join(f"{lab} {a}" for lab in trial.labels
                                                                          for a in "XYZ") + "\t")
    for f in range(trial.n_frames):
        cells = [gap if np.isnan(v) else f"{1000 * v:.3f}" for v in trial.markers[f].ravel()]
        lead = [str(trial.first_frame + f + 1), f"{(trial.first_frame + f) / trial.rate:.5f}"] if frame_time else []
        lines.append("\t".join(lead + cells))
    return "\n".join(lines) + "\n"


def motive_text(trial: Trial, *, units: str | None = "Millimeters", prefix: str = "Skeleton:",
                unlabelled: np.ndarray | None = None, timecode: bool = True, markers: bool = True) -> str:
    """Motive's CSV export as its documentation lays it out: line 1 the take's settings, a blank line, the Type,
    Name, ID and component rows, then Frame,Time (Seconds)[,TimeCode],X,Y,Z...; a rigid body's rotation and
    position and the skeleton's marker constraints (not measurements) before the markers; occlusions blank."""
    scale = {"Millimeters": 1000.0, "Centimeters": 100.0}.get(units, 1.0)
    first = (f"Format Version,1.23,Take Name,Take 001,Take Notes,,Capture Frame Rate,{trial.rate:.6f},"
             f"Export Frame Rate,{trial.rate:.6f},Capture Start Time,2024-03-01 10.00.00.000 AM,"
             f"Total Frames in Take,{trial.n_frames},Total Exported Frames,{trial.n_frames},Rotation Type,Quaternion")
    first += f",Length Units,{units},Coordinate Space,Global" if units else ""
    cols: list[tuple[str, str, str, str]] = [("Rigid Body", "Pelvis", "Rotation", a) for a in "XYZW"]
    cols += [("Rigid Body", "Pelvis", "Position", a) for a in "XYZ"]
    cols += [("Bone Marker", f"{prefix}{lab}", "Position", a) for lab in trial.labels for a in "XYZ"]
    names = list(trial.labels) + (["Unlabeled 1000"] if unlabelled is not None else [])
    if markers:
        cols += [("Marker", f"{prefix}{lab}" if not lab.startswith("Unlabeled") else lab, "Position", a)
                 for lab in names for a in "XYZ"]
    lead = ["Frame", "Time (Seconds)"] + (["TimeCode"] if timecode else [])
    pad = [""] * (len(lead) - 1)
    rows = [first, "",
            ",".join(["", "Type"] + pad[1:] + [c[0] for c in cols]) if timecode else
            ",".join(["", "Type"] + [c[0] for c in cols]),
            ",".join(["", "Name"] + pad[1:] + [f'"{c[1]}"' for c in cols]),
            ",".join(["", "ID"] + pad[1:] + [str(k // 3) for k in range(len(cols))]),
            ",".join(["", ""] + pad[1:] + [c[2] for c in cols]),
            ",".join(lead + [c[3] for c in cols])]
    pos = trial.markers if unlabelled is None else np.concatenate([trial.markers, unlabelled[:, None]], axis=1)
    for f in range(trial.n_frames):
        body = ["0.0", "0.0", "0.0", "1.0", "0.1", "0.9", "0.2"]
        constraint = [f"{scale * v:.6f}" if np.isfinite(v) else "0.5" for v in trial.markers[f].ravel()]
        measured = ["" if np.isnan(v) else f"{scale * v:.6f}" for v in pos[f].ravel()] if markers else []
        stamp = ["10:00:00:00.0"] if timecode else []
        rows.append(",".join([str(f), f"{f / trial.rate:.6f}"] + stamp + body + constraint + measured))
    return "\n".join(rows) + "\n"


def same_positions(got: Trial, want: np.ndarray, atol: float) -> None:
    np.testing.assert_array_equal(np.isnan(got.markers), np.isnan(want))
    np.testing.assert_allclose(got.markers, want, rtol=0, atol=atol, equal_nan=True)


# ------------------------------------------------------------------------------------------------ Qualisys QTM
@pytest.mark.parametrize("gap", ["0.000", ""])
def test_qtm_tsv_read_back(tmp_path: Path, gap: str) -> None:
    """Positions to QTM's 3 decimals of a millimetre, gaps written as zeros or left empty, the frame numbers
    and times of the file's first row; read_trial chooses the reader by the .tsv suffix."""
    trial = make_trial()
    path = tmp_path / "walk.tsv"
    path.write_text(qtm_text(trial, gap=gap))
    got = read_trial(path)
    assert got.labels == trial.labels and got.rate == trial.rate
    assert got.first_frame == trial.first_frame
    assert got.start_time == pytest.approx(trial.first_frame / trial.rate, abs=5e-6)  # 5 decimals written
    same_positions(got, trial.markers, 0.5e-6)


@pytest.mark.parametrize("frame_time", [True, False])
def test_qtm_tsv_without_its_column_row(tmp_path: Path, frame_time: bool) -> None:
    """Older exports have no Frame/Time/NAME X row: the rows' length says whether they lead with a frame and time."""
    trial = make_trial()
    path = tmp_path / "walk.tsv"
    path.write_text(qtm_text(trial, column_row=False, frame_time=frame_time))
    got = read_qtm_tsv(path)
    assert got.first_frame == (trial.first_frame if frame_time else 0)
    same_positions(got, trial.markers, 0.5e-6)
    # the first row's last marker missing, its cells empty (and the row ending in a tab)
    markers = trial.markers.copy()
    markers[0, -1] = np.nan
    path.write_text(qtm_text(Trial(trial.labels, markers, trial.rate), column_row=False, frame_time=frame_time,
                             gap="").replace("\n", "\t\n"))
    same_positions(read_qtm_tsv(path), markers, 0.5e-6)


def test_qtm_tsv_external_timebase_rate_from_the_time_column(tmp_path: Path) -> None:
    trial = make_trial(rate=240.0)
    path = tmp_path / "walk.tsv"
    path.write_text(qtm_text(trial, freq="EXT"))
    assert read_qtm_tsv(path).rate == pytest.approx(240.0, rel=1e-3)  # times to 5 decimals
    path.write_text(qtm_text(trial, freq="EXT", frame_time=False, column_row=False))
    with pytest.raises(TrialError, match="FREQUENCY is EXT and there is no Time column"):
        read_qtm_tsv(path)


def _one_line(excinfo: pytest.ExceptionInfo, path: Path) -> str:
    message = str(excinfo.value)
    assert path.name in message and "\n" not in message
    return message


QTM_BAD = [
    (lambda t: qtm_text(t, kind="2D"), r"holds QTM's 2D camera data \(DATA_INCLUDED 2D\), not 3D marker positions"),
    (lambda t: qtm_text(t, kind="6D"), "holds QTM's 6DOF rigid-body data"),
    (lambda t: qtm_text(t, header=False), "has no MARKER_NAMES line"),
    (lambda t: qtm_text(t, frames=31), "NO_OF_FRAMES says 31 but the file has 30 rows of data"),
    (lambda t: qtm_text(t).replace("NO_OF_MARKERS\t4", "NO_OF_MARKERS\t5"), "NO_OF_MARKERS says 5 but MARKER_NAMES"),
    (lambda t: qtm_text(t).replace("\t150\n", "\tfast\n"), "FREQUENCY 'fast' is not a number"),
    (lambda t: re.sub(r"\n(8\t[^\t]*\t)[^\t]*", r"\n\1x1", qtm_text(t)), r"line 14, column 3: 'x1' is not a number"),
    (lambda t: "Time,RASI\n0,1\n", "not a Qualisys QTM TSV export"),
]


def test_qtm_tsv_a_row_longer_than_the_markers(tmp_path: Path) -> None:
    trial = make_trial()
    path = tmp_path / "bad.tsv"
    lines = qtm_text(trial).splitlines()
    lines[20] += "\t1.0\t2.0\t3.0"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(TrialError, match="line 21 has more values than the 4 markers"):
        read_qtm_tsv(path)


# ------------------------------------------------------------------------------------------- OptiTrack Motive
@pytest.mark.parametrize("units", ["Millimeters", "Centimeters", "Meters", None])
def test_motive_csv_read_back(tmp_path: Path, units: str | None) -> None:
    """The measured markers only (not the rigid body nor the skeleton's marker constraints), in the file's length
    units (metres where line 1 names none), the skeleton's prefix removed, an unlabelled marker kept as such;
    read_trial chooses the reader by the .csv suffix."""
    trial = make_trial()
    stray = np.random.default_rng(2).uniform(-1, 1, size=(trial.n_frames, 3))
    path = tmp_path / "take.csv"
    path.write_text(motive_text(trial, units=units, unlabelled=stray))
    got = read_trial(path)
    assert got.labels == (*trial.labels, "Unlabeled 1000") and UNLABELLED.fullmatch(got.labels[-1])
    assert got.rate == trial.rate and got.first_frame == 0 and got.start_time == 0.0
    decimals = {"Millimeters": 1e-3, "Centimeters": 1e-2}.get(units, 1.0) * 0.5e-6  # 6 decimals of the unit
    same_positions(got, np.concatenate([trial.markers, stray[:, None]], axis=1), 1.001 * decimals)
    assert read_motive_csv(path, strip_prefix=False).labels[0] == "Skeleton:M0"


def test_motive_csv_without_a_timecode_column(tmp_path: Path) -> None:
    trial = make_trial()
    path = tmp_path / "take.csv"
    path.write_text(motive_text(trial, timecode=False))
    same_positions(read_motive_csv(path), trial.markers, 1e-8)


MOTIVE_BAD = [
    (lambda t: motive_text(t, markers=False), r"has no marker positions \(it holds Bone Marker, Rigid Body columns"),
    (lambda t: motive_text(Trial(t.labels, t.markers * 1000, t.rate), units=None),  # millimetres, unsaid
     "gives no Length Units and the markers reach"),
    (lambda t: motive_text(t, units="Furlongs"), "unknown length units 'Furlongs'"),
    (lambda t: "time,pelvis_tx\n0.0,0.1\n", "not an OptiTrack Motive CSV export"),
    (lambda t: "time,root_x,root_y\n0.0,0.1,0.2\n", r"is a motion CSV \(a model's coordinates"),
    (lambda t: "\n".join(ln for ln in motive_text(t).splitlines() if not ln.startswith((",Type", ",Name"))),
     "has no Type and Name lines"),
    (lambda t: motive_text(t).replace("Export Frame Rate,150.000000,", "").replace("Capture Frame Rate,150.000000,",
                                                                                   ""),
     "gives no Export Frame Rate or Capture Frame Rate"),
    (lambda t: "\n".join(motive_text(t).splitlines()[:7]) + "\n", "contains no frames"),
    (lambda t: "\n".join(motive_text(t).splitlines()[:-1]) + "\n",
     r"says Total Exported Frames 30 but the file has 29 rows of data \(truncated\?\)"),
]


@pytest.mark.parametrize("suffix, text, match", [(".tsv", *bad) for bad in QTM_BAD] +
                         [(".csv", *bad) for bad in MOTIVE_BAD])
def test_bad_exports(tmp_path: Path, suffix: str, text, match) -> None:  # noqa: ANN001
    """Each bad form in one line naming the file, what is wrong and what to export instead."""
    trial = make_trial()
    path = tmp_path / f"bad{suffix}"
    path.write_text(text(trial))
    with pytest.raises(TrialError) as excinfo:
        read_trial(path)
    assert re.search(match, _one_line(excinfo, path)), str(excinfo.value)


def test_binary_text_export_refused(tmp_path: Path) -> None:
    path = tmp_path / "bad.tsv"
    path.write_bytes(b"NO_OF_FRAMES\t3\n\x00\x01\x02")
    with pytest.raises(TrialError, match="not a text file"):
        read_trial(path)


# ------------------------------------------------------------------------------------------ the command line
def _urdf_places(path: Path) -> np.ndarray:
    """Every xyz of the URDF (joint centres, marker places, centres of mass), metres."""
    return np.array([float(v) for xyz in re.findall(r'xyz="([^"]*)"', path.read_text()) for v in xyz.split()])


def test_squat_from_qtm_and_motive_exports_as_from_c3d(human, tmp_path: Path, capsys) -> None:  # noqa: ANN001
    """A simulated squat exported as QTM and Motive would export it calibrates through the command line to the
    subject its C3D gives: every place in the subject URDF within 0.5 mm (QTM keeps a micrometre; the solve stops
    within tens of micrometres of its minimum), Motive's in its own Y-up axes; the same markers (Motive's
    unlabelled one left out, and named in a warning of its own)."""
    sim = simulate_squats(human, frames=120, noise_mm=1.0, seed=3)
    write_c3d(tmp_path / "squat.c3d", sim.trial)
    (tmp_path / "squat.tsv").write_text(qtm_text(sim.trial))
    # Motive's own axes, Y up (the lab's z up becomes y, its y becomes -z)
    y_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    motive_trial = Trial(sim.trial.labels, sim.trial.markers @ y_up.T, sim.trial.rate)
    stray = motive_trial.markers[:, 0] + np.array([0.3, 0.0, 0.0])
    (tmp_path / "take.csv").write_text(motive_text(motive_trial, unlabelled=stray))
    for name in ("squat.c3d", "squat.tsv", "take.csv"):
        out = tmp_path / name.replace(".", "_")
        out.mkdir()
        code = main([str(tmp_path / name), str(human.path), "-o", str(out / "s.urdf"), "-q"])
        err = capsys.readouterr().err
        assert code == 0, err
        if name == "take.csv":
            assert "warning: 1 unlabelled trajectory ignored (Unlabeled 1000)" in err
    want = _urdf_places(tmp_path / "squat_c3d" / "s.urdf")
    for name in ("squat_tsv", "take_csv"):
        got = _urdf_places(tmp_path / name / "s.urdf")
        assert got.shape == want.shape
        assert np.max(np.abs(got - want)) < 5e-4, (name, np.max(np.abs(got - want)))
