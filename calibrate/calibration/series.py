"""The report's time series, in compact form: what the HTML report draws (calibrate.calibration.html)
and `calibrate report` reads back from the JSON alone.

Per trial: each marker's residual norm (mm, 0.1 mm steps) and each coordinate's angle (deg, 0.01 deg
steps) at no more than MAX_POINTS instants.  A longer trial is cut into MAX_POINTS equal blocks of
frames: a block's residual is the largest in it (a spike stays visible), its angle the block's first
frame's.  So the JSON grows with markers x MAX_POINTS, not with the trial's length (about 60 kB per
trial of 40 markers).  Also: the base model's coordinate limits (deg) and the segment lengths of the
base model and the subject (mm).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .result import Calibration

MAX_POINTS = 400  # instants per trial in the report's series


def _rounded(a: np.ndarray, digits: int) -> list:
    return [None if not math.isfinite(float(v)) else round(float(v), digits) for v in a]


def blocks(n_frames: int, max_points: int = MAX_POINTS) -> np.ndarray:
    """First frame of each block when `n_frames` are cut into at most `max_points` equal blocks."""
    step = max(1, math.ceil(n_frames / max_points))
    return np.arange(0, n_frames, step)


def trial_series(cal: Calibration, i: int, max_points: int = MAX_POINTS) -> dict:
    """Trial i's residual norms per marker (mm, the largest of each block) and angles per
    coordinate (deg, each block's first frame), with the blocks' first frames and times (s)."""
    res = cal.residuals[cal.trial_frames(i)]
    err = 1000.0 * np.linalg.norm(res, axis=2)  # (F, n_markers), NaN where not seen
    starts = blocks(err.shape[0], max_points)
    with np.errstate(all="ignore"):
        seen = np.where(np.isfinite(err), err, -np.inf)
        peak = np.maximum.reduceat(seen, starts, axis=0) if err.size else err
        peak = np.where(np.isfinite(peak), peak, np.nan)
    motion = cal.motions[i]
    names = cal.model.marker_names
    return {
        "frames": [int(s) for s in starts],
        "times_s": _rounded(motion.times[starts], 4),
        "block": int(starts[1] - starts[0]) if len(starts) > 1 else 1,
        "residual_mm": {n: _rounded(peak[:, k], 1) for k, n in enumerate(names)
                        if np.isfinite(peak[:, k]).any()},
        "angles_deg": {d: _rounded(np.degrees(motion.angles[starts, k]), 2)
                       for k, d in enumerate(motion.dof_names)},
    }


def segment_lengths(cal: Calibration) -> dict:
    """Per anatomical joint below a segment (its centre at least 5 cm from the segment's origin): the
    segment's length to it (mm), base model and subject."""
    base = (cal.base_model or cal.model).parameters()
    p, model = cal.params, cal.model
    out = {}
    for j, joint in enumerate(model.joints):
        s = model.segment_index(joint.parent)
        b = float(np.linalg.norm(base.scale[s] * base.centre[j]))
        if b < 0.05:
            continue
        v = float(np.linalg.norm(p.scale[s] * p.centre[j]))
        out[joint.name] = {"segment": joint.parent, "base_mm": round(1000 * b, 2), "subject_mm": round(1000 * v, 2)}
    return out


def report_series(cal: Calibration, max_points: int = MAX_POINTS) -> dict:
    """The series section of the report JSON (module docstring)."""
    limits = {d.name: [None if not math.isfinite(d.lower) else round(math.degrees(d.lower), 3),
                       None if not math.isfinite(d.upper) else round(math.degrees(d.upper), 3)]
              for d in (cal.base_model or cal.model).dofs}
    return {"max_points": max_points,
            "trials": [trial_series(cal, i, max_points) for i in range(len(cal.trials))],
            "limits_deg": limits, "segment_lengths": segment_lengths(cal)}
