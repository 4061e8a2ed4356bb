"""Markers that sit elsewhere on their segment in a still trial than in the moving trials.

A static trial and the walks after it share each marker's place on its segment (one offset in p).  Real
sessions break that: a thigh cluster slips down the strap, an acromion marker rides on skin that the arm
raised in the static lifts, a head band or a sternum marker is put back after the static.  Fitted with
one place, such a marker bends the geometry towards a compromise between the two (Rajagopal2016's
recording: the left femur 464 mm where the lab's HJC and knee-joint markers say 416, every walk frame 11 mm RMS
off).

Test (after a solve): a marker is linear in its own offset, so each frame's residual says where on the
segment that frame puts the marker (the offset that would fit it exactly).  In a still trial those
places cluster at one point; in the moving trials they spread with the skin's motion.  A marker is
*moved* in a still trial when its place there lies both MOVED_MIN from the moving trials' mean place and
MOVED_SIGMAS of their spread away from it (Mahalanobis): the moving trials never put it there.  The
still trial's positions of a moved marker are then left out of the fit (with one pose, a place of its
own would fit them exactly and tell nothing else); the model keeps the moving trials' place.  With
Settings.moved_markers off, the test runs once at the solution and its finds are only named
(Calibration.moved_kept), except for markers re-placed, REPLACED_MIN or more away, which are left out all the same.

A cluster's labels exchanged between the still trial and the moving ones (exchanged_clusters) are a move of
another kind, found before the solve: a near-symmetric plate's markers keep every distance when its labels are
mirrored (AddBiomechanics' Expert1: the left thigh plate's 1-3 and 2-4 exchanged between the static and the
walk, each pair's distances within 3 mm), but on the segment each label of the still trial sits where the
moving trials put another.  Those are read exchanged back in the still trial (relabel_columns), so that its
positions still place the cluster."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..problem.problem import Problem
from ..problem.state import State

MOVED_MIN = 0.010  # m: a slipped cluster or a marker put back moves a centimetre or more (skin over bone, less)
# m: a marker this far elsewhere in a still trial was re-placed (or its cluster's labels exchanged), not carried by
# skin: the real recordings' skin-borne shifts reach 46-63 mm (acromia lifted by the static's arms, a cluster slid down
# its strap), AddBiomechanics' Expert1 static shows its left thigh cluster 75-145 mm from the walk's places.  Without
# Settings.moved_markers the still trial's positions of such a marker, and of its segment's other markers, are left
# out all the same (moved_markers, replaced()).
REPLACED_MIN = 0.080
MOVED_SIGMAS = 3.0  # Mahalanobis distance from the moving trials' places (chi2, 3 dof: outside 97 % of them)
MIN_STILL_FRAMES = 3  # frames of the still trial that show the marker, at least
MIN_MOVING_FRAMES = 12  # frames of the moving trials that show it (their spread is measured on them)
# A cluster's labels read exchanged in a still trial (exchanged_clusters) where each exchanged label's place there
# lies at least EXCHANGE_OWN from its own place in the moving trials (a plate's markers stand 60-180 mm apart; skin and
# the start's poses move a place 5-36 mm) and, taken together, the places they are read as lie at most EXCHANGE_GAIN
# times as far (Expert1's static on models/human.urdf: 215 mm -> 44; on the girdle's start, a poorer pose of the
# left leg: 434 -> 183).
EXCHANGE_OWN = REPLACED_MIN / 2
EXCHANGE_GAIN = 0.5
_DELTA = 1e-3  # step in the offset entries of p: the marker is linear in them (exact differences)
_FLOOR = 5e-4  # m: added to the moving trials' SD on each axis (their spread can be tiny: a rigid cluster)


@dataclass(frozen=True)
class MovedMarker:
    """A marker whose place on its segment in still trial `trial` is not where the moving trials put it."""

    trial: int  # index of the still trial among the calibration's trials
    marker: str
    segment: str
    distance: float  # m: from the moving trials' mean place to the still trial's
    sigmas: float  # that difference against the moving trials' spread (Mahalanobis)
    # A marker taken with a re-placed one of its segment (moved_markers' `before`): that marker's name, else ''.
    beside: str = ""

    def text(self, source: str) -> str:
        if self.beside:
            return (f"{self.marker} rides on {self.segment} with {self.beside}, re-placed in {source} ("
                    f"{1e3 * self.distance:.0f} mm from the moving trials' place there)")
        return (f"{self.marker} sits {1e3 * self.distance:.0f} mm elsewhere on {self.segment} in {source} than in the "
                f"moving trials ({self.sigmas:.0f} SD of their spread)")

    def to_json(self) -> dict:
        out = {"trial": self.trial, "marker": self.marker, "segment": self.segment,
               "distance_mm": 1e3 * self.distance, "sigmas": self.sigmas}
        return {**out, "beside": self.beside} if self.beside else out


def replaced(found: Sequence[MovedMarker], before: Sequence[MovedMarker] = ()) -> list[MovedMarker]:
    """The moved markers of `found` on a segment that one of them (or of `before`, an earlier look's) left by
    REPLACED_MIN or more in that still trial: a cluster put back elsewhere moves as a whole, its nearer markers
    with it."""
    far = {(m.trial, m.segment) for m in (*found, *before) if m.distance >= REPLACED_MIN}
    return [m for m in found if (m.trial, m.segment) in far]


def marker_places(problem: Problem, state: State) -> np.ndarray:
    """(F, n_markers, 3) where each frame puts each marker on its segment: the displacement (m, segment
    axes) from the marker's fitted place that would make the frame's model marker meet the observed one
    (NaN where not seen)."""
    d0 = problem.marker_residuals(state)
    entries = problem.layout.entries("marker")  # (n_markers, 3) the offsets' entries in p
    A = np.empty(d0.shape + (3,))  # d(model marker)/d(offset): the segment's rotation times its scale
    for c in range(3):
        p = state.p.copy()
        p[entries[:, c]] += _DELTA
        A[..., c] = (problem.marker_residuals(replace(state, p=p)) - d0) / _DELTA
    seen = np.all(np.isfinite(d0), axis=2)
    out = np.full(d0.shape, np.nan)
    As, ds = A[seen], d0[seen]
    scale = np.linalg.norm(As[:, :, 0], axis=1)  # the segment's scale (its rotation's columns are unit)
    out[seen] = -np.linalg.solve(As, ds[..., None])[..., 0] * scale[:, None]
    return out


def moved_markers(problem: Problem, state: State, trial_of: np.ndarray, still: Sequence[bool],
                  before: Sequence[MovedMarker] = ()) -> list[MovedMarker]:
    """The markers moved in each still trial (module docstring), worst first: `trial_of` (F,) the trial of
    each frame of `problem`, `still` which trials are still.  On a segment one of them (or of `before`, an
    earlier look's) left by REPLACED_MIN or more in a still trial, every other marker that trial shows there
    comes too (`beside`): a cluster put back elsewhere moved as a whole, and the pose the still trial's fit gives
    its segment, bent by the cluster, hides part of its nearer markers' move (AddBiomechanics' Expert1 walking3:
    L_thigh3 moved with its cluster, 36 mm off in the static and 44-85 mm in the walk, kept; left out, the walk
    fits 5.8 mm, not 11.8)."""
    still_arr = np.asarray(still, dtype=bool)
    if not still_arr.any() or still_arr.all():
        return []
    places = marker_places(problem, state)
    moving = ~still_arr[trial_of]
    seg_of = {m.name: m.segment for m in problem.model.markers}
    out, rest = [], []
    for k, name in enumerate(problem.model.marker_names):
        mv = places[moving, k]
        mv = mv[np.all(np.isfinite(mv), axis=1)]
        if len(mv) < MIN_MOVING_FRAMES:
            continue
        mean = mv.mean(axis=0)
        cov = np.cov(mv.T) + _FLOOR**2 * np.eye(3)
        for t in np.flatnonzero(still_arr):
            st = places[trial_of == t, k]
            st = st[np.all(np.isfinite(st), axis=1)]
            if len(st) < MIN_STILL_FRAMES:
                continue
            diff = st.mean(axis=0) - mean
            dist = float(np.linalg.norm(diff))
            sig = float(np.sqrt(diff @ np.linalg.solve(cov, diff)))
            found = MovedMarker(int(t), name, seg_of[name], dist, sig)
            (out if dist >= MOVED_MIN and sig >= MOVED_SIGMAS else rest).append(found)
    far = {}
    for m in sorted((*before, *out), key=lambda m: -m.distance):
        if m.distance >= REPLACED_MIN:
            far.setdefault((m.trial, m.segment), m.marker)
    out += [replace(m, beside=far[m.trial, m.segment]) for m in rest if (m.trial, m.segment) in far]
    return sorted(out, key=lambda m: -m.distance)


@dataclass(frozen=True)
class ExchangedCluster:
    """Labels of one segment's markers that still trial `trial` names otherwise than the moving trials: its
    `labels[i]` sits where the moving trials put `read_as[i]` (the places compared in the segment's frame, at
    the start's poses, which the segment's other markers fix)."""

    trial: int
    segment: str
    labels: tuple[str, ...]
    read_as: tuple[str, ...]
    own: tuple[float, ...]  # m: each label's place in the still trial from its own in the moving trials
    exchanged: tuple[float, ...]  # m: ... from the place of the label it is read as

    def text(self, source: str) -> str:
        pairs = ", ".join(f"{a} as {b}" for a, b in zip(self.labels, self.read_as, strict=True))
        return (f"{source} (still) names the markers of {self.segment} otherwise than the moving trials: read "
                f"{pairs} (their places there {', '.join(f'{1e3 * d:.0f}' for d in self.own)} mm from their "
                f"labels' in the moving trials, {', '.join(f'{1e3 * d:.0f}' for d in self.exchanged)} from the "
                "labels read; a symmetric cluster labelled the other way round)")

    def to_json(self) -> dict:
        return {"trial": self.trial, "segment": self.segment, "labels": list(self.labels),
                "read_as": list(self.read_as), "own_mm": [1e3 * d for d in self.own],
                "exchanged_mm": [1e3 * d for d in self.exchanged]}


def exchanged_clusters(places: np.ndarray, trial_of: np.ndarray, still: Sequence[bool], names: Sequence[str],
                       segments: Sequence[str]) -> list[ExchangedCluster]:
    """The labels each still trial names otherwise than the moving trials (module docstring): `places` (F, n, 3)
    where each of `trial_of`'s frames puts markers `names` (riding on `segments`) in their segment's frame (m;
    NaN: not seen), from poses their positions did not set.  Per still trial and segment, the still trial's median
    places are matched to the moving trials' (least total distance); a match other than the labels' own is kept
    where EXCHANGE_OWN and EXCHANGE_GAIN hold."""
    still_arr = np.asarray(still, dtype=bool)
    if not still_arr.any() or still_arr.all():
        return []
    moving = ~still_arr[trial_of]
    out = []
    for t in np.flatnonzero(still_arr):
        at: dict[str, list[tuple[int, np.ndarray, np.ndarray]]] = {}
        for k in range(len(names)):
            st, mv = places[trial_of == t, k], places[moving, k]
            st, mv = st[np.all(np.isfinite(st), axis=1)], mv[np.all(np.isfinite(mv), axis=1)]
            if len(st) >= MIN_STILL_FRAMES and len(mv) >= MIN_MOVING_FRAMES:
                at.setdefault(segments[k], []).append((k, np.median(st, axis=0), np.median(mv, axis=0)))
        for segment, items in at.items():
            if len(items) < 2:
                continue
            C = np.linalg.norm(np.array([x[1] for x in items])[:, None] - np.array([x[2] for x in items])[None],
                               axis=2)
            rows, cols = linear_sum_assignment(C)
            moved_ = [(i, j) for i, j in zip(rows, cols, strict=True) if i != j]
            if not moved_:
                continue
            own = np.array([C[i, i] for i, _ in moved_])
            other = np.array([C[i, j] for i, j in moved_])
            if own.min() >= EXCHANGE_OWN and other.sum() <= EXCHANGE_GAIN * own.sum():
                out.append(ExchangedCluster(int(t), segment, tuple(names[items[i][0]] for i, _ in moved_),
                                            tuple(names[items[j][0]] for _, j in moved_),
                                            tuple(float(d) for d in own), tuple(float(d) for d in other)))
    return out


def relabel_columns(observed: np.ndarray, spans: Sequence[slice], found: Sequence[ExchangedCluster],
                    names: Sequence[str]) -> np.ndarray:
    """`observed` (F, n_markers, 3; columns `names`) with each exchange of `found` undone in its trial's frames
    (`spans`): the column of a label read as another takes that label's place."""
    out = observed.copy()
    for x in found:
        sl = spans[x.trial]
        src = [names.index(a) for a in x.labels]
        dst = [names.index(b) for b in x.read_as]
        out[sl, dst] = observed[sl][:, src]
    return out
