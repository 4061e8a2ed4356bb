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
from itertools import permutations

import numpy as np

from ..model.blocks import FrameLayout
from ..model.kinematics import Kinematics
from ..model.model import Parameters
from ..problem.problem import LIMIT_MARGIN, Problem
from ..problem.state import State
from ..solve.ik import FrameSolver

MOVED_MIN = 0.010  # m: a slipped cluster or a marker put back moves a centimetre or more (skin over bone, less)
# m: a marker this far elsewhere in a still trial was re-placed (or its cluster's labels exchanged), not carried by
# skin: the real recordings' skin-borne shifts reach 46-63 mm (acromia lifted by the static's arms, a cluster slid down
# its strap), AddBiomechanics' Expert1 static shows its left thigh cluster 75-145 mm from the walk's places (its labels
# exchanged: read back first where the match finds them, exchanged_clusters; walking3's L_thigh1 is not).  Without
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
SUSPECT = 0.025  # m: a segment's markers are read for labels named otherwise where two or more of them fit worse than
# this in a trial (median over its frames; a subject's own trials fit a cluster marker to 3-12 mm)
EXCHANGE_OWN = REPLACED_MIN / 2
EXCHANGE_GAIN = 0.5
EXCHANGE_MOST = 7  # labels of one segment at most that the match permutes (7! orders); more: none judged
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
                  before: Sequence[MovedMarker] = (), places: np.ndarray | None = None) -> list[MovedMarker]:
    """The markers moved in each still trial (module docstring), worst first: `trial_of` (F,) the trial of
    each frame of `problem`, `still` which trials are still.  On a segment one of them (or of `before`, an
    earlier look's) left by REPLACED_MIN or more in a still trial, every other marker that trial shows there
    comes too (`beside`): a cluster put back elsewhere moved as a whole, and the pose the still trial's fit gives
    its segment, bent by the cluster, hides part of its nearer markers' move (AddBiomechanics' Expert1 walking3:
    L_thigh3 moved with its cluster, 36 mm off in the static and 44-85 mm in the walk, kept; left out, the walk
    fits 5.8 mm, not 11.8).  `places`: marker_places at `state`, where the caller has them."""
    still_arr = np.asarray(still, dtype=bool)
    if not still_arr.any() or still_arr.all():
        return []
    places = marker_places(problem, state) if places is None else places
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


APART_PLACE = 0.025  # m: two moving trials put a marker this far apart on its segment (their mean places):
# AddBiomechanics' Expert1's walks (plain, toe-in, toe-out, trunk-sway) put none over 16 mm apart; its squats,
# sit-to-stand and jump put C7 and the acromia 29-48 mm from its walk's places (the trunk flexing, the shoulder blades
# lifted with the arms)


#: What PlacesApart means, and what to do (said once after them).
PLACES_APART_ADVICE = ("skin that slides over the bone in one motion and not the other, or a marker put back between "
                       "them: one place per marker cannot fit both, and the geometry bends between them; calibrate "
                       "from the static and the trials of one kind of motion, and fit the others to that subject with "
                       "calibrate ik (calibrate batch: ik_trials)")


@dataclass(frozen=True)
class PlacesApart:
    """Two moving trials that put markers APART_PLACE or more apart on their segments: `markers` (name, segment,
    distance between the two trials' mean places in m), largest first."""

    trials: tuple[int, int]
    markers: tuple[tuple[str, str, float], ...]
    # of them, acromion markers (Plug-in Gait's xSHO, or labels read as them) riding on the segment a shoulder ball
    # hangs from: a model without a shoulder girdle, whose shoulder blade lifts them with the arm
    acromia: tuple[str, ...] = ()

    def text(self, first: str, second: str) -> str:
        """The summary's words, naming the two trials."""
        return (f"{first} and {second} put " + ", ".join(f"{m} {1e3 * d:.0f}" for m, _, d in self.markers)
                + " mm apart on their segments")

    def to_json(self, sources: Sequence[str]) -> dict:
        return {"trials": [sources[t] for t in self.trials],
                "markers": [{"marker": m, "segment": s, "apart_mm": round(1e3 * d, 3)} for m, s, d in self.markers],
                "acromia": list(self.acromia)}


def girdle_advice(acromia: Sequence[str]) -> str:
    """What to say where the markers apart include acromion markers on a model without a shoulder girdle."""
    one = len(acromia) == 1
    return (f"{', '.join(acromia)} ride{'s' if one else ''} on the trunk in this model while the shoulder blade lifts "
            f"{'it' if one else 'them'} with the arm: a model with a shoulder girdle carries {'it' if one else 'them'} "
            "on a clavicle "
            "(models/human_girdle.urdf: Expert1's static, walk, squats and jump fit 4.6-6.8 mm per trial on it, none "
            "apart, against 10.7-13.8 on models/human.urdf)")


def _acromia(model, names: Sequence[str]) -> tuple[str, ...]:
    """Those of `names` that are acromion markers riding on a segment a ball joint (a shoulder) hangs from."""
    from ..io.labels import alias_for

    parents = {j.parent for j in model.joints if j.kind == "ball"}
    return tuple(n for n in names if model.markers[model.marker_index(n)].segment in parents
                 and (n in ("RSHO", "LSHO") or alias_for(n, ("RSHO", "LSHO")) is not None))


def places_apart(problem: Problem, state: State, trial_of: np.ndarray, moving: Sequence[bool],
                 places: np.ndarray | None = None) -> list[PlacesApart]:
    """Each two moving trials (`moving`: per trial; `trial_of` (F,): each frame's trial) whose mean places of a marker
    on its segment (marker_places, over MIN_MOVING_FRAMES frames or more of each) lie APART_PLACE or more apart: the
    place where each trial would put the marker, wherever the fit put it, so the compromise it took does not hide
    the gap.  `places`: marker_places at `state`, where the caller has them."""
    trials = np.flatnonzero(np.asarray(moving, dtype=bool))
    if trials.size < 2:
        return []
    places = marker_places(problem, state) if places is None else places
    names = problem.model.marker_names
    mean = np.full((trials.size, len(names), 3), np.nan)
    for i, t in enumerate(trials):
        at = places[trial_of == t]
        ok = np.all(np.isfinite(at), axis=2)
        for k in np.flatnonzero(ok.sum(axis=0) >= MIN_MOVING_FRAMES):
            mean[i, k] = at[ok[:, k], k].mean(axis=0)
    segment = [m.segment for m in problem.model.markers]
    out = []
    for i in range(trials.size):
        for j in range(i + 1, trials.size):
            gap = np.linalg.norm(mean[i] - mean[j], axis=1)
            far = [(names[k], segment[k], float(gap[k])) for k in np.flatnonzero(gap >= APART_PLACE)]
            if far:
                far.sort(key=lambda x: -x[2])
                out.append(PlacesApart((int(trials[i]), int(trials[j])), tuple(far),
                                       _acromia(problem.model, [m for m, _, _ in far])))
    return out


@dataclass(frozen=True)
class ExchangedCluster:
    """Labels of one segment's markers that trial `trial` names otherwise than the others: its `labels[i]` sits
    where they put `read_as[i]` (the places compared in the segment's frame, on poses the segment's other markers
    fix).  `reference`: the moving trial whose names it is read by (calibrate.calibration.hosts.trial_exchanges:
    moving trials that disagree), or -1: `trial` is still, read by the moving trials'."""

    trial: int
    segment: str
    labels: tuple[str, ...]
    read_as: tuple[str, ...]
    own: tuple[float, ...]  # m: each label's place in the trial from its own in the others
    exchanged: tuple[float, ...]  # m: ... from the place of the label it is read as
    reference: int = -1

    def text(self, source: str, reference: str = "the moving trials") -> str:
        """The summary's words; `reference`: the name of the trial `reference` indexes, where it is one."""
        pairs = ", ".join(f"{a} as {b}" for a, b in zip(self.labels, self.read_as, strict=True))
        still = " (still)" if self.reference < 0 else ""
        return (f"{source}{still} names the markers of {self.segment} otherwise than {reference}: read "
                f"{pairs} (their places there {', '.join(f'{1e3 * d:.0f}' for d in self.own)} mm from their "
                f"labels' in {reference}, {', '.join(f'{1e3 * d:.0f}' for d in self.exchanged)} from the "
                "labels read; a symmetric cluster labelled the other way round)")

    def to_json(self) -> dict:
        out = {"trial": self.trial, "segment": self.segment, "labels": list(self.labels),
               "read_as": list(self.read_as), "own_mm": [1e3 * d for d in self.own],
               "exchanged_mm": [1e3 * d for d in self.exchanged]}
        return out if self.reference < 0 else {**out, "reference": self.reference}


def exchange_of(trial: int, segment: str, names: Sequence[str], still: np.ndarray, moving: np.ndarray,
              near: float = np.inf) -> ExchangedCluster | None:
    """The labels `names` of one segment's markers that still trial `trial` names otherwise than the moving trials:
    its places `still` (n, 3, m) matched to theirs `moving` (least total distance); a match other than the labels'
    own, kept where EXCHANGE_OWN and EXCHANGE_GAIN hold and the places read lie `near` or nearer on average; else
    None."""
    C = np.linalg.norm(still[:, None] - moving[None], axis=2)
    # Only labels EXCHANGE_OWN or more from their own place can be read as another (the rule below), and the one each is
    # read as is such a label too: the least total distance over their orders (numpy: scipy's assignment would add its
    # import, 0.4 s, to every run).
    far = np.flatnonzero(np.diag(C) >= EXCHANGE_OWN)
    if not 2 <= far.size <= EXCHANGE_MOST:
        return None
    orders = np.array(list(permutations(range(far.size))))
    best = orders[C[far[:, None], far[orders].T].sum(axis=0).argmin()]
    pairs = [(int(far[i]), int(far[j])) for i, j in enumerate(best) if i != j]
    if not pairs:
        return None
    own = np.array([C[i, i] for i, _ in pairs])
    other = np.array([C[i, j] for i, j in pairs])
    if own.min() < EXCHANGE_OWN or other.sum() > EXCHANGE_GAIN * own.sum() or other.mean() > near:
        return None
    return ExchangedCluster(trial, segment, tuple(names[i] for i, _ in pairs), tuple(names[j] for _, j in pairs),
                            tuple(float(d) for d in own), tuple(float(d) for d in other))


def exchanged_clusters(places: np.ndarray, trial_of: np.ndarray, still: Sequence[bool], names: Sequence[str],
                       segments: Sequence[str]) -> list[ExchangedCluster]:
    """The labels each still trial names otherwise than the moving trials (module docstring): `places` (F, n, 3)
    where each of `trial_of`'s frames puts markers `names` (riding on `segments`) in their segment's frame (m;
    NaN: not seen), from poses their positions did not set.  Per still trial and segment, the still trial's median
    places are matched to the moving trials' (exchange_of)."""
    still_arr = np.asarray(still, dtype=bool)
    if not still_arr.any() or still_arr.all():
        return []
    moving = ~still_arr[trial_of]
    out = []
    for t in np.flatnonzero(still_arr):
        at: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}
        for k in range(len(names)):
            st, mv = places[trial_of == t, k], places[moving, k]
            st, mv = st[np.all(np.isfinite(st), axis=1)], mv[np.all(np.isfinite(mv), axis=1)]
            if len(st) >= MIN_STILL_FRAMES and len(mv) >= MIN_MOVING_FRAMES:
                at.setdefault(segments[k], []).append((names[k], np.median(st, axis=0), np.median(mv, axis=0)))
        for segment, items in at.items():
            x = exchange_of(int(t), segment, [n for n, _, _ in items], np.array([a for _, a, _ in items]),
                          np.array([b for _, _, b in items]))
            if x is not None:
                out.append(x)
    return out


def segment_axes(kin: Kinematics, Z: np.ndarray, Q: np.ndarray, params: Parameters,
                 markers: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's frame of the segment that each of `markers` (model indices) rides on, at URDF coordinates Z, Q
    (absolute) and geometry `params`: its origin (F, n, 3) and axes R (F, n, 3 lab, 3 segment), lab frame, m."""
    idx = list(markers)
    model = kin.model
    s = np.array([params.scale[model.segment_index(model.markers[k].segment)] for k in idx])
    p = params.copy()
    p.marker[idx] = 0.0
    origin = kin.batch(Z, Q, p)[0][:, idx]
    axes = []
    for c in range(3):
        p.marker[idx] = 0.0
        p.marker[idx, c] = 1.0 / s
        axes.append(kin.batch(Z, Q, p)[0][:, idx] - origin)  # the segment's axis c in the lab
    return origin, np.stack(axes, axis=3)


def exchanged_after_solve(problem: Problem, state: State, trial_of: np.ndarray,
                          still: Sequence[bool]) -> list[ExchangedCluster]:
    """The labels of the model's own markers that a still trial names otherwise than the moving trials (they set the
    start's poses, so they are not judged before the fit), at the first subsample solution.  Fitted as labelled, the
    still trial bends its pose of the segment towards them (a simulated static turned its hip 179 deg to meet a
    mirrored thigh plate, each label then 14-24 mm from its own place), so its middle frame is posed again from
    scratch without the segment's markers (FrameSolver.global_start: the joints above and below carry the segment,
    the geometry held) and their places read there; the moving trials' places are their median over the solution's
    frames (marker_places).  Only segments with a marker MOVED_MIN or more from its own place are posed so, and the
    places read must lie within EXCHANGE_OWN on average (a bent static misplaces every segment below: that
    simulated static's heel and toe matched each other's places at 120-142 mm).  Expert1 on its generic.osim:
    L_thigh1-4 97-135 mm from their own places, 16-25 from those read.  Where the cluster has bent the geometry too
    (models/human_girdle.urdf on Expert1, the knee's axis 84 deg off) nothing is found: what the start's places
    (exchanged_clusters) do not read back, the moved-marker test still sees."""
    still_arr = np.asarray(still, dtype=bool)
    if not still_arr.any() or still_arr.all():
        return []
    model, kin = problem.model, problem.kin
    params = model.unpack(state.p)
    fitted = np.array([params.scale[model.segment_index(m.segment)] * params.marker[k]
                       for k, m in enumerate(model.markers)])
    places = marker_places(problem, state) + fitted[None]
    moving = ~still_arr[trial_of]
    seen = problem.seen
    # Every coordinate but the locked ones (a ball with a locked angle: whole), as the solve holds them.
    held = set(np.flatnonzero(problem.locked).tolist())
    for ball in kin.balls:
        if held & set(ball.dofs):
            held |= set(ball.dofs)
    free = np.array([c for c in range(model.nz) if c < FrameLayout.angle(0) or FrameLayout.dof(c) not in held])
    locked_cols = np.isin(np.arange(model.nz), free, invert=True)
    solver = None
    out = []
    for t in np.flatnonzero(still_arr):
        rows = np.flatnonzero(trial_of == t)
        f = int(rows[len(rows) // 2])
        for segment in dict.fromkeys(m.segment for m in model.markers):
            ks = [k for k, m in enumerate(model.markers) if m.segment == segment and seen[f, k]
                  and np.isfinite(places[moving, k, 0]).sum() >= MIN_MOVING_FRAMES]
            if len(ks) < 2:
                continue
            mean = np.array([np.nanmedian(places[moving, k], axis=0) for k in ks])
            if np.linalg.norm(places[f, ks] - mean, axis=1).max() < MOVED_MIN:
                continue
            others = seen[f] & np.array([m.segment != segment for m in model.markers])
            solver = solver or FrameSolver(kin, state.p, problem.frame_evaluator(state.p), margin=LIMIT_MARGIN)
            # From scratch (the default pose and joint by joint, the better fit), not from the solution's pose: a
            # simulated static bent by a mirrored thigh plate had turned its hip 179 deg, a basin the segments
            # below then keep.
            z, q = solver.global_start(problem.observed[f], others, local=True, free=free,
                                       held=lambda z, f=f: np.where(locked_cols, state.Z[f], z))
            Zf, Qf = kin.absolute(z[None], q[None, :4], None if state.B is None else q[None, 4:].reshape(1, -1, 4))
            origin, R = segment_axes(kin, Zf, Qf, params, ks)
            local = np.einsum("nij,ni->nj", R[0], problem.observed[f, ks] - origin[0])
            x = exchange_of(int(t), segment, [model.marker_names[k] for k in ks], local, mean, near=EXCHANGE_OWN)
            if x is not None:
                out.append(x)
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
