"""Argument types of the command line: each checks one value and says what is wrong with it."""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from ..errors import CalibrateError


def int_at_least(least: int) -> Callable[[str], int]:
    """An argparse type: a whole number >= `least`."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
        if v < least:
            raise argparse.ArgumentTypeError(f"need at least {least}, got {v}")
        return v
    return parse


positive_int = int_at_least(2)  # frame counts and the like


def lock_arg(text: str) -> dict[str, float]:
    """'subtalar_r,ankle_l=10' -> {'subtalar_r': 0.0, 'ankle_l': 10.0} (degrees)."""
    out: dict[str, float] = {}
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        name, _, deg = item.partition("=")
        try:
            out[name.strip()] = float(deg) if deg.strip() else 0.0
        except ValueError:
            raise CalibrateError(f"--lock {text}: '{deg}' is not an angle in degrees (use DOF or DOF=DEG)") from None
    return out


def _number(text: str, convert, ok, rule: str, expected: str = "a number", shown=None) -> float | int:
    """`text` converted (`convert`: float, int, ...) and satisfying `ok`, else argparse's one-line error
    ('expected <expected>, got ...' or 'must be <rule>, got <shown or text>')."""
    try:
        v = convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {expected}, got '{text}'") from None
    if not ok(v):
        raise argparse.ArgumentTypeError(f"must be {rule}, got {text if shown is None else shown(v)}")
    return v


def positive_float(text: str) -> float:
    return _number(text, float, lambda v: v > 0 and np.isfinite(v), "positive")


def nonneg_float(text: str) -> float:
    return _number(text, float, lambda v: v >= 0 and np.isfinite(v), "zero or positive")


def count_arg(text: str) -> int:
    return _number(text, int, lambda v: v >= 0, "zero or positive", "a whole number", shown=str)


def height_arg(text: str) -> float:
    from ..simulation.simulate import HEIGHT_RANGE

    lo, hi = HEIGHT_RANGE
    return _number(text, float, lambda v: lo <= v <= hi, f"a stature of {lo:g}-{hi:g} m", "a stature in metres")


def fraction_arg(text: str) -> float:
    return _number(text, lambda t: float(t[:-1]) / 100 if t.endswith("%") else float(t), lambda v: 0 <= v <= 0.5,
                   "a fraction of 0-0.5 (0-50 %)", "a fraction such as 0.05 or 5%")


def frames_arg(text: str) -> slice:
    """'A:B' (0-based, B excluded, either side optional) -> slice."""
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a = int(parts[0]) if parts[0].strip() else None
        b = int(parts[1]) if parts[1].strip() else None
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B (0-based frame indices, B excluded), got '{text}'") from None
    if (a is not None and a < 0) or (b is not None and b < 0):
        raise argparse.ArgumentTypeError(f"frame indices must be 0 or more, got '{text}'")
    return slice(a, b)
