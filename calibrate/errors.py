"""Error types: every user-facing failure is one of these, carrying one clear line.

The CLI prints ``calibrate: error: <message>`` and exits with status 2 for any
:class:`CalibrateError`; Python users catch the same classes.  Messages name the
file (or argument), say what is wrong, and say what to do.
"""

from __future__ import annotations

from pathlib import Path


class CalibrateError(Exception):
    """Base class: a problem with the user's input that they can fix."""


class ModelError(CalibrateError):
    """A model (URDF) file that cannot be used: unreadable, or outside the model format."""


class NoMarkersError(ModelError):
    """An OpenSim model without markers on its bodies (its marker set comes in a MarkerSet file)."""


class TrialError(CalibrateError):
    """A motion-capture trial (C3D/TRC) that cannot be read or written."""


def read_text_file(path: Path, what: str) -> str:
    """The text of a model file, or one ModelError line saying what is wrong and to give `what`."""
    if not path.exists():
        raise ModelError(f"{path}: no such file; check the path to {what}")
    if path.is_dir():
        raise ModelError(f"{path}: is a directory; give {what}")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ModelError(f"{path}: cannot read ({e}); give {what} as a text file") from None
    if not text.strip():
        raise ModelError(f"{path}: empty file; give {what}")
    return text
