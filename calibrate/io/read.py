"""read_trial: a trial by its file's extension (C3D, TRC, Qualisys QTM's .tsv, OptiTrack Motive's .csv)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from calibrate.io.c3d import read_c3d
from calibrate.io.tables import read_motive_csv, read_qtm_tsv
from calibrate.io.trc import read_trc
from calibrate.io.trial import Trial, fail


def read_trial(path: str | os.PathLike[str], *, strip_prefix: bool = True,
               progress: Callable[[float], None] | None = None) -> Trial:
    """Read a trial from a .c3d, .trc, .tsv (Qualisys QTM's 3D export) or .csv (OptiTrack Motive's export) file,
    chosen by the file suffix.

    ``strip_prefix``: remove a subject prefix shared by the labels (``Sub01:RASI`` -> ``RASI``),
    see :func:`strip_subject_prefix`.  ``progress(share of the rows read)``: a text file's reading
    (a C3D file is read by ezc3d in one call).
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".c3d":
        return read_c3d(path, strip_prefix=strip_prefix)
    if suffix == ".trc":
        return read_trc(path, strip_prefix=strip_prefix, progress=progress)
    if suffix == ".tsv":
        return read_qtm_tsv(path, strip_prefix=strip_prefix, progress=progress)
    if suffix == ".csv":
        return read_motive_csv(path, strip_prefix=strip_prefix, progress=progress)
    raise fail(
        path,
        f"unknown trial file type {Path(path).suffix or '(no suffix)'!r}",
        "give a .c3d or .trc file (or a Qualisys .tsv, an OptiTrack Motive .csv export)",
    )
