"""From unlabelled tracks to the markers of a base model (seed 002, Section 3, then labels).

1. The tracks are grouped into rigid segments and the groups joined into a tree by seed 002's Section 3
   (calibrate.seed.associate).
2. The root segment (the pelvis) is the group whose inter-marker distances best match the root's markers
   (one overall scale factor allowed); of its orderings that match equally well (a left–right mirror has
   the same distances), the one whose fitted rotation keeps the lab's up axis (+z) up.
3. Every frame's root pose (Kabsch fit of the scaled base-model root markers) carries every track into
   the root's frame; each track's median position there is compared with the base model's markers in its
   neutral pose.  Groups are matched to segments of the same number of markers by a Hungarian assignment
   (scipy's linear_sum_assignment) on the best ordering's cost: mean distance in the root frame plus the
   misfit of the inter-marker distances; each group's ordering gives the labels.
4. Near ties — two orderings of a group whose distances match equally well (a mirror image), or two
   groups of the same size that could trade segments (within ``TIE_M`` of the Hungarian cost) — are
   settled by inverse kinematics of the base model (scaled) on a subsample of frames: the labelling whose
   marker RMS is lower is kept.
5. Tracks left over (a group no segment matched) are matched one by one to the model's markers still
   free, by distance in the root frame, when within ``MAX_LEFTOVER`` metres; the rest keep their track
   names (the calibration then places them on segments by rigidity, or leaves them out).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import CalibrateError
from ..io.trial import Trial
from ..model.kinematics import build_kinematics
from ..model.model import Model
from ..seed.association import associate
from ..seed.geometry import kabsch_batch

SHAPE_WEIGHT = 5.0  # metres of root-frame distance per metre of inter-marker distance misfit


MAX_LEFTOVER = 0.15  # m: a leftover track this close (root frame, median) to a free model marker takes its label


MAX_PERMUTATIONS = 5040  # orderings tried per group (7 markers)


TIE_M = 0.05  # m: Hungarian costs this close count as a tie to settle by inverse kinematics


TIE_SHAPE = 0.002  # m: orderings of a group whose distance misfits are this close are ties


IK_FRAMES = 60  # frames of the subsample the ties are settled on


@dataclass(frozen=True)
class Labelling:
    """Model labels for tracks."""

    labels: dict[str, str]  # track name -> model marker
    groups: list[list[str]]  # the tracks' groups (track names)
    segments: dict[int, str]  # group index -> model segment
    scale: float  # the subject's size relative to the base model (from the root's markers)

    def trial(self, trial: Trial) -> Trial:
        """`trial` with its tracks renamed to the model's labels (unlabelled ones keep their names)."""
        return Trial([self.labels.get(x, x) for x in trial.labels], trial.markers, trial.rate, trial.first_frame,
                     trial.source)


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
        c = scale if scale is not None else float(d @ Dg[iu] / max(d @ d, 1e-12))
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
    if not cands:
        raise CalibrateError(f"{model.path}: no group of {len(R_idx)} tracks moves rigidly like the "
                             f"{root.name}'s markers; the tracks cannot be labelled")
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
    Y = np.einsum("fji,fnj->fni", R, X - t[:, None, :])
    med = np.nanmedian(Y, axis=0)
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
    rows, cols = linear_sum_assignment(cost)
    labels: dict[str, str] = {}
    segments: dict[int, str] = {}
    used = set()
    for a, b in zip(rows, cols, strict=True):
        if cost[a, b] >= 1e6:
            continue
        idx = seg_idx[segs[b].name]
        for track, j in zip(groups[a], best_perm[a, b], strict=True):
            labels[trial.labels[track]] = names[idx[j]]
            used.add(idx[j])
        segments[a] = segs[b].name
    # 4. near-ties settled by how well the scaled base model fits (inverse kinematics on a subsample)
    labels = _settle_ties(model, kin, trial, scale, labels, groups, segs, seg_idx, segments, cost, best_perm,
                          med_dist, neutral)
    used = {names.index(v) for v in labels.values()}
    # 5. leftovers one by one
    left = [i for i in range(trial.n_markers) if trial.labels[i] not in labels and np.all(np.isfinite(med[i]))]
    free = [j for j in range(len(names)) if j not in used and model.markers[j].segment in seg_idx]
    if left and free:
        C = np.linalg.norm(med[left][:, None] - ref[free][None], axis=2)
        for r, c in zip(*linear_sum_assignment(C), strict=True):
            if C[r, c] < MAX_LEFTOVER:
                labels[trial.labels[left[r]]] = names[free[c]]
    return Labelling(labels, [[trial.labels[i] for i in g] for g in groups], segments, scale)


def _distances_series(P: np.ndarray) -> np.ndarray:
    """(F, k, k) distances between k tracks in every frame (NaN where one is missing)."""
    return np.linalg.norm(P[:, :, None] - P[:, None, :], axis=-1)


def _settle_ties(model, kin, trial: Trial, scale: float, labels: dict[str, str], groups, segs, seg_idx,
                 segments: dict[int, str], cost: np.ndarray, best_perm, med_dist, neutral) -> dict[str, str]:
    """Labels with near ties settled by the inverse-kinematics fit of the scaled base model (step 4)."""
    from ..solve.ik import inverse_kinematics

    names = model.marker_names
    step = max(1, trial.n_frames // IK_FRAMES)
    markers = trial.markers[::step]
    params = model.parameters()
    params = type(params)(params.scale * scale, params.centre, params.axis, params.marker)

    def fit(lab: dict[str, str]) -> float:
        sub = Trial([lab.get(x, x) for x in trial.labels], markers, trial.rate / step, 0, None)
        return float(inverse_kinematics(kin, sub, params, max_iterations=15).rms)

    candidates: list[dict[str, str]] = []  # label changes to try
    seg_of = {v: k for k, v in segments.items()}
    col = {s.name: b for b, s in enumerate(segs)}
    for a, sname in segments.items():  # orderings of a group that fit its distances as well
        idx = seg_idx[sname]
        if len(idx) < 2:
            continue
        _, perms, errs = _shape(med_dist[a], _distances(neutral[idx]), scale)
        mine = best_perm[a, col[sname]]
        for k in np.flatnonzero(errs <= errs[perms.index(mine)] + TIE_SHAPE):
            if perms[k] != mine and sum(x != y for x, y in zip(perms[k], mine, strict=True)) == 2:
                candidates.append({trial.labels[t]: names[idx[j]] for t, j in zip(groups[a], perms[k], strict=True)})
    matched = sorted(segments.items())
    for (a1, s1), (a2, s2) in itertools.combinations(matched, 2):  # two groups trading segments
        b1, b2 = col[s1], col[s2]
        if len(groups[a1]) != len(groups[a2]) or cost[a1, b2] >= 1e6:
            continue
        if cost[a1, b2] + cost[a2, b1] - cost[a1, b1] - cost[a2, b2] < TIE_M:
            change = {trial.labels[t]: names[seg_idx[s2][j]] for t, j in zip(groups[a1], best_perm[a1, b2],
                                                                              strict=True)}
            change.update({trial.labels[t]: names[seg_idx[s1][j]] for t, j in zip(groups[a2], best_perm[a2, b1],
                                                                                   strict=True)})
            candidates.append(change)
    del seg_of
    if not candidates:
        return labels
    current = fit(labels)
    for change in candidates:
        trial_labels = {**labels, **change}
        if len(set(trial_labels.values())) < len(trial_labels):
            continue
        rms = fit(trial_labels)
        if rms < current:
            labels, current = trial_labels, rms
    return labels
