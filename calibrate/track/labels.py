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
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import CalibrateError
from ..io.trial import Trial
from ..model.kinematics import build_kinematics
from ..model.model import Model
from ..seed.association import associate
from ..seed.geometry import kabsch_batch

SCALES = (0.75, 1.3)  # the subject's size relative to the base model's that distances may be scaled by


ROOT_MISFIT = 0.01  # m: RMS inter-marker distance misfit a group may have to be taken for the root


SHAPE_WEIGHT = 5.0  # metres of root-frame distance per metre of inter-marker distance misfit


MAX_LEFTOVER = 0.06  # m: mean misfit of a leftover track's distances to the markers of the neighbouring segments
#                      (median over frames, against the scaled base model) for it to take a free marker's label


MAX_MATCH = 0.3  # m: a lone track matched to a one-marker segment further away is left to step 5


MAX_PERMUTATIONS = 5040  # orderings tried per group (7 markers)


TIE_M = 0.25  # m: Hungarian costs this close count as a tie to settle by inverse kinematics


TIE_SHAPE = 0.002  # m: orderings of a group whose distance misfits are this close are ties


IK_FRAMES = 40  # frames of the subsample the ties are settled on


STANDING_SHARE = 0.1  # share of the frames, those with the tallest posture, whose median positions are compared


@dataclass(frozen=True)
class Labelling:
    """Model labels for tracks."""

    labels: dict[str, str]  # track name -> model marker
    groups: list[list[str]]  # the tracks' groups (track names)
    segments: dict[int, str]  # group index -> model segment
    scale: float  # the subject's size relative to the base model (from the root's markers)

    def trial(self, trial: Trial) -> Trial:
        """`trial` with its tracks renamed to the model's labels (unlabelled ones keep their names)."""
        return Trial(_renamed(trial.labels, self.labels), trial.markers, trial.rate, trial.first_frame, trial.source)


def _renamed(names, labels: dict[str, str]) -> list[str]:
    """Track names with their labels; an unlabelled track whose name is someone's label becomes 'track:NAME'."""
    taken = set(labels.values())
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


def label_tracks(model: Model, trial: Trial) -> Labelling:
    """Labels of the base model for the unlabelled tracks of `trial` (module docstring)."""
    X = trial.markers
    assoc = associate(X)
    groups = [list(g) for g in assoc.groups]
    kin = build_kinematics(model)
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
    if not cands:
        raise CalibrateError(f"{model.path}: no group of {len(R_idx)} tracks moves rigidly like the "
                             f"{root.name}'s markers (within {1e3 * ROOT_MISFIT:g} mm of their distances, scaled "
                             f"{SCALES[0]:g}-{SCALES[1]:g}); the tracks cannot be labelled: check the tracks "
                             "(calibrate track without MODEL) and that MODEL has the subject's marker set")
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
            _, perms, errs = _shape(med_dist[a], _distances(neutral[idx]), scale)
            pos = np.array([np.mean(np.linalg.norm(med[g] - ref[[idx[j] for j in p]], axis=1)) for p in perms])
            total = pos + SHAPE_WEIGHT * errs
            k = int(np.argmin(total))
            cost[a, b] = total[k]
            best_perm[a, b] = perms[k]
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
    labels = _settle_ties(model, kin, trial, scale, labels, groups, segs, seg_idx, segments, cost, best_perm,
                          med_dist, neutral)
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
    return Labelling(labels, [[trial.labels[i] for i in g] for g in groups], segments, scale)


def _distances_series(P: np.ndarray) -> np.ndarray:
    """(F, k, k) distances between k tracks in every frame (NaN where one is missing)."""
    return np.linalg.norm(P[:, :, None] - P[:, None, :], axis=-1)


def _settle_ties(model, kin, trial: Trial, scale: float, labels: dict[str, str], groups, segs, seg_idx,
                 segments: dict[int, str], cost: np.ndarray, best_perm, med_dist, neutral) -> dict[str, str]:
    """Labels with near ties settled by the inverse-kinematics fit of the scaled base model (step 4): passes
    over the candidate changes (another ordering of a group, two groups trading segments), each kept when it
    lowers the fit's marker RMS, until a pass changes nothing."""
    from ..solve.ik import inverse_kinematics

    names = model.marker_names
    step = max(1, trial.n_frames // IK_FRAMES)
    markers = trial.markers[::step]
    params = model.parameters()
    params = type(params)(params.scale * scale, params.centre, params.axis, params.marker)

    def fit(lab: dict[str, str]) -> float:
        sub = Trial(_renamed(trial.labels, lab), markers, trial.rate / step, 0, None)
        return float(inverse_kinematics(kin, sub, params, max_iterations=15).rms)

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
