"""read_trial: a C3D or TRC trial by its file's extension."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from calibrate.io.c3d import read_c3d
from calibrate.io.trc import read_trc
from calibrate.io.trial import Trial, fail


def read_trial(path: str | os.PathLike[str], *, strip_prefix: bool = True,
               progress: Callable[[float], None] | None = None) -> Trial:
    """Read a trial from a .c3d or .trc file, chosen by the file suffix.

    ``strip_prefix``: remove a subject prefix shared by the labels (``Sub01:RASI`` -> ``RASI``),
    see :func:`strip_subject_prefix`.  ``progress(share of the rows read)``: a TRC file's reading
    (a C3D file is read by ezc3d in one call).
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".c3d":
        return read_c3d(path, strip_prefix=strip_prefix)
    if suffix == ".trc":
        return read_trc(path, strip_prefix=strip_prefix, progress=progress)
    raise fail(
        path,
        f"unknown trial file type {Path(path).suffix or '(no suffix)'!r}",
        "give a .c3d or .trc file",
    )
