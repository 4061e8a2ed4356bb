"""Error types: every user-facing failure is one of these, carrying one clear line.

The CLI prints ``calibrate: error: <message>`` and exits with status 2 for any
:class:`CalibrateError`; Python users catch the same classes.  Messages name the
file (or argument), say what is wrong, and say what to do.
"""

from __future__ import annotations


class CalibrateError(Exception):
    """Base class: a problem with the user's input that they can fix."""


class ModelError(CalibrateError):
    """A model (URDF) file that cannot be used: unreadable, or outside the model format."""


class TrialError(CalibrateError):
    """A motion-capture trial (C3D/TRC) that cannot be read or written."""
