"""Marker tables exported by the capture programs themselves: Qualisys QTM's 3D ``.tsv`` and OptiTrack Motive's
``.csv``, read into a trial in metres.

Both programs also export C3D, which keeps more (analog data, the lab's parameters); these readers are for the
labs whose pipelines keep the text exports.  Layouts as the vendors document them (QTM manual, "Motion data
(.tsv)"; Motive documentation, "Data Export: CSV"):

- QTM: header lines ``KEY<tab>value`` (``NO_OF_FRAMES``, ``FREQUENCY``, ``DATA_INCLUDED 3D``, ``MARKER_NAMES``
  ..., written when "Include TSV header" is on), an optional column row (``Frame Time NAME X NAME Y NAME Z``),
  then one row per frame: frame number and time when exported, three coordinates per marker, in mm.
- Motive: line 1 ``Format Version,1.2x,...,Export Frame Rate,120,...,Length Units,Millimeters,...``, then rows
  ``,Type,...`` / ``,Name,...`` / ``,ID,...`` (and ``,Parent,...``), ``,,Position,...`` and
  ``Frame,Time (Seconds),X,Y,Z,...``; one row per frame.  Only physical markers (type ``Marker``) are read: a
  rigid body's or skeleton's "marker constraints" are where the asset expects its markers, not measurements.

In both, an empty cell (Motive's occlusion, QTM's missing data) or a marker at exactly 0, 0, 0 (QTM's older
missing data) is a gap.  The files are read line by line, twice (layout, then values): the marker array is the
only copy of a long trial held.
"""

from __future__ import annotations

import csv
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from calibrate.io.trc import text_lines
from calibrate.io.trial import Trial, check_input_file, fail, file_labels, parse_units

_QTM_REDO = "export the 3D data to TSV again from QTM (with 'Include TSV header' on), or export the trial to C3D"
_MOTIVE_REDO = "export the take to CSV again from Motive (with the header and markers on), or export it to C3D"
_QTM_KEY = re.compile(r"[A-Z][A-Z0-9_]*")
_MISSING = ("", "null", "nan", "-nan")


def read_qtm_tsv(path: str | os.PathLike[str], *, strip_prefix: bool = True,
                 progress: Callable[[float], None] | None = None) -> Trial:
    """Read Qualisys QTM's 3D ``.tsv`` export into a trial in metres (the file's millimetres).

    Needs the TSV header (``MARKER_NAMES`` and ``FREQUENCY``); a 2D or 6DOF export is refused with what to
    export instead.  The frame number and time columns are read where the file has them (``Frame``/``Time``
    column row, or rows two values longer than three per marker); the first frame's number (QTM counts from 1)
    and time become :attr:`Trial.first_frame` and :attr:`Trial.start_time`.  ``NO_OF_FRAMES`` and
    ``NO_OF_MARKERS`` are checked against the rows and names.  ``progress(share of the rows parsed)`` every 1000
    rows.
    """
    path = Path(path)
    check_input_file(path)
    return _with_encoding(path, lambda enc: _read_qtm(path, enc, strip_prefix, progress))


def read_motive_csv(path: str | os.PathLike[str], *, strip_prefix: bool = True,
                    progress: Callable[[float], None] | None = None) -> Trial:
    """Read OptiTrack Motive's ``.csv`` export into a trial in metres.

    Units from ``Length Units`` (Millimeters, Centimeters or Meters; Motive's own metres where the line does not
    say), rate from ``Export Frame Rate`` (else ``Capture Frame Rate``).  Every physical marker's three
    ``Position`` columns are read (labelled ``Skeleton:LASI``, whose shared prefix is removed unless
    ``strip_prefix`` is False, or unlabelled ``Unlabeled 1000``); rigid bodies, bones and their marker
    constraints are not markers and are left out.  ``progress(share of the rows parsed)`` every 1000 rows.
    """
    path = Path(path)
    check_input_file(path)
    return _with_encoding(path, lambda enc: _read_motive(path, enc, strip_prefix, progress))


def _with_encoding(path: Path, read: Callable[[str], Trial]) -> Trial:
    for encoding in ("utf-8-sig", "latin-1"):
        try:
            return read(encoding)
        except UnicodeDecodeError:
            continue
    raise AssertionError("latin-1 decodes any bytes")  # pragma: no cover


def _lines(path: Path, encoding: str) -> Iterator[tuple[int, str]]:
    """(0-based line number, text without its line end) of every line of `path`; binary content refused."""
    for number, line in text_lines(path, encoding):
        if "\x00" in line:
            raise fail(path, "not a text file (it contains binary data)",
                       "give the .tsv or .csv text export, or the trial's .c3d file")
        yield number, line


def _number(cell: str) -> float:
    """A cell's value; NaN for a missing one (empty, NULL, NaN)."""
    cell = cell.strip()
    if cell.lower() in _MISSING:
        return np.nan
    return float(cell)


def _is_number(cell: str) -> bool:
    try:
        _number(cell)
    except ValueError:
        return False
    return True


def _parse_row(path: Path, number: int, cells: list[str], columns: list[int], redo: str) -> np.ndarray:
    """The values of `cells` at `columns` (missing cells past the row's end: gaps); one line naming the cell that
    is not a number."""
    if len(cells) > columns[-1]:  # the common row: every cell there, each a number or empty
        try:
            return np.array([float(c) if c.strip() else np.nan for c in (cells[j] for j in columns)])
        except ValueError:
            pass
    values = np.empty(len(columns))
    for k, j in enumerate(columns):
        cell = cells[j] if j < len(cells) else ""
        try:
            values[k] = _number(cell)
        except ValueError:
            raise fail(path, f"line {number + 1}, column {j + 1}: {cell.strip()!r} is not a number",
                       "fix that cell or " + redo) from None
    return values


def _rate(path: Path, text: str, what: str, redo: str) -> float:
    try:
        rate = float(text)
    except ValueError:
        raise fail(path, f"{what} {text!r} is not a number of frames per second", redo) from None
    if not np.isfinite(rate) or rate <= 0:
        raise fail(path, f"{what} must be a positive number of frames per second, got {text}", redo)
    return rate


def _finish(path: Path, raw_labels: list[str], markers: np.ndarray, rate: float, first: float | None,
            time0: float | None, strip_prefix: bool, one_based: bool) -> Trial:
    """The trial: gaps where a marker reads exactly 0, 0, 0; labels made unique (and their shared prefix removed);
    the first frame's number from the file's frame column (`one_based`: the file counts frames from 1)."""
    markers[(markers == 0.0).all(axis=2)] = np.nan
    markers.flags.writeable = False  # the trial takes it over rather than copies it
    (labels,) = file_labels([raw_labels], strip=strip_prefix)
    first_frame = 0
    if first is not None and np.isfinite(first) and first == int(first):
        first_frame = max(int(first) - (1 if one_based else 0), 0)
    return Trial(labels=labels, markers=markers, rate=rate, first_frame=first_frame, source=str(path),
                 start_time=time0 if time0 is not None and np.isfinite(time0) else None)


def _read_qtm(path: Path, encoding: str, strip_prefix: bool, progress: Callable[[float], None] | None) -> Trial:
    redo = _QTM_REDO
    meta: dict[str, list[str]] = {}
    column_row: list[str] | None = None
    first_row: list[str] | None = None
    start = n_rows = 0
    for number, line in _lines(path, encoding):
        if not line.strip():
            continue
        cells = line.split("\t")
        head = cells[0].strip()
        if first_row is None:
            if column_row is None and _QTM_KEY.fullmatch(head):
                meta.setdefault(head, [c.strip() for c in cells[1:]])
                continue
            if column_row is None and head.lower() == "frame":
                column_row = [c.strip() for c in cells]
                continue
            if not _is_number(head):
                if number == 0:
                    raise fail(path, "not a Qualisys QTM TSV export (line 1 is neither a header line such as "
                                     "NO_OF_FRAMES nor a row of numbers)", "give QTM's 3D .tsv export, or the "
                                     "trial's .c3d file")
                raise fail(path, f"line {number + 1}: {head!r} is neither a TSV header line nor a row of numbers",
                           redo)
            first_row, start = cells, number
        n_rows += 1
    kind = (meta.get("DATA_INCLUDED") or [""])[0].upper()
    if kind and kind != "3D":
        what = {"2D": "QTM's 2D camera data", "6D": "QTM's 6DOF rigid-body data"}.get(kind, f"{kind} data")
        raise fail(path, f"holds {what} (DATA_INCLUDED {kind}), not 3D marker positions", redo)
    names = list(meta.get("MARKER_NAMES", []))
    while names and not names[-1]:
        names.pop()
    if not names:
        raise fail(path, "has no MARKER_NAMES line (a TSV exported without its header names no marker)", redo)
    n = len(names)
    if "NO_OF_MARKERS" in meta:
        count = (meta["NO_OF_MARKERS"] or [""])[0]
        if count != str(n) and (not _is_number(count) or _number(count) != n):
            raise fail(path, f"NO_OF_MARKERS says {count} but MARKER_NAMES names {n} markers", redo)
    if first_row is None:
        raise fail(path, "contains no frames", "export the trial again with its frames")
    if "NO_OF_FRAMES" in meta:
        count = (meta["NO_OF_FRAMES"] or [""])[0]
        if _is_number(count) and _number(count) != n_rows:
            raise fail(path, f"NO_OF_FRAMES says {count} but the file has {n_rows} rows of data (truncated?)", redo)
    # Where the coordinates start: after the column row's Frame and Time (and any other leading column), else
    # after two values where the rows are two longer than three per marker (a missing marker's cells are empty, not
    # left out, so the first row's length tells).
    if column_row is not None:
        first_x = f"{names[0]} X"
        if first_x not in column_row:
            raise fail(path, f"the column row names no {first_x!r} column (MARKER_NAMES' first marker)", redo)
        offset = column_row.index(first_x)
        frame_col = 0 if column_row[0].lower() == "frame" else None
        time_col = next((j for j in range(offset) if column_row[j].lower() == "time"), None)
    else:
        width = len(first_row)  # (a row may end in a tab: one empty cell more)
        if width in (3 * n + 2, 3 * n + 3):
            offset, frame_col, time_col = 2, 0, 1
        elif width in (3 * n, 3 * n + 1):
            offset, frame_col, time_col = 0, None, None
        else:
            raise fail(path, f"line {start + 1} has {width} values, not 3 per marker of MARKER_NAMES' {n} "
                             "(and a frame and time)", redo)
    freq = (meta.get("FREQUENCY") or [""])[0]
    rate = None if freq.upper() in ("EXT", "") else _rate(path, freq, "FREQUENCY", redo)
    cols = list(range(offset, offset + 3 * n))
    lead = [c for c in (frame_col, time_col) if c is not None]
    markers = np.empty((n_rows, n, 3))
    leads = np.empty((n_rows, len(lead)))
    r = 0
    for number, line in _lines(path, encoding):
        if number < start or not line.strip():
            continue
        cells = line.split("\t")
        if len(cells) > offset + 3 * n and any(c.strip() for c in cells[offset + 3 * n:]):
            raise fail(path, f"line {number + 1} has more values than the {n} markers MARKER_NAMES names", redo)
        markers[r] = _parse_row(path, number, cells, cols, redo).reshape(n, 3) * 1e-3
        leads[r] = _parse_row(path, number, cells, lead, redo) if lead else leads[r]
        r += 1
        if progress is not None and r % 1000 == 0:
            progress(r / n_rows)
    times = leads[:, lead.index(time_col)] if time_col is not None else None
    if rate is None:  # an external timebase (FREQUENCY EXT): the Time column's steps
        steps = np.diff(times) if times is not None else np.array([])
        steps = steps[np.isfinite(steps) & (steps > 0)]
        if not steps.size:
            raise fail(path, f"FREQUENCY is {freq or 'missing'} and there is no Time column to take the rate from",
                       "export it again with the time column, or give the trial's .c3d file")
        rate = 1.0 / float(np.median(steps))
    first = float(leads[0, 0]) if frame_col is not None else None
    return _finish(path, names, markers, rate, first, None if times is None else float(times[0]), strip_prefix,
                   one_based=True)


def _csv_rows(path: Path, encoding: str) -> Iterator[tuple[int, list[str]]]:
    """(0-based line number, cells) of every non-blank line of a CSV file."""
    for number, line in _lines(path, encoding):
        if line.strip():
            yield number, next(csv.reader([line])) if '"' in line else line.split(",")


def _read_motive(path: Path, encoding: str, strip_prefix: bool, progress: Callable[[float], None] | None) -> Trial:
    redo = _MOTIVE_REDO
    rows: dict[str, list[str]] = {}
    axis_row: list[str] | None = None
    meta: dict[str, str] | None = None
    start = n_rows = 0
    for number, cells in _csv_rows(path, encoding):
        if meta is None:
            if cells[0].strip() == "time" and "root_x" in (c.strip() for c in cells):
                raise fail(path, "is a motion CSV (a model's coordinates, as calibrate writes them), not marker "
                                 "positions", "give the trial's marker file (.c3d, .trc, or Motive's .csv export)")
            if cells[0].strip() != "Format Version":
                raise fail(path, "not an OptiTrack Motive CSV export (line 1 should start with 'Format Version')",
                           "give Motive's .csv export, a Qualisys .tsv, or the trial's .c3d or .trc file")
            meta = {cells[i].strip(): cells[i + 1].strip() for i in range(0, len(cells) - 1, 2)}
            continue
        if axis_row is None:
            key = cells[1].strip() if len(cells) > 1 else ""
            if cells[0].strip() == "Frame":
                axis_row, start = [c.strip() for c in cells], number + 1
            elif key in ("Type", "Name", "ID", "Parent") or (not cells[0].strip() and not key):
                rows[key or "component"] = [c.strip() for c in cells]
            else:
                raise fail(path, f"line {number + 1}: {cells[0].strip()!r} where the header's rows (Type, Name, ID, "
                                 "Position, then Frame and Time) should be", redo)
        else:
            n_rows += 1
    if meta is None or axis_row is None:
        raise fail(path, "has no 'Frame,Time (Seconds),X,Y,Z,...' line", redo)
    if "Type" not in rows or "Name" not in rows:
        raise fail(path, "has no Type and Name lines (a CSV exported without its header names no marker)", redo)

    def cell(row: str, j: int) -> str:
        got = rows.get(row, [])
        return got[j] if j < len(got) else ""

    # Each physical marker's Position X, Y, Z: three columns side by side under one name.
    names: list[str] = []
    columns: list[int] = []
    others: set[str] = set()
    j = 0
    while j < len(axis_row):
        kind = cell("Type", j)
        if kind == "Marker" and cell("component", j) == "Position" and axis_row[j:j + 3] == ["X", "Y", "Z"] \
                and cell("Name", j) == cell("Name", j + 1) == cell("Name", j + 2):
            names.append(cell("Name", j))
            columns += [j, j + 1, j + 2]
            j += 3
            continue
        if kind not in ("", "Type", "Marker"):
            others.add(kind)
        j += 1
    if not names:
        held = f" (it holds {', '.join(sorted(others))} columns only)" if others else ""
        raise fail(path, f"has no marker positions{held}", "export the take again with Markers on, or export it to C3D")
    if n_rows == 0:
        raise fail(path, "contains no frames", "export the take again with its frames")
    total = meta.get("Total Exported Frames", "")
    if _is_number(total) and _number(total) != n_rows:
        raise fail(path, f"line 1 says Total Exported Frames {total} but the file has {n_rows} rows of data "
                         "(truncated?)", redo)
    rate_key = next((k for k in ("Export Frame Rate", "Capture Frame Rate") if meta.get(k)), None)
    if rate_key is None:
        raise fail(path, "line 1 gives no Export Frame Rate or Capture Frame Rate", redo)
    rate = _rate(path, meta[rate_key], rate_key, redo)
    units = meta.get("Length Units")
    scale = parse_units(units, path, "export it again in Millimeters or Meters", reading=True) if units else 1.0
    time_col = next((k for k, c in enumerate(axis_row) if c.lower().startswith("time") and c.lower() != "timecode"),
                    None)
    lead = [0] + ([time_col] if time_col is not None else [])
    n = len(names)
    markers = np.empty((n_rows, n, 3))
    leads = np.empty((n_rows, len(lead)))
    r = 0
    for number, cells in _csv_rows(path, encoding):
        if number < start:
            continue
        markers[r] = _parse_row(path, number, cells, columns, redo).reshape(n, 3) * scale
        leads[r] = _parse_row(path, number, cells, lead, redo)
        r += 1
        if progress is not None and r % 1000 == 0:
            progress(r / n_rows)
    if not units and np.nanmax(np.abs(markers), initial=0.0) > 100.0:
        raise fail(path, f"line 1 gives no Length Units and the markers reach {np.nanmax(np.abs(markers)):.0f} "
                         "(more than 100 m in Motive's metres)", "export it again with Length Units set")
    return _finish(path, names, markers, rate, float(leads[0, 0]),
                   float(leads[0, 1]) if time_col is not None else None, strip_prefix, one_based=False)

