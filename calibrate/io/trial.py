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
  as older Motion Analysis files); Intel, DEC or big-endian MIPS (SGI) processor formats
  (an SGI file, whose data ezc3d cannot read, is read as the Intel file it converts to: c3d.org's
  SGI samples read bit for bit as their PC twins).  The header and POINT:SCALE must agree on
  float or integer storage, on the scale itself in integer storage, and POINT:SCALE must not be
  0 (any would silently give wrong positions: c3d.org's sample06 would read 2.56 times small).
- POINT:UNITS ``mm``, ``cm``, ``m`` (any case; also spelt out, ``millimeters``, ``metres``..., or cut to four
  characters or more, ``mete``, as c3d.org's sample15 stores it), mm when absent or blank; only the first entry
  counts when there is one per point.
- the parameter section read on to the data section where the header's count of its blocks falls short or is 0
  (c3d.org's sample15, PhaseSpace), and a parameter of no group (c3d.org's Vicon force-plate samples) left out,
  as ezc3d reads them: every c3d.org and BTKData sample with markers that ezc3d reads is read here.  Where the
  ANALOG parameters count other analog words per frame than the header (BTS's files, c3d.org sample28: ANALOG:USED
  0 beside 6 words a frame), ezc3d would step through the frames by the parameters, reading every frame but the
  first from the wrong place: the points are then read here as the header lays them out, as they are where
  ANALOG:SCALE or OFFSET does not cover the channels (c3d.org's sample06 names them OFFSETS), on which ezc3d
  crashes the interpreter: it reads a copy told of no analog channels.
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
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from calibrate.errors import TrialError
from calibrate.io.measurements import SubjectMeasurements
from calibrate.io.outputs import write_all

__all__ = [
    "Trial",
    "strip_subject_prefix",
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


def one_line(text: object) -> str:
    """Collapse any message to a single line."""
    return " ".join(str(text).split())


def origin(source: str | os.PathLike[str] | None) -> str:
    """Prefix for messages about a trial: its file, or 'trial' when it has none."""
    return str(source) if source is not None else "trial"


def fail(path: str | os.PathLike[str] | None, what: str, todo: str) -> TrialError:
    """Build a one-line TrialError: where, what is wrong, what to do."""
    return TrialError(one_line(f"{origin(path)}: {what}; {todo}"))


def parse_units(units: object, path: str | os.PathLike[str] | None, todo: str, *, reading: bool = False) -> float:
    """Metres per file unit for a units string such as ' MM '; when reading also 'millimeters' and the like."""
    key = str(units).strip().strip("\x00").strip().lower()
    if reading:
        # A name cut to the parameter's width (c3d.org's sample15 stores 'mete' in a 4-character POINT:UNITS): the
        # one unit whose spelt-out names it begins, at 4 characters or more.
        cut = {unit for name, unit in _UNIT_NAMES.items() if len(key) >= 4 and name.startswith(key)}
        key = _UNIT_NAMES.get(key, cut.pop() if len(cut) == 1 else key)
    if key not in UNITS_TO_METRES:
        raise fail(path, f"unknown length units {str(units).strip()!r} (expected mm, cm or m)", todo)
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


def subject_prefixes(labels: Iterable[str]) -> dict[str, int]:
    """Each subject prefix among `labels` (the text before the first ``:``, as Vicon Nexus writes
    ``Derrick:RASI`` for each subject of a session) and how many labels carry it."""
    out: dict[str, int] = {}
    for label in labels:
        if ":" in label and (prefix := label.split(":", 1)[0].strip()) and label.split(":", 1)[1].strip():
            out[prefix] = out.get(prefix, 0) + 1
    return out


def unique_labels(raw: Iterable[str], numbers: Iterable[int] | None = None) -> tuple[str, ...]:
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


def file_labels(groups: Sequence[Sequence[str]], numbers: Sequence[Sequence[int]] | None = None,
                strip: bool = True) -> list[tuple[str, ...]]:
    """A trial file's point labels, group by group (e.g. markers, then model outputs): the subject
    prefix they all share removed (strip_subject_prefix, when `strip`), then each group made unique
    (unique_labels; `numbers`: each label's 1-based point number in the file, per group)."""
    sizes = [len(g) for g in groups]
    everything = [label for g in groups for label in g]
    if strip:
        everything, _ = strip_subject_prefix(everything)
    out, at = [], 0
    for i, n in enumerate(sizes):
        out.append(unique_labels(everything[at:at + n], None if numbers is None else numbers[i]))
        at += n
    return out


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
    #: are not markers: calibration does not see them, unless a marker map or the model's own marker of the
    #: name names a point among them (:func:`calibrate.io.labels.map_labels`).
    model_outputs: Mapping[str, np.ndarray] = field(default_factory=dict)
    #: label -> 'point', 'angle', 'force', 'moment', 'power', 'scalar' or 'reaction'.
    output_kinds: Mapping[str, str] = field(default_factory=dict)
    #: label -> unit of its values in ``model_outputs`` ('m', 'rad', 'N', 'N m', 'W', or the
    #: file's own unit when it is not one converted on reading).
    output_units: Mapping[str, str] = field(default_factory=dict)
    #: What the lab measured on the subject (body mass, height, joint widths: a Plug-in Gait session's
    #: PROCESSING parameters), None when the file carries none.
    measurements: SubjectMeasurements | None = None
    #: Time of the first frame in seconds as the file gives it (a TRC's Time column, which need not be
    #: ``first_frame / rate``: OpenSim's example running trial starts at frame 23, 0.23 s at 100 Hz); None:
    #: ``first_frame / rate``.  The lab's time ranges (an OpenSim setup's) and the motion's times count from it.
    start_time: float | None = None
    #: label -> what the file says the marker is where its label is a code (a C3D's POINT:DESCRIPTIONS: c3d.org's
    #: sample10 labels the Helen Hayes set ``R``, ``RK``, ``RA`` and describes them "Right ASIS", "Right knee",
    #: "Right lateral ankle"); only descriptions other than the label itself (in any case and spacing).
    #: :func:`calibrate.io.labels.map_labels` reads a label its own name does not match by it.
    descriptions: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = origin(self.source)
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

        markers = self.markers
        # A read-only float64 array that owns its memory (what the readers make) is taken as it is: a
        # long trial's marker array is never held twice.  Anything else is copied (the trial is immutable).
        adopt = (isinstance(markers, np.ndarray) and markers.dtype == np.float64 and markers.base is None
                 and not markers.flags.writeable and markers.flags.c_contiguous)
        if not adopt:
            try:
                markers = np.array(markers, dtype=np.float64, copy=True)
            except (TypeError, ValueError) as exc:
                raise TrialError(f"{where}: marker positions are not numbers ({one_line(exc)})") from None
        if markers.ndim != 3 or markers.shape[2] != 3 or markers.shape[1] != len(labels):
            raise TrialError(
                f"{where}: marker array has shape {markers.shape}, expected (n_frames, {len(labels)}, 3) "
                f"for {len(labels)} labels"
            )
        bad = ~np.isfinite(markers).all(axis=2)  # a gap: all three coordinates NaN
        if bad.any() and not np.isnan(markers[bad]).all():
            markers = markers.copy() if adopt else markers
            markers.flags.writeable = True
            markers[bad] = np.nan
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

        if self.start_time is not None:
            try:
                start_time = float(self.start_time)
            except (TypeError, ValueError):
                raise TrialError(f"{where}: start time {self.start_time!r} is not a number") from None
            if not np.isfinite(start_time):
                raise TrialError(f"{where}: start time must be a finite number of seconds, got {start_time}")
            object.__setattr__(self, "start_time", start_time)
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
        if self.measurements is not None and not isinstance(self.measurements, SubjectMeasurements):
            raise TrialError(f"{where}: measurements must be a SubjectMeasurements, got "
                             f"{type(self.measurements).__name__}")
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
        """Time of each frame in seconds: from ``start_time`` where the file gave one, else counted from the
        first frame of the original recording (``first_frame / rate``)."""
        if self.start_time is not None:
            return self.start_time + np.arange(self.n_frames) / self.rate
        return (self.first_frame + np.arange(self.n_frames)) / self.rate

    def _index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            known = ", ".join(self.labels[:8])
            more = f" and {self.n_markers - 8} more" if self.n_markers > 8 else ""
            raise TrialError(
                f"{origin(self.source)}: no marker labelled {label!r} in this trial "
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
        return replace(self, labels=wanted, markers=self.markers[:, idx, :])

    def columns(self, labels: Sequence[str]) -> np.ndarray:
        """(F, len(labels), 3) the markers of `labels` in that order (m), NaN for those the trial does not show: trials
        of one session side by side over the labels of all of them."""
        out = np.full((self.n_frames, len(labels), 3), np.nan)
        have = [k for k, label in enumerate(labels) if label in self.labels]
        out[:, have] = self.markers[:, [self._index(labels[k]) for k in have], :]
        return out

    def of_subject(self, name: str) -> Trial:
        """The markers of subject `name` of a file holding several subjects (Vicon's ``Derrick:RASI``,
        ``Viktor:RASI``): its labels with the prefix removed, beside the labels that carry none; its model
        outputs likewise.  A trial without prefixed labels (one subject, its prefix removed on reading)
        comes back as it is.  TrialError with one line when no label carries `name`."""
        found = subject_prefixes(self.labels)
        if not found:
            return self
        if name not in found:
            raise TrialError(f"{origin(self.source)}: no labels of subject '{name}' (its subjects: "
                             f"{', '.join(found)}); give one of those")

        def own(label: str) -> str | None:
            """The label's name for subject `name`, or None when it belongs to another subject."""
            if ":" not in label:
                return label
            prefix, rest = label.split(":", 1)
            return rest.strip() if prefix.strip() == name and rest.strip() else None

        kept = [(i, n) for i, label in enumerate(self.labels) if (n := own(label)) is not None]
        if len({n for _, n in kept}) != len(kept):
            raise TrialError(f"{origin(self.source)}: subject '{name}' has a label that another marker also has "
                             "without the prefix; rename one in the capture software")
        outputs = {n: self.model_outputs[k] for k in self.model_outputs if (n := own(k)) is not None}
        return replace(self, labels=tuple(n for _, n in kept), markers=self.markers[:, [i for i, _ in kept], :],
                       model_outputs=outputs,
                       output_kinds={n: self.output_kinds[k] for k in self.output_kinds if (n := own(k)) in outputs},
                       output_units={n: self.output_units[k] for k in self.output_units if (n := own(k)) in outputs},
                       descriptions={n: self.descriptions[k] for k in self.descriptions if (n := own(k)) is not None})

    def frames(self, start: int, stop: int) -> Trial:
        """Frames ``start`` to ``stop - 1`` of this trial (0-based, relative to this trial's first frame)."""
        try:
            start, stop = operator.index(start), operator.index(stop)
        except TypeError:
            raise TrialError(
                f"{origin(self.source)}: frame numbers must be whole numbers, got {start!r}:{stop!r}"
            ) from None
        if not (0 <= start <= stop <= self.n_frames):
            raise TrialError(
                f"{origin(self.source)}: frames {start}:{stop} are outside this trial's 0:{self.n_frames}; "
                "choose start and stop with 0 <= start <= stop <= number of frames"
            )
        return replace(self, markers=self.markers[start:stop], first_frame=self.first_frame + start,
                       model_outputs={name: values[start:stop] for name, values in self.model_outputs.items()},
                       start_time=None if self.start_time is None else self.start_time + start / self.rate)

    def time_range(self, start: float, stop: float) -> Trial:
        """The frames from time `start` to `stop` (s, as ``times`` counts them), both ends taken to the nearest
        frame and kept, as OpenSim's tools read a setup's ``time_range``.  TrialError with one line when the range
        is reversed or lies wholly outside the trial."""
        start, stop = float(start), float(stop)
        times = self.times
        half = 0.5 / self.rate
        if not (np.isfinite(start) and np.isfinite(stop)) or stop < start:
            raise TrialError(f"{origin(self.source)}: time range {start:g} to {stop:g} s is not a range; give the "
                             "start first")
        if self.n_frames == 0 or stop < times[0] - half or start > times[-1] + half:
            span = f"{times[0]:g} to {times[-1]:g} s" if self.n_frames else "no frames"
            raise TrialError(f"{origin(self.source)}: time range {start:g} to {stop:g} s lies outside the trial "
                             f"({span}); check the setup's time_range against this trial")
        first = int(np.clip(np.rint((start - times[0]) * self.rate), 0, self.n_frames - 1))
        last = int(np.clip(np.rint((stop - times[0]) * self.rate), first, self.n_frames - 1))
        return self.frames(first, last + 1)


def check_input_file(path: Path) -> int:
    """Fail unless ``path`` is an existing, non-empty regular file; return its size in bytes."""
    if not path.exists():
        raise fail(path, "no such file", "check the path and file name")
    if path.is_dir():
        raise fail(path, "is a directory, not a trial file", "give the path of a .c3d, .trc, .tsv or .csv file")
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise fail(path, f"cannot be read ({one_line(exc.strerror or exc)})", "check the file permissions") from None
    if size == 0:
        raise fail(path, "file is empty", "export the trial again from your capture software")
    return size


def read_input_file(path: Path) -> bytes:
    """The bytes of the trial file at ``path`` (checked as check_input_file does); one TrialError line if
    it cannot be read."""
    check_input_file(path)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise fail(path, f"cannot be read ({one_line(exc.strerror or exc)})", "check the file permissions") from None


def output_target(path: str | os.PathLike[str], trial: Trial, units: str) -> tuple[Path, str, float]:
    """Check the output path, trial and units; return the path, normalised units and metres per unit."""
    path = Path(path)
    todo = "use mm, cm or m"
    key = str(units).strip().lower()
    scale = parse_units(units, path, todo)
    parent = path.parent
    if not parent.is_dir():
        raise fail(path, f"output directory {str(parent)!r} does not exist", "create it first or choose another path")
    if path.is_dir():
        raise fail(path, "is a directory", "give a file name to write the trial to")
    if not isinstance(trial, Trial):
        raise TypeError(f"expected a Trial, got {type(trial).__name__}")
    if trial.n_markers == 0 or trial.n_frames == 0:
        raise fail(
            path,
            f"cannot write a trial with {trial.n_frames} frames and {trial.n_markers} markers",
            "write a trial with at least one frame and one marker",
        )
    return path, key, scale


def write_staged(path: Path, kind: str, write: Callable[[Path], None],
                 errors: tuple[type[Exception], ...] = (OSError,)) -> None:
    """Write a trial file through `write` (given a staged file beside `path`; calibrate.io.outputs.write_all:
    all or nothing); a failure among `errors` becomes one TrialError line naming the `kind` of file."""
    try:
        write_all({path: write})
    except errors as exc:
        raise fail(path, f"could not write the {kind} file ({one_line(exc) or type(exc).__name__})",
                   "check the directory is writable and has free space") from None
