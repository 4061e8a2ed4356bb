"""Labels for unlabelled tracks by fitting the base model to them (what label_tracks falls back on when
the tracks do not group into rigid segments: skin markers; where they do, the labelling it checks the
groups' against).

Seed 002's grouping (calibrate.seed.associate) needs markers that ride rigidly on their segments.  Skin
markers do not: on the real Plug-in Gait walk (../shared/data/real/pig_walk) the pelvis markers' distances
vary by 1.5–2.6 mm SD against the 1.1 mm of the trial's rigid pairs, the pelvis splits into three groups
and most leg markers stay alone, so no group can be taken for the root.  This labelling needs no groups:
it alternates, as iterative closest point does, between

1. assigning whole tracks to the base model's markers (scaled to the subject) by a Hungarian assignment
   (scipy's linear_sum_assignment) on the median distance, over a subsample of frames, between each track
   and each model marker where the model's current poses put it, a track left unassigned at a cost that
   shrinks from ``FAR`` to ``NEAR`` over the rounds (a limb far from where the model holds it is labelled
   once the markers nearer the trunk have posed the model); and
2. posing the model by frame-wise inverse kinematics (calibrate.solve.ik) to the tracks so labelled;

until the labels stop changing.  The first assignment compares the subject in the frames in which it
stands tallest with the model standing (its neutral pose), scaled to the tracks' height, its lowest
markers on the lowest tracks, its centroid on theirs, turned to each of ``HEADINGS`` headings about the
vertical (and to the direction of travel when the tracks travel), each for ``SCREEN_ROUNDS`` rounds, the
``SCREEN_KEEP`` whose labellings then fit best to the end: the heading whose labelling fits best
(assignment cost, tracks left out counted at ``NEAR``) is kept; at that heading the model with its arms
raised sideways (``ARM_ANGLES``; a static trial holds the arms out from the body) is tried too.  Then the
tracks still unlabelled are matched to the model's markers still free at a looser ``LEFTOVER``; each
segment of a few markers reordered where its layout fits better (_shapes: the pelvis, the head); each
two-marker segment's pair exchanged where the model then fits better (_pair_swaps: the wrist's).

Measured (scripts/bench_labelling.py; the true trajectories with their labels removed and shuffled): the
Plug-in Gait walk and static trial 39 of 39 right (the walk refused by the grouping); simulated gait with
soft-tissue artefact 3 and 10 mm, two seeds, 37–39 of 39, at most one wrong; simulated squats, whose arms
sweep 120° and which stand in place (no direction of travel), 32–36 right and 2–3 wrong (a foot's markers
turned round, or an arm's).
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..io.trial import Trial
from ..model.blocks import FrameLayout
from ..model.kinematics import Kinematics
from ..model.model import Model, Parameters
from ..model.resolve import descendants
from ..problem.problem import compiled_kinematics
from ..seed.geometry import kabsch_batch
from ..solve.ik import DECISION_TOLERANCE, inverse_kinematics

FRAMES = 40  # frames spread over the trial that the assignment and the inverse kinematics read
TALL_SHARE = 0.1  # the first assignment reads the frames in which the tracks span the most height (standing)
HEADINGS = 8  # headings about the vertical tried for the first assignment, evenly spaced
TRAVEL = 0.5  # m: tracks whose centroid moves this far over the trial also try their direction of travel
FAR = 0.3  # m: cost of leaving a track unassigned in the first round ...
NEAR = 0.06  # m: ... shrinking by SHRINK a round to this
SHRINK = 0.7
LEFTOVER = 0.15  # m: a track still unlabelled takes a free model marker within this median distance
ROUNDS = 14  # assignment and inverse-kinematics rounds at most, per heading
SCREEN_ROUNDS = 3  # rounds every heading runs; then ...
SCREEN_KEEP = 3  # ... the headings whose labels fit best after them run to the end
SHAPE_MARKERS = 5  # segments of at most this many labelled markers have their orderings checked (_shapes)
SHAPE_GAIN = 0.002  # m: a reordering must fit the segment's layout this much better to be taken
SCALES = (0.75, 1.3)  # the subject's height over the base model's, at most
ARM_ANGLES = (np.radians(45.0), np.radians(90.0))  # arms raised sideways, tried for the first assignment
SHOULDER_HEIGHT = 0.7  # a shoulder sits above this share of the standing markers' height ...
SHOULDER_WIDTH = 0.06  # ... and this share of it off the midline, its parent joint nearer the midline


@dataclass(frozen=True)
class FittedLabels:
    """Model labels for tracks found by fitting the base model (fit_labels)."""

    labels: dict[str, str]  # track name -> model marker
    scale: float  # the subject's height over the base model's
    heading: float  # rad: the heading about the vertical whose labelling was kept
    cost: float  # m: the kept labelling's assignment cost (median distances summed, tracks left out at NEAR)


def fit_labels(model: Model, kin: Kinematics, trial: Trial, X: np.ndarray | None = None) -> FittedLabels:
    """Labels of `model`'s markers for the unlabelled tracks of `trial` by fitting the scaled base model
    to them (module docstring).  `X`: the tracks to read (e.g. despiked; default the trial's markers)."""
    X = np.asarray(trial.markers if X is None else X, dtype=float)
    kin = compiled_kinematics(kin)  # the model is fitted frame by frame to every labelling tried
    names = model.marker_names
    frames, tall = _frames(X)
    Xs = X[frames]
    p0 = model.parameters()
    z0, q0 = np.zeros(model.nz), np.array([0.0, 0.0, 0.0, 1.0])
    standing = np.asarray(kin.markers(z0, q0, p0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        height = np.nanquantile(np.nanmax(X[..., 2], axis=1) - np.nanmin(X[..., 2], axis=1), 1 - TALL_SHARE)
        centroid = np.nanmean(Xs, axis=1)
        floor = np.nanmin(Xs[..., 2], axis=1)
        travel = np.nanmean(X[-50:], axis=(0, 1)) - np.nanmean(X[:50], axis=(0, 1))
    scale = float(np.clip(height / np.ptp(standing[:, 2]), *SCALES))
    params = Parameters(p0.scale * scale, p0.centre, p0.axis, p0.marker)
    standing = np.asarray(kin.markers(z0, q0, params))
    headings = list(2 * np.pi * np.arange(HEADINGS) / HEADINGS)
    if np.hypot(travel[0], travel[1]) > TRAVEL:
        headings.insert(0, float(np.arctan2(travel[1], travel[0])))
    best: tuple[FittedLabels, np.ndarray] | None = None

    def placed(layout: np.ndarray, heading: float) -> np.ndarray:
        """The model's markers (frames, markers, 3): `layout` turned to `heading`, on the tracks' centroid and floor."""
        c, s = np.cos(heading), np.sin(heading)
        M = (layout - layout.mean(axis=0)) @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        M = centroid[:, None, :] + M[None]
        M[..., 2] += (floor - M[..., 2].min(axis=1))[:, None]  # arms held up or forward move the centroid
        return M

    def keep(heading: float, fitted: _Rounds) -> None:
        nonlocal best
        if best is None or fitted.cost < best[0].cost:
            best = FittedLabels(fitted.labels, scale, float(heading), fitted.cost), fitted.M

    # Every heading's first SCREEN_ROUNDS rounds; the SCREEN_KEEP that fit best then run to the end.
    poses: dict[frozenset, np.ndarray] = {}

    def posed(labels: dict[str, str]) -> np.ndarray:
        """The model posed to `labels` (_posed), once per labelling: headings and rounds that reach the same
        labels (a third of the fits on the real and simulated walks) pose it alike."""
        key = frozenset(labels.items())
        if key not in poses:
            poses[key] = _posed(kin, trial, Xs, params, labels)
            poses[key].setflags(write=False)
        return poses[key]

    screened = [(h, _rounds(trial, Xs, placed(standing, h), tall, names, posed, stop=SCREEN_ROUNDS))
                for h in headings]
    for heading, fitted in sorted(screened, key=lambda x: x[1].cost)[:SCREEN_KEEP]:
        keep(heading, _rounds(trial, Xs, fitted.M, tall, names, posed, resume=fitted))
    # A static trial holds the arms out from the body (Plug-in Gait's: abducted, elbows bent): at the best
    # heading the first assignment is tried again with the model's arms raised sideways.
    for layout in _arms_raised(model, kin, params, standing):
        keep(best[0].heading, _rounds(trial, Xs, placed(layout, best[0].heading), tall, names, posed))
    # The heading chosen: its leftovers labelled, its segments' orderings and two-marker pairs checked
    fitted, M = best
    labels, cost = _leftovers(trial, Xs, M, names, fitted.labels, fitted.cost)
    labels = _shapes(model, trial, Xs, standing, labels)
    return FittedLabels(_pair_swaps(model, kin, trial, Xs, params, labels), scale, fitted.heading, cost)


def _arms_raised(model: Model, kin: Kinematics, params: Parameters, standing: np.ndarray) -> list[np.ndarray]:
    """The standing model's markers (`standing`) with its arms raised sideways by each of ``ARM_ANGLES``:
    every marker below a shoulder turned about the forward axis (+x) through its centre.  A shoulder is a
    joint high on the body (above ``SHOULDER_HEIGHT`` of the markers' height) and off the midline (by
    more than ``SHOULDER_WIDTH`` of it) whose parent joint is on the midline: the arm's branch from the
    trunk, whatever the model calls it.  Nothing when the model has no such joint."""
    z0, q0 = np.zeros(model.nz), np.array([0.0, 0.0, 0.0, 1.0])
    centres = np.asarray(kin.centres(z0, q0, params))
    low, height = standing[:, 2].min(), np.ptp(standing[:, 2])
    mid = float(np.median(standing[:, 1]))
    index = {j.name: k for k, j in enumerate(model.joints)}
    into = {j.child: j.name for j in model.joints}  # segment -> the joint that carries it
    below = descendants(model)
    arms = []
    for j in model.joints:
        c = centres[index[j.name]]
        up = into.get(j.parent)
        if (c[2] < low + SHOULDER_HEIGHT * height or abs(c[1] - mid) < SHOULDER_WIDTH * height or up is None
                or abs(centres[index[up]][1] - mid) >= SHOULDER_WIDTH * height):
            continue
        segs = set(below[j.child])
        on = [k for k, m in enumerate(model.markers) if m.segment in segs]
        if on:
            arms.append((c, np.sign(c[1] - mid), on))
    out = []
    for angle in (ARM_ANGLES if arms else ()):
        layout = standing.copy()
        for c, side, on in arms:
            a = side * angle
            R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
            layout[on] = c + (standing[on] - c) @ R.T
        out.append(layout)
    return out


def _shapes(model: Model, trial: Trial, Xs: np.ndarray, layout: np.ndarray,
            labels: dict[str, str]) -> dict[str, str]:
    """Each segment of 3 to ``SHAPE_MARKERS`` labelled markers (the pelvis, the head) ordered as the
    model's layout (`layout`: its markers standing, scaled) fits its tracks best (_layout_fit): a
    heading tried 45° off can leave the pelvis's four markers turned a quarter round, which the inverse
    kinematics fits by turning the pelvis.  Of the orderings that fit within ``SHAPE_GAIN`` of the best
    (a layout symmetric under a half turn about the vertical, as the head's four markers), the one whose
    heading is nearest the root segment's (the pelvis's, settled first): a head faces where the pelvis
    does."""
    track_of = {m: t for t, m in labels.items()}
    col = {t: i for i, t in enumerate(trial.labels)}
    labels = dict(labels)
    root_heading = None
    for seg in model.segments:  # the root first
        mine = [m for m in seg.markers if m in track_of]
        if not 3 <= len(mine) <= SHAPE_MARKERS:
            continue
        local = layout[[model.marker_index(m) for m in mine]]
        tracks = [track_of[m] for m in mine]
        world = Xs[:, [col[t] for t in tracks]]
        world = world[np.all(np.isfinite(world), axis=(1, 2))]
        if world.shape[0] < 3:
            continue
        orders = list(itertools.permutations(range(len(mine))))
        fits = [_layout_fit(local, world[:, list(o)]) for o in orders]
        errs = np.array([e for e, _ in fits])
        near = [k for k in range(len(orders)) if errs[k] <= errs.min() + SHAPE_GAIN]
        if root_heading is not None:  # of the near-equal orderings, the one facing as the root does
            k = min(near, key=lambda k: abs(np.angle(np.exp(1j * (fits[k][1] - root_heading)))))
        else:
            k = 0 if 0 in near else int(np.argmin(errs))  # the root: reordered only when clearly better
        if k != 0:
            labels.update({tracks[j]: mine[i] for i, j in enumerate(orders[k])})
        if seg.name == model.segments[0].name:
            root_heading = fits[k][1]
    return labels


def _layout_fit(local: np.ndarray, world: np.ndarray) -> tuple[float, float]:
    """The rigid fit of a segment's marker layout `local` (P, 3; the model standing) to `world` (frames,
    P, 3): the median over the frames of its RMS (m), infinite when it turns the segment upside down in
    most frames (a flat layout, as the pelvis's, fits its mirror image so); and its median heading (rad,
    the turn of the layout's forward axis about the vertical)."""
    R, t = kabsch_batch(local, world, np.ones(world.shape[:2]))
    fit = np.einsum("fij,pj->fpi", R, local) + t[:, None, :]
    rms = float(np.nanmedian(np.sqrt(np.mean(np.sum((fit - world) ** 2, axis=2), axis=1))))
    heading = float(np.angle(np.nanmean(np.exp(1j * np.arctan2(R[:, 1, 0], R[:, 0, 0])))))
    return (rms if np.nanmedian(R[:, 2, 2]) > 0 else np.inf), heading


def _typical_rms(kin: Kinematics, trial: Trial, Xs: np.ndarray, params: Parameters, labels: dict[str, str]) -> float:
    """Median over the frames of the per-frame marker RMS (m) of the model posed to `labels`."""
    sub = Trial(fitted_names(trial.labels, labels), Xs, trial.rate, 0, None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        fit = inverse_kinematics(kin, sub, params, max_iterations=15, tolerance=DECISION_TOLERANCE)
        return float(np.nanmedian(fit.marker_rms))


def _pair_swaps(model: Model, kin: Kinematics, trial: Trial, Xs: np.ndarray, params: Parameters,
                labels: dict[str, str]) -> dict[str, str]:
    """The two markers of each two-marker segment exchanged where the model then fits better: a pair 5 cm
    apart (the wrist's) is as near either place after the rounds, and only the segment's turn tells."""
    track_of = {m: t for t, m in labels.items()}
    rms = _typical_rms(kin, trial, Xs, params, labels)
    for seg in model.segments:
        if len(seg.markers) != 2 or not all(m in track_of for m in seg.markers):
            continue
        a, b = seg.markers
        swapped = labels | {track_of[a]: b, track_of[b]: a}
        r = _typical_rms(kin, trial, Xs, params, swapped)
        if r < rms:
            labels, rms, track_of = swapped, r, {m: t for t, m in swapped.items()}
    return labels


def fitted_names(tracks: list[str], labels: dict[str, str]) -> list[str]:
    """The names a model is fitted to: each track's label, an unlabelled track 'track:NAME' (the tracker's
    track 'T10' must not pass for the model's marker T10)."""
    return [labels.get(t, f"track:{t}") for t in tracks]


def _frames(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FRAMES frames spread over those in which most tracks are seen, and half as many of the tallest
    (sorted, merged); with a mask of the tallest among them."""
    seen = np.all(np.isfinite(X), axis=2).mean(axis=1)
    good = np.flatnonzero(seen >= 0.5 * seen.max())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        span = np.nanmax(X[good, :, 2], axis=1) - np.nanmin(X[good, :, 2], axis=1)
    tallest = good[span >= np.nanquantile(span, 1 - TALL_SHARE)]
    spread = good[np.linspace(0, good.size - 1, min(FRAMES, good.size)).astype(int)]
    tall = tallest[np.linspace(0, tallest.size - 1, min(FRAMES // 2, tallest.size)).astype(int)]
    frames = np.union1d(tall, spread)
    return frames, np.isin(frames, tall)


def _median_distances(Xs: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(tracks, model markers) median over the frames of the distance between each track and each marker."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        C = np.nanmedian(np.linalg.norm(Xs[:, :, None, :] - M[:, None, :, :], axis=3), axis=0)
    return np.where(np.isfinite(C), C, 1e3)


@dataclass(frozen=True)
class _Rounds:
    """Where _rounds stopped: the labels, their assignment cost, the model's markers at the last poses, the
    next round and whether the labels had settled."""

    labels: dict[str, str]
    cost: float
    M: np.ndarray
    next: int
    settled: bool


def _rounds(trial: Trial, Xs: np.ndarray, M: np.ndarray, tall: np.ndarray, names: list[str],
            posed: Callable[[dict[str, str]], np.ndarray], stop: int = ROUNDS,
            resume: _Rounds | None = None) -> _Rounds:
    """Step 1 and 2 of the module docstring from the model's markers `M` (frames, markers, 3), rounds up to
    `stop` (or until the labels settle); `posed(labels)`: the model's markers posed to those labels (_posed);
    `resume`: go on from where an earlier call stopped."""
    n = Xs.shape[1]
    labels: dict[str, str] = {} if resume is None else resume.labels
    cost = np.inf if resume is None else resume.cost
    if resume is not None and resume.settled:
        return resume
    k = 0 if resume is None else resume.next
    while k < stop:
        leave = max(NEAR, FAR * SHRINK**k)
        C = _median_distances(Xs[tall] if k == 0 else Xs, M[tall] if k == 0 else M)
        rows, cols = linear_sum_assignment(np.hstack([C, np.full((n, n), leave)]))
        new = {trial.labels[i]: names[j] for i, j in zip(rows, cols, strict=True) if j < len(names)}
        cost = float(sum(C[i, j] if j < len(names) else NEAR for i, j in zip(rows, cols, strict=True)))
        k += 1
        if new == labels and leave <= NEAR:
            return _Rounds(labels, cost, M, k, True)
        labels = new
        M = posed(labels)
    return _Rounds(labels, cost, M, k, k >= ROUNDS)


def _posed(kin: Kinematics, trial: Trial, Xs: np.ndarray, params: Parameters,
           labels: dict[str, str]) -> np.ndarray:
    """The model's markers (frames, markers, 3) posed by inverse kinematics to `labels`."""
    sub = Trial(fitted_names(trial.labels, labels), Xs, trial.rate, 0, None)
    m = inverse_kinematics(kin, sub, params, max_iterations=15, tolerance=DECISION_TOLERANCE).motion
    return np.asarray(kin.batch(FrameLayout.coordinates(m.root_translation, m.angles), m.root_quaternion,
                                params)[0])


def _leftovers(trial: Trial, Xs: np.ndarray, M: np.ndarray, names: list[str], labels: dict[str, str],
               cost: float) -> tuple[dict[str, str], float]:
    """The tracks still unlabelled matched to the model's markers still free, within LEFTOVER (a skin or
    wand marker placed further from the base model's place than the rounds' NEAR)."""
    used = set(labels.values())
    tracks = [i for i, t in enumerate(trial.labels) if t not in labels]
    free = [j for j, m in enumerate(names) if m not in used]
    if not tracks or not free:
        return labels, cost
    C = _median_distances(Xs[:, tracks], M[:, free])
    labels = dict(labels)
    for a, b in zip(*linear_sum_assignment(C), strict=True):
        if C[a, b] < LEFTOVER:
            labels[trial.labels[tracks[a]]] = names[free[b]]
            cost += C[a, b] - NEAR
    return labels, cost
