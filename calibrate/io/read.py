"""read_trial: a trial by its file's extension (C3D, TRC, Qualisys QTM's .tsv, OptiTrack Motive's .csv)."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from calibrate.io.c3d import read_c3d
from calibrate.io.tables import read_motive_csv, read_qtm_tsv
from calibrate.io.trc import read_trc
from calibrate.io.trial import Trial, fail
from calibrate.io.vicon import axes_as_outputs, segment_axes


def read_trial(path: str | os.PathLike[str], *, strip_prefix: bool = True,
               progress: Callable[[float], None] | None = None) -> Trial:
    """Read a trial from a .c3d, .trc, .tsv (Qualisys QTM's 3D export) or .csv (OptiTrack Motive's export) file,
    chosen by the file suffix.

    ``strip_prefix``: remove a subject prefix shared by the labels (``Sub01:RASI`` -> ``RASI``),
    see :func:`strip_subject_prefix`.  ``progress(share of the rows read)``: a text file's reading
    (a C3D file is read by ezc3d in one call).  Segment axes a modelling program wrote among the markers under
    names of its own (:func:`calibrate.io.vicon.segment_axes`) go to the trial's model outputs, as Plug-in Gait's do.
    """
    suffix = Path(path).suffix.lower()
    readers = {".c3d": lambda: read_c3d(path, strip_prefix=strip_prefix),
               ".trc": lambda: read_trc(path, strip_prefix=strip_prefix, progress=progress),
               ".tsv": lambda: read_qtm_tsv(path, strip_prefix=strip_prefix, progress=progress),
               ".csv": lambda: read_motive_csv(path, strip_prefix=strip_prefix, progress=progress)}
    if suffix in readers:
        trial = readers[suffix]()
        axes = segment_axes(trial.labels, trial.markers)
        if axes and len(axes) == trial.n_markers:
            raise fail(path, "holds only segment axes a modelling program wrote (<segment>O, A, L, P), no markers",
                       "export the trial with its markers")
        return axes_as_outputs(trial, axes)
    raise fail(
        path,
        f"unknown trial file type {Path(path).suffix or '(no suffix)'!r}",
        "give a .c3d or .trc file (or a Qualisys .tsv, an OptiTrack Motive .csv export)",
    )
