"""The markers' noise learnt from the trial (leverage-corrected, winsorised residual scatter and its
correlation time) and the outliers measured against it."""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np

from calibrate.seed.seeding import MAD_SD

from ..problem.problem import Problem
from ..problem.state import State
from ..solve.assembly import factor_frames
from ..solve.chunks import each_chunk
from .options import PipelineOptions
from .records import Countdown, Progress

NOISE_FLOOR = 0.0005  # m: a learnt marker noise SD is never below this (sub-millimetre: a camera system's floor)


NOISE_CAP = 0.015  # m: ... nor above this (beyond it a marker is mislabelled, not noisy: outliers catch it; a marker
#   whose positions scatter as white noise is left out before, calibrate.seed.jitter)


NOISE_MIN_FRAMES = 20  # a marker seen in fewer frames takes its segment's (or all markers') median learnt SD


NOISE_CHANGE = 0.1  # stop re-learning when no marker's SD changes by more than this fraction


NOISE_TAU_SECONDS = 16 / 120  # s: on every frame a marker's residual correlation time counts up to this (16
#   frames at pig_walk's 120 Hz, where the cap was set as 16 frames; a cap in frames weighed a trial by its rate) ...


NOISE_TAU_MAX = 16.0  # ... and on a subsample, whose rows lie frames apart, up to this many of its rows


NOISE_CLIP = 4.0  # a residual counts in the learnt SD up to this many robust SDs per coordinate (spikes: no more)


def fixed_noise(problem: Problem, options: PipelineOptions) -> np.ndarray | None:
    """The problem's markers whose noise SD is the user's (ProblemOptions.marker_noise), or None when
    nothing is learnt (PipelineOptions.learn_noise)."""
    if not options.learn_noise:
        return None
    named = {label for label, _ in problem.settings.marker_noise}
    return np.array([n in named for n in problem.model.marker_names])


def relearn(problem: Problem, state: State, fixed: np.ndarray, say: Callable[[str | Progress], None],
             trial_of: np.ndarray, tau_max: float | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """learned_noise at `state`: the weights' SDs sigma sqrt(τ) (a marker whose residuals are correlated
    over τ frames carries the information of 1/τ of its frames) and the noise SDs sigma.  The first is
    None if nine markers in ten changed their weights' SD by no more than NOISE_CHANGE (a few poorly
    seen markers may go on wavering without moving the geometry).  `tau_max`: learned_noise's."""
    scatter, tau = learned_noise(problem, state, fixed, trial_of, correlation=True,
                                 progress=Countdown(say, "noise", "the markers' scatter over every frame"),
                                 tau_max=tau_max)
    sigma = scatter * np.sqrt(tau)
    shown = ~problem.unseen  # a marker no frame shows weighs nothing: its SD neither counts nor shows
    sc, ta = scatter[shown], tau[shown]
    change = float(np.quantile(np.abs(sigma / problem.sigma - 1.0)[shown], 0.9))
    say(Progress("noise", f"learnt marker SDs {1000 * np.median(sc):.2f} mm median ({1000 * sc.min():.2f}-"
                          f"{1000 * sc.max():.2f}), correlation times {np.median(ta):.1f} frames median (up to "
                          f"{ta.max():.1f}); 9 in 10 weights changed by <= {100 * change:.0f} %"))
    return (sigma if change > NOISE_CHANGE else None), scatter


def leverage(problem: Problem, state: State,
             progress: Callable[[float], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(F, n_markers) leverage of each observed marker in its frame — the trace of the weighted hat
    matrix J_z A_f⁻¹ J_zᵀ W over its three rows, / 3: the fraction of its error the frame's pose
    absorbs — and the raw residuals (F, 3 n_markers) at `state`.  With A_f = L L' (the compiled
    Cholesky of the solver's frame blocks), each row's hat-matrix diagonal is |L⁻¹ J_row'|².  The
    frames' blocks are formed once each, chunk by chunk within the problem's memory budget
    (calibrate.solve.chunks.each_chunk); `progress(share of the frames done)` after each chunk."""
    nm = len(problem.model.markers)
    zr, zc, nrows, nz = problem.jz_pattern
    F = problem.F
    h = np.zeros((F, nm))
    d = np.empty((F, nrows))
    for sl, lin in each_chunk(problem, state, False, problem.settings.memory_mb * 1e6):
        dc, jz, _, wrow = lin.jacobian[:4]
        d[sl] = dc
        for s in range(0, dc.shape[0], LEVERAGE_FRAMES):  # the dense per-frame Jacobians are (rows x nz)
            e = min(dc.shape[0], s + LEVERAGE_FRAMES)
            h[sl.start + s:sl.start + e] = _hat_diagonal(lin.A[s:e], jz[s:e], wrow[s:e], zr, zc, nrows) \
                .reshape(e - s, nm, 3).sum(axis=2) / 3
        if progress is not None:
            progress(sl.stop / F)
    return np.where(problem.seen, h, 0.0), d


LEVERAGE_FRAMES = 128  # frames whose dense Jacobians (rows x nz) leverage() holds at once


def _hat_diagonal(A: np.ndarray, jz: np.ndarray, wrow: np.ndarray, zr: np.ndarray, zc: np.ndarray,
                  nrows: int) -> np.ndarray:
    """(frames, rows) diagonal of each frame's weighted hat matrix W J A⁻¹ J' (A = J'WJ + limits):
    J' forward-substituted through the Cholesky factor of A + a 1e-12 relative ridge (a coordinate no
    marker reaches has a zero column in J and a zero row in A)."""
    e, nz = A.shape[0], A.shape[1]
    Jt = np.zeros((e, nz, nrows))
    Jt[:, zc, zr] = jz
    Jt *= wrow[:, None, :]
    ridge = 1e-12 * max(float(np.max(np.abs(np.diagonal(A, axis1=1, axis2=2)), initial=0.0)), 1e-300)
    L, Y, yz = np.empty((e, nz, nz)), np.empty((e, nz, nrows)), np.empty((e, nz))
    if factor_frames(np.ascontiguousarray(A), np.full((e, nz), ridge), Jt, np.zeros((e, nz)), L, Y, yz):
        return np.einsum("fir,fir->fr", Y, Y)
    # A block not positive definite even with the ridge (rounding): the inverse, as a fallback.
    Ainv = np.linalg.inv(A + ridge * np.eye(nz))
    return np.einsum("fir,fij,fjr->fr", Jt, Ainv, Jt, optimize=True)


def tau_cap(rates: np.ndarray, frames: np.ndarray) -> float:
    """The longest correlation time (in frames) that a marker's residuals count for on every frame of trials
    read at `rates` (Hz) with `frames` frames each: NOISE_TAU_SECONDS at the trials' frame-weighted mean rate.
    A cap in seconds keeps what a second of trial weighs whatever its rate (in frames, the same walk read at
    60 Hz counted half as much as at 120 Hz against the priors: pig_walk's joint centres moved 0.7-15.8 mm)."""
    frames = np.asarray(frames, dtype=float)
    return NOISE_TAU_SECONDS * float(np.asarray(rates, dtype=float) @ frames / max(frames.sum(), 1.0))


def learned_noise(problem: Problem, state: State, fixed: np.ndarray | None = None,
                  trial_of: np.ndarray | None = None, correlation: bool = False,
                  progress: Callable[[float], None] | None = None, tau_max: float | None = None):
    """Each marker's noise SD (m) from the residuals at `state`: the root mean square of its 3-D
    residuals over the frames, each winsorised at NOISE_CLIP robust SDs per coordinate (MAD_SD times
    the median absolute deviation of its components in the same trial: `trial_of` (F,) gives each
    frame's trial; a static trial's scatter is smaller than a walk's), so that skin-motion scatter
    counts and spikes count no more than a few SDs.  A residual is smaller than the noise by the
    part of it the fit absorbs, so each is first divided by sqrt(1 − h): h its frame's leverage
    (the trace of the weighted hat matrix J_z A_f⁻¹ J_zᵀ W over the marker's three rows, / 3:
    one frame's 38 coordinates absorb about a third of 39 markers' 117 coordinates) plus 1/n for
    the marker's own offset, fitted over its n frames.  Markers seen in fewer than NOISE_MIN_FRAMES
    frames or almost wholly absorbed (h > 0.8) take the median of their segment's (else of all
    markers'); `fixed` markers (the user's marker_noise) keep problem.sigma.  Clipped to
    [NOISE_FLOOR, NOISE_CAP].

    `correlation`: also return each marker's correlation time τ (rows of `problem`; 1 for white
    noise): (1 + ρ)/(1 − ρ), ρ the lag-1 autocorrelation of its standardised residuals within each
    trial, in [1, `tau_max`] (a fixed marker: 1).  `tau_max`: for a problem of every frame, tau_cap of its
    trials; None: NOISE_TAU_MAX rows (a subsample, its rows frames apart)."""
    model = problem.model
    nm = len(model.markers)
    F = problem.F
    h, d = leverage(problem, state, progress)
    res = d.reshape(F, nm, 3)
    seen = problem.seen
    # A frame of weight w (Problem.frame_weight: a static trial's) counts w times in every sum and median.
    fw = problem.frame_weight
    n = seen.sum(axis=0) if fw is None else fw @ seen
    sigma = problem.sigma.copy()
    learnt = np.full(nm, np.nan)
    trial_of = np.zeros(F, dtype=int) if trial_of is None else np.asarray(trial_of)
    for k in range(nm):
        use = seen[:, k]
        if n[k] < NOISE_MIN_FRAMES:
            continue
        lev = h[use, k] + 1.0 / n[k]
        wk = None if fw is None else fw[use]
        if _median(lev, wk) > 0.8:
            continue
        r = res[use, k]
        keep = np.clip(1.0 - lev, 0.2, 1.0)
        u = r / np.sqrt(keep)[:, None]
        cap = np.empty(use.sum())
        for t in np.unique(trial_of[use]):
            mine = trial_of[use] == t
            s0 = MAD_SD * float(np.median(np.abs(u[mine] - np.median(u[mine], axis=0))))
            cap[mine] = 3 * (NOISE_CLIP * s0) ** 2 * keep[mine]
        # The mean square, winsorised at NOISE_CLIP robust SDs: a marker whose residual the fit confines
        # to fewer than 3 directions (a single hand marker: 1) has no Gaussian components for the MAD,
        # but E|r|^2 = 3 sigma^2 (1 - h) whatever the rank.
        sq = np.minimum(np.sum(r**2, axis=1), cap)
        if wk is None:
            learnt[k] = math.sqrt(float(np.sum(sq)) / float(np.sum(3 * keep)))
        else:
            learnt[k] = math.sqrt(float(np.sum(wk * sq)) / float(np.sum(3 * wk * keep)))
    seg = problem.marker_segment
    overall = float(np.nanmedian(learnt)) if np.isfinite(learnt).any() else float(np.median(sigma))
    for k in np.flatnonzero(~np.isfinite(learnt)):
        mine = learnt[(seg == seg[k]) & np.isfinite(learnt)]
        learnt[k] = float(np.median(mine)) if mine.size else overall
    learnt = np.clip(learnt, NOISE_FLOOR, NOISE_CAP)
    if fixed is not None:
        learnt = np.where(fixed, sigma, learnt)
    if not correlation:
        return learnt
    tau = np.ones(nm)
    cap = NOISE_TAU_MAX if tau_max is None else max(1.0, float(tau_max))
    lag = seen[1:] & seen[:-1] & (trial_of[1:] == trial_of[:-1])[:, None]  # (F-1, nm): consecutive pairs
    pair_w = None if fw is None else fw[1:]  # a pair within a trial weighs as its frames (one trial: one weight)
    for k in range(nm):
        pairs = lag[:, k].sum() if pair_w is None else float(pair_w[lag[:, k]].sum())
        if pairs < NOISE_MIN_FRAMES or (fixed is not None and fixed[k]):
            continue
        u = np.where(seen[:, k, None], res[:, k], 0.0)
        for t in np.unique(trial_of):
            mine = (trial_of == t) & seen[:, k]
            if mine.any():
                u[mine] -= u[mine].mean(axis=0)
        a, b = u[:-1][lag[:, k]], u[1:][lag[:, k]]
        if pair_w is not None:
            q = np.sqrt(pair_w[lag[:, k]])[:, None]
            a, b = a * q, b * q
        rho = float(np.sum(a * b)) / max(math.sqrt(float(np.sum(a * a)) * float(np.sum(b * b))), 1e-300)
        tau[k] = float(np.clip((1 + rho) / max(1 - rho, 1e-9), 1.0, cap))
    return learnt, tau


def _median(x: np.ndarray, weight: np.ndarray | None = None) -> float:
    """The median of `x`, each value counted `weight` times (the weighted median: where the cumulative
    weight reaches half); None: np.median."""
    if weight is None:
        return float(np.median(x))
    order = np.argsort(x, kind="stable")
    end = np.cumsum(weight[order])
    return float(x[order][min(int(np.searchsorted(end, 0.5 * end[-1])), x.size - 1)])


def find_outliers(problem: Problem, state: State, options: PipelineOptions, sigma: np.ndarray | None = None,
                  trial_of: np.ndarray | None = None, progress: Callable[[float], None] | None = None,
                  h: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Observations (F, n_markers) whose studentised 3-D error |r| / (σ sqrt(1 − h)) exceeds
    `options.outliers` (σ: `sigma`, default problem.sigma, scaled up if the fit shows more noise than
    that: median / 1.538, a 3-D Gaussian's; h: the leverage): a spike on a marker whose frame's pose
    absorbs most of it (one of a foot's two markers) keeps its small residual but not its studentised
    one.  `h`: the leverage at `state` if known (leverage(); e.g. kept from the last test and formed
    again only on the frames changed since).  Returns the mask and the studentised errors times σ (m:
    comparable across markers)."""
    err = np.linalg.norm(problem.marker_residuals(state), axis=2)
    ok = np.isfinite(err)
    if not ok.any():
        return np.zeros_like(ok), err
    if h is None:
        h, _ = leverage(problem, state, progress)
    err = err / np.sqrt(np.clip(1.0 - h, 0.05, 1.0))
    sigma = problem.sigma if sigma is None else sigma
    scale = max(1.0, float(np.median((err / sigma)[ok])) / 1.538)
    sd = np.broadcast_to(scale * sigma, err.shape).copy()
    # Per trial and marker, never below what its own median error shows: a shoulder marker riding the
    # scapula scatters 10-20 mm in a walk and 1 mm in the static trial, and its noise SD, learnt over
    # both, would otherwise reject every walking frame of it (outliers are the rare exceptions).  Not above NOISE_CAP:
    # a marker whose median error is larger is off its place in many frames, and the fit has smeared its place
    # between them (gait2392's R.Thigh.Rear on the floor for 41 of 151 frames: every residual 140-470 mm, none
    # rejected, the fit 48.7 mm RMS; refit_outliers in the pipeline then calibrates again without them).
    trial_of = np.zeros(problem.F, dtype=int) if trial_of is None else trial_of
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for t in np.unique(trial_of):
            rows = trial_of == t
            med = np.nanmedian(np.where(ok[rows], err[rows], np.nan), axis=0) / 1.538
            sd[rows] = np.maximum(sd[rows], np.where(np.isfinite(med), np.minimum(med, NOISE_CAP), 0.0)[None, :])
    return ok & (err > options.outliers * sd), err
