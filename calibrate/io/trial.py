"""Motion-capture trials: labelled marker trajectories read from and written to C3D and TRC.

Inside the program a trial holds marker positions in metres in the lab frame,
one row per frame, with NaN wherever a marker is not seen (a gap).  Units are
converted at the file edges: C3D ``POINT:UNITS`` and the TRC ``Units`` header
may be ``mm``, ``cm`` or ``m``.

Frame numbering: :attr:`Trial.first_frame` is 0-based.  A C3D header stores the
first frame 1-based; ezc3d reports (and accepts) it 0-based, so the value from
``c3d["header"]["points"]["first_frame"]`` is used as is.  TRC frame numbers
(the ``Frame#`` column) are 1-based, as OpenSim writes them.

ezc3d also maps a header value of 0 (a writer that forgot the 1-base) to 0.

Gaps in C3D: on reading, a point is a gap when its residual is negative, when all
three coordinates are exactly zero, or when a coordinate is not finite.  ezc3d
itself already turns points with a negative residual into NaN coordinates.  Given
NaN coordinates, ezc3d would write the NaN floats as they are with residual 0,
which other software reads as a valid point; so gaps are written the standard way
instead (coordinates 0, residual -1), which ezc3d reads back as NaN.

Before ezc3d opens a C3D file its header and parameter section are checked here:
ezc3d crashes the interpreter on some damaged files (a record that overruns its
neighbours, analog channels without ANALOG:SCALE/OFFSET) and silently drops the
missing frames of a truncated file.

What the C3D reader accepts, as the capture programs write it (every case has a test
in tests/test_c3d_vendors.py, the files written there with ezc3d or byte by byte):

- storage: float (POINT:SCALE < 0; its size only scales residuals, e.g. Vicon -0.01,
  Qualisys -0.076) or integer (POINT:SCALE > 0 multiplies every coordinate, e.g. 0.1 mm,
  as older Motion Analysis files); Intel or DEC processor formats.  Big-endian MIPS
  (SGI) files are refused with a clear message: ezc3d cannot read their data.  The
  header and POINT:SCALE must agree on float or integer storage, and POINT:SCALE must
  not be 0 (either would silently give wrong positions).
- POINT:UNITS ``mm``, ``cm``, ``m`` (any case; also spelt out, ``millimeters``, ``metres``...),
  mm when absent or blank; only the first entry counts when there is one per point.
- gaps: a negative residual word (the C3D "invalid point", -1 as Vicon, Qualisys,
  Motion Analysis and OptiTrack write it), all three coordinates exactly 0, or a
  non-finite coordinate.  A residual of 0 is a valid point (interpolated or filtered).
- labels from POINT:LABELS, LABELS2, LABELS3, ... (255 per parameter, so any number of
  points); labels of any length.
- subject prefixes: when every label with a ``:`` has the same prefix (Vicon Nexus
  ``Sub01:RASI``, OptiTrack Motive ``Skeleton:RASI``), the prefix is removed (``RASI``),
  unless that would make two labels the same.  With several prefixes (two subjects, a
  skeleton and rigid bodies) the labels are kept whole: :func:`calibrate.io.labels.map_labels`
  matches their names after the prefix.  ``strip_prefix=False`` keeps every label whole.
- model outputs are not markers: the points a modelling program (Vicon Plug-in Gait) wrote
  into the file are kept apart in :attr:`Trial.model_outputs` (never among the markers).  They
  are the labels listed in POINT:ANGLES, FORCES, MOMENTS, POWERS, SCALARS, REACTIONS and
  MODELED_MARKERS and in any group POINT:TYPE_GROUPS names (Vicon Nexus writes these), and,
  whatever the parameters say, the labels with a Plug-in Gait output name
  (:func:`is_model_output`: the bones ``PELO``, ``LFEO``, ``RHNP``..., joint centres ``LHJC``...,
  ``CentreOfMass``, ``LKneeAngles``, ``RHipMoment``...).  Their units are converted by their
  group's ``*_UNITS`` parameter (angles to rad, moments to N m, positions to m); see
  :func:`plugin_gait_centres` for Plug-in Gait's own hip, knee and ankle centres.
- long trials: when the header's frame numbers stop at 65535 (its last frame or POINT:FRAMES
  is 65535), the count comes from POINT:LONG_FRAMES, else TRIAL:ACTUAL_START_FIELD /
  ACTUAL_END_FIELD, else the length of the data section less its zero padding (which ezc3d
  would read as extra frames); the first frame from TRIAL:ACTUAL_START_FIELD when the
  header's is 65535.  ezc3d reads only 65535 frames of some long files (those with a
  ROTATION group, as ezc3d itself writes them): these are refused rather than returned cut
  short, and :func:`write_c3d` writes at most 65535 frames.
"""

from __future__ import annotations

import operator
import os
import re
import struct
import uuid
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import ezc3d
import numpy as np

from calibrate.errors import TrialError

__all__ = [
    "OUTPUT_SI_UNITS",
    "Trial",
    "is_model_output",
    "plugin_gait_centres",
    "read_c3d",
    "read_trc",
    "read_trial",
    "strip_subject_prefix",
    "write_c3d",
    "write_trc",
]

#: Length units accepted in trial files, with their size in metres.
UNITS_TO_METRES: dict[str, float] = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}

#: Spelt-out units some programs write, accepted when reading.
_UNIT_NAMES: dict[str, str] = {
    "millimeter": "mm",
    "millimeters": "mm",
    "millimetre": "mm",
    "millimetres": "mm",
    "centimeter": "cm",
    "centimeters": "cm",
    "centimetre": "cm",
    "centimetres": "cm",
    "meter": "m",
    "meters": "m",
    "metre": "m",
    "metres": "m",
}

#: POINT parameters in which Vicon lists its model outputs, with the kind of quantity.
_C3D_OUTPUT_GROUPS: dict[str, str] = {
    "ANGLES": "angle",
    "FORCES": "force",
    "MOMENTS": "moment",
    "POWERS": "power",
    "SCALARS": "scalar",
    "REACTIONS": "reaction",
    "MODELED_MARKERS": "point",
}

#: SI unit of each kind of model output (what :attr:`Trial.model_outputs` holds when the file
#: gives a unit it knows; see :attr:`Trial.output_units`).
OUTPUT_SI_UNITS: dict[str, str] = {"point": "m", "angle": "rad", "force": "N", "moment": "N m", "power": "W"}

#: Model-output units that are converted to SI on reading: unit (lower case, no spaces or dots) -> factor.
_OUTPUT_UNIT_FACTORS: dict[str, dict[str, float]] = {
    "angle": {"deg": np.pi / 180.0, "degree": np.pi / 180.0, "degrees": np.pi / 180.0, "rad": 1.0, "radians": 1.0},
    "force": {"n": 1.0, "kn": 1e3},
    "moment": {"nmm": 1e-3, "nm": 1.0, "knm": 1e3},
    "power": {"w": 1.0, "kw": 1e3, "mw": 1e-3},
    "point": {"mm": 1e-3, "cm": 1e-2, "m": 1.0},
}

#: Plug-in Gait "bones": segment codes whose origin (O), anterior (A), lateral (L) and proximal (P)
#: points Plug-in Gait writes (Vicon Nexus help, "Plug-in Gait bones"); side-less codes first.
PIG_BONES_MIDLINE = ("PEL", "HED", "TRX", "CSP", "SAC")
PIG_BONES_SIDED = ("FE", "TI", "FO", "TO", "CL", "HU", "RA", "HN")
_PIG_BONE = re.compile(
    r"^(?:(?:" + "|".join(PIG_BONES_MIDLINE) + r")|[LR](?:" + "|".join(PIG_BONES_SIDED) + r"))[OALP]$"
)
#: Joint-centre and other point outputs of Plug-in Gait and its clones (pyCGM, pyCGM2, biomechZoo).
_PIG_CENTRE = re.compile(
    r"^(?:[LR](?:HJC|KJC|AJC|SJC|EJC|WJC|FJC|HipJC|KneeJC|AnkleJC|ShoulderJC|ElbowJC|WristJC)"
    r"|CentreOfMass|CentreOfMassFloor|CenterOfMass|CenterOfMassFloor|COM|COMFloor)$"
)
#: Names of Plug-in Gait's angle, force, moment and power outputs: LKneeAngles, RHipMoment, LNormalisedGRF...
_PIG_QUANTITY = re.compile(
    r"^[LR]?[A-Za-z]+(?:Angles?|Force|GRF|Moment|Power)$"
)
_QUANTITY_KIND = (("Angle", "angle"), ("Force", "force"), ("GRF", "force"), ("Moment", "moment"), ("Power", "power"))

_TRC_KEYS = (
    "DataRate",
    "CameraRate",
    "NumFrames",
    "NumMarkers",
    "Units",
    "OrigDataRate",
    "OrigDataStartFrame",
    "OrigNumFrames",
)

_C3D_MAX_HEADER_FRAME = 65535  # the C3D header stores frame numbers as 16-bit words


def _one_line(text: object) -> str:
    """Collapse any message to a single line."""
    return " ".join(str(text).split())


def _where(source: str | os.PathLike[str] | None) -> str:
    """Prefix for messages about a trial: its file, or 'trial' when it has none."""
    return str(source) if source is not None else "trial"


def _fail(path: str | os.PathLike[str] | None, what: str, todo: str) -> TrialError:
    """Build a one-line TrialError: where, what is wrong, what to do."""
    return TrialError(_one_line(f"{_where(path)}: {what}; {todo}"))


def _parse_units(units: object, path: str | os.PathLike[str] | None, todo: str, *, reading: bool = False) -> float:
    """Metres per file unit for a units string such as ' MM '; when reading also 'millimeters' and the like."""
    key = str(units).strip().strip("\x00").strip().lower()
    if reading:
        key = _UNIT_NAMES.get(key, key)
    if key not in UNITS_TO_METRES:
        raise _fail(path, f"unknown length units {str(units).strip()!r} (expected mm, cm or m)", todo)
    return UNITS_TO_METRES[key]


def strip_subject_prefix(labels: Iterable[str]) -> tuple[list[str], str | None]:
    """Labels without their subject prefix, and the prefix (None when nothing was removed).

    A prefix is the text before the first ``:`` (``Sub01:RASI``, ``Skeleton:RASI``).  It is
    removed only when every label that has one has the same one, the prefix is not blank,
    and removing it leaves no label empty and makes no two labels equal that were not equal
    before; otherwise the labels come back as they were.
    """
    labels = [str(label).strip() for label in labels]
    prefixes = {label.split(":", 1)[0] for label in labels if ":" in label}
    if len(prefixes) != 1:
        return labels, None
    prefix = prefixes.pop().strip()
    if not prefix:
        return labels, None
    stripped = [label.split(":", 1)[1].strip() if ":" in label else label for label in labels]
    if any(":" in label and not new for label, new in zip(labels, stripped, strict=True)):
        return labels, None
    if len({label for label in stripped if label}) != len({label for label in labels if label}):
        return labels, None
    return stripped, prefix


def is_model_output(label: str) -> str | None:
    """The kind of model output a label names by Plug-in Gait's conventions, or None for a marker.

    ``'point'`` for the Plug-in Gait bones (``<SEG>O/A/L/P``: ``PELO``, ``LFEO``, ``HEDA``, ``RHNP``...),
    joint centres (``LHJC``, ``RKJC``, ``LKneeJC``...) and the centre of mass (``CentreOfMass``,
    ``CentreOfMassFloor``); ``'angle'``, ``'force'``, ``'moment'`` or ``'power'`` for names such as
    ``LKneeAngles``, ``RNormalisedGRF``, ``LHipMoment``, ``RAnklePower``.  A subject prefix
    (``Sub01:LFEO``) is ignored.
    """
    name = str(label).strip().split(":")[-1].strip()
    if _PIG_BONE.match(name) or _PIG_CENTRE.match(name):
        return "point"
    if _PIG_QUANTITY.match(name):
        return next(kind for word, kind in _QUANTITY_KIND if word in name)
    return None


#: Plug-in Gait outputs at (or, for the hip, next to) the lower-limb joint centres, per joint of
#: ``models/human.urdf``: explicit joint-centre outputs first, then the bone points.
_PIG_CENTRE_LABELS: dict[str, tuple[str, ...]] = {
    "hip_l": ("LHJC", "LHipJC", "LFEP"),
    "hip_r": ("RHJC", "RHipJC", "RFEP"),
    "knee_l": ("LKJC", "LKneeJC", "LFEO"),
    "knee_r": ("RKJC", "RKneeJC", "RFEO"),
    "ankle_l": ("LAJC", "LAnkleJC", "LTIO"),
    "ankle_r": ("RAJC", "RAnkleJC", "RTIO"),
}


def plugin_gait_centres(trial: Trial) -> dict[str, np.ndarray]:
    """Plug-in Gait's own hip, knee and ankle joint centres from a trial's model outputs.

    Returns ``{'hip_l': (n_frames, 3), ..., 'ankle_r': ...}`` in metres (lab frame, NaN where
    the file has a gap), keyed by the joint names of ``models/human.urdf``; a joint is absent when
    the file carries none of its outputs.  Explicit joint-centre points (``LHJC``, ``LKJC``,
    ``LAJC``, and pyCGM's ``LHipJC``...) are used when present, else the Plug-in Gait bones:

    - knee: the femur origin ``LFEO``/``RFEO`` (Plug-in Gait's knee joint centre, KJC);
    - ankle: the tibia origin ``LTIO``/``RTIO`` (its ankle joint centre, AJC);
    - hip: the femur proximal point ``LFEP``/``RFEP`` (its hip joint centre, HJC, from the Davis
      regression; Plug-in Gait writes no hip-centre point of its own); the pelvis bone origin
      ``PELO`` is the midpoint of the two.

    Checked on the pyCGM sample subject (docs/calibration.md, "Vicon model outputs"): ``LFEO``
    is KneeWidth/2 + marker radius from ``LKNE`` in every frame, ``LTIO`` AnkleWidth/2 + marker
    radius from ``LANK`` (Plug-in Gait's chord function), and ``LFEP``, ``RFEP`` sit where the
    Davis regression with the file's own subject measurements puts the hip centres in the pelvis.
    """
    found: dict[str, np.ndarray] = {}
    for joint, names in _PIG_CENTRE_LABELS.items():
        for name in names:
            if name in trial.model_outputs and trial.output_kinds.get(name) == "point":
                found[joint] = np.array(trial.model_outputs[name], dtype=float)
                break
    return found


def _unique_labels(raw: Iterable[str], numbers: Iterable[int] | None = None) -> tuple[str, ...]:
    """Strip labels, name empty ones ``unlabelled_<n>``, suffix duplicates ``_2``, ``_3``...

    ``n`` is the label's entry in ``numbers`` (its 1-based point number in the file), or its
    1-based position when ``numbers`` is not given.
    """
    stripped = [str(label).strip() for label in raw]
    numbers = list(numbers) if numbers is not None else list(range(1, len(stripped) + 1))
    taken = {label for label in stripped if label}
    out: list[str] = []
    used: set[str] = set()
    for number, label in zip(numbers, stripped, strict=True):
        if not label:
            label = f"unlabelled_{number}"
        if label in used:
            base, k = label, 2
            while f"{base}_{k}" in used or f"{base}_{k}" in taken:
                k += 1
            label = f"{base}_{k}"
        used.add(label)
        out.append(label)
    return tuple(out)


@dataclass(frozen=True, eq=False)
class Trial:
    """One motion-capture trial: labelled marker trajectories in metres.

    ``markers`` is copied to a read-only float64 array of shape
    (n_frames, n_markers, 3); a marker with any non-finite coordinate in a frame
    is a gap in that frame and all three of its coordinates become NaN.
    Trials compare by identity (arrays have no single truth value).
    """

    labels: tuple[str, ...]
    markers: np.ndarray
    rate: float
    first_frame: int = 0
    source: str | None = None
    #: Points a modelling program wrote into the file (Vicon Plug-in Gait's bones, joint centres,
    #: angles, forces...): label -> (n_frames, 3), SI units (``output_units``), NaN in gaps.  They
    #: are never markers: calibration does not see them.
    model_outputs: Mapping[str, np.ndarray] = field(default_factory=dict)
    #: label -> 'point', 'angle', 'force', 'moment', 'power', 'scalar' or 'reaction'.
    output_kinds: Mapping[str, str] = field(default_factory=dict)
    #: label -> unit of its values in ``model_outputs`` ('m', 'rad', 'N', 'N m', 'W', or the
    #: file's own unit when it is not one converted on reading).
    output_units: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = _where(self.source)
        labels = self.labels
        if isinstance(labels, str) or not isinstance(labels, Iterable):
            raise TrialError(f"{where}: marker labels must be a sequence of strings, got {type(labels).__name__}")
        labels = tuple(labels)
        for label in labels:
            if not isinstance(label, str) or not label.strip():
                raise TrialError(f"{where}: every marker needs a non-empty text label, got {label!r}")
            if label != label.strip():
                raise TrialError(f"{where}: marker label {label!r} has surrounding whitespace; strip it")
        seen: set[str] = set()
        dupes: set[str] = set()
        for label in labels:
            (dupes if label in seen else seen).add(label)
        if dupes:
            raise TrialError(f"{where}: marker labels must be unique; repeated: {', '.join(sorted(dupes)[:5])}")

        try:
            markers = np.array(self.markers, dtype=np.float64, copy=True)
        except (TypeError, ValueError) as exc:
            raise TrialError(f"{where}: marker positions are not numbers ({_one_line(exc)})") from None
        if markers.ndim != 3 or markers.shape[2] != 3 or markers.shape[1] != len(labels):
            raise TrialError(
                f"{where}: marker array has shape {markers.shape}, expected (n_frames, {len(labels)}, 3) "
                f"for {len(labels)} labels"
            )
        markers[~np.isfinite(markers).all(axis=2)] = np.nan
        markers.flags.writeable = False

        try:
            rate = float(self.rate)
        except (TypeError, ValueError):
            raise TrialError(f"{where}: frame rate {self.rate!r} is not a number") from None
        if not np.isfinite(rate) or rate <= 0:
            raise TrialError(f"{where}: frame rate must be a positive number of frames per second, got {rate}")

        if isinstance(self.first_frame, bool) or not isinstance(self.first_frame, (int, np.integer)):
            raise TrialError(f"{where}: first frame must be a whole number, got {self.first_frame!r}")
        first_frame = int(self.first_frame)
        if first_frame < 0:
            raise TrialError(f"{where}: first frame must be 0 or more (0-based), got {first_frame}")

        source = None if self.source is None else str(self.source)
        outputs: dict[str, np.ndarray] = {}
        for name, values in dict(self.model_outputs).items():
            array = np.array(values, dtype=np.float64, copy=True)
            if array.shape != (markers.shape[0], 3):
                raise TrialError(f"{where}: model output {name!r} has shape {array.shape}, expected "
                                 f"({markers.shape[0]}, 3) like the markers")
            array.flags.writeable = False
            outputs[str(name)] = array
        object.__setattr__(self, "model_outputs", outputs)
        object.__setattr__(self, "output_kinds", {str(k): str(v) for k, v in dict(self.output_kinds).items()})
        object.__setattr__(self, "output_units", {str(k): str(v) for k, v in dict(self.output_units).items()})
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "markers", markers)
        object.__setattr__(self, "rate", rate)
        object.__setattr__(self, "first_frame", first_frame)
        object.__setattr__(self, "source", source)

    def __repr__(self) -> str:
        return (
            f"Trial({self.n_frames} frames x {self.n_markers} markers at {self.rate:g} Hz, "
            f"first_frame={self.first_frame}, source={self.source!r})"
        )

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return int(self.markers.shape[0])

    @property
    def n_markers(self) -> int:
        """Number of markers."""
        return int(self.markers.shape[1])

    @property
    def times(self) -> np.ndarray:
        """Time of each frame in seconds, counted from the first frame of the original recording."""
        return (self.first_frame + np.arange(self.n_frames)) / self.rate

    def _index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            known = ", ".join(self.labels[:8])
            more = f" and {self.n_markers - 8} more" if self.n_markers > 8 else ""
            raise TrialError(
                f"{_where(self.source)}: no marker labelled {label!r} in this trial "
                f"(markers: {known or 'none'}{more}); check the marker names"
            ) from None

    def marker(self, label: str) -> np.ndarray:
        """Trajectory of one marker, (n_frames, 3) in metres, NaN in gaps."""
        return self.markers[:, self._index(label), :]

    def gap_fraction(self) -> np.ndarray:
        """Fraction of frames in which each marker is missing, (n_markers,); 1.0 for a trial with no frames."""
        if self.n_frames == 0:
            return np.ones(self.n_markers)
        return np.isnan(self.markers).any(axis=2).mean(axis=0)

    def select(self, labels: Iterable[str]) -> Trial:
        """Trial with only the given markers, in the given order."""
        wanted = (labels,) if isinstance(labels, str) else tuple(labels)
        idx = [self._index(label) for label in wanted]
        return Trial(
            labels=wanted,
            markers=self.markers[:, idx, :],
            rate=self.rate,
            first_frame=self.first_frame,
            source=self.source,
            model_outputs=self.model_outputs,
            output_kinds=self.output_kinds,
            output_units=self.output_units,
        )

    def frames(self, start: int, stop: int) -> Trial:
        """Frames ``start`` to ``stop - 1`` of this trial (0-based, relative to this trial's first frame)."""
        try:
            start, stop = operator.index(start), operator.index(stop)
        except TypeError:
            raise TrialError(
                f"{_where(self.source)}: frame numbers must be whole numbers, got {start!r}:{stop!r}"
            ) from None
        if not (0 <= start <= stop <= self.n_frames):
            raise TrialError(
                f"{_where(self.source)}: frames {start}:{stop} are outside this trial's 0:{self.n_frames}; "
                "choose start and stop with 0 <= start <= stop <= number of frames"
            )
        return Trial(
            labels=self.labels,
            markers=self.markers[start:stop],
            rate=self.rate,
            first_frame=self.first_frame + start,
            source=self.source,
            model_outputs={name: values[start:stop] for name, values in self.model_outputs.items()},
            output_kinds=self.output_kinds,
            output_units=self.output_units,
        )


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------


def _check_input_file(path: Path) -> int:
    """Fail unless ``path`` is an existing, non-empty regular file; return its size in bytes."""
    if not path.exists():
        raise _fail(path, "no such file", "check the path and file name")
    if path.is_dir():
        raise _fail(path, "is a directory, not a trial file", "give the path of a .c3d or .trc file")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise _fail(path, f"cannot be read ({_one_line(exc.strerror or exc)})", "check the file permissions") from None
    if size == 0:
        raise _fail(path, "file is empty", "export the trial again from your capture software")
    return size


def read_trial(path: str | os.PathLike[str], *, strip_prefix: bool = True) -> Trial:
    """Read a trial from a .c3d or .trc file, chosen by the file suffix.

    ``strip_prefix``: remove a subject prefix shared by the labels (``Sub01:RASI`` -> ``RASI``),
    see :func:`strip_subject_prefix`.
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".c3d":
        return read_c3d(path, strip_prefix=strip_prefix)
    if suffix == ".trc":
        return read_trc(path, strip_prefix=strip_prefix)
    raise _fail(
        path,
        f"unknown trial file type {Path(path).suffix or '(no suffix)'!r}",
        "give a .c3d or .trc file",
    )


class _BadC3D(ValueError):
    """Internal: a structural problem found in a C3D file before ezc3d reads it."""


def _c3d_float(raw: bytes, processor: int) -> float:
    """One 4-byte float in the file's processor format (84 Intel, 85 DEC, 86 MIPS)."""
    if processor == 86:
        return struct.unpack(">f", raw)[0]
    if processor == 85:  # DEC F-float: swap the 16-bit words, read as IEEE, divide by 4
        return struct.unpack("<f", raw[2:4] + raw[0:2])[0] / 4.0
    return struct.unpack("<f", raw)[0]


def _c3d_parameter_section(section: bytes, processor: int) -> dict[tuple[str, str], tuple[int, tuple[int, ...], bytes]]:
    """Walk the records of a C3D parameter section; map (GROUP, NAME) to (type, dimensions, raw data).

    Raises _BadC3D when a record does not fit the section, names an unknown type, or
    belongs to no group: ezc3d can crash the interpreter on such files.
    """
    endian = ">" if processor == 86 else "<"
    end = len(section)
    pos = 4
    groups: dict[int, str] = {}
    records: list[tuple[int, str, int, tuple[int, ...], bytes]] = []
    while pos + 2 <= end:
        n_chars = struct.unpack("b", section[pos : pos + 1])[0]
        if n_chars == 0:
            break
        group_id = struct.unpack("b", section[pos + 1 : pos + 2])[0]
        name_end = pos + 2 + abs(n_chars)
        if group_id == 0 or name_end + 2 > end:
            raise _BadC3D("a parameter record is broken")
        name = section[pos + 2 : name_end].decode("latin-1")
        if not name.isprintable() or not name.strip():
            raise _BadC3D("a parameter name is not text")
        link = struct.unpack(endian + "h", section[name_end : name_end + 2])[0]
        body = name_end + 2
        if group_id < 0:
            data_end = body
            groups[-group_id] = name.strip().upper()
        else:
            if body + 2 > end:
                raise _BadC3D(f"parameter {name} is cut short")
            kind = struct.unpack("b", section[body : body + 1])[0]
            n_dims = section[body + 1]
            if kind not in (-1, 1, 2, 4) or n_dims > 7:
                raise _BadC3D(f"parameter {name} has an unknown type or shape")
            dims = tuple(section[body + 2 : body + 2 + n_dims])
            data_start = body + 2 + n_dims
            data_end = data_start + int(np.prod(dims, dtype=np.int64)) * abs(kind)
            records.append((group_id, name.strip().upper(), kind, dims, section[data_start:data_end]))
        if data_end + 1 > end:
            raise _BadC3D(f"parameter {name} runs past the parameter section")
        record_end = data_end + 1 + section[data_end]  # after the description
        if record_end > end:
            raise _BadC3D(f"the description of {name} runs past the parameter section")
        if link == 0:
            break
        following = name_end + link
        if link < 0 or following < record_end or following > end:
            raise _BadC3D(f"the link after {name} does not lead to the next parameter")
        pos = following
    table: dict[tuple[str, str], tuple[int, tuple[int, ...], bytes]] = {}
    for group_id, name, kind, dims, raw in records:
        if group_id not in groups:
            raise _BadC3D(f"parameter {name} belongs to no group")
        table[(groups[group_id], name)] = (kind, dims, raw)
    return table


def _c3d_integer(
    table: dict[tuple[str, str], tuple[int, tuple[int, ...], bytes]], key: tuple[str, str], processor: int
) -> int | None:
    """First value of an integer or float parameter read as a whole number, or None."""
    if key not in table:
        return None
    kind, _, raw = table[key]
    if kind == 2 and len(raw) >= 2:
        return struct.unpack((">" if processor == 86 else "<") + "H", raw[:2])[0]
    if kind == 1 and raw:
        return raw[0]
    if kind == 4 and len(raw) >= 4:
        value = _c3d_float(raw[:4], processor)
        return int(value) if np.isfinite(value) else None
    return None


def _c3d_number(
    table: dict[tuple[str, str], tuple[int, tuple[int, ...], bytes]], key: tuple[str, str], processor: int
) -> float | None:
    """First value of a float or integer parameter (integers signed, as C3D stores them), or None."""
    if key not in table:
        return None
    kind, _, raw = table[key]
    if kind == 4 and len(raw) >= 4:
        value = _c3d_float(raw[:4], processor)
        return float(value) if np.isfinite(value) else None
    if kind == 2 and len(raw) >= 2:
        return float(struct.unpack((">" if processor == 86 else "<") + "h", raw[:2])[0])
    if kind == 1 and raw:
        return float(raw[0])
    return None


def _c3d_long_field(
    table: dict[tuple[str, str], tuple[int, tuple[int, ...], bytes]], key: tuple[str, str], processor: int
) -> int | None:
    """A TRIAL:ACTUAL_*_FIELD frame number: two unsigned 16-bit words, low word first; None when absent."""
    if key not in table:
        return None
    kind, _, raw = table[key]
    if kind == 2 and len(raw) >= 4:
        low, high = struct.unpack((">" if processor == 86 else "<") + "2H", raw[:4])
        return low + (high << 16)
    if kind == 4 and len(raw) >= 8:  # some writers store the two words as floats
        low, high = _c3d_float(raw[:4], processor), _c3d_float(raw[4:8], processor)
        if np.isfinite(low) and np.isfinite(high) and low >= 0 and high >= 0:
            return int(low) + (int(high) << 16)
    return None


@dataclass(frozen=True)
class _C3DLayout:
    """What the reader needs from a C3D file's header and parameters besides what ezc3d gives."""

    frames: int | None  # frames of a trial too long for the header; None: ezc3d's count is used as is
    first_frame: int | None  # 0-based first frame from TRIAL:ACTUAL_START_FIELD past the header's 65535, else None


def _check_c3d_layout(path: Path, size: int) -> _C3DLayout:
    """Check a C3D file's header and parameter section against its size before ezc3d reads it.

    ezc3d can crash the interpreter on a file cut or damaged inside its parameter
    section, and silently drops frames from a file cut inside its data; both are caught here.
    Returns the frame count and first frame the file gives for trials too long for the header.
    """
    redo = "export it again from your capture software"

    def bad(reason: str) -> TrialError:
        return _fail(path, f"not a readable C3D file ({reason})", redo)

    if size < 512:
        raise bad(f"only {size} bytes, shorter than a C3D header")
    with open(path, "rb") as fh:
        header = fh.read(512)
        if header[0] == 0:  # some writers pad the start with zeros; ezc3d skips them
            return _C3DLayout(frames=None, first_frame=None)
        if header[1] != 0x50 or header[0] < 2:
            raise bad("no C3D signature in its header")
        param_start = (header[0] - 1) * 512
        fh.seek(param_start)
        head = fh.read(4)
        if len(head) < 4:
            raise bad("truncated: its parameter section is missing")
        n_blocks, processor = head[2], head[3]
        if processor not in (84, 85, 86):
            raise bad(f"unknown processor type {processor} in its parameter section")
        if processor == 86:
            raise _fail(
                path,
                "C3D file is in the big-endian MIPS (SGI) format, whose data ezc3d cannot read",
                "convert it to an Intel (PC) C3D file, e.g. by opening and saving it in Mokka, or export it as TRC",
            )
        if n_blocks == 0 or param_start + 512 * n_blocks > size:
            raise bad("truncated inside its parameter section")
        fh.seek(param_start)
        section = fh.read(512 * n_blocks)
        fh.seek(max(size - 512, 0))
        tail = fh.read(512)
    try:
        table = _c3d_parameter_section(section, processor)
    except _BadC3D as exc:
        raise bad(f"damaged parameter section: {exc}") from None

    endian = "<"  # Intel and DEC store integers little-endian
    n_points, n_analog, first, last = struct.unpack(endian + "4H", header[2:10])
    data_block = struct.unpack(endian + "H", header[16:18])[0]
    is_float = _c3d_float(header[12:16], processor) < 0
    used = _c3d_integer(table, ("POINT", "USED"), processor)
    if used is not None and used != n_points:
        raise bad(f"its header lists {n_points} points but POINT:USED says {used}")
    point_scale = _c3d_number(table, ("POINT", "SCALE"), processor)
    if n_points and point_scale is not None:  # ezc3d reads the points by POINT:SCALE, the size check by the header
        if point_scale == 0:
            raise bad("POINT:SCALE is 0, which would make every coordinate 0")
        if (point_scale < 0) != is_float:
            raise bad(
                f"its header says {'float' if is_float else 'integer'} storage but POINT:SCALE "
                f"({point_scale:g}) says {'float' if point_scale < 0 else 'integer'}"
            )
    analog_per_frame = struct.unpack(endian + "H", header[18:20])[0]
    n_channels = max(
        n_analog // analog_per_frame if analog_per_frame else 0,
        _c3d_integer(table, ("ANALOG", "USED"), processor) or 0,
    )
    for name in ("SCALE", "OFFSET"):  # ezc3d crashes when these are shorter than the channel list
        _, dims, _ = table.get(("ANALOG", name), (0, (0,), b""))
        if n_channels and int(np.prod(dims, dtype=np.int64)) < n_channels:
            raise bad(f"ANALOG:{name} does not cover its {n_channels} analog channels")
    if data_block == 0 or (data_block - 1) * 512 > size:
        raise bad("truncated before its data section")

    frame_bytes = (4 * n_points + n_analog) * (4 if is_float else 2)
    data_start = (data_block - 1) * 512
    start_field = _c3d_long_field(table, ("TRIAL", "ACTUAL_START_FIELD"), processor)
    end_field = _c3d_long_field(table, ("TRIAL", "ACTUAL_END_FIELD"), processor)
    long_frames = _c3d_number(table, ("POINT", "LONG_FRAMES"), processor)
    n_frames: int | None = _c3d_integer(table, ("POINT", "FRAMES"), processor)
    long_count: int | None = None  # the count of a trial that may be longer than the header can say
    if (last == 0xFFFF or n_frames == 0xFFFF) and frame_bytes:
        if long_frames is not None and long_frames >= 1:
            long_count = int(long_frames)
        elif start_field and end_field and end_field >= start_field:
            long_count = end_field - start_field + 1
    if long_count is None and (n_frames is None or n_frames == 0xFFFF) and last == 0xFFFF and frame_bytes:
        # The header is capped at 65535 and nothing else gives the count: as many frames as
        # the data section holds, less the zero bytes that pad its last 512-byte block.
        held = max(size - data_start, 0)
        zeros = min(len(tail) - len(tail.rstrip(b"\x00")), 511, held)
        long_count = min(-(-(held - zeros) // frame_bytes), held // frame_bytes)
    if long_count is not None:
        n_frames = long_count
    elif n_frames is None or n_frames == 0xFFFF:  # no count, or a long trial counted elsewhere
        n_frames = last - first + 1 if first >= 1 and last >= first else 0
    if frame_bytes and data_start + n_frames * frame_bytes > size:
        held = max(size - data_start, 0) // frame_bytes
        raise _fail(
            path,
            f"C3D file is truncated: it should hold {n_frames} frames but holds only {held}",
            redo,
        )
    first_frame = start_field - 1 if start_field and first == 0xFFFF else None  # past what the header holds
    return _C3DLayout(frames=long_count if frame_bytes else None, first_frame=first_frame)


def _c3d_param(params: object, group: str, name: str) -> list | np.ndarray | None:
    """Value of parameter GROUP:NAME, or None when it is absent."""
    try:
        return params[group][name]["value"]  # type: ignore[index]
    except (KeyError, TypeError):
        return None


def _first_number(value: list | np.ndarray | None) -> float | None:
    """First element of a numeric parameter value, or None."""
    if value is None:
        return None
    flat = np.asarray(value).ravel()
    if flat.size == 0:
        return None
    try:
        return float(flat[0])
    except (TypeError, ValueError):
        return None


def _c3d_strings(value: list | np.ndarray | None) -> list[str]:
    """A character parameter's entries as stripped strings (NUL padding removed)."""
    if value is None:
        return []
    return [str(v).replace("\x00", " ").strip() for v in np.asarray(value, dtype=object).ravel()]


def read_c3d(path: str | os.PathLike[str], *, strip_prefix: bool = True) -> Trial:
    """Read the marker trajectories of a C3D file (via ezc3d) into a trial in metres.

    Labels come from POINT:LABELS, LABELS2, ... for the first POINT:USED points;
    an empty label becomes ``unlabelled_<n>`` (n the 1-based point number) and a
    repeated label gets a suffix (``RASI_2``).  A subject prefix shared by the labels
    is removed unless ``strip_prefix`` is False (:func:`strip_subject_prefix`).  Points
    Vicon lists as angles, forces, moments, powers, scalars or reactions are left out.
    POINT:UNITS may be mm, cm or m (mm when absent).  Points with a negative residual,
    all three coordinates exactly zero, or a non-finite coordinate are gaps (NaN).
    The module docstring lists the vendor conventions this covers.
    """
    path = Path(path)
    size = _check_input_file(path)
    layout = _check_c3d_layout(path, size)
    redo = "export it again from your capture software"
    try:
        c3d = ezc3d.c3d(str(path))
        params = c3d["parameters"]
        points = np.asarray(c3d["data"]["points"], dtype=np.float64)
        residuals = np.asarray(c3d["data"]["meta_points"]["residuals"], dtype=np.float64)
        header_first = int(c3d["header"]["points"]["first_frame"])
        header_rate = float(c3d["header"]["points"]["frame_rate"])
    except Exception as exc:  # noqa: BLE001 - ezc3d raises OSError, RuntimeError, ValueError, ... on bad files
        raise _fail(path, f"not a readable C3D file (ezc3d: {_one_line(exc) or type(exc).__name__})", redo) from None

    if "POINT" not in params:
        raise _fail(path, "C3D file has no POINT group, so no marker trajectories", redo)
    used = _first_number(_c3d_param(params, "POINT", "USED"))
    n_points = points.shape[1] if points.ndim == 3 else 0
    if used is not None:
        n_points = min(n_points, max(int(used), 0))
    n_frames = points.shape[2] if points.ndim == 3 else 0
    if layout.frames is not None and n_frames != layout.frames:
        if n_frames < layout.frames:
            raise _fail(
                path,
                f"C3D file holds {layout.frames} frames but ezc3d reads only {n_frames} of them",
                "export the trial in parts of at most 65535 frames, or as a TRC file",
            )
        n_frames = layout.frames  # ezc3d read the zero padding after the last frame as frames
    if n_points == 0:
        raise _fail(
            path, "C3D file contains no marker trajectories (POINT:USED is 0)", "export the trial with its markers"
        )
    if n_frames == 0:
        raise _fail(path, "C3D file contains no frames", "export the trial again with its frames")

    raw_labels: list[str] = []
    k = 1
    while True:
        name = "LABELS" if k == 1 else f"LABELS{k}"
        value = _c3d_param(params, "POINT", name)
        if value is None:
            break
        raw_labels.extend(_c3d_strings(value))
        k += 1
    raw_labels = (raw_labels + [""] * n_points)[:n_points]

    kinds = _c3d_output_kinds(params, raw_labels)
    keep = [i for i, label in enumerate(raw_labels) if i not in kinds]
    if not keep:
        raise _fail(
            path,
            "C3D file contains no marker trajectories, only model outputs (POINT:ANGLES, FORCES, PELO, ...)",
            "export the trial with its markers",
        )
    kept_labels = [raw_labels[i] for i in keep]
    outputs = sorted(kinds)
    output_labels = [raw_labels[i] for i in outputs]
    if strip_prefix:
        both, _ = strip_subject_prefix(kept_labels + output_labels)
        kept_labels, output_labels = both[: len(keep)], both[len(keep) :]
    labels = _unique_labels(kept_labels, numbers=[i + 1 for i in keep])
    output_labels = list(_unique_labels(output_labels, numbers=[i + 1 for i in outputs]))

    units_value = _c3d_strings(_c3d_param(params, "POINT", "UNITS"))
    units = units_value[0] if units_value else ""
    scale = (
        _parse_units(units, path, "set POINT:UNITS to mm, cm or m", reading=True) if units else UNITS_TO_METRES["mm"]
    )

    rate = _first_number(_c3d_param(params, "POINT", "RATE"))
    if rate is None or not np.isfinite(rate) or rate <= 0:
        rate = header_rate
    if not np.isfinite(rate) or rate <= 0:
        raise _fail(path, "C3D file gives no valid frame rate (POINT:RATE)", redo)

    xyz = points[:3, keep, :n_frames].transpose(2, 1, 0) * scale  # (frames, markers, 3)
    gap = ~np.isfinite(xyz).all(axis=2) | (xyz == 0.0).all(axis=2)
    if residuals.ndim == 3 and residuals.shape[1] >= n_points and residuals.shape[2] >= n_frames:
        gap |= (residuals[0, keep, :n_frames] < 0).T
    xyz[gap] = np.nan
    model_outputs: dict[str, np.ndarray] = {}
    output_kinds: dict[str, str] = {}
    output_units: dict[str, str] = {}
    for i, label in zip(outputs, output_labels, strict=True):
        kind, unit = kinds[i]
        factor, si = (scale, "m") if kind == "point" and not unit else _output_factor(kind, unit)
        values = points[:3, i, :n_frames].T * factor
        bad = ~np.isfinite(values).all(axis=1)
        if kind == "point":
            bad |= (values == 0.0).all(axis=1)
        if residuals.ndim == 3 and residuals.shape[1] > i and residuals.shape[2] >= n_frames:
            bad |= residuals[0, i, :n_frames] < 0
        values[bad] = np.nan
        model_outputs[label], output_kinds[label], output_units[label] = values, kind, si
    first_frame = layout.first_frame if layout.first_frame is not None else max(header_first, 0)
    return Trial(labels=labels, markers=xyz, rate=rate, first_frame=first_frame, source=str(path),
                 model_outputs=model_outputs, output_kinds=output_kinds, output_units=output_units)


def _output_factor(kind: str, unit: str) -> tuple[float, str]:
    """Factor from a model output's file unit to SI, and the unit of the result (the file's when unknown)."""
    key = re.sub(r"[\s.·*]", "", unit).lower()
    factors = _OUTPUT_UNIT_FACTORS.get(kind, {})
    if key in factors:
        return factors[key], OUTPUT_SI_UNITS[kind]
    if not key and kind == "angle":  # Vicon writes angles in degrees
        return factors["deg"], OUTPUT_SI_UNITS[kind]
    return 1.0, unit.strip() or "file units"


def _c3d_output_kinds(params: dict, raw_labels: list[str]) -> dict[int, tuple[str, str]]:
    """Point index -> (kind, file unit) for every point that is a model output, not a marker.

    By the file's parameters: the labels listed in POINT:ANGLES, FORCES, ... (unit from
    ANGLE_UNITS, FORCE_UNITS, ...) and in every group POINT:TYPE_GROUPS names (pairs of group
    and singular name: ``ANGLES, ANGLE, MODELED_MARKERS, MODELED_MARKER``); then by name
    (:func:`is_model_output`), the units of the group of that kind.
    """
    groups = dict(_C3D_OUTPUT_GROUPS)
    singular = {"ANGLES": "ANGLE", "FORCES": "FORCE", "MOMENTS": "MOMENT", "POWERS": "POWER",
                "SCALARS": "SCALAR", "REACTIONS": "REACTION", "MODELED_MARKERS": "MODELED_MARKER"}
    pairs = [str(v).strip().upper() for v in _c3d_strings(_c3d_param(params, "POINT", "TYPE_GROUPS"))]
    for group, single in zip(pairs[0::2], pairs[1::2], strict=False):
        if group and group not in groups:
            groups[group] = single.lower() or group.lower()
            singular[group] = single
    unit_of: dict[str, str] = {}
    listed: dict[str, tuple[str, str]] = {}
    for group, kind in groups.items():
        units = _c3d_strings(_c3d_param(params, "POINT", f"{singular.get(group, group)}_UNITS"))
        unit = str(units[0]).strip() if units else ""
        unit_of.setdefault(kind, unit)
        for label in _c3d_strings(_c3d_param(params, "POINT", group)):
            if str(label).strip():
                listed.setdefault(str(label).strip(), (kind, unit))
    out: dict[int, tuple[str, str]] = {}
    for i, label in enumerate(raw_labels):
        label = str(label).strip()
        if not label:
            continue
        if label in listed:
            out[i] = listed[label]
        elif (kind := is_model_output(label)) is not None:
            out[i] = (kind, "" if kind == "point" else unit_of.get(kind, ""))
    return out


def read_trc(path: str | os.PathLike[str], *, strip_prefix: bool = True) -> Trial:
    """Read an OpenSim-style TRC marker file into a trial in metres; blank (or NaN) cells are gaps.

    Tab-separated, as OpenSim reads and writes it: line 2 the header keys, line 3 their values
    (``DataRate`` and ``Units`` required; ``Units`` mm, cm or m, also spelt out), line 4
    ``Frame#``, ``Time`` and one label every three columns (labels may contain spaces and
    dots), line 5 the X/Y/Z names, data from line 6 on (blank lines skipped).  A subject
    prefix shared by the labels is removed unless ``strip_prefix`` is False.  Columns with a
    Plug-in Gait output name (:func:`is_model_output`) go to :attr:`Trial.model_outputs`.
    """
    path = Path(path)
    _check_input_file(path)
    redo = "export the TRC file again"
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise _fail(path, f"cannot be read ({_one_line(exc.strerror or exc)})", "check the file permissions") from None
    if b"\x00" in data:
        raise _fail(path, "not a TRC text file (it contains binary data)", redo)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if len(lines) < 5:
        raise _fail(path, f"not a TRC file ({len(lines)} line(s), a TRC header needs 5)", redo)
    if not lines[0].lstrip().startswith("PathFileType"):
        raise _fail(path, "not a TRC file (line 1 should start with PathFileType)", redo)

    keys = [cell.strip() for cell in lines[1].split("\t") if cell.strip()]
    values = [cell.strip() for cell in lines[2].split("\t")]
    filled = [v for v in values if v]
    if len(filled) == len(keys) and len(values) != len(keys):  # values padded with empty fields (some exporters)
        values = filled
    values = values[: len(keys)] + [""] * (len(keys) - len(values))
    meta = dict(zip(keys, values, strict=True))
    for key in ("DataRate", "Units"):
        if not meta.get(key):
            raise _fail(path, f"TRC header has no {key} value (lines 2-3)", redo)
    try:
        rate = float(meta["DataRate"])
    except ValueError:
        raise _fail(path, f"TRC DataRate {meta['DataRate']!r} is not a number", redo) from None
    if not np.isfinite(rate) or rate <= 0:
        raise _fail(path, f"TRC DataRate must be a positive number of frames per second, got {meta['DataRate']}", redo)
    scale = _parse_units(meta["Units"], path, "set Units in the TRC header to mm, cm or m", reading=True)

    def header_int(key: str) -> int | None:
        if not meta.get(key):
            return None
        try:
            return int(float(meta[key]))
        except (ValueError, OverflowError):
            raise _fail(path, f"TRC {key} {meta[key]!r} is not a number", redo) from None

    num_markers = header_int("NumMarkers")
    num_frames = header_int("NumFrames")

    label_cells = lines[3].split("\t")
    if len(label_cells) < 2 or label_cells[0].strip() != "Frame#" or label_cells[1].strip() != "Time":
        raise _fail(path, "TRC line 4 should start with Frame# and Time", redo)
    marker_cells = label_cells[2:]
    misplaced = [cell.strip() for i, cell in enumerate(marker_cells) if i % 3 and cell.strip()]
    if misplaced:
        raise _fail(
            path,
            f"TRC line 4 has marker labels out of step with the X/Y/Z columns (near {misplaced[0]!r})",
            redo,
        )
    raw_labels = marker_cells[0::3]
    while raw_labels and not raw_labels[-1].strip():
        raw_labels.pop()
    n_markers = len(raw_labels)
    if num_markers is not None and num_markers != n_markers:
        raise _fail(path, f"TRC header says NumMarkers {num_markers} but line 4 names {n_markers} markers", redo)
    if n_markers == 0:
        raise _fail(path, "TRC file names no markers", "export the trial with its markers")
    if strip_prefix:
        raw_labels, _ = strip_subject_prefix(raw_labels)
    labels = _unique_labels(raw_labels)

    width = 2 + 3 * n_markers
    rows: list[list[str]] = []
    line_numbers: list[int] = []
    for number, line in enumerate(lines[5:], start=6):
        if not line.strip():
            continue
        cells = [cell.strip() for cell in line.split("\t")]
        if len(cells) > width:
            extra = [cell for cell in cells[width:] if cell]
            if extra:
                raise _fail(
                    path,
                    f"line {number} has more values than the {n_markers} markers named in the header",
                    redo,
                )
            cells = cells[:width]
        cells += [""] * (width - len(cells))
        rows.append(cells)
        line_numbers.append(number)
    if not rows:
        raise _fail(path, "TRC file contains no frames", "export the trial again with its frames")
    if num_frames is not None and num_frames != len(rows):
        raise _fail(
            path,
            f"TRC header says NumFrames {num_frames} but the file has {len(rows)} data rows (truncated?)",
            redo,
        )

    values_array = np.empty((len(rows), width), dtype=np.float64)
    for r, cells in enumerate(rows):
        try:
            values_array[r] = [float(cell) if cell else np.nan for cell in cells]
        except ValueError:
            column = next(i for i, cell in enumerate(cells) if cell and not _is_number(cell))
            raise _fail(
                path,
                f"line {line_numbers[r]}, column {column + 1}: {cells[column]!r} is not a number",
                "fix that cell or export the file again",
            ) from None

    first_number = values_array[0, 0]
    if not np.isfinite(first_number) or first_number != int(first_number):
        raise _fail(path, f"line {line_numbers[0]}: Frame# should be a whole number, got {rows[0][0]!r}", redo)
    markers = values_array[:, 2:].reshape(len(rows), n_markers, 3) * scale
    kinds = {i: kind for i, label in enumerate(labels) if (kind := is_model_output(label)) is not None}
    keep = [i for i in range(n_markers) if i not in kinds]
    if not keep:
        raise _fail(path, "TRC file holds only model outputs (PELO, LFEO, ...), no markers",
                    "export the trial with its markers")
    return Trial(
        labels=tuple(labels[i] for i in keep),
        markers=markers[:, keep],
        rate=rate,
        first_frame=max(int(first_number) - 1, 0),
        source=str(path),
        model_outputs={labels[i]: markers[:, i] / (1.0 if kind == "point" else scale) for i, kind in kinds.items()},
        output_kinds={labels[i]: kind for i, kind in kinds.items()},
        output_units={labels[i]: "m" if kind == "point" else "file units" for i, kind in kinds.items()},
    )


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------


def _target(path: str | os.PathLike[str], trial: Trial, units: str) -> tuple[Path, str, float]:
    """Check the output path, trial and units; return the path, normalised units and metres per unit."""
    path = Path(path)
    todo = "use mm, cm or m"
    key = str(units).strip().lower()
    scale = _parse_units(units, path, todo)
    parent = path.parent
    if not parent.is_dir():
        raise _fail(path, f"output directory {str(parent)!r} does not exist", "create it first or choose another path")
    if path.is_dir():
        raise _fail(path, "is a directory", "give a file name to write the trial to")
    if not isinstance(trial, Trial):
        raise TypeError(f"expected a Trial, got {type(trial).__name__}")
    if trial.n_markers == 0 or trial.n_frames == 0:
        raise _fail(
            path,
            f"cannot write a trial with {trial.n_frames} frames and {trial.n_markers} markers",
            "write a trial with at least one frame and one marker",
        )
    return path, key, scale


def _temporary_sibling(path: Path, suffix: str) -> Path:
    """A fresh hidden name in the same directory, for writing before replacing."""
    return path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}.tmp{suffix}")


def _discard(tmp: Path) -> None:
    try:
        tmp.unlink()
    except OSError:
        pass


def write_c3d(path: str | os.PathLike[str], trial: Trial, units: str = "mm") -> None:
    """Write a trial's marker trajectories to a C3D file (float data, POINT:UNITS ``units``).

    Gaps are written as coordinates 0 with residual -1 (the C3D "invalid point").
    At most 65535 frames: ezc3d does not read longer files back whole.
    The file is written next to its target and then moved into place.
    """
    path, key, scale = _target(path, trial, units)
    if trial.n_frames > _C3D_MAX_HEADER_FRAME:
        raise _fail(
            path,
            f"{trial.n_frames} frames are more than a C3D file written here can hold ({_C3D_MAX_HEADER_FRAME}; "
            "ezc3d reads back only that many)",
            "write a TRC file instead or split the trial with Trial.frames",
        )
    if trial.first_frame + 1 > _C3D_MAX_HEADER_FRAME:
        raise _fail(
            path,
            f"first frame {trial.first_frame} is past the last frame number a C3D header can hold "
            f"({_C3D_MAX_HEADER_FRAME})",
            "write a TRC file instead or start the trial at an earlier frame",
        )
    xyz = trial.markers / scale  # (frames, markers, 3) in file units
    gap = np.isnan(xyz).any(axis=2)  # (frames, markers)
    points = np.zeros((4, trial.n_markers, trial.n_frames))
    points[:3] = np.where(gap[:, :, None], 0.0, xyz).transpose(2, 1, 0)
    points[3] = 1.0
    residuals = np.where(gap.T, -1.0, 0.0)[None, :, :]

    tmp = _temporary_sibling(path, ".c3d")  # ezc3d appends .c3d to names without it
    try:
        c3d = ezc3d.c3d()
        c3d["parameters"]["POINT"]["RATE"]["value"] = [trial.rate]
        c3d["parameters"]["POINT"]["LABELS"]["value"] = list(trial.labels)
        c3d["parameters"]["POINT"]["UNITS"]["value"] = [key]
        c3d["header"]["points"]["first_frame"] = trial.first_frame  # 0-based; stored 1-based in the file
        c3d["data"]["points"] = points
        c3d["data"]["meta_points"] = {"residuals": residuals}
        c3d.write(str(tmp))
        os.replace(tmp, path)
    except Exception as exc:  # noqa: BLE001 - any ezc3d or OS failure becomes one TrialError line
        _discard(tmp)
        raise _fail(
            path,
            f"could not write the C3D file ({_one_line(exc) or type(exc).__name__})",
            "check the directory is writable and has free space",
        ) from None
    except BaseException:
        _discard(tmp)
        raise


def write_trc(path: str | os.PathLike[str], trial: Trial, units: str = "mm") -> None:
    """Write a trial to an OpenSim-style TRC file in ``units``; gaps are empty cells.

    Frame numbers are 1-based (``first_frame + 1`` onwards), times in seconds.
    The file is written next to its target and then moved into place.
    """
    path, key, scale = _target(path, trial, units)
    bad = [label for label in trial.labels if any(ch in label for ch in "\t\r\n")]
    if bad:
        raise _fail(path, f"marker label {bad[0]!r} contains a tab or line break", "rename the marker")
    decimals = {"mm": 6, "cm": 7, "m": 9}[key]  # nanometre resolution in every unit
    rate = f"{trial.rate:.12g}"
    n = trial.n_markers
    head = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "\t".join(_TRC_KEYS),
        "\t".join(
            [rate, rate, str(trial.n_frames), str(n), key, rate, str(trial.first_frame + 1), str(trial.n_frames)]
        ),
        "Frame#\tTime\t" + "".join(f"{label}\t\t\t" for label in trial.labels),
        "\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, n + 1)),
        "",
    ]
    rows = (trial.markers / scale).reshape(trial.n_frames, 3 * n).tolist()
    times = trial.times.tolist()
    spec = f".{decimals}f"

    tmp = _temporary_sibling(path, ".trc")
    try:
        with open(tmp, "x", encoding="utf-8", newline="\n") as fh:
            fh.write("\n".join(head) + "\n")
            for i, row in enumerate(rows):
                cells = "\t".join("" if v != v else format(v, spec) for v in row)  # v != v: NaN, a gap
                fh.write(f"{trial.first_frame + i + 1}\t{times[i]:.9g}\t{cells}\n")
        os.replace(tmp, path)
    except OSError as exc:
        _discard(tmp)
        raise _fail(
            path,
            f"could not write the TRC file ({_one_line(exc)})",
            "check the directory is writable and has free space",
        ) from None
    except BaseException:
        _discard(tmp)
        raise
