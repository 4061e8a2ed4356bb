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


def positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (v > 0 and np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return v


def nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (v >= 0 and np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be zero or positive, got {text}")
    return v


def count_arg(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be zero or positive, got {v}")
    return v


def height_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a stature in metres, got '{text}'") from None
    if not (1.4 <= v <= 2.2):
        raise argparse.ArgumentTypeError(f"must be a stature of 1.4-2.2 m, got {text}")
    return v


def fraction_arg(text: str) -> float:
    try:
        v = float(text[:-1]) / 100 if text.endswith("%") else float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction such as 0.05 or 5%, got '{text}'") from None
    if not (0 <= v <= 0.5):
        raise argparse.ArgumentTypeError(f"must be a fraction of 0-0.5 (0-50 %), got {text}")
    return v


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
