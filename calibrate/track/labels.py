"""From unlabelled tracks to the markers of a base model (seed 002, Section 3, then labels).

1. The tracks are grouped into rigid segments and the groups joined into a tree by seed 002's Section 3
   (calibrate.seed.associate).
2. The root segment (the pelvis) is the group whose inter-marker distances best match the root's markers
   (one overall scale factor in ``SCALES`` allowed; at most ``ROOT_MISFIT`` RMS, else no labels); of its
   orderings that match equally well (a left–right mirror has the same distances), the one whose fitted
   rotation keeps the lab's up axis (+z) up.
3. Every frame's root pose (Kabsch fit of the scaled base-model root markers), reduced to its heading (a
   turn about the lab's vertical: a tilted pelvis must not swing the legs sideways), carries every track
   into the root's frame; each track's median position there, over the frames in which the subject stands
   tallest (``STANDING_SHARE`` of them: nearest the neutral pose), is compared with the base model's
   markers in its neutral pose.  Groups are matched to segments of the same number of markers by a Hungarian assignment
   (scipy's linear_sum_assignment) on the best ordering's cost: mean distance in the root frame plus the
   misfit of the inter-marker distances (a lone track further than ``MAX_MATCH`` is refused); each group's
   ordering gives the labels; of a group of three or more markers, among the orderings its distances cannot
   tell apart, the one whose rigid fit is turned least from the root's heading.
4. Near ties — two orderings of a group whose distances match equally well (a mirror image), or two
   groups of the same size that could trade segments (within ``TIE_M`` of the Hungarian cost) — are
   settled by inverse kinematics of the base model (scaled) on a subsample of frames: the labelling whose
   marker RMS is lower is kept.
5. Tracks left over (a group no segment matched) are matched one by one to the model's markers still
   free (Hungarian) by how well their median distances to the labelled markers of the marker's own and
   neighbouring segments match the scaled base model's, when within ``MAX_LEFTOVER`` metres on average;
   the rest keep their track names (the calibration then places them on segments by rigidity, or leaves
   them out).

Two refinements for what real tracking gives (docs/tracking.md, "Labelling"):

* Grouping (step 1) and the distances of steps 2–5 use the tracks with their spikes removed (``_despiked``:
  frames further than ``SPIKE_Z`` robust SDs, and ``SPIKE_MIN``, from the track's running median over
  ``SPIKE_WINDOW`` frames): a few frames in which a track followed another marker's rays must not make a rigid
  group look loose.  The trial itself is labelled as it is.
* 4b. A group that no single segment took is matched to a chain of up to ``MAX_CHAIN`` adjacent segments
  still free (through segments without markers) holding as many markers: forearm, wrist and hand barely
  bend in walking, so their markers form one rigid group.  Cost as in step 3, cheapest first, at most
  ``MAX_CHAIN_COST``; orderings its distances cannot tell apart settled by the inverse-kinematics fit.
* 6. Repair by the base model's fit (inverse kinematics of the scaled base model on ``IK_FRAMES`` frames,
  judged by the median frame's marker RMS so that a few frames gone astray do not decide): the two markers
  of every two-marker segment are tried exchanged; a marker fitted ``SUSPECT`` times worse than the median
  marker is tried swapped with the labelled markers of its own and the neighbouring segments, and moved
  to their free markers; a track still unlabelled is tried on the free markers next to labelled ones.
  The change that helps most is kept, at most ``REPAIR_ROUNDS`` times.  Each change is first fitted on every
  ``REPAIR_SCREEN``-th of those frames, and on all of them only where it scores within ``REPAIR_MARGIN`` of helping.
* 7. What step 6 cannot mend: the well-fitted markers are trusted and every other track is matched afresh
  by its distances to the trusted markers of the nearest segment up the tree (``_relabel_limbs``), kept
  only if it labels as many tracks and fits better.
* 2b. When no group can be the root (skin markers, whose groups split): the base model fitted instead
  (calibrate.track.fitting: tracks assigned to the scaled model's markers and the model posed to them in
  turn, as iterative closest point does), then step 8; refused in one line if it labels fewer than half
  the tracks.
* 8. A track still unlabelled that continues a labelled one — seen with it in at most ``OVERLAP_FRAMES``
  frames, its distances to the marker's segment-mates the same — is joined to it (``_continuations``;
  ``Labelling.merged``, as the tracks of one group joined before grouping).
* 9. Where the groups gave a root, the base model is fitted too (step 2b) and the labelling a calibration
  of the subject supports is kept (``better_labelling``): skin markers that still group (simulated
  soft-tissue artefact) give wrong groups, and the fit can turn a rigid trial's foot round.

Measured on 8 simulated 8-camera trials (300 frames, squats and gait) and the 1000-frame benchmark trial:
every track labelled right in all but one, in which one arm's six markers stay scrambled (the scaled
base model fits that small subject to 43 mm in the median frame even with the true labels, too loosely
to tell its arm's markers apart).
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..calibration.records import Progress
from ..errors import CalibrateError
from ..io.motion import Motion
from ..io.trial import Trial
from ..model.kinematics import build_kinematics
from ..model.model import Model
from ..problem.problem import compiled_kinematics
from ..seed.association import associate
from ..seed.geometry import kabsch_batch
from .fitting import fit_labels, fitted_names

SCALES = (0.75, 1.3)  # the subject's size relative to the base model's that distances may be scaled by


ROOT_MISFIT = 0.01  # m: RMS inter-marker distance misfit a group may have to be taken for the root


SHAPE_WEIGHT = 5.0  # metres of root-frame distance per metre of inter-marker distance misfit


MAX_LEFTOVER = 0.06  # m: mean misfit of a leftover track's distances to the markers of the neighbouring segments
#                      (median over frames, against the scaled base model) for it to take a free marker's label


MAX_MATCH = 0.3  # m: a lone track matched to a one-marker segment further away is left to step 5


MAX_PERMUTATIONS = 5040  # orderings tried per group (7 markers)


TIE_M = 0.25  # m: Hungarian costs this close count as a tie to settle by inverse kinematics


TIE_SHAPE = 0.002  # m: orderings of a group whose distance misfits are this close are ties


MAX_CHAIN = 3  # adjacent segments a group that no single segment took may span (step 4b)


MAX_CHAIN_COST = 0.6  # m: largest step-3 cost (root-frame distance + shape misfit) of a group on a chain


SPIKE_WINDOW = 15  # frames of the running median a track is despiked against before grouping
SPIKE_PASSES = 2  # a second pass catches a spike's frames the first one's medians leaned towards
SPIKE_MIN = 0.005  # m: departures from it smaller than this are never spikes
SPIKE_Z = 6.0  # robust SDs of the track's own departures beyond which a frame is a spike


SUSPECT = 2.0  # a marker the scaled base model fits this many times worse than the median marker is suspect (step 6)


REPAIR_ROUNDS = 4  # changes step 6 may make, one per round


# Step 6 fits each change first on every REPAIR_SCREEN-th of its IK_FRAMES frames (scored against the same frames of
# the current labels' fit), and on all of them only where it scores above -REPAIR_MARGIN there: on bench_labelling's
# simulated squats and gait (STA 3 mm) 111 of 778 changes went on, and in all 13 rounds where a change helped the one
# that helped most on every frame was among them (docs/benchmarks.md)
REPAIR_SCREEN = 4
REPAIR_MARGIN = 0.002  # m


JOIN_FACTOR = 1.5  # a union of two groups taken for the root may vary this much more than either group
CHECK_FRAMES = 2000  # frames step 9's calibrations read at most (a longer trial: every k-th frame)
CHECK_NOISE = 0.002  # m: the markers' noise SD those calibrations assume (fixed, so their costs compare)
CHECK_RATIO = 3.0  # a labelling whose calibration fits this many times worse (chi-square) is the wrong one
UNLABELLED_MOVE = 0.06  # m: what a track left unlabelled counts as in step 9 (3 times the markers' prior SD)


RIGID_SD = 0.0005  # m: the SD of a rigid pair's distance assumed at least (tracked markers' noise)


OVERLAP_FRAMES = 2  # frames two tracks of one marker may share (the ends a track followed a stray ray in)


SAME_MARKER = 0.01  # m: two tracks of a group never seen together are one marker if their distances to the rest agree


MAX_RELABEL = 0.1  # m: mean distance misfit beyond which step 7 leaves a track unlabelled


IK_FRAMES = 40  # frames of the subsample the ties are settled on


STANDING_SHARE = 0.1  # share of the frames, those with the tallest posture, whose median positions are compared


@dataclass(frozen=True)
class Labelling:
    """Model labels for tracks."""

    labels: dict[str, str]  # track name -> model marker
    groups: list[list[str]]  # the tracks' groups (track names)
    segments: dict[int, str]  # group index -> model segment
    scale: float  # the subject's size relative to the base model (from the root's markers)

    merged: dict[str, str] = field(default_factory=dict)  # a track found to be another's marker -> that track
    # The base model's marker names: an unlabelled track never keeps one as its name (the tracker's track
    # 'T10' written into the labelled C3D would be read back as the model's marker T10).
    reserved: frozenset[str] = frozenset()

    def trial(self, trial: Trial) -> Trial:
        """`trial` with the tracks of one marker joined (`merged`) and its tracks renamed to the model's
        labels (unlabelled ones keep their names, or become 'track:NAME' where that is a model marker's)."""
        trial = _merged(trial, self.merged)
        return Trial(_renamed(trial.labels, self.labels, self.reserved), trial.markers, trial.rate, trial.first_frame,
                     trial.source)


def _merged(trial: Trial, merged: dict[str, str]) -> Trial:
    """`trial` with each track of `merged` moved into the track it maps to (its frames fill that track's gaps)."""
    if not merged:
        return trial
    M = np.array(trial.markers, dtype=float)
    for drop, keep in merged.items():
        i, j = trial.labels.index(keep), trial.labels.index(drop)
        gap = ~np.isfinite(M[:, i, 0])
        M[gap, i] = M[gap, j]
    cols = [k for k, x in enumerate(trial.labels) if x not in merged]
    return Trial([trial.labels[k] for k in cols], M[:, cols], trial.rate, trial.first_frame, trial.source)


def _joined_root(X: np.ndarray, groups: list[list[int]], size: int) -> tuple[int, int] | None:
    """Two groups of `size` tracks in all whose union is as rigid as the groups themselves (the largest
    SD of a distance within the union at most ``JOIN_FACTOR`` times the largest within either): the grouping
    split a segment that moves as one.  The most rigid such pair, or None."""
    def spread(g: list[int]) -> float:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            sd = np.nanstd(_distances_series(X[:, g]), axis=0)
        return float(np.nanmax(sd)) if len(g) > 1 else 0.0

    best, out = np.inf, None
    for a, b in itertools.combinations(range(len(groups)), 2):
        if len(groups[a]) + len(groups[b]) != size or len(groups[a]) < 2 or len(groups[b]) < 2:
            continue
        own = max(spread(groups[a]), spread(groups[b]), RIGID_SD)
        union = spread(groups[a] + groups[b])
        if union <= JOIN_FACTOR * own and union < best:
            best, out = union, (a, b)
    return out


def _same_markers(X: np.ndarray, groups: list[list[int]], names: list[str]) -> dict[str, str]:
    """Tracks of one marker in a rigid group: two tracks never seen in the same frame whose median
    distances to the group's other tracks agree within ``SAME_MARKER`` (a track the tracker lost and
    started again, too late or too far away to be stitched).  Returns {the shorter: the longer}."""
    seen = np.isfinite(X[..., 0])
    out: dict[str, str] = {}
    for g in groups:
        if len(g) < 3:
            continue
        for i, j in itertools.combinations(sorted(g, key=lambda k: -seen[:, k].sum()), 2):
            if names[i] in out or names[j] in out or np.any(seen[:, i] & seen[:, j]):
                continue
            others = [k for k in g if k not in (i, j) and names[k] not in out]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                di = np.nanmedian(np.linalg.norm(X[:, [i]] - X[:, others], axis=2), axis=0)
                dj = np.nanmedian(np.linalg.norm(X[:, [j]] - X[:, others], axis=2), axis=0)
            if np.all(np.isfinite(di - dj)) and np.max(np.abs(di - dj)) <= SAME_MARKER:
                out[names[j]] = names[i]
    return out


def _renamed(names, labels: dict[str, str], reserved: frozenset[str] = frozenset()) -> list[str]:
    """Track names with their labels; an unlabelled track whose name is someone's label or in `reserved` (the
    model's markers) becomes 'track:NAME'."""
    taken = set(labels.values()) | reserved
    return [labels.get(x, f"track:{x}" if x in taken else x) for x in names]


def _distances(P: np.ndarray) -> np.ndarray:
    return np.linalg.norm(P[:, None] - P[None], axis=-1)


def _orderings(k: int):
    perms = itertools.permutations(range(k))
    return list(itertools.islice(perms, MAX_PERMUTATIONS))


def _shape(Dg: np.ndarray, Ds: np.ndarray, scale: float | None) -> tuple[float, list[tuple[int, ...]], np.ndarray]:
    """Least inter-marker distance misfit (m, RMS over pairs) of a group (k, k) against a segment's
    distances, over orderings, the scale fitted when None; returns it, every ordering's misfit."""
    k = len(Dg)
    perms = _orderings(k)
    iu = np.triu_indices(k, 1)
    if k < 2:
        return 0.0, perms, np.zeros(len(perms))
    errs = np.empty(len(perms))
    for i, p in enumerate(perms):
        d = Ds[np.ix_(p, p)][iu]
        c = scale if scale is not None else float(np.clip(d @ Dg[iu] / max(d @ d, 1e-12), *SCALES))
        errs[i] = np.sqrt(np.mean((Dg[iu] - c * d) ** 2))
    return float(errs.min()), perms, errs


def label_tracks(model: Model, trial: Trial, progress: Callable[[Progress], None] | None = None) -> Labelling:
    """Labels of the base model for the unlabelled tracks of `trial` (module docstring).  `progress`: told each
    step as it starts (stage 'labels'; tens of seconds on a long trial, most of it fitting the base model)."""
    def say(text: str, long: bool = False) -> None:
        if progress is not None:
            progress(Progress("labels", text, long=long))

    original = trial
    say(f"{trial.n_markers} tracks grouped into rigid segments by the variance of their distances (seed 002)",
        long=True)  # the labelling takes seconds to minutes: announced at once
    X = _despiked(trial.markers)
    assoc = associate(X)
    merged = _same_markers(X, [list(g) for g in assoc.groups], list(trial.labels))
    if merged:  # one marker's tracks joined, then grouped again
        trial = _merged(trial, merged)
        X = _despiked(trial.markers)
        assoc = associate(X)
    groups = [list(g) for g in assoc.groups]
    kin = compiled_kinematics(build_kinematics(model))  # 100+ frame-wise fits of one model follow
    neutral = np.asarray(kin.markers(np.zeros(model.nz), np.array([0.0, 0.0, 0.0, 1.0]), model.parameters()))
    names = model.marker_names
    segs = [s for s in model.segments if s.markers]
    seg_idx = {s.name: [names.index(m) for m in s.markers] for s in segs}
    med_dist = [np.nanmedian(_distances_series(X[:, g]), axis=0) for g in groups]
    root = segs[0]
    R_idx = seg_idx[root.name]
    # 2. the root: best distance match among groups of its size; the mirror resolved by the up axis
    cands = [(i, *_shape(med_dist[i], _distances(neutral[R_idx]), None)) for i, g in enumerate(groups)
             if len(g) == len(R_idx)]
    cands = [c for c in cands if c[1] <= ROOT_MISFIT]
    if not cands:  # the root's markers split into two groups that together move as one
        joined = _joined_root(X, groups, len(R_idx))
        if joined is not None:
            a, b = joined
            groups = [g for k, g in enumerate(groups) if k not in (a, b)] + [groups[a] + groups[b]]
            med_dist = [np.nanmedian(_distances_series(X[:, g]), axis=0) for g in groups]
            cands = [(len(groups) - 1, *_shape(med_dist[-1], _distances(neutral[R_idx]), None))]
            cands = [c for c in cands if c[1] <= ROOT_MISFIT]
    if not cands:  # skin markers that do not group into rigid segments: the base model fitted instead
        say(f"no group moves like the {root.name}'s markers: the scaled base model fitted to the tracks instead")
        fitted = _by_fitting(model, kin, trial, X, groups, merged)
        if 2 * len(fitted.labels) < trial.n_markers:
            raise CalibrateError(f"{model.path}: the tracks neither group into the model's rigid segments (no "
                                 f"group moves like the {root.name}'s markers) nor does the scaled base model fit "
                                 f"them ({len(fitted.labels)} of {trial.n_markers} tracks labelled); check the "
                                 "tracks (calibrate track without MODEL) and that MODEL has the subject's marker set")
        return fitted
    gi, best, perms, errs = min(cands, key=lambda c: c[1])
    iu = np.triu_indices(len(R_idx), 1)
    tied = [perms[i] for i in np.flatnonzero(errs <= best + 0.002)]
    Dr = _distances(neutral[R_idx])[iu]
    scale = float(Dr @ med_dist[gi][iu] / (Dr @ Dr))
    world = X[:, groups[gi]]
    seen = np.all(np.isfinite(world), axis=2)
    filled = np.where(seen[..., None], world, 0.0)
    up_best, frames = -np.inf, None
    for p in tied:
        local = scale * neutral[[R_idx[j] for j in p]]
        R, t = kabsch_batch(local, filled, seen.astype(float))
        up = np.nanmean(R[:, 2, 2])
        if up > up_best:
            up_best, frames = up, (R, t)
    R, t = frames
    # 3. every track in the root's frame (the base model's neutral pose is that frame, scaled)
    # the root's heading only (a turn about the lab's vertical): the body stands on the floor, so a tilted
    # pelvis must not swing the legs sideways in the frame the positions are compared in
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    c, s_ = np.cos(yaw), np.sin(yaw)
    H = np.zeros_like(R)
    H[:, 0, 0], H[:, 0, 1], H[:, 1, 0], H[:, 1, 1], H[:, 2, 2] = c, -s_, s_, c, 1.0
    Y = np.einsum("fji,fnj->fni", H, X - t[:, None, :])
    # the frames nearest the neutral pose: the subject standing tallest (largest vertical span of the tracks)
    with warnings.catch_warnings():  # a frame without the root's pose (its markers unseen) has no span
        warnings.simplefilter("ignore", RuntimeWarning)
        span = np.nanmax(Y[..., 2], axis=1) - np.nanmin(Y[..., 2], axis=1)
    ok = np.isfinite(span)
    tall = np.flatnonzero(ok & (span >= np.quantile(span[ok], 1 - STANDING_SHARE)))
    with warnings.catch_warnings():  # tracks unseen while standing tall: their median over every frame
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(Y[tall], axis=0)
        med = np.where(np.isfinite(med), med, np.nanmedian(Y, axis=0))
    ref = scale * neutral
    cost = np.full((len(groups), len(segs)), 1e6)
    best_perm: dict[tuple[int, int], tuple[int, ...]] = {}
    for a, g in enumerate(groups):
        for b, s in enumerate(segs):
            idx = seg_idx[s.name]
            if len(idx) != len(g):
                continue
            cost[a, b], best_perm[a, b] = _match_cost(med[g], med_dist[a], neutral, ref, idx, scale)
    cost = np.where(np.isfinite(cost), cost, 1e6)
    rows, cols = linear_sum_assignment(cost)
    for a, b in zip(rows, cols, strict=True):  # a group of 3 or more: of the orderings its distances cannot
        idx = seg_idx[segs[b].name]             # tell apart, the one turned least from the root's heading
        if cost[a, b] < 1e6 and len(idx) >= 3 and a != gi:
            best_perm[a, b] = _upright(X[tall][:, groups[a]], ref, idx, med_dist[a], scale, H[tall])
    labels: dict[str, str] = {}
    segments: dict[int, str] = {}
    used = set()
    for a, b in zip(rows, cols, strict=True):
        if cost[a, b] >= 1e6 or (len(groups[a]) == 1 and cost[a, b] > MAX_MATCH):  # a lone track far from
            continue                                                                # the segment: step 5
        idx = seg_idx[segs[b].name]
        for track, j in zip(groups[a], best_perm[a, b], strict=True):
            labels[trial.labels[track]] = names[idx[j]]
            used.add(idx[j])
        segments[a] = segs[b].name
    # 4. near-ties settled by how well the scaled base model fits (inverse kinematics on a subsample)
    say(f"{len(segments)} of {len(groups)} groups matched to {model.path.name}'s segments; near ties settled by "
        "fitting the scaled base model")
    labels = _settle_ties(model, kin, trial, scale, labels, groups, segs, seg_idx, segments, cost, best_perm,
                          med_dist, neutral)
    # 4b. groups no single segment took: a chain of adjacent segments not yet taken that moves as one body
    #     (forearm, wrist and hand barely bend in walking: their markers form one rigid group)
    taken = set(segments.values())
    free_segs = [s.name for s in segs if s.name not in taken and s.name != root.name]
    for a, chain, idx, perm in _chain_matches(model, groups, set(segments), free_segs, seg_idx, med, med_dist,
                                              neutral, ref, scale):
        _, perms, errs = _shape(med_dist[a], _distances(neutral[idx]), scale)
        tied = [perms[k] for k in np.flatnonzero(errs <= errs[perms.index(perm)] + TIE_SHAPE)]
        if len(tied) > 1:  # orderings its distances cannot tell apart (a mirror pair): the base model's fit
            fits = [_ik_rms(model, kin, trial, scale, labels | {trial.labels[t]: names[idx[j]]
                                                                for t, j in zip(groups[a], q, strict=True)})
                    for q in tied]
            perm = tied[int(np.argmin(fits))]
        for track, j in zip(groups[a], perm, strict=True):
            labels[trial.labels[track]] = names[idx[j]]
        segments[a] = "+".join(chain)
    used = {names.index(v) for v in labels.values()}
    # 5. leftovers one by one, by their distances to the labelled tracks of the neighbouring segments
    left = [i for i in range(trial.n_markers) if trial.labels[i] not in labels]
    free = [j for j in range(len(names)) if j not in used and model.markers[j].segment in seg_idx]
    if left and free:
        near = _neighbours(model)
        where = {v: trial.labels.index(k) for k, v in labels.items()}
        C = np.full((len(left), len(free)), np.inf)
        for c, j in enumerate(free):
            mates = [names.index(x) for s_ in near[model.markers[j].segment] for x in model.segments[
                model.segment_index(s_)].markers if x in where]
            if not mates:
                continue
            cols = [where[names[x]] for x in mates]
            d = np.nanmedian(np.linalg.norm(X[:, left][:, :, None] - X[:, cols][:, None], axis=-1), axis=0)
            want = scale * np.linalg.norm(neutral[j] - neutral[mates], axis=1)
            C[:, c] = np.nanmean(np.abs(d - want[None]), axis=1)
        C = np.where(np.isfinite(C), C, 1e6)
        for r, c in zip(*linear_sum_assignment(C), strict=True):
            if C[r, c] < MAX_LEFTOVER:
                labels[trial.labels[left[r]]] = names[free[c]]
    # 6. what the base model's fit still shows: a swapped pair, a track on a neighbour's marker, a track left out
    say(f"{len(labels)} tracks labelled; the base model's fit checked for swapped pairs, a neighbour's markers and "
        "tracks left out")
    labels = _repair(model, kin, trial, scale, labels)
    labels = _relabel_limbs(model, kin, X, trial, scale, labels, neutral, med, ref)
    # 8. a track still unlabelled that continues a labelled one (one marker lost and found again)
    grouped = Labelling(labels, [[trial.labels[i] for i in g] for g in groups], segments, scale,
                        merged | _continuations(model, X, trial.labels, labels), frozenset(model.marker_names))
    # 9. the base model fitted as well (step 2b), and the labelling whose calibration fits better kept
    say("the scaled base model fitted to the tracks as well (every heading): a second labelling")
    fitted = _by_fitting(model, kin, trial, X, groups, merged)
    if fitted.labels != grouped.labels:
        say("the two labellings differ: each calibrated, the one the subject's fit supports kept")
    return better_labelling(model, original, grouped, fitted)


def _continuations(model: Model, X: np.ndarray, names: list[str], labels: dict[str, str]) -> dict[str, str]:
    """Unlabelled tracks that are a labelled track's marker at other times: seen together with it in at
    most ``OVERLAP_FRAMES`` frames, and with median distances to the labelled markers of that marker's
    segment (else of its neighbours) within ``SAME_MARKER`` of its own.  Only a track that continues
    exactly one labelled track is joined to it.  Returns {unlabelled track: labelled track}."""
    seen = np.isfinite(X[..., 0])
    col = {t: i for i, t in enumerate(names)}
    track_of = {v: k for k, v in labels.items()}
    seg_of = {m.name: m.segment for m in model.markers}
    on = {sg.name: [m for m in sg.markers if m in track_of] for sg in model.segments}
    near = _neighbours(model)
    out: dict[str, str] = {}
    for u in [t for t in names if t not in labels]:
        hits = []
        for t, m in labels.items():
            if np.sum(seen[:, col[u]] & seen[:, col[t]]) > OVERLAP_FRAMES:
                continue
            refs = [x for x in on[seg_of[m]] if x != m] or \
                [x for sg in near[seg_of[m]] if sg != seg_of[m] for x in on[sg]]
            if not refs:
                continue
            cols = [col[track_of[x]] for x in refs]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                du = np.nanmedian(np.linalg.norm(X[:, [col[u]]] - X[:, cols], axis=2), axis=0)
                dt = np.nanmedian(np.linalg.norm(X[:, [col[t]]] - X[:, cols], axis=2), axis=0)
            if np.all(np.isfinite(du - dt)) and np.max(np.abs(du - dt)) <= SAME_MARKER:
                hits.append(t)
        if len(hits) == 1 and hits[0] not in out.values():
            out[u] = hits[0]
    return out


def _by_fitting(model: Model, kin, trial: Trial, X: np.ndarray, groups: list[list[int]],
                merged: dict[str, str]) -> Labelling:
    """The labelling by fitting the scaled base model to the tracks (calibrate.track.fitting; no groups
    needed), then step 8."""
    fitted = fit_labels(model, kin, trial, X)
    merged = merged | _continuations(model, X, trial.labels, fitted.labels)
    return Labelling(fitted.labels, [[trial.labels[i] for i in g] for g in groups], {}, fitted.scale, merged,
                     frozenset(model.marker_names))


def better_labelling(model: Model, trial: Trial, grouped: Labelling, fitted: Labelling) -> Labelling:
    """Of two labellings of `trial`'s tracks (the groups' and the fitted base model's), the one a
    calibration of the subject supports (step 9).  Each labelling's tracks are calibrated at the fixed
    noise ``CHECK_NOISE`` (`_check`).  Where one fits its markers more than ``CHECK_RATIO`` times worse
    (chi-square per observed coordinate), the motion shows its wrong labels: the other is kept.  Otherwise
    the motion cannot tell them apart (a label moved across a joint the trial barely bends: a walk's
    elbows), and on the tracks the two label differently, the labelling whose calibration moves none of
    their markers as far from its place on the base model is kept — a label taken from another segment
    moves its marker by the distance between the two; a track left unlabelled counts as ``UNLABELLED_MOVE``.
    Ties go to the groups."""
    if grouped.labels == fitted.labels:
        return grouped
    (fit_g, moved_g), (fit_f, moved_f) = _check(model, trial, grouped), _check(model, trial, fitted)
    if fit_f > CHECK_RATIO * fit_g:
        return grouped
    if fit_g > CHECK_RATIO * fit_f:
        return fitted
    differ = [t for t in set(grouped.labels) | set(fitted.labels) if grouped.labels.get(t) != fitted.labels.get(t)]

    def worst(labelling: Labelling, moved: dict[str, float]) -> float:
        return max(moved.get(labelling.labels[t], np.inf) if t in labelling.labels else UNLABELLED_MOVE
                   for t in differ)

    return fitted if worst(fitted, moved_f) < worst(grouped, moved_g) else grouped


def _check(model: Model, trial: Trial, labelling: Labelling) -> tuple[float, dict[str, float]]:
    """`model` calibrated to the tracks `labelling` labels (`better_labelling`; at most ``CHECK_FRAMES``
    frames, a longer trial read every k-th frame): its chi-square per observed coordinate at
    ``CHECK_NOISE``, and each labelled marker's distance (m) from its place on the base model (inf and {}
    when it cannot calibrate).  The whole trial, not a sparse subsample: squats read at a quarter of their
    100 Hz end with a wrist 130 mm off even with the right labels."""
    from ..calibration.pipeline import calibrate
    from ..problem.settings import Settings

    named = labelling.trial(trial)
    keep = [k for k, x in enumerate(named.labels) if x in set(labelling.labels.values())]
    step = -(-named.n_frames // CHECK_FRAMES)
    sub = Trial([named.labels[k] for k in keep], named.markers[::step, keep], named.rate / step, 0, None)
    try:
        cal = calibrate(model, sub, Settings(outliers=0, noise=CHECK_NOISE, learn_noise=False), aliases=False)
    except CalibrateError:
        return np.inf, {}
    coords = 3 * int(np.isfinite(sub.markers[..., 0]).sum())
    moved = {c.item: 0.001 * c.change for c in cal.changes if c.group == "marker" and c.item in sub.labels}
    return 2.0 * cal.summary.final_cost / max(coords, 1), moved


def _fit(model: Model, kin, trial: Trial, scale: float, labels: dict[str, str], start: Motion | None = None,
         every: int = 1):
    """The base model, scaled by `scale`, fitted by inverse kinematics to `labels` on ``IK_FRAMES`` frames of
    `trial` spread over it (calibrate.solve.ik.IKResult); `start`: an earlier such fit's motion to start every
    frame from (labels that differ by a track or two: step 6 in 0.45-0.76x the time, the same labels chosen);
    `every`: only every `every`-th of those frames (`start` then holds those frames)."""
    from ..solve.ik import DECISION_TOLERANCE, inverse_kinematics

    step = max(1, trial.n_frames // IK_FRAMES)
    params = model.parameters()
    params = type(params)(params.scale * scale, params.centre, params.axis, params.marker)
    sub = Trial(fitted_names(trial.labels, labels), trial.markers[::step][::every], trial.rate / step / every, 0, None)
    return inverse_kinematics(kin, sub, params, max_iterations=15, tolerance=DECISION_TOLERANCE, start=start)


def _ik_rms(model: Model, kin, trial: Trial, scale: float, labels: dict[str, str]) -> float:
    """Typical marker RMS (m) of the scaled base model's fit (`_fit`) to `labels` (the median frame's):
    how well a labelling fits."""
    return _typical_rms(_fit(model, kin, trial, scale, labels))


def _typical_rms(res, frames: np.ndarray | slice = slice(None)) -> float:
    """Median over the frames (`frames` of the fit) of the per-frame marker RMS (m): the few frames whose inverse
    kinematics went astray from the base model's pose must not outweigh the rest."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(np.nanmedian(res.marker_rms[frames]))


def _marker_errors(res, names: list[str], labels: dict[str, str],
                   frames: np.ndarray | slice = slice(None)) -> dict[str, float]:
    """Median 3-D distance (m) over the frames (`frames` of the fit) between each labelled model marker and the
    model's."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        err = np.nanmedian(np.linalg.norm(res.residuals[frames], axis=2), axis=0)
    return {names[m]: float(err[m]) for m in range(len(names)) if names[m] in set(labels.values())
            and np.isfinite(err[m])}


def _change_score(res, names: list[str], new: dict[str, str], change: dict[str, str], swap: bool, rms0: float,
                  limit: float) -> float:
    """How much a change of step 6 helps (m; > 0: it helps), from its fit `res` to the labels `new`: a swap (`swap`)
    by how much it lowers the fit's typical RMS from `rms0`, a move or an addition by how far within `limit` the
    marker it places fits."""
    if swap:  # a swap: the whole fit must improve
        return rms0 - _typical_rms(res)
    e = _marker_errors(res, names, new)  # a move or an addition: the marker it places must fit like the others
    return limit - max(e.get(v, np.inf) for v in change.values())


def _motion_frames(motion: Motion, frames: np.ndarray) -> Motion:
    """`motion` on `frames` only."""
    return Motion(motion.times[frames], motion.root_translation[frames], motion.root_quaternion[frames],
                  motion.angles[frames], motion.dof_names)


def _repair(model: Model, kin, trial: Trial, scale: float, labels: dict[str, str]) -> dict[str, str]:
    """Step 6: labels the scaled base model's fit (`_fit`) prefers.  The two markers of every two-marker
    segment are tried exchanged (their distances cannot order them, and the fit of step 4 had fewer
    markers labelled); a marker whose fit is ``SUSPECT`` times worse than the median marker's is tried
    swapped with every labelled marker of its own and the neighbouring segments and moved to every free
    marker there; a track left unlabelled is tried on every free marker whose segment or a neighbour has
    labelled markers.  The change that lowers the fit's RMS most (a swap) or fits the moved or added marker
    within ``SUSPECT`` times the median (a move, an addition) is kept; then again, at most
    ``REPAIR_ROUNDS`` times."""
    names = model.marker_names
    seg_of = {m.name: m.segment for m in model.markers}
    near = _neighbours(model)
    on = {s.name: set(s.markers) for s in model.segments}
    pairs = [tuple(s.markers) for s in model.segments if len(s.markers) == 2]
    paired = {frozenset(q) for q in pairs}
    for _ in range(REPAIR_ROUNDS):
        base = _fit(model, kin, trial, scale, labels)
        err = _marker_errors(base, names, labels)
        if not err:
            return labels
        typical = float(np.median(list(err.values())))
        limit = SUSPECT * typical
        track_of = {v: k for k, v in labels.items()}
        free = [m for m in names if m not in track_of and seg_of[m] in near]
        around = {m: set().union(*(on[x] for x in near[seg_of[m]])) for m in names}
        changes: list[dict[str, str]] = []
        for pair in pairs:  # the two orderings of a two-marker segment have the same distances: the fit decides
            if all(m in track_of for m in pair):
                changes.append({track_of[pair[0]]: pair[1], track_of[pair[1]]: pair[0]})
        for a in sorted(err, key=lambda m: -err[m]):
            if err[a] <= limit:
                break
            for b in sorted(around[a] - {a}):
                if b in track_of and frozenset((a, b)) not in paired:
                    changes.append({track_of[a]: b, track_of[b]: a})
                elif b in free:
                    changes.append({track_of[a]: b})
        placed = set(labels)
        for t in trial.labels:
            if t in placed:
                continue
            for b in free:
                if any(x in track_of for x in around[b]):
                    changes.append({t: b})
        best, best_score = None, 0.0
        rms0 = _typical_rms(base)
        # the screen: every REPAIR_SCREEN-th frame of the fit, the current labels scored on the same frames
        few = np.arange(0, base.motion.n_frames, REPAIR_SCREEN)
        few_start = _motion_frames(base.motion, few)
        few_err = _marker_errors(base, names, labels, few)
        few_limit = SUSPECT * float(np.median(list(few_err.values())))
        few_rms0 = _typical_rms(base, few)
        unique = {frozenset(c.items()): c for c in reversed(changes)}  # a swap found from either side: once
        for change in [c for c in changes if unique.get(frozenset(c.items())) is c]:
            new = {k: v for k, v in labels.items() if k not in change and v not in change.values()}
            new.update(change)
            swap = len(change) == 2 and all(k in labels for k in change)
            res = _fit(model, kin, trial, scale, new, start=few_start, every=REPAIR_SCREEN)
            if _change_score(res, names, new, change, swap, few_rms0, few_limit) <= -REPAIR_MARGIN:
                continue
            res = _fit(model, kin, trial, scale, new, start=base.motion)  # one or two tracks changed
            score = _change_score(res, names, new, change, swap, rms0, limit)
            if score > best_score:
                best, best_score = new, score
        if best is None:
            return labels
        labels = best
    return labels


def _relabel_limbs(model: Model, kin, X: np.ndarray, trial: Trial, scale: float, labels: dict[str, str],
                   neutral: np.ndarray, med: np.ndarray, ref: np.ndarray) -> dict[str, str]:
    """Step 7: what step 6 could not mend.  The markers the scaled base model's fit (`_fit`) fits within
    ``SUSPECT`` times the median are trusted; every other track (suspect or unlabelled) is matched afresh to
    the markers no trusted track holds (Hungarian), by how well its median distances to the trusted markers
    of the nearest segment up the tree that has any match the scaled base model's, then mended as in step 6.
    The new labels are kept when they label as many tracks and the fit's marker RMS drops."""
    names = model.marker_names
    base = _fit(model, kin, trial, scale, labels)
    err = _marker_errors(base, names, labels)
    if not err:
        return labels
    limit = SUSPECT * float(np.median(list(err.values())))
    trusted = {k: v for k, v in labels.items() if err.get(v, np.inf) <= limit}
    if len(trusted) == len(labels) and len(labels) == trial.n_markers:
        return labels
    held = set(trusted.values())
    where = {v: trial.labels.index(k) for k, v in trusted.items()}
    parent = {j.child: j.parent for j in model.joints}
    seg_of = {m.name: m.segment for m in model.markers}
    on = {sg.name: [m for m in sg.markers if m in held] for sg in model.segments}
    free = [m for m in names if m not in held]
    tracks = [i for i, t in enumerate(trial.labels) if t not in trusted
              and np.isfinite(X[:, i, 0]).sum() >= IK_FRAMES // 4]
    if not tracks or not free:
        return labels
    C = np.full((len(tracks), len(free)), 1e6)
    for c, m in enumerate(free):
        sg = seg_of[m]
        while sg is not None and not on[sg]:
            sg = parent.get(sg)
        if sg is None:
            continue
        mates = on[sg]
        cols = [where[x] for x in mates]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            d = np.nanmedian(np.linalg.norm(X[:, tracks][:, :, None] - X[:, cols][:, None], axis=-1), axis=0)
        want = scale * np.linalg.norm(neutral[names.index(m)] - neutral[[names.index(x) for x in mates]], axis=1)
        C[:, c] = np.nan_to_num(np.mean(np.abs(d - want[None]), axis=1), nan=1e6)
    new = dict(trusted)
    on_seg: dict[str, list[tuple[int, str]]] = {}
    for r, c in zip(*linear_sum_assignment(C), strict=True):
        if C[r, c] < MAX_RELABEL:
            on_seg.setdefault(seg_of[free[c]], []).append((tracks[r], free[c]))
    for pairs in on_seg.values():  # a segment's markers among its tracks: by their positions in the root's
        ts, ms = zip(*pairs, strict=True)  # frame (the distances to a parent cannot tell a mirror pair apart)
        P = np.array([[np.linalg.norm(med[t] - ref[names.index(m)]) for m in ms] for t in ts])
        for r, c in zip(*linear_sum_assignment(np.nan_to_num(P, nan=1e3)), strict=True):
            new[trial.labels[ts[r]]] = ms[c]
    if new == labels:
        return labels
    new = _repair(model, kin, trial, scale, new)
    better = len(new) >= len(labels) and _ik_rms(model, kin, trial, scale, new) < _typical_rms(base)
    return new if better else labels


def _match_cost(pos_g: np.ndarray, dist_g: np.ndarray, neutral: np.ndarray, ref: np.ndarray, idx: list[int],
                scale: float) -> tuple[float, tuple[int, ...]]:
    """Step 3's cost of a group (median root-frame positions `pos_g`, median distances `dist_g`) on the
    model markers `idx`: mean distance to their scaled neutral places (`ref`) plus ``SHAPE_WEIGHT`` times
    the distance misfit, for the best ordering; returns it and that ordering."""
    _, perms, errs = _shape(dist_g, _distances(neutral[idx]), scale)
    pos = np.array([np.mean(np.linalg.norm(pos_g - ref[[idx[j] for j in p]], axis=1)) for p in perms])
    total = pos + SHAPE_WEIGHT * errs
    k = int(np.argmin(total))
    return float(total[k]), perms[k]


def _chain_matches(model: Model, groups: list[list[int]], matched: set[int], free_segs: list[str],
                   seg_idx: dict[str, list[int]], med: np.ndarray, med_dist: list[np.ndarray], neutral: np.ndarray,
                   ref: np.ndarray, scale: float) -> list[tuple[int, tuple[str, ...], list[int], tuple[int, ...]]]:
    """Groups of two or more tracks that no single segment took, matched to chains of up to ``MAX_CHAIN``
    adjacent segments (through segments without markers) from `free_segs` holding as many markers: by the
    cost of step 3 against the chain's markers in the base model's neutral pose, cheapest first, no segment
    twice, each at most ``MAX_CHAIN_COST``.  Returns (group, chain, model marker indices, ordering)."""
    near = _neighbours(model)
    free = set(free_segs)
    chains: set[tuple[str, ...]] = set()
    todo = [(s,) for s in free_segs]
    while todo:
        c = todo.pop()
        if len(c) >= 2:
            chains.add(tuple(sorted(c, key=free_segs.index)))
        if len(c) < MAX_CHAIN:
            todo += [(*c, n) for n in sorted({n for x in c for n in near[x]} & free - set(c))]
    options = []
    for a, g in enumerate(groups):
        if a in matched or len(g) < 2:
            continue
        for chain in sorted(chains):
            idx = [i for s in chain for i in seg_idx[s]]
            if len(idx) != len(g):
                continue
            c, perm = _match_cost(med[g], med_dist[a], neutral, ref, idx, scale)
            options.append((c, a, chain, idx, perm))
    out, used_groups, used_segs = [], set(), set()
    for c, a, chain, idx, perm in sorted(options, key=lambda o: o[0]):
        if c <= MAX_CHAIN_COST and a not in used_groups and not used_segs & set(chain):
            out.append((a, chain, idx, perm))
            used_groups.add(a)
            used_segs |= set(chain)
    return out


def _distances_series(P: np.ndarray) -> np.ndarray:
    """(F, k, k) distances between k tracks in every frame (NaN where one is missing)."""
    return np.linalg.norm(P[:, :, None] - P[:, None, :], axis=-1)


def _settle_ties(model, kin, trial: Trial, scale: float, labels: dict[str, str], groups, segs, seg_idx,
                 segments: dict[int, str], cost: np.ndarray, best_perm, med_dist, neutral) -> dict[str, str]:
    """Labels with near ties settled by the inverse-kinematics fit of the scaled base model (step 4): passes
    over the candidate changes (another ordering of a group, two groups trading segments), each kept when it
    lowers the fit's marker RMS, until a pass changes nothing."""
    names = model.marker_names

    def fit(lab: dict[str, str]) -> float:
        return _ik_rms(model, kin, trial, scale, lab)

    col = {s.name: b for b, s in enumerate(segs)}
    order: dict[int, tuple[int, ...]] = {a: best_perm[a, col[sn]] for a, sn in segments.items()}
    assign = dict(segments)

    def named(a: int, sname: str, perm) -> dict[str, str]:
        return {trial.labels[t]: names[seg_idx[sname][j]] for t, j in zip(groups[a], perm, strict=True)}

    def candidates():
        for a, sname in assign.items():  # orderings of a pair that fit its distances as well
            idx = seg_idx[sname]
            if len(idx) != 2:
                continue
            _, perms, errs = _shape(med_dist[a], _distances(neutral[idx]), scale)
            mine = order[a]
            for k in np.flatnonzero(errs <= errs[perms.index(mine)] + TIE_SHAPE):
                if perms[k] != mine:
                    yield {a: (sname, perms[k])}
        for (a1, s1), (a2, s2) in itertools.combinations(sorted(assign.items()), 2):  # two groups trading
            b1, b2 = col[s1], col[s2]
            if len(groups[a1]) != len(groups[a2]) or cost[a1, b2] >= 1e6 or cost[a2, b1] >= 1e6:
                continue
            if cost[a1, b2] + cost[a2, b1] - cost[a1, b1] - cost[a2, b2] < TIE_M:
                yield {a1: (s2, best_perm[a1, b2]), a2: (s1, best_perm[a2, b1])}

    current = fit(labels)
    for _ in range(3):
        changed = False
        for change in list(candidates()):
            if any(assign.get(a) is None for a in change):
                continue
            new = dict(labels)
            for a, (sname, perm) in change.items():
                new.update(named(a, sname, perm))
            if len(set(new.values())) < len(new):
                continue
            rms = fit(new)
            if rms < current - 1e-5:
                labels, current, changed = new, rms, True
                for a, (sname, perm) in change.items():
                    assign[a], order[a] = sname, perm
        if not changed:
            break
    return labels


def _despiked(markers: np.ndarray, window: int = SPIKE_WINDOW) -> np.ndarray:
    """(F, N, 3) tracks with the frames NaN where a track leaves its running median (over `window`
    frames) by more than ``SPIKE_MIN`` and ``SPIKE_Z`` robust SDs of its own departures: a few frames in
    which the tracker followed another detection must not make a rigid group look loose.  For grouping and
    labelling only (a real frame lost there costs nothing); the trial itself is left as it is."""
    from numpy.lib.stride_tricks import sliding_window_view

    X = np.array(markers, dtype=float)
    h = window // 2
    for n in [n for _ in range(SPIKE_PASSES) for n in range(X.shape[1])]:
        x = X[:, n]
        pad = np.pad(x, ((h, h), (0, 0)), constant_values=np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(sliding_window_view(pad, window, axis=0), axis=-1)
            dev = np.linalg.norm(x - med, axis=1)
            scale = 1.4826 * np.nanmedian(dev)
        bad = dev > max(SPIKE_MIN, SPIKE_Z * (scale if np.isfinite(scale) else 0.0))
        X[bad, n] = np.nan
    return X


def _upright(world: np.ndarray, ref: np.ndarray, idx: list[int], dist: np.ndarray, scale: float,
             heading: np.ndarray) -> tuple[int, ...]:
    """Of a group's orderings whose distances fit equally well, the one whose rigid fit (the scaled base-model
    markers `ref[idx]` onto the tracks `world` (F, k, 3)) is turned least from the `heading` frames (F, 3, 3)."""
    _, perms, errs = _shape(dist, _distances(ref[idx] / scale), scale)
    seen = np.all(np.isfinite(world), axis=2)
    filled = np.where(seen[..., None], world, 0.0)
    best, out = -np.inf, perms[int(np.argmin(errs))]
    for k in np.flatnonzero(errs <= errs.min() + TIE_SHAPE):
        R, _ = kabsch_batch(ref[[idx[j] for j in perms[k]]], filled, seen.astype(float))
        score = np.nanmean(np.einsum("fij,fij->f", heading, R))  # trace(Hᵀ R): 3 when aligned
        if score > best:
            best, out = score, perms[k]
    return out


def _neighbours(model: Model) -> dict[str, list[str]]:
    """Every segment with its neighbours in the tree (parent and children), through segments without markers."""
    adj: dict[str, set[str]] = {s.name: set() for s in model.segments}
    for j in model.joints:
        adj[j.parent].add(j.child)
        adj[j.child].add(j.parent)
    bare = {s.name for s in model.segments if not s.markers}
    out = {}
    for s in adj:
        seen, todo = {s}, [s]
        while todo:
            for n in adj[todo.pop()]:
                if n not in seen:
                    seen.add(n)
                    if n in bare:
                        todo.append(n)
        out[s] = sorted(seen - bare)
    return out
