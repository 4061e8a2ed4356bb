"""TRC trials (OpenSim's marker format): read and written, units at the edge."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from calibrate.io.trial import (
    Trial,
    check_input_file,
    fail,
    file_labels,
    one_line,
    output_target,
    parse_units,
    write_staged,
)
from calibrate.io.vicon import is_model_output

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


def read_trc(path: str | os.PathLike[str], *, strip_prefix: bool = True,
             progress: Callable[[float], None] | None = None) -> Trial:
    """Read an OpenSim-style TRC marker file into a trial in metres; blank (or NaN) cells are gaps, and so
    is a marker written as exactly 0, 0, 0 (as several exporters write a marker they did not see: the
    Hamner running trial of OpenSim's models repository holds L.Bicep so for all its 600 frames).

    Tab-separated, as OpenSim reads and writes it: line 2 the header keys, line 3 their values
    (``DataRate`` and ``Units`` required; ``Units`` mm, cm or m, also spelt out), line 4
    ``Frame#``, ``Time`` and one label every three columns (labels may contain spaces and
    dots), line 5 the X/Y/Z names, data from line 6 on (blank lines skipped).  A subject
    prefix shared by the labels is removed unless ``strip_prefix`` is False.  Columns with a
    Plug-in Gait output name (:func:`is_model_output`) go to :attr:`Trial.model_outputs`.
    The file is read line by line, twice (count, then parse): a long trial's marker array is
    the only copy of it held.  ``progress(share of the rows parsed)`` every 1000 rows.
    """
    path = Path(path)
    check_input_file(path)
    for encoding in ("utf-8-sig", "latin-1"):
        try:
            return _read_trc(path, encoding, strip_prefix, progress)
        except UnicodeDecodeError:
            continue
    raise AssertionError("latin-1 decodes any bytes")  # pragma: no cover


def text_lines(path: Path, encoding: str) -> Iterator[tuple[int, str]]:
    """(0-based line number, text without its line end) of every line of `path`."""
    try:
        with open(path, encoding=encoding, newline=None) as fh:
            for number, line in enumerate(fh):
                yield number, line.rstrip("\n")
    except OSError as exc:
        raise fail(path, f"cannot be read ({one_line(exc.strerror or exc)})", "check the file permissions") from None


def _read_trc(path: Path, encoding: str, strip_prefix: bool, progress: Callable[[float], None] | None) -> Trial:
    redo = "export the TRC file again"
    binary = fail(path, "not a TRC text file (it contains binary data)", redo)
    # Pass 1: the header's five lines, then how many data rows follow (blank lines skipped).
    lines: list[str] = []
    n_rows = n_lines = 0
    for number, line in text_lines(path, encoding):
        if "\x00" in line:
            raise binary
        n_lines = number + 1 if line.strip() else n_lines
        if number < 5:
            lines.append(line)
        elif line.strip():
            n_rows += 1
    lines = lines[:n_lines]
    if len(lines) < 5:
        raise fail(path, f"not a TRC file ({len(lines)} line(s), a TRC header needs 5)", redo)
    if not lines[0].lstrip().startswith("PathFileType"):
        raise fail(path, "not a TRC file (line 1 should start with PathFileType)", redo)

    keys = [cell.strip() for cell in lines[1].split("\t") if cell.strip()]
    values = [cell.strip() for cell in lines[2].split("\t")]
    filled = [v for v in values if v]
    if len(filled) == len(keys) and len(values) != len(keys):  # values padded with empty fields (some exporters)
        values = filled
    values = values[: len(keys)] + [""] * (len(keys) - len(values))
    meta = dict(zip(keys, values, strict=True))
    for key in ("DataRate", "Units"):
        if not meta.get(key):
            raise fail(path, f"TRC header has no {key} value (lines 2-3)", redo)
    try:
        rate = float(meta["DataRate"])
    except ValueError:
        raise fail(path, f"TRC DataRate {meta['DataRate']!r} is not a number", redo) from None
    if not np.isfinite(rate) or rate <= 0:
        raise fail(path, f"TRC DataRate must be a positive number of frames per second, got {meta['DataRate']}", redo)
    scale = parse_units(meta["Units"], path, "set Units in the TRC header to mm, cm or m", reading=True)

    def header_int(key: str) -> int | None:
        if not meta.get(key):
            return None
        try:
            return int(float(meta[key]))
        except (ValueError, OverflowError):
            raise fail(path, f"TRC {key} {meta[key]!r} is not a number", redo) from None

    num_markers = header_int("NumMarkers")
    num_frames = header_int("NumFrames")

    label_cells = lines[3].split("\t")
    # "Times" as some exporters write it (AddBiomechanics' test trials); OpenSim's reader wants "Time"
    if len(label_cells) < 2 or label_cells[0].strip() != "Frame#" or label_cells[1].strip().lower() not in ("time",
                                                                                                          "times"):
        raise fail(path, "TRC line 4 should start with Frame# and Time", redo)
    marker_cells = label_cells[2:]
    misplaced = [cell.strip() for i, cell in enumerate(marker_cells) if i % 3 and cell.strip()]
    named = [cell for cell in marker_cells if cell.strip()]
    if misplaced and (num_markers is None or len(named) != num_markers):
        raise fail(
            path,
            f"TRC line 4 has marker labels out of step with the X/Y/Z columns (near {misplaced[0]!r})",
            redo,
        )
    # Labels one tab apart rather than three: taken in order, as OpenSim's reader takes them, when they are as many as
    # the header's NumMarkers (each row's values are then checked against that count).
    raw_labels = named if misplaced else marker_cells[0::3]
    while raw_labels and not raw_labels[-1].strip():
        raw_labels.pop()
    n_markers = len(raw_labels)
    if num_markers is not None and num_markers != n_markers:
        raise fail(path, f"TRC header says NumMarkers {num_markers} but line 4 names {n_markers} markers", redo)
    if n_markers == 0:
        raise fail(path, "TRC file names no markers", "export the trial with its markers")
    (labels,) = file_labels([raw_labels], strip=strip_prefix)

    width = 2 + 3 * n_markers
    if n_rows == 0:
        raise fail(path, "TRC file contains no frames", "export the trial again with its frames")
    if num_frames is not None and num_frames != n_rows:
        raise fail(
            path,
            f"TRC header says NumFrames {num_frames} but the file has {n_rows} data rows (truncated?)",
            redo,
        )
    kinds = {i: kind for i, label in enumerate(labels) if (kind := is_model_output(label)) is not None}
    keep = [i for i in range(n_markers) if i not in kinds]
    if not keep:
        raise fail(path, "TRC file holds only model outputs (PELO, LFEO, ...), no markers",
                    "export the trial with its markers")
    # Pass 2: each row parsed straight into the marker array (metres) and the model outputs' columns.
    markers = np.empty((n_rows, len(keep), 3))
    outputs = {i: np.empty((n_rows, 3)) for i in kinds}
    keep_cols = (2 + 3 * np.asarray(keep)[:, None] + np.arange(3)).ravel()
    first_number = np.nan
    first_time = None  # the Time column's first value (OpenSim's time ranges count from it)
    r = 0
    for number, line in text_lines(path, encoding):
        if number < 5 or not line.strip():
            continue
        cells = [cell.strip() for cell in line.split("\t")]
        if len(cells) > width:
            if any(cells[width:]):
                raise fail(path, f"line {number + 1} has more values than the {n_markers} markers named in the header",
                           redo)
            cells = cells[:width]
        cells += [""] * (width - len(cells))
        try:
            row = np.array([float(cell) if cell else np.nan for cell in cells])
        except ValueError:
            column = next(i for i, cell in enumerate(cells) if cell and not _is_number(cell))
            raise fail(
                path,
                f"line {number + 1}, column {column + 1}: {cells[column]!r} is not a number",
                "fix that cell or export the file again",
            ) from None
        if r == 0:
            first_number = row[0]
            if not np.isfinite(first_number) or first_number != int(first_number):
                raise fail(path, f"line {number + 1}: Frame# should be a whole number, got {cells[0]!r}", redo)
            first_time = float(row[1]) if np.isfinite(row[1]) else None
        markers[r] = (row[keep_cols] * scale).reshape(len(keep), 3)
        for i, out in outputs.items():
            out[r] = row[2 + 3 * i:5 + 3 * i]
        r += 1
        if progress is not None and r % 1000 == 0:
            progress(r / n_rows)
    markers[(markers == 0.0).all(axis=2)] = np.nan  # the C3D reader's rule too (calibrate.io.c3d)
    markers.flags.writeable = False  # the trial takes it over rather than copies it
    return Trial(
        labels=tuple(labels[i] for i in keep),
        markers=markers,
        rate=rate,
        first_frame=max(int(first_number) - 1, 0),
        source=str(path),
        start_time=first_time,
        model_outputs={labels[i]: outputs[i] * (scale if kind == "point" else 1.0) for i, kind in kinds.items()},
        output_kinds={labels[i]: kind for i, kind in kinds.items()},
        output_units={labels[i]: "m" if kind == "point" else "file units" for i, kind in kinds.items()},
    )


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def write_trc(path: str | os.PathLike[str], trial: Trial, units: str = "mm") -> None:
    """Write a trial to an OpenSim-style TRC file in ``units``; gaps are empty cells.

    Frame numbers are 1-based (``first_frame + 1`` onwards), times in seconds.
    The file is written next to its target and then moved into place.
    """
    path, key, scale = output_target(path, trial, units)
    bad = [label for label in trial.labels if any(ch in label for ch in "\t\r\n")]
    if bad:
        raise fail(path, f"marker label {bad[0]!r} contains a tab or line break", "rename the marker")
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

    def write(staged: Path) -> None:
        with open(staged, "w", encoding="utf-8", newline="\n") as fh:
            fh.write("\n".join(head) + "\n")
            for i, row in enumerate(rows):
                cells = "\t".join("" if v != v else format(v, spec) for v in row)  # v != v: NaN, a gap
                fh.write(f"{trial.first_frame + i + 1}\t{times[i]:.9g}\t{cells}\n")

    write_staged(path, "TRC", write)
