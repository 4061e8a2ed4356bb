"""Small shared helpers for writing text files: exact number formatting, atomic writes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .outputs import write_text


def fmt_float(x: float) -> str:
    """Shortest text that reads back to the same float (round-trip exact); '0' for ±0."""
    r = repr(float(x))
    return "0" if r in ("0.0", "-0.0") else r


def fmt_vec(v) -> str:
    """Space-separated round-trip-exact floats, as URDF attributes want them."""
    return " ".join(fmt_float(x) for x in np.ravel(v))


def atomic_write_text(path: Path, text: str) -> None:
    """Write `text` to `path` all or nothing (calibrate.io.outputs.write_text): a failure part-way
    leaves `path` as it was (absent or the old content), never half-written."""
    write_text(path, text)
