"""Motion: the per-frame coordinates of a model through a trial, and its CSV format.

CSV (written by the simulator for the truth and by the calibrator for its result):
a header row, then one row per frame with columns ``time`` (s),
``root_x root_y root_z`` (m, lab frame), ``root_qx root_qy root_qz root_qw`` (unit
quaternion, Pinocchio's free-flyer order) and one column per moving URDF joint,
named by the joint, in radians.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import CalibrateError
from ..model.blocks import FrameLayout
from .text import atomic_write_text

ROOT_COLUMNS = ("root_x", "root_y", "root_z", "root_qx", "root_qy", "root_qz", "root_qw")


@dataclass(frozen=True)
class Motion:
    """Coordinates of every frame: root pose and joint angles."""

    times: np.ndarray  # (n_frames,) s
    root_translation: np.ndarray  # (n_frames, 3) m
    root_quaternion: np.ndarray  # (n_frames, 4) x, y, z, w; unit
    angles: np.ndarray  # (n_frames, n_dofs) rad
    dof_names: tuple[str, ...]

    def __post_init__(self) -> None:
        nf = len(self.times)
        shapes = {"root_translation": (nf, 3), "root_quaternion": (nf, 4), "angles": (nf, len(self.dof_names))}
        for name, shape in shapes.items():
            got = np.shape(getattr(self, name))
            if got != shape:
                raise ValueError(f"Motion.{name}: expected shape {shape}, got {got}")

    @property
    def n_frames(self) -> int:
        return len(self.times)

    def z(self) -> np.ndarray:
        """Per-frame coordinates (n_frames, 6 + n_dofs) with zero rotation increments.

        Pair with ``root_quaternion`` as the reference orientation (see calibrate.model.kinematics).
        """
        return FrameLayout.coordinates(self.root_translation, self.angles)


def motion_csv_text(motion: Motion, progress: Callable[[float], None] | None = None) -> str:
    """The motion CSV document: time, root position, root quaternion (x, y, z, w), angles by DoF name,
    each number as Python's shortest round-trip repr.  `progress(share of the frames done)` after each
    CSV_ROWS frames (100 000 frames take about 2 s)."""
    data = np.hstack([motion.times[:, None], motion.root_translation, motion.root_quaternion, motion.angles])
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow(("time", *ROOT_COLUMNS, *motion.dof_names))
    n = data.shape[0]
    for a in range(0, n, CSV_ROWS):
        buf.write("".join(",".join(map(repr, row)) + "\n" for row in data[a:a + CSV_ROWS].tolist()))
        if progress is not None:
            progress(min(n, a + CSV_ROWS) / n)
    return buf.getvalue()


CSV_ROWS = 5000  # frames of the motion CSV formatted between two progress calls


def write_motion_csv(path: str | os.PathLike[str], motion: Motion) -> Path:
    """Write `motion` as CSV (atomically: temporary file, then rename)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise CalibrateError(f"{path}: directory '{path.parent}' does not exist; create it first")
    atomic_write_text(path, motion_csv_text(motion))
    return path


def read_motion_csv(path: str | os.PathLike[str]) -> Motion:
    """Read a motion CSV; one-line CalibrateError if the file is not in the format."""
    path = Path(path)
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except OSError as e:
        raise CalibrateError(f"{path}: cannot read motion file ({e.strerror})") from None
    if not rows:
        raise CalibrateError(f"{path}: empty motion file")
    header = [h.strip() for h in rows[0]]
    if tuple(header[:8]) != ("time", *ROOT_COLUMNS):
        raise CalibrateError(
            f"{path}: header must start with time,{','.join(ROOT_COLUMNS)}; got {','.join(header[:8])}"
        )
    try:
        data = np.array([[float(x) for x in r] for r in rows[1:] if r], dtype=float).reshape(-1, len(header))
    except ValueError as e:
        raise CalibrateError(f"{path}: non-numeric or missing value ({e})") from None
    return Motion(data[:, 0], data[:, 1:4], data[:, 4:8], data[:, 8:], tuple(header[8:]))
