"""Markers that jitter: a trajectory whose positions scatter from frame to frame as white noise (a camera ray matched
to the wrong blob, a marker half hidden, a reconstruction gone bad), told from a fast limb by its fourth differences.

A marker's fourth difference x[f-2] - 4 x[f-1] + 6 x[f] - 4 x[f+1] + x[f+2] is its motion's fourth derivative times
dt⁴ (a few tenths of a millimetre for any real limb at 50 Hz or faster) plus its white noise times √70.  Measured
on 90 real trials (the shared collection's C3D files, OpenSim's TRCs, Pose2Sim's video keypoints; 2026-12-01): the
noise SD so read is at most 0.9 mm for any marker over a whole trial, at most 3.1 mm in any half second (c3d.org's
sample01 at 50 Hz; a 50 Hz tennis serve's forearm 3.0), and 4.6 mm median, 16 mm at worst, for unfiltered video
keypoints whose markers all jitter alike.  A marker given
20 mm of noise in pig_walk's walk moved a joint centre 60 mm; 100 mm of noise on LKNE, the left hip 240 mm (its
learnt noise stops at calibrate.calibration.noise.NOISE_CAP, and every sample pulled)."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..io.trial import Trial

JITTER_BLOCK_S = 0.5  # s: a marker's jitter is judged in blocks this long ...
JITTER_BLOCK_FRAMES = 20  # ... and of at least this many frames
JITTER_MIN = 0.005  # m: a block's noise SD above this ...
JITTER_REL = 5.0  # ... and this many times the trial's markers' median: the marker's samples there are left out
JITTER_GAUGE = math.sqrt(70.0) * 0.888  # a fourth difference's 3-D RMS per unit noise SD, at its median (√χ²₃/3)


@dataclass(frozen=True)
class Jittery:
    """A marker left out where it jitters."""

    label: str
    sd: float  # m: its noise SD where left out (the median of its frames' jitter_sd there)
    reference: float  # m: the trial's markers' median noise SD, so read
    frames: int  # frames left out
    seen: int  # frames the trial shows it in

    def text(self) -> str:
        share = "all" if self.frames == self.seen else f"{self.frames} of the {self.seen}"
        return (f"{self.label} jitters {1e3 * self.sd:.0f} mm SD from frame to frame (white noise; the trial's markers "
                f"{1e3 * self.reference:.2g} mm median) in {share} frames it is seen: left out there; check its "
                "reconstruction")

    def to_json(self) -> dict:
        return {"label": self.label, "noise_sd_mm": 1e3 * self.sd, "trial_median_mm": 1e3 * self.reference,
                "frames_left_out": self.frames, "frames_seen": self.seen}


def jitter_sd(markers: np.ndarray) -> np.ndarray:
    """(frames, markers) each position's white-noise SD as its fourth difference reads it (m; NaN at the trial's
    first and last two frames and wherever one of the five frames is unseen): on its own a rough guess, whose
    median over a few dozen frames is the noise SD."""
    X = np.asarray(markers, dtype=float)
    out = np.full(X.shape[:2], np.nan)
    if X.shape[0] >= 5:
        d4 = X[:-4] - 4 * X[1:-3] + 6 * X[2:-2] - 4 * X[3:-1] + X[4:]
        out[2:-2] = np.sqrt(np.sum(d4**2, axis=2) / 3.0) / JITTER_GAUGE
    return out


def _median_of_half(s: np.ndarray, width: int) -> np.ndarray:
    """The median over the first axis of `s` (a window of `width` frames' jitter_sd), NaN where fewer than half the
    window's frames read one."""
    return np.where(np.sum(np.isfinite(s), axis=0) >= width // 2, nanmedian_first(s), np.nan)


def jittery_samples(trial: Trial) -> tuple[np.ndarray, tuple[Jittery, ...]]:
    """(n_frames, n_markers) True where a marker jitters, and each such marker: where the median noise SD (jitter_sd)
    of a marker's JITTER_BLOCK_S (at least JITTER_BLOCK_FRAMES frames) about a frame is above JITTER_MIN and
    JITTER_REL times the trial's markers' median, its position there is taken, and the two frames each side (a
    fourth difference spans them).  Relative to the trial: video keypoints all jitter a few millimetres and none is
    taken.  Markers are first screened in windows half a block apart (a noisy stretch of a block or more fills most
    of one), then followed frame by frame.  Spikes and swapped labels (seeding.jump_episodes) are read with the rest:
    a jump moves five fourth differences, which no median of a block heeds, while the frames they would take out of
    a noisy marker (its noise makes jumps too) left too few to judge it."""
    X = np.asarray(trial.markers, dtype=float)
    F, M = X.shape[:2]
    out = np.zeros((F, M), dtype=bool)
    block = max(JITTER_BLOCK_FRAMES, int(round(JITTER_BLOCK_S * trial.rate)))
    if F < block:
        return out, ()
    s = jitter_sd(X)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        reference = float(np.nanmedian(np.nanmedian(s, axis=0)))
    if not math.isfinite(reference):
        return out, ()
    limit = max(JITTER_MIN, JITTER_REL * reference)
    windows = sliding_window_view(s, block, axis=0)[::max(1, block // 2)]  # (windows, markers, block)
    screened = np.nan_to_num(_median_of_half(np.moveaxis(windows, 2, 0), block)) > limit
    seen = np.all(np.isfinite(X), axis=2)
    found = []
    half = block // 2
    for k in np.flatnonzero(screened.any(axis=0)):
        padded = np.concatenate([np.full(half, np.nan), s[:, k], np.full(block - half - 1, np.nan)])
        about = _median_of_half(sliding_window_view(padded, block).T, block)  # (F,): the block about each frame
        hit = np.nan_to_num(about) > limit
        hit = np.convolve(hit, np.ones(5), mode="same") > 0  # the frames a hit's fourth difference spans
        out[:, k] = hit & seen[:, k]
        if out[:, k].any():
            found.append(Jittery(trial.labels[k], float(np.nanmedian(s[hit, k])), reference, int(out[:, k].sum()),
                                 int(seen[:, k].sum())))
    return out, tuple(found)


def nanmedian_first(a: np.ndarray) -> np.ndarray:
    """np.nanmedian(a, axis=0) for a short first axis (a few frames' steps) and a long rest: sorted once
    (NaN last), the middle of each column's finite values taken, NaN where it has none; numpy's own
    partitions with NaN handling column by column (several times slower on long trials)."""
    srt = np.sort(a, axis=0)
    n = np.sum(np.isfinite(a), axis=0)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[None], axis=0)[0]
    hi = np.take_along_axis(srt, np.minimum(n // 2, a.shape[0] - 1)[None], axis=0)[0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)
