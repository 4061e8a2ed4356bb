"""C3D files as Vicon, Qualisys, Motion Analysis and OptiTrack write them, read with read_trial.

Each test writes its file, with ezc3d where ezc3d can write that variant (float storage,
Intel processor) and byte by byte, following the C3D specification (c3d.org, "The C3D
File Format User Guide"), where it cannot (integer storage with a positive POINT:SCALE,
DEC and MIPS processor formats, the residual word exactly as the vendors store it, long
trials).  Expected positions are computed here from what was written, in metres.

What the vendors write, as far as these tests model it:

- Vicon Nexus: float, POINT:SCALE -0.01 (its size scales the residuals), mm, labels
  ``Subject:RASI`` with a SUBJECTS group, unlabelled trajectories ``*12``, modelled outputs
  (``LHipAngles``...) stored as points and listed in POINT:ANGLES/FORCES/MOMENTS/POWERS;
  invalid points: coordinates 0, residual word -1.
- Qualisys QTM: float, an odd POINT:SCALE (-0.0762), mm, long labels, first frame past 1,
  analog channels, the parameter section's first two bytes 0.
- Motion Analysis Cortex (and EVaRT before it): integer storage with POINT:SCALE 0.1
  (coordinate = stored integer x 0.1 mm), Helen Hayes labels (``R.ASIS``, ``V.Sacral``);
  invalid points: residual word -1, or all coordinates 0.
- OptiTrack Motive: float, POINT:UNITS ``m``, labels ``Skeleton:RASI`` (fully qualified
  names), ``Unlabeled 1001`` markers, hundreds of points (POINT:LABELS2, LABELS3...), long takes.
"""

from __future__ import annotations

import struct
from pathlib import Path

import ezc3d
import numpy as np
import pytest

from calibrate.errors import CalibrateError, TrialError
from calibrate.io.c3d import read_c3d
from calibrate.io.read import read_trial

ATOL = 1e-6  # metres: float32 storage in mm or m is good to well below a micrometre

PIG = ["LASI", "RASI", "LPSI", "RPSI", "LKNE", "RKNE", "LANK", "RANK", "LHEE", "RHEE", "LTOE", "RTOE"]
HELEN_HAYES = ["R.ASIS", "L.ASIS", "V.Sacral", "R.Thigh", "R.Knee", "R.Shank", "R.Ankle", "R.Heel", "R.Toe"]


# ---------------------------------------------------------------------------
# A minimal C3D writer, byte by byte
# ---------------------------------------------------------------------------

PROCESSOR = {"intel": 84, "dec": 85, "mips": 86}


def _float32(values: np.ndarray, processor: str) -> bytes:
    """Float32 values in a processor's format; DEC: the IEEE value x 4 with its 16-bit words swapped."""
    values = np.asarray(values, dtype=np.float64)
    if processor == "mips":
        return values.astype(">f4").tobytes()
    if processor == "dec":
        words = (values * 4.0).astype("<f4").view("<u2").reshape(-1, 2)
        return words[:, ::-1].copy().tobytes()
    return values.astype("<f4").tobytes()


def _int16(values: np.ndarray, processor: str) -> bytes:
    values = np.asarray(values)
    assert ((values >= -32768) & (values <= 65535)).all(), "a value does not fit 16 bits"
    as_int = values.astype(np.int64) & 0xFFFF
    return as_int.astype(">u2" if processor == "mips" else "<u2").tobytes()


def _parameter(value: object, processor: str) -> tuple[int, tuple[int, ...], bytes]:
    """(type, dimensions, data) of a parameter value: str, list of str, int, float, or lists of them; bytes: one
    character of no dimensions (a scalar)."""
    if isinstance(value, bytes):
        return -1, (), value
    if isinstance(value, str):
        raw = value.encode("latin-1")
        return -1, (len(raw),), raw
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        width = max(len(v) for v in value) or 1
        return -1, (width, len(value)), b"".join(v.encode("latin-1").ljust(width) for v in value)
    values = value if isinstance(value, list) else [value]
    dims = (len(values),) if isinstance(value, list) else ()
    if all(isinstance(v, int) for v in values):
        return 2, dims, _int16(np.array(values), processor)
    return 4, dims, _float32(np.array(values, dtype=float), processor)


def c3d_bytes(
    xyz: np.ndarray,
    word4: np.ndarray,
    labels: list[str],
    *,
    processor: str = "intel",
    scale: float = -0.1,
    units: str = "mm",
    rate: float = 100.0,
    first_frame: int = 1,
    frames: object = None,
    header_last_frame: int | None = None,
    analog_channels: int = 0,
    analog_per_frame: int = 0,
    parameters: tuple[tuple[str, str, object], ...] = (),
    parameter_start: bytes = b"\x01\x50",
    offsets: object = None,
) -> bytes:
    """A C3D file: header block, parameter blocks, data blocks (C3D User Guide, chapters 2-4).

    ``xyz`` (frames, points, 3) in file units; ``word4`` (frames, points) the fourth word
    of each point (float storage: written as a float; integer: as a 16-bit integer;
    -1 is the invalid point).  Integer storage (``scale`` > 0) stores round(xyz / scale).
    ``frames`` overrides POINT:FRAMES (an int is stored as a 16-bit word, a float as a float); ``offsets``
    ANALOG:OFFSET (floats are stored as floats).
    """
    n_frames, n_points, _ = xyz.shape
    is_float = scale < 0
    groups = {"POINT": 1, "ANALOG": 2}
    params: list[tuple[str, str, object]] = [
        ("POINT", "USED", n_points),
        ("POINT", "SCALE", float(scale)),
        ("POINT", "RATE", float(rate)),
        ("POINT", "FRAMES", min(n_frames, 65535) if frames is None else frames),
        ("POINT", "UNITS", units),
    ]
    for k in range(0, len(labels), 255):
        params.append(("POINT", "LABELS" if k == 0 else f"LABELS{k // 255 + 1}", labels[k : k + 255]))
    params.append(("ANALOG", "USED", analog_channels))
    params.append(("ANALOG", "RATE", float(rate * max(analog_per_frame, 1))))
    if analog_channels:
        params.append(("ANALOG", "LABELS", [f"A{i + 1}" for i in range(analog_channels)]))
        params.append(("ANALOG", "SCALE", [1.0] * analog_channels))
        params.append(("ANALOG", "OFFSET", [0] * analog_channels if offsets is None else offsets))
        params.append(("ANALOG", "GEN_SCALE", 1.0))
        params.append(("ANALOG", "UNITS", ["V"] * analog_channels))
    params.extend(parameters)
    for group, _, _ in params:
        groups.setdefault(group, len(groups) + 1)

    def section(data_block: int) -> bytes:
        records = [(name.encode(), -gid, b"\x00") for name, gid in groups.items()]
        for group, name, value in [*params, ("POINT", "DATA_START", data_block)]:
            kind, dims, data = _parameter(value, processor)
            body = struct.pack("b", kind) + bytes([len(dims), *dims]) + data + b"\x00"
            records.append((name.encode(), groups[group], body))
        out = bytearray(parameter_start + b"\x00" + bytes([PROCESSOR[processor]]))
        for i, (name, gid, body) in enumerate(records):
            link = 0 if i == len(records) - 1 else 2 + len(body)  # from the link word to the next record
            out += struct.pack("b", len(name)) + struct.pack("b", gid) + name + _int16(np.array([link]), processor)
            out += body
        out += b"\x00" * (-len(out) % 512)
        out[2] = len(out) // 512
        return bytes(out)

    n_blocks = len(section(0)) // 512
    params_bytes = section(2 + n_blocks)

    header = bytearray(512)
    header[0], header[1] = 2, 0x50
    last = min(first_frame + n_frames - 1, 65535) if header_last_frame is None else header_last_frame
    header[2:12] = _int16(np.array([n_points, analog_channels * analog_per_frame, first_frame, last, 10]), processor)
    header[12:16] = _float32(np.array([scale]), processor)
    header[16:20] = _int16(np.array([2 + n_blocks, analog_per_frame]), processor)
    header[20:24] = _float32(np.array([rate]), processor)
    header[298:300] = _int16(np.array([12345]), processor)  # 4-character event labels

    point_words = np.concatenate([xyz, word4[:, :, None]], axis=2).reshape(n_frames, 4 * n_points)
    analog_words = np.zeros((n_frames, analog_channels * analog_per_frame))
    if is_float:
        frame_words = np.concatenate([point_words, analog_words], axis=1)
        data = _float32(frame_words, processor)
    else:
        stored = point_words.copy()
        stored.reshape(n_frames, n_points, 4)[:, :, :3] = np.round(xyz / scale)
        data = _int16(np.concatenate([stored, analog_words], axis=1).astype(np.int64), processor)
    data += b"\x00" * (-len(data) % 512)
    return bytes(header) + params_bytes + data


def residual_word(residual_mm: float, cameras: int, point_scale: float) -> int:
    """The C3D fourth word of a valid point: camera bits in the high byte, residual / |POINT:SCALE| in the low."""
    return (cameras << 8) | int(round(residual_mm / abs(point_scale)))


def positions_mm(n_frames: int, n_points: int, seed: int) -> np.ndarray:
    """Marker positions in mm within a 3 m capture volume, rounded to 0.1 mm (exact in integer storage)."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-1500.0, 1500.0, size=(n_frames, n_points, 3))
    xyz[:, :, 2] = rng.uniform(50.0, 1800.0, size=(n_frames, n_points))
    return np.round(xyz, 1)


def assert_positions(got: np.ndarray, want_m: np.ndarray) -> None:
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want_m))
    np.testing.assert_allclose(got, want_m, rtol=0, atol=ATOL, equal_nan=True)


def assert_one_line(excinfo: pytest.ExceptionInfo[TrialError], path: Path) -> None:
    message = str(excinfo.value)
    assert message.startswith(f"{path}: ") and "; " in message
    assert "\n" not in message
    assert isinstance(excinfo.value, CalibrateError)


# ---------------------------------------------------------------------------
# Vicon Nexus
# ---------------------------------------------------------------------------


def test_vicon_nexus_subject_prefix_residuals_and_modelled_outputs(tmp_path: Path) -> None:
    """ezc3d-written, as Nexus exports: Subject: prefixes, residuals, unlabelled and modelled points."""
    n_frames = 12
    markers = [f"Sub01:{label}" for label in PIG] + ["*12"]
    outputs = ["Sub01:LHipAngles", "Sub01:LKneeMoment", "Sub01:LAnklePower"]
    labels = markers[:4] + outputs[:1] + markers[4:] + ["Sub01:LHJC"] + outputs[1:]  # LHJC: a model output by name
    n = len(labels)
    xyz = positions_mm(n_frames, n, seed=1)
    residuals = np.full((n_frames, n), 0.8)
    residuals[:, 1] = 0.0  # residual 0: valid (a filtered or gap-filled point)
    residuals[3, 0] = -1.0  # invalid
    residuals[5:8, 6] = -1.0
    xyz[residuals < 0] = 0.0
    xyz[9, 2] = 0.0  # all-zero coordinates with a valid residual: also a gap

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["POINT"]["SCALE"]["value"] = [-0.01]
    c3d.add_parameter("POINT", "ANGLES", outputs[:1])
    c3d.add_parameter("POINT", "ANGLE_UNITS", ["deg"])
    c3d.add_parameter("POINT", "MOMENTS", outputs[1:2])
    c3d.add_parameter("POINT", "POWERS", outputs[2:])
    c3d.add_parameter("SUBJECTS", "NAMES", ["Sub01"])
    c3d.add_parameter("SUBJECTS", "LABEL_PREFIXES", ["Sub01:"])
    c3d.add_parameter("SUBJECTS", "USES_PREFIXES", [1])
    c3d.add_parameter("TRIAL", "ACTUAL_START_FIELD", [1, 0])
    c3d.add_parameter("TRIAL", "ACTUAL_END_FIELD", [n_frames, 0])
    c3d.add_parameter("TRIAL", "CAMERA_RATE", [100.0])
    c3d.add_parameter("MANUFACTURER", "COMPANY", ["Vicon"])  # ezc3d then needs the TRIAL group, as Nexus writes
    points = np.ones((4, n, n_frames))
    points[:3] = xyz.transpose(2, 1, 0)
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals.T[None]}
    path = tmp_path / "vicon_nexus.c3d"
    c3d.write(str(path))
    assert ezc3d.c3d(str(path))["parameters"]["POINT"]["SCALE"]["value"][0] == pytest.approx(-0.01)

    trial = read_trial(path)
    assert trial.labels == (*PIG, "*12")  # prefix gone, modelled outputs kept apart
    assert set(trial.model_outputs) == {"LHJC", "LHipAngles", "LKneeMoment", "LAnklePower"}
    hjc = xyz[:, labels.index("Sub01:LHJC")] / 1000.0
    hjc[(residuals[:, labels.index("Sub01:LHJC")] < 0) | (hjc == 0).all(axis=1)] = np.nan
    assert_positions(trial.model_outputs["LHJC"], hjc)
    assert trial.output_kinds["LHipAngles"] == "angle" and trial.output_units["LHipAngles"] == "rad"
    assert np.allclose(trial.model_outputs["LHipAngles"], np.radians(xyz[:, labels.index("Sub01:LHipAngles")]))
    assert trial.rate == 100.0 and trial.first_frame == 0
    keep = [labels.index(label) for label in markers]
    want = xyz[:, keep] / 1000.0
    want[(residuals[:, keep] < 0) | (xyz[:, keep] == 0).all(axis=2)] = np.nan
    assert np.isnan(want[3, 0]).all() and np.isnan(want[9, 2]).all() and np.isnan(want[5:8, 5]).all()
    assert_positions(trial.markers, want)
    assert np.isfinite(trial.marker("RASI")).all()  # residual 0 throughout: valid

    whole = read_c3d(path, strip_prefix=False)
    assert whole.labels == tuple(markers)


def test_vicon_residual_word_as_the_specification_stores_it(tmp_path: Path) -> None:
    """Byte by byte: the float fourth word holds cameras << 8 | residual / |scale|; -1.0 is invalid, 0.0 valid."""
    n_frames, labels = 6, PIG[:4]
    xyz = positions_mm(n_frames, 4, seed=2)
    word4 = np.full((n_frames, 4), float(residual_word(0.85, cameras=0b0110101, point_scale=-0.01)))
    word4[:, 1] = 0.0
    word4[2, 2] = -1.0
    xyz[2, 2] = 0.0
    word4[4, 3] = -1.0  # invalid with leftover coordinates: still a gap
    path = tmp_path / "vicon_raw.c3d"
    path.write_bytes(c3d_bytes(xyz, word4, labels, scale=-0.01, rate=120.0, first_frame=31))

    trial = read_trial(path)
    assert trial.labels == tuple(labels)
    assert trial.rate == 120.0 and trial.first_frame == 30
    want = xyz / 1000.0
    want[word4 < 0] = np.nan
    assert_positions(trial.markers, want)


# ---------------------------------------------------------------------------
# Qualisys QTM
# ---------------------------------------------------------------------------


def test_qualisys_long_labels_odd_scale_analogs_and_late_first_frame(tmp_path: Path) -> None:
    n_frames = 10
    labels = [
        "Q_HeadLeftFront_with_a_rather_long_descriptive_name_01",
        "Right Anterior Superior Iliac Spine",
        "L_ASIS",
        "",  # an unidentified trajectory
        "LeftKneeLateralEpicondyle_marker_long_label",
    ]
    n = len(labels)
    xyz = positions_mm(n_frames, n, seed=3)
    residuals = np.abs(np.random.default_rng(4).normal(1.2, 0.3, size=(n_frames, n)))
    residuals[0, 1] = -1.0
    residuals[6:, 3] = -1.0
    xyz[residuals < 0] = 0.0

    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [200.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["POINT"]["SCALE"]["value"] = [-0.0762322545]
    c3d["parameters"]["ANALOG"]["RATE"]["value"] = [2000.0]
    c3d["parameters"]["ANALOG"]["LABELS"]["value"] = ["Force_1_Fz", "Force_2_Fz", "EMG 1"]
    c3d.add_parameter("MANUFACTURER", "COMPANY", ["Qualisys"])
    c3d.add_parameter("MANUFACTURER", "SOFTWARE", ["Qualisys Track Manager"])
    c3d["header"]["points"]["first_frame"] = 704  # 0-based: 705 in the file
    points = np.ones((4, n, n_frames))
    points[:3] = xyz.transpose(2, 1, 0)
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals.T[None]}
    c3d["data"]["analogs"] = np.random.default_rng(5).normal(size=(1, 3, 10 * n_frames))
    path = tmp_path / "qtm.c3d"
    c3d.write(str(path))
    data = bytearray(path.read_bytes())
    param_start = (data[0] - 1) * 512
    data[param_start : param_start + 2] = b"\x00\x00"  # QTM leaves the parameter section's first bytes 0
    path.write_bytes(bytes(data))
    assert int.from_bytes(data[6:8], "little") == 705

    trial = read_trial(path)
    assert trial.labels == (labels[0], labels[1], "L_ASIS", "unlabelled_4", labels[4])
    assert trial.rate == 200.0 and trial.first_frame == 704
    want = xyz / 1000.0
    want[residuals < 0] = np.nan
    assert_positions(trial.markers, want)


# ---------------------------------------------------------------------------
# Motion Analysis Cortex: integer storage
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("processor", ["intel", "dec"])
def test_motion_analysis_integer_storage_with_scale(tmp_path: Path, processor: str) -> None:
    """Integer coordinates x POINT:SCALE 0.1 mm; invalid by residual word -1 or by all-zero coordinates."""
    n_frames, n = 9, len(HELEN_HAYES)
    xyz = positions_mm(n_frames, n, seed=6)
    word4 = np.full((n_frames, n), residual_word(0.7, cameras=0b0011, point_scale=0.1))
    word4[1, 0] = -1
    xyz[1, 0] = 0.0
    word4[2, 4] = -1
    xyz[7, 5] = 0.0  # all zero, residual word valid: a gap
    path = tmp_path / f"cortex_{processor}.c3d"
    path.write_bytes(c3d_bytes(xyz, word4, HELEN_HAYES, processor=processor, scale=0.1, rate=60.0))
    if processor == "intel":
        assert struct.unpack("<f", path.read_bytes()[12:16])[0] == pytest.approx(0.1)  # integer storage

    trial = read_trial(path)
    assert trial.labels == tuple(HELEN_HAYES)
    assert trial.rate == 60.0 and trial.first_frame == 0
    want = np.round(xyz / 0.1) * 0.1 / 1000.0  # what the integers hold, in metres
    want[(word4 < 0) | (xyz == 0).all(axis=2)] = np.nan
    assert_positions(trial.markers, want)
    if processor == "intel":  # a header scale of 0 names no scale of its own: POINT:SCALE's is read
        data = bytearray(path.read_bytes())
        data[12:16] = struct.pack("<f", 0.0)
        path.write_bytes(bytes(data))
        assert_positions(read_trial(path).markers, want)


@pytest.mark.parametrize(("scale", "units", "metres_per_unit"), [(-1.0, "mm", 1e-3), (1.0, "mm", 1e-3),
                                                                   (0.01, "cm", 1e-2), (-0.001, "m", 1.0)])
def test_dec_processor_float_and_integer(tmp_path: Path, scale: float, units: str, metres_per_unit: float) -> None:
    n_frames, labels = 5, ["RASI", "LASI", "RKNE"]
    xyz = positions_mm(n_frames, 3, seed=7) * (1e-3 / metres_per_unit)
    if scale > 0:
        xyz = np.round(xyz / scale) * scale
    word4 = np.zeros((n_frames, 3))
    word4[4, 1] = -1
    xyz[4, 1] = 0.0
    path = tmp_path / "dec.c3d"
    path.write_bytes(c3d_bytes(xyz, word4, labels, processor="dec", scale=scale, units=units))
    trial = read_trial(path)
    want = xyz * metres_per_unit
    want[4, 1] = np.nan
    assert trial.labels == tuple(labels)
    assert_positions(trial.markers, want)


@pytest.mark.parametrize("scale", [-1.0, 0.1])
def test_mips_processor_float_and_integer(tmp_path: Path, scale: float) -> None:
    """Big-endian MIPS (SGI) files, whose data ezc3d cannot read: read as the Intel file they convert to, the same
    trial as the Intel file of the same data (c3d.org's SGI samples 01 and 02 read bit for bit as their PC twins)."""
    n_frames, labels = 8, ["RASI", "LASI", "RKNE", "LKNE"]
    xyz = positions_mm(n_frames, 4, seed=8)
    if scale > 0:
        xyz = np.round(xyz / scale) * scale
    word4 = np.full((n_frames, 4), residual_word(0.5, cameras=0b0101, point_scale=scale))
    word4[2, 1] = -1
    xyz[2, 1] = 0.0
    read = {}
    for processor in ("mips", "intel"):
        path = tmp_path / f"{processor}.c3d"
        path.write_bytes(c3d_bytes(xyz, word4, labels, processor=processor, scale=scale, rate=120.0, first_frame=5,
                                   analog_channels=2, analog_per_frame=2))
        read[processor] = read_trial(path)
    sgi = read["mips"]
    want = xyz / 1000.0
    want[2, 1] = np.nan
    assert sgi.labels == tuple(labels) and sgi.rate == 120.0 and sgi.first_frame == 4
    assert_positions(sgi.markers, want)
    np.testing.assert_array_equal(sgi.markers, read["intel"].markers)


def test_mips_link_in_intel_order_is_read(tmp_path: Path) -> None:
    """c3d.org's SGI sample02 files carry one link in Intel order (POINT:LABELS's), which leads where its record
    ends: read as it leads."""
    xyz = positions_mm(5, 3, seed=9)
    data = bytearray(c3d_bytes(xyz, np.zeros((5, 3)), ["RASI", "LASI", "RPSI"], processor="mips"))
    at = bytes(data).find(bytes([4, 1]) + b"RATE")  # POINT:RATE: its link follows the name
    assert at > 0 and struct.unpack(">h", data[at + 6 : at + 8])[0] > 0
    data[at + 6 : at + 8] = data[at + 6 : at + 8][::-1]
    path = tmp_path / "sgi_link.c3d"
    path.write_bytes(bytes(data))
    trial = read_trial(path)
    assert trial.labels == ("RASI", "LASI", "RPSI") and trial.rate == 100.0
    assert_positions(trial.markers, xyz / 1000.0)


def test_a_description_length_byte_left_out_is_read_as_no_description(tmp_path: Path) -> None:
    """OptiTrack Arena's mocap36.c3d (BTKData) leaves out POINT:LABELS's description length byte, its link leading
    to where the byte belongs (where BTK reads on): read as no description, through a copy that ezc3d reads."""
    xyz = positions_mm(6, 3, seed=22)
    data = bytearray(c3d_bytes(xyz, np.zeros((6, 3)), ["RASI", "LASI", "RPSI"], scale=-1.0))
    at = bytes(data).find(bytes([6, 1]) + b"LABELS")  # POINT (group 1):LABELS
    assert at > 0
    link = struct.unpack("<h", data[at + 8 : at + 10])[0]
    described = at + 8 + link - 1  # the description's length byte: the record's last (0, no description)
    assert data[described] == 0 and data[described + 1] > 0  # the next record's name length follows it
    data[at + 8 : at + 10] = struct.pack("<h", link - 1)
    del data[described]
    data.insert(512 * (1 + data[512 + 2]) - 1, 0)  # the parameter section's padding keeps the data in place
    path = tmp_path / "arena.c3d"
    path.write_bytes(bytes(data))
    trial = read_trial(path)
    assert trial.labels == ("RASI", "LASI", "RPSI") and trial.rate == 100.0
    assert_positions(trial.markers, xyz / 1000.0)


@pytest.mark.parametrize("processor", ["intel", "mips"])
def test_analog_offsets_that_do_not_cover_the_channels_leave_the_points_read(tmp_path: Path, processor: str) -> None:
    """No ANALOG:OFFSET beside 3 channels (c3d.org's sample06 names it OFFSETS), on which ezc3d crashes the
    interpreter: ezc3d reads a copy told of no analog channels, and the points are read as the header lays them out,
    past each frame's analog words."""
    xyz = positions_mm(6, 3, seed=10)
    data = bytearray(c3d_bytes(xyz, np.zeros((6, 3)), ["RASI", "LASI", "RPSI"], scale=-1.0, processor=processor,
                               analog_channels=3, analog_per_frame=2))
    at = bytes(data).find(bytes([6, 2]) + b"OFFSET")  # ANALOG (group 2):OFFSET
    assert at > 0
    data[at + 2 : at + 8] = b"OFFSTS"
    path = tmp_path / "no_offsets.c3d"
    path.write_bytes(bytes(data))
    trial = read_trial(path)
    assert trial.labels == ("RASI", "LASI", "RPSI")
    assert_positions(trial.markers, xyz / 1000.0)


# ---------------------------------------------------------------------------
# OptiTrack Motive
# ---------------------------------------------------------------------------


def _motive_file(path: Path, labels: list[str], n_frames: int, units: str, seed: int) -> np.ndarray:
    """An ezc3d-written Motive-like file; returns the positions in metres, NaN where invalid."""
    n = len(labels)
    metres = positions_mm(n_frames, n, seed=seed) / 1000.0
    residuals = np.zeros((n_frames, n))
    rng = np.random.default_rng(seed + 1)
    invalid = rng.random((n_frames, n)) < 0.1
    residuals[invalid] = -1.0
    file_units = metres / {"m": 1.0, "cm": 1e-2, "mm": 1e-3}[units]
    file_units[invalid] = 0.0
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [240.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["UNITS"]["value"] = [units]
    c3d.add_parameter("MANUFACTURER", "COMPANY", ["NaturalPoint"])
    points = np.ones((4, n, n_frames))
    points[:3] = file_units.transpose(2, 1, 0)
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals.T[None]}
    c3d.write(str(path))
    metres[invalid] = np.nan
    return metres


@pytest.mark.parametrize("units", ["m", "mm"])
def test_optitrack_motive_many_points_skeleton_prefix(tmp_path: Path, units: str) -> None:
    """600 points (POINT:LABELS, LABELS2, LABELS3), Skeleton: names and unlabelled markers, units m or mm."""
    named = [f"Skeleton:{label}" for label in PIG]
    labels = named + [f"Unlabeled {1000 + i}" for i in range(600 - len(named))]
    path = tmp_path / f"motive_{units}.c3d"
    want = _motive_file(path, labels, n_frames=8, units=units, seed=9)
    params = ezc3d.c3d(str(path))["parameters"]["POINT"]
    assert [len(params[name]["value"]) for name in ("LABELS", "LABELS2", "LABELS3")] == [255, 255, 90]

    trial = read_trial(path)
    assert trial.n_markers == 600 and trial.rate == 240.0
    assert trial.labels[: len(PIG)] == tuple(PIG)
    assert trial.labels[-1] == "Unlabeled 1587"
    assert_positions(trial.markers, want)


def test_optitrack_skeleton_and_rigid_bodies_keep_their_prefixes(tmp_path: Path) -> None:
    labels = ["Skeleton:RASI", "Skeleton:LASI", "Wand:Marker1", "Wand:Marker2", "Skeleton:RKNE"]
    path = tmp_path / "motive_two_assets.c3d"
    want = _motive_file(path, labels, n_frames=6, units="m", seed=10)
    trial = read_trial(path)
    assert trial.labels == tuple(labels)  # two prefixes: nothing removed (map_labels matches after the prefix)
    assert_positions(trial.markers, want)


def test_prefix_removal_that_would_repeat_a_label_is_skipped(tmp_path: Path) -> None:
    labels = ["Sub01:RASI", "RASI", "Sub01:LASI"]
    path = tmp_path / "clash.c3d"
    _motive_file(path, labels, n_frames=3, units="mm", seed=11)
    assert read_trial(path).labels == tuple(labels)


# ---------------------------------------------------------------------------
# Units, long takes, inconsistent files
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("units", "metres_per_unit"),
    [("mm", 1e-3), ("MM", 1e-3), ("cm", 1e-2), ("m", 1.0), (" M ", 1.0), ("millimeters", 1e-3), ("metres", 1.0),
     ("mete", 1.0), ("Mill", 1e-3), ("cent", 1e-2)],  # cut to a 4-character parameter (c3d.org's sample15: 'mete')
)
def test_point_units(tmp_path: Path, units: str, metres_per_unit: float) -> None:
    xyz = np.array([[[12.5, -3.25, 7.0]]])
    path = tmp_path / "units.c3d"
    path.write_bytes(c3d_bytes(xyz, np.zeros((1, 1)), ["RASI"], scale=-1.0, units=units))
    np.testing.assert_allclose(read_trial(path).markers[0, 0], xyz[0, 0] * metres_per_unit, rtol=1e-7)


def test_long_take_counted_by_long_frames_and_trial_fields(tmp_path: Path) -> None:
    """70 000 frames: header capped at 65535, POINT:FRAMES -1, count in POINT:LONG_FRAMES / TRIAL fields."""
    n_frames = 70_000
    xyz = np.zeros((n_frames, 1, 3))
    xyz[:, 0, 0] = 1.0 + np.arange(n_frames) * 0.01
    xyz[:, 0, 1:] = [250.0, 900.0]
    word4 = np.zeros((n_frames, 1))
    word4[-1] = -1
    xyz[-1] = 0.0
    for name, parameters in [
        ("long_frames", (("POINT", "LONG_FRAMES", float(n_frames)),)),
        ("trial_fields", (("TRIAL", "ACTUAL_START_FIELD", [1, 0]), ("TRIAL", "ACTUAL_END_FIELD", [4464, 1]))),
    ]:
        path = tmp_path / f"{name}.c3d"
        path.write_bytes(c3d_bytes(xyz, word4, ["RASI"], scale=-1.0, frames=-1, parameters=parameters))
        trial = read_trial(path)
        assert trial.n_frames == n_frames, name
        want = xyz / 1000.0
        want[-1] = np.nan
        assert_positions(trial.markers, want)


def test_long_take_that_ezc3d_cannot_read_whole_is_refused(tmp_path: Path) -> None:
    """70 000 frames written by ezc3d itself: it reads back only 65535 of them; refuse rather than cut."""
    n_frames = 70_000
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = ["RASI"]
    c3d["data"]["points"] = np.full((4, 1, n_frames), 100.0)
    path = tmp_path / "cut.c3d"
    c3d.write(str(path))
    assert ezc3d.c3d(str(path))["data"]["points"].shape[2] == 65535
    with pytest.raises(TrialError, match="holds 70000 frames but ezc3d reads only 65535") as excinfo:
        read_trial(path)
    assert_one_line(excinfo, path)


def test_header_capped_without_a_count_reads_to_the_end_without_padding(tmp_path: Path) -> None:
    n_frames = 65_601
    xyz = np.full((n_frames, 2, 3), 5.0)
    xyz[:, 1] = [1.0, 2.0, 3.0]
    path = tmp_path / "uncounted.c3d"
    path.write_bytes(c3d_bytes(xyz, np.zeros((n_frames, 2)), ["RASI", "LASI"], scale=-1.0, frames=-1))
    data = path.read_bytes()
    data_start = (int.from_bytes(data[16:18], "little") - 1) * 512
    assert len(data) - data_start - n_frames * 32 == 480  # zero padding: ezc3d reads it as 15 more frames
    assert ezc3d.c3d(str(path))["data"]["points"].shape[2] == n_frames + 15
    trial = read_trial(path)
    assert trial.n_frames == n_frames
    assert np.isfinite(trial.markers).all()


@pytest.mark.parametrize(
    ("header_scale", "point_scale", "match"),
    [(-1.0, 0.1, "POINT:SCALE"), (0.1, -1.0, "POINT:SCALE"), (0.0, 0.0, "POINT:SCALE is 0"),
     (0.0551, 0.0215, "different scales")],  # c3d.org's sample06: integer coordinates 2.56 times apart
)
def test_inconsistent_storage_is_refused(tmp_path: Path, header_scale: float, point_scale: float, match: str) -> None:
    xyz = positions_mm(3, 2, seed=12)
    data = bytearray(c3d_bytes(xyz, np.zeros((3, 2)), ["RASI", "LASI"], scale=-1.0))
    at = bytes(data).find(bytes([5, 1]) + b"SCALE")  # POINT:SCALE: name, link (2), type, 0 dimensions, value
    assert struct.unpack("<f", data[at + 11 : at + 15])[0] == -1.0
    data[at + 11 : at + 15] = struct.pack("<f", point_scale)
    data[12:16] = struct.pack("<f", header_scale)
    path = tmp_path / "inconsistent.c3d"
    path.write_bytes(bytes(data))
    with pytest.raises(TrialError, match=match) as excinfo:
        read_trial(path)
    assert_one_line(excinfo, path)


def test_only_modelled_outputs_is_refused(tmp_path: Path) -> None:
    xyz = positions_mm(3, 2, seed=13)
    path = tmp_path / "angles_only.c3d"
    outputs = ["LHipAngles", "RHipAngles"]
    path.write_bytes(c3d_bytes(xyz, np.zeros((3, 2)), outputs, parameters=(("POINT", "ANGLES", outputs),)))
    with pytest.raises(TrialError, match="no marker trajectories") as excinfo:
        read_trial(path)
    assert_one_line(excinfo, path)


@pytest.mark.parametrize("units", ["met", "mi", "meters per second"])
def test_units_that_name_no_length_are_refused(tmp_path: Path, units: str) -> None:
    """Only a name cut at 4 characters or more, and only to one unit, is read as that unit."""
    path = tmp_path / "units.c3d"
    path.write_bytes(c3d_bytes(np.ones((1, 1, 3)), np.zeros((1, 1)), ["RASI"], scale=-1.0, units=units))
    with pytest.raises(TrialError, match="unknown length units") as excinfo:
        read_trial(path)
    assert_one_line(excinfo, path)


@pytest.mark.parametrize("count", [1, 0])
def test_parameter_blocks_counted_short_read_to_the_data_section(tmp_path: Path, count: int) -> None:
    """The parameter section's own count of its blocks short of where the data start (c3d.org's sample15 says 3
    of 5, PhaseSpace's 0): the parameters are read on to the data section, as ezc3d reads them."""
    labels = [f"MARKER{k:02d}" for k in range(60)]  # a parameter section of two blocks
    xyz = positions_mm(4, len(labels), seed=14)
    data = bytearray(c3d_bytes(xyz, np.zeros((4, len(labels))), labels, scale=-1.0))
    assert data[512 + 2] == 2 and data[16] == 4  # two parameter blocks, the data from block 4
    data[512 + 2] = count
    path = tmp_path / "short_count.c3d"
    path.write_bytes(bytes(data))
    trial = read_trial(path)
    assert trial.labels == tuple(labels)
    assert_positions(trial.markers, xyz / 1000.0)


def test_a_parameter_of_no_group_is_left_out(tmp_path: Path) -> None:
    """A parameter whose group the file never names (c3d.org's Vicon force-plate samples: IS_STATIC): read past."""
    xyz = positions_mm(3, 2, seed=15)
    data = bytearray(c3d_bytes(xyz, np.zeros((3, 2)), ["RASI", "LASI"], scale=-1.0,
                               parameters=(("SEG", "IS_STATIC", 1),)))
    at = bytes(data).find(bytes([3]) + struct.pack("b", -3) + b"SEG")  # the group record: its id -3
    assert at > 0
    data[at + 1 : at + 2] = struct.pack("b", -9)  # the group now 9: IS_STATIC (group 3) belongs to none
    path = tmp_path / "orphan.c3d"
    path.write_bytes(bytes(data))
    trial = read_trial(path)
    assert trial.labels == ("RASI", "LASI")
    assert_positions(trial.markers, xyz / 1000.0)


def test_points_without_a_point_group_are_refused_in_one_line(tmp_path: Path) -> None:
    """A header that counts points beside a parameter section without a POINT group (PhaseSpace's c3d.org sample20:
    40 points, 701 frames, no labels): said so, not "POINT:USED is 0"."""
    xyz = positions_mm(3, 2, seed=16)
    data = bytearray(c3d_bytes(xyz, np.zeros((3, 2)), ["RASI", "LASI"], scale=-1.0))
    at = bytes(data).find(bytes([5]) + struct.pack("b", -1) + b"POINT")  # the group record: its id -1
    assert at > 0
    data[at + 2 : at + 7] = b"PXINT"  # the group renamed: no POINT group left
    path = tmp_path / "phasespace.c3d"
    path.write_bytes(bytes(data))
    with pytest.raises(TrialError, match="header lists 2 points but its parameter section has no POINT group") as e:
        read_trial(path)
    assert_one_line(e, path)


def test_point_frames_one_past_the_header_and_the_data_reads_what_they_hold(tmp_path: Path) -> None:
    """POINT:FRAMES one more than the header's first..last and the data section hold (c3d.org's sample13: 515
    against 514 and 514): the frames held are read, not "truncated"; a data section short of the header's count
    is still truncated."""
    xyz = positions_mm(10, 8, seed=17)
    labels = [f"M{i}" for i in range(8)]
    data = c3d_bytes(xyz, np.zeros((10, 8)), labels, scale=-1.0, frames=11)
    start = (struct.unpack("<H", data[16:18])[0] - 1) * 512
    path = tmp_path / "frames_one_past.c3d"
    path.write_bytes(data[: start + 10 * 8 * 16])  # no padding past the last frame: 10 frames held, not 11
    trial = read_trial(path)
    assert trial.n_frames == 10
    assert_positions(trial.markers, xyz / 1000.0)
    path.write_bytes(data[: start + 9 * 8 * 16])
    with pytest.raises(TrialError, match="truncated: it should hold 11 frames but holds only 9") as e:
        read_trial(path)
    assert_one_line(e, path)


@pytest.mark.parametrize(("scale", "processor"), [(-1.0, "intel"), (0.1, "intel"), (-1.0, "dec")])
def test_analog_words_the_parameters_do_not_count_are_skipped(tmp_path: Path, scale: float, processor: str) -> None:
    """BTS's files (c3d.org sample28): the header lays 6 analog words after every frame's points while ANALOG:USED
    says 0, and ezc3d, stepping by the parameters, reads every frame but the first from the wrong place; the points
    are read as the header lays them out."""
    xyz = positions_mm(5, 3, seed=16)
    data = bytearray(c3d_bytes(xyz, np.zeros((5, 3)), ["RASI", "LASI", "RPSI"], scale=scale, processor=processor,
                               analog_channels=2, analog_per_frame=1))
    at = bytes(data).find(bytes([4, 2]) + b"USED")  # ANALOG (group 2):USED, an int16 after link, type and 0 dims
    assert at > 0 and data[at + 8] == 2 and data[at + 9] == 0
    data[at + 10 : at + 12] = b"\x00\x00"
    path = tmp_path / "bts.c3d"
    path.write_bytes(bytes(data))
    assert not np.allclose(ezc3d.c3d(str(path))["data"]["points"][:3, :, 1].T, xyz[1], atol=1.0)  # ezc3d's stride
    trial = read_trial(path)
    assert trial.n_frames == 5 and trial.labels == ("RASI", "LASI", "RPSI")
    assert_positions(trial.markers, xyz / 1000.0)


def test_descriptions_longer_than_ezc3d_reads_are_cut_for_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A parameter's or a group's description of 128-255 characters (a KINARM robot's EXPERIMENT:SESSION, 163; ezc3d
    writes them too): ezc3d reads the length byte as signed and asked for 4 GB, three times, before it failed.  The
    file is read through a copy with the descriptions cut, which is removed afterwards; the file is not changed."""
    xyz = positions_mm(6, 3, seed=18)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [120.0]
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = ["RASI", "LASI", "RPSI"]
    points = np.ones((4, 3, 6))
    points[:3] = xyz.transpose(2, 1, 0)
    c3d["data"]["points"] = points
    c3d.add_parameter("EXPERIMENT", "SESSION", [1, 2], description="s" * 163)
    c3d.add_parameter("EXPERIMENT", "NOTES", "walk", description="n" * 255)
    c3d.add_parameter("EXPERIMENT", "STUDY", "gait", description="d" * 127)
    path = tmp_path / "kinarm.c3d"
    c3d.write(str(path))
    written = path.read_bytes()
    for name, length in ((b"SESSION", 163), (b"NOTES", 255)):
        at = written.find(name)
        assert at > 0 and written.find(bytes([length]) + bytes([ord(name[:1].lower())]) * 3, at) > 0
    copies = tmp_path / "tmp"
    copies.mkdir()
    monkeypatch.setattr("tempfile.tempdir", str(copies))
    trial = read_c3d(path)
    assert trial.labels == ("RASI", "LASI", "RPSI")
    assert trial.rate == 120.0
    assert_positions(trial.markers, xyz / 1000.0)
    assert list(copies.iterdir()) == []  # the copy removed
    assert path.read_bytes() == written


@pytest.mark.parametrize("spelling", [(b"OFFSET", b"Offset"), (b"ANALOG", b"Analog"), (b"POINT", b"point")],
                         ids=["ANALOG:Offset", "Analog", "point"])
def test_names_in_other_cases_are_read_as_capitals(tmp_path: Path, spelling: tuple[bytes, bytes]) -> None:
    """A C3D's group and parameter names are read regardless of case; ezc3d looks them up by their exact spelling,
    and crashed the interpreter on an `ANALOG:Offset` beside analog channels (it filled in an empty OFFSET).  Read
    through a copy with the names in capitals."""
    xyz = positions_mm(7, 3, seed=19)
    data = c3d_bytes(xyz, np.zeros((7, 3)), ["RASI", "LASI", "RPSI"], scale=-1.0, analog_channels=2,
                     analog_per_frame=2)
    was, now = spelling
    at = data.find(was, 512)
    assert at > 0 and data[at - 2] == len(was)  # a record's name, after its length and id
    path = tmp_path / "cases.c3d"
    path.write_bytes(data[:at] + now + data[at + len(was) :])
    trial = read_trial(path)
    assert trial.labels == ("RASI", "LASI", "RPSI") and trial.rate == 100.0
    assert_positions(trial.markers, xyz / 1000.0)


@pytest.mark.parametrize("processor", ["intel", "dec"])
def test_analog_offsets_stored_as_floats_are_read(tmp_path: Path, processor: str) -> None:
    """ANALOG:OFFSET stored as floats (c3d.org's sample13, Dance.c3d and golfswing.c3d), which ezc3d refuses ("OFFSET
    parameter is not an INT"): read through a copy with them as the standard's 16-bit integers."""
    xyz = positions_mm(6, 3, seed=20)
    data = c3d_bytes(xyz, np.zeros((6, 3)), ["RASI", "LASI", "RPSI"], scale=-1.0, processor=processor,
                     analog_channels=2, analog_per_frame=1, offsets=[3.0, -2.0])
    path = tmp_path / "float_offsets.c3d"
    path.write_bytes(data)
    trial = read_trial(path)
    assert trial.labels == ("RASI", "LASI", "RPSI")
    assert_positions(trial.markers, xyz / 1000.0)


def test_a_text_parameter_of_no_dimensions_is_read(tmp_path: Path) -> None:
    """A character parameter with no dimensions (a scalar: one character), on which ezc3d crashed the interpreter
    (found by fuzzing): read through a copy with one dimension of 1."""
    xyz = positions_mm(5, 3, seed=21)
    data = c3d_bytes(xyz, np.zeros((5, 3)), ["RASI", "LASI", "RPSI"], scale=-1.0, analog_channels=2,
                     analog_per_frame=1, parameters=(("EXPERIMENT", "FLAG", b"Y"), ("ANALOG", "ZERO_DIM", b"V")))
    path = tmp_path / "scalar_text.c3d"
    path.write_bytes(data)
    trial = read_trial(path)
    assert trial.labels == ("RASI", "LASI", "RPSI")
    assert_positions(trial.markers, xyz / 1000.0)
