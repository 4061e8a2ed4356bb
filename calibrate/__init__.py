"""calibrate: subject-specific human models from one motion-capture trial."""

from __future__ import annotations

__version__ = "0.1.0"
