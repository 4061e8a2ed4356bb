"""Small shared helpers for text files: exact number formatting, strict number reading, atomic writes."""

from __future__ import annotations

import re
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


_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def finite_numbers(text: str | None) -> list[float] | None:
    """The whitespace-separated numbers of `text` as a C or C++ reader takes them (URDF, OpenSim), or None if one is
    not such a number or not finite: Python's float() also takes '1_000', 'nan' and 'inf', and '1e999' as inf."""
    values = []
    for token in (text or "").split():
        if not _NUMBER.fullmatch(token):
            return None
        values.append(float(token))
    return values if np.all(np.isfinite(values)) else None


def atomic_write_text(path: Path, text: str) -> None:
    """Write `text` to `path` all or nothing (calibrate.io.outputs.write_text): a failure part-way
    leaves `path` as it was (absent or the old content), never half-written."""
    write_text(path, text)
