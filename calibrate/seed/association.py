"""Which marker is on which segment, from the marker trajectories alone (Ringer & Lasenby, Section 3).

Two stages, as in the paper:

1. **Markers to groups.**  Markers on one segment keep constant distances to each other.
   :func:`distance_variance` builds D (variance over frames of every inter-marker distance);
   :func:`group_markers` grows groups greedily from the smallest D entry, only over pairs
   that are rigid within the noise (:func:`rigid_threshold`) and with *complete linkage*:
   a marker joins a group only if it is rigid with every member.  Pairs the greedy could
   not honour are *inconsistencies*; forcing each one onto a segment gives alternative
   groupings, which :func:`marker_hypotheses` ranks by the reconstruction error of a
   rigid body per group (the paper's Eq. 5).
2. **Groups to a tree.**  :func:`group_adjacency` joins groups into a spanning tree,
   Kruskal-style: the paper's order (mean centroid distance D′) is kept for reference; the
   tree itself takes first the pairs that pass a joint-model test (sphere fit of one group
   in the other's frame), then the rest by how far apart their markers get.

:func:`associate` runs both stages on unlabelled trajectories; :func:`associate_to_model`
places the markers of a trial on the segments of a model (unknown labels by rigidity
with a segment's known markers; known labels checked, never moved).

Everything works on all frames at once; gaps are NaN and left out frame by frame.
Units: metres (variances in m²).
"""

from __future__ import annotations

import warnings
from collections import Counter
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from calibrate.seed.rigidity import (
    MIN_FRAMES,
    Grouping,
    canonical_groups,
    distance_moments,
    distance_variance,
    greedy_groups,
    group_labels,
    noise_sigma,
    pair_counts,
    rigid_threshold,
    typical_count,
)

from ..io.trial import Trial
from ..model.model import Model
from .geometry import kabsch_batch, rigid_fit, sphere_fit
from .jitter import jitter_sd
from .seeding import MAD_SD, without_broken

Z_ADMISSIBLE = 5.0  # standard errors of a group's residual allowed above the noise


SIGMA_SLACK = 0.05  # relative uncertainty allowed for the estimated noise variance


JOINT_FACTOR = 4.0  # a joint's sphere-fit RMS must be below JOINT_FACTOR x noise sigma


SPREAD_SD = 2.0  # spread = mean + SPREAD_SD x std of the distance between the markers of two groups


Z_TIE = 3.0  # standard errors within which two hypotheses' errors count as equal


@dataclass(frozen=True)
class Hypothesis:
    """One candidate marker-to-segment grouping with its rigid-body reconstruction error."""

    groups: tuple[tuple[int, ...], ...]
    error: float  # E of Eq. 5: sum over frames, groups and markers of squared residuals (m²)
    rms_per_group: tuple[float, ...]  # RMS residual per marker sample in each group (m); 0 for singletons
    dof_per_group: tuple[float, ...]  # residual degrees of freedom per group (pure noise: E_g ≈ dof σ²)
    admissible: bool  # every group's residual is consistent with the marker noise
    origin: str = "greedy"  # how it was made, e.g. "move RKNE to RTHI's group"

    @property
    def n_groups(self) -> int:
        return len(self.groups)

    def label(self, n_markers: int) -> np.ndarray:
        """(n_markers,) group index of every marker."""
        return group_labels(self.groups, n_markers)


@dataclass(frozen=True)
class _Residual:
    error: float  # sum of squared residuals (m²)
    samples: int  # marker samples that entered the fit
    dof: float  # residual degrees of freedom (noise only: error ≈ dof σ²)


class _Scorer:
    """Rigid-body residual of groups (cached), and admissibility against the noise."""

    def __init__(self, X: np.ndarray, D: np.ndarray, sigma: float):
        self.X, self.D, self.sigma = X, D, sigma
        self.seen = np.all(np.isfinite(X), axis=2)
        self.cache: dict[tuple[int, ...], _Residual] = {}

    def residual(self, g: tuple[int, ...]) -> _Residual:
        if g not in self.cache:
            self.cache[g] = self._residual(g)
        return self.cache[g]

    def _residual(self, g: tuple[int, ...]) -> _Residual:
        if len(g) == 1:
            return _Residual(0.0, 0, 0.0)
        if len(g) == 2:  # best rigid fit of two points: each moves half the distance error along their line
            i, j = g
            n = int(np.sum(self.seen[:, i] & self.seen[:, j]))
            if n < 2 or not np.isfinite(self.D[i, j]):
                return _Residual(0.0, 0, 0.0)
            return _Residual(0.5 * (n - 1) * float(self.D[i, j]), 2 * n, float(n - 1))
        fit = rigid_fit(self.X[:, list(g)])
        count = self.seen[:, list(g)].sum(1)
        ok = fit.valid & (count >= 3)
        err = float(np.sum(fit.rms[ok] ** 2 * count[ok]))
        return _Residual(err, int(count[ok].sum()), float(np.sum(3 * count[ok] - 6)))

    def admissible(self, g: tuple[int, ...]) -> bool:
        """E_g / dof ≤ σ² (1 + SIGMA_SLACK + Z_ADMISSIBLE·sqrt(2 / dof)): a chi-square test of the
        group's rigid-body residual against the noise, not a fixed multiple of σ."""
        r = self.residual(g)
        if r.dof <= 0:
            return True
        limit = self.sigma**2 * (1.0 + SIGMA_SLACK + Z_ADMISSIBLE * np.sqrt(2.0 / r.dof))
        return r.error / r.dof <= limit

    def hypothesis(self, groups, origin: str) -> Hypothesis:
        res = [self.residual(g) for g in groups]
        rms = tuple(float(np.sqrt(r.error / r.samples)) if r.samples else 0.0 for r in res)
        return Hypothesis(groups, float(sum(r.error for r in res)), rms, tuple(r.dof for r in res),
                          all(self.admissible(g) for g in groups), origin)


def _alternatives(groups, D: np.ndarray, threshold: float, names) -> dict:
    """Groupings that force each rigid pair split across two groups (an inconsistency) onto one segment."""
    label = group_labels(groups, len(D))
    iu, ju = np.triu_indices(len(D), 1)
    cross = (D[iu, ju] <= threshold) & (label[iu] != label[ju])
    out: dict[tuple[tuple[int, ...], ...], str] = {}
    for i, j in zip(iu[cross], ju[cross], strict=True):
        gi, gj = set(groups[label[i]]), set(groups[label[j]])
        rest = [g for k, g in enumerate(groups) if k not in (label[i], label[j])]
        ni, nj = names[i], names[j]
        cands = {
            f"move {ni} to {nj}'s group": rest + [gi - {i}, gj | {i}],
            f"move {nj} to {ni}'s group": rest + [gj - {j}, gi | {j}],
            f"merge the groups of {ni} and {nj}": rest + [gi | gj],
            f"greedy with {ni}-{nj} first": list(greedy_groups(D, threshold, ((int(i), int(j)),)).groups),
        }
        for origin, cand in cands.items():
            out.setdefault(canonical_groups(cand), origin)
    return out


def marker_hypotheses(markers: np.ndarray, threshold: float | None = None, labels=None,
                      rounds: int = 4) -> tuple[Grouping, list[Hypothesis], float]:
    """The greedy grouping, its alternatives ranked best first, and the noise σ (m) used.

    Alternatives: for every pair (i, j) that is rigid (D ≤ threshold) but split across two
    groups — the greedy's inconsistencies — move i to j's group, move j to i's group,
    merge the two groups, and rerun the greedy with (i, j) as its first pair (this reaches
    groupings that need two changes, e.g. KNE taken first with ANK).  The alternatives of
    the best hypothesis are added again, for up to `rounds` rounds.

    Each hypothesis is scored by the reconstruction error E (Eq. 5) of a rigid body per
    group: per-frame rigid fit for groups of ≥ 3 markers, the distance variance for pairs
    (E = (n − 1) D / 2, the residual of the best rigid fit of two points), 0 for singletons.
    Splitting always lowers E, so the ranking is: admissible first (every group's residual
    per degree of freedom within σ² (1 + 0.05 + 5 sqrt(2 / dof)), a chi-square test), then
    fewer groups, then lower E.

    Limits, both physical rather than numerical: no prior breaks near-ties — a marker on a
    hinge axis (ELB on the elbow axis) keeps constant distances to both segments and its
    two placements differ in E by noise only (:func:`ambiguous_markers` reports such
    markers); and two segments whose relative motion moves their markers by less than the
    noise (FRM on the ulna against WRA/WRB on the radius, for some subjects) come out as
    one group, since fewer groups win among admissible hypotheses.
    """
    X = np.asarray(markers, dtype=float)
    D = distance_variance(X)
    n = typical_count(pair_counts(X))
    if threshold is None:
        threshold = rigid_threshold(D, n)
    sigma = noise_sigma(D, n)
    names = list(labels) if labels is not None else [f"m{i}" for i in range(len(D))]
    base = greedy_groups(D, threshold)
    scorer = _Scorer(X, D, sigma)
    pool: dict[tuple[tuple[int, ...], ...], str] = {base.groups: "greedy"}
    expanded: set[tuple[tuple[int, ...], ...]] = set()
    ranked: list[Hypothesis] = []
    for _ in range(max(rounds, 1)):
        ranked = sorted((scorer.hypothesis(g, o) for g, o in pool.items()),
                        key=lambda h: (not h.admissible, h.n_groups, h.error))
        best = ranked[0].groups
        if best in expanded:
            break
        expanded.add(best)
        for g, origin in _alternatives(best, D, threshold, names).items():
            pool.setdefault(g, origin)
    return base, ranked, sigma


def tied_hypotheses(hypotheses: list[Hypothesis], sigma: float, z: float = Z_TIE) -> list[Hypothesis]:
    """The hypotheses the data cannot tell from the best (which is included, first).

    Same admissibility and number of groups as the best, and an error E above the best's by
    at most z standard errors of the difference: σ² sqrt(2 Σ dof) over the groups in which
    the two differ (E/σ² of a pure-noise group is chi-square with dof degrees of freedom).
    """
    if not hypotheses:
        return []
    best = hypotheses[0]
    dof_of = dict(zip(best.groups, best.dof_per_group, strict=True))
    out = [best]
    for h in hypotheses[1:]:
        if h.admissible != best.admissible or h.n_groups != best.n_groups:
            continue
        mine = dict(zip(h.groups, h.dof_per_group, strict=True))
        dof = sum(d for g, d in dof_of.items() if g not in mine) + sum(d for g, d in mine.items() if g not in dof_of)
        if h.error - best.error <= z * sigma**2 * np.sqrt(2.0 * max(dof, 1.0)):
            out.append(h)
    return out


def ambiguous_markers(hypotheses: list[Hypothesis], sigma: float, z: float = Z_TIE) -> tuple[int, ...]:
    """Markers whose group (its set of members) differs between the best hypothesis and one the
    data cannot tell from it (:func:`tied_hypotheses`)."""
    tied = tied_hypotheses(hypotheses, sigma, z)
    if len(tied) < 2:
        return ()
    n = 1 + max(i for g in tied[0].groups for i in g)

    def member_sets(h: Hypothesis) -> list[frozenset[int]]:
        out: list[frozenset[int]] = [frozenset()] * n
        for g in h.groups:
            for i in g:
                out[i] = frozenset(g)
        return out

    ref = member_sets(tied[0])
    moved: set[int] = set()
    for h in tied[1:]:
        moved |= {i for i, s in enumerate(member_sets(h)) if s != ref[i]}
    return tuple(sorted(moved))


# ---------------------------------------------------------------------------- stage 2: tree
@dataclass(frozen=True)
class Edge:
    """A presumed joint between two groups (indices into the groups, a < b)."""

    a: int
    b: int
    mean_distance: float  # D′: mean distance between the group centroids (m)
    joint_rms: float  # sphere-fit RMS of one group's markers in the other's frame (m); NaN if untestable
    spread: float  # mean over marker pairs of (mean + SPREAD_SD std) of their distance (m)

    def joint(self, sigma: float) -> str:
        """'consistent', 'untestable' or 'rejected' as a joint, for marker noise σ (m)."""
        if not np.isfinite(self.joint_rms):
            return "untestable"
        return "consistent" if self.joint_rms <= JOINT_FACTOR * sigma else "rejected"


@dataclass(frozen=True)
class Adjacency:
    """Groups joined into a tree of presumed joints."""

    tree: tuple[Edge, ...]  # L − 1 edges (fewer if some groups are never seen together)
    alternatives: tuple[Edge, ...]  # every other pair (the greedy's inconsistencies), in the order tried
    greedy_tree: tuple[Edge, ...]  # the paper's tree: greedy on D′ alone
    mean_distance: np.ndarray  # D′ (L, L), m
    sigma: float  # marker noise σ used for the joint test (m)


def group_centroids(markers: np.ndarray, groups) -> np.ndarray:
    """(F, L, 3) centroid of each group per frame.

    Groups of ≥ 3 markers: the origin of their rigid fit (the centroid of the fitted shape,
    defined even when some markers are hidden).  Smaller groups: the mean of their markers,
    NaN when any is hidden (a partial mean would jump).
    """
    X = np.asarray(markers, dtype=float)
    out = np.full((X.shape[0], len(groups), 3), np.nan)
    for k, g in enumerate(groups):
        out[:, k] = rigid_fit(X[:, list(g)]).t if len(g) >= 3 else X[:, list(g)].mean(1)
    return out


def group_adjacency(markers: np.ndarray, groups, sigma: float | None = None) -> Adjacency:
    """Which groups share a joint (paper Section 3, second stage), as a spanning tree.

    The paper: D′[l1, l2] is the mean over frames of the distance between the centroids of
    groups l1 and l2; pairs are taken greedily from the smallest D′, and a pair whose groups
    are already connected is an inconsistency, so the result is a spanning tree (Kruskal).
    That tree is returned as `greedy_tree`.  On a squat trial it is often wrong: the two
    feet or shanks can be closer to each other than the shank centroid is to the thigh's.

    The returned `tree` is Kruskal's on a joint-aware order:

    1. pairs that pass a joint-model test, by increasing residual.  The markers of one group
       (≥ 2 of them) are expressed in the rigid frame of the other (≥ 3 markers; the larger
       group is the reference) and fitted by a sphere (Gamage & Lasenby); the RMS of the fit
       is near the noise for two groups that share a ball or hinge joint, and the pair passes
       when it is ≤ JOINT_FACTOR σ.  In Plug-in Gait only the pelvis, thorax and head have
       3 markers, so this settles the hips, lumbar, neck and shoulders;
    2. every other pair by `spread`: the mean over marker pairs of (mean + 2 std) of their
       distance over frames — how far apart the two segments' markers get.  Heuristic: a
       shared joint bounds that distance, while left and right feet swing apart.  Two groups
       joined through a segment without markers (tibia and calcaneus through the talus) are
       judged on the same footing and come out adjacent.

    A single marker in a frame always fits some sphere over a limited range of motion, so
    single-marker groups are never tested (their joint_rms is NaN).
    """
    X = np.asarray(markers, dtype=float)
    groups = [tuple(int(i) for i in g) for g in groups]
    L = len(groups)
    if sigma is None:
        sigma = noise_sigma(distance_variance(X), typical_count(pair_counts(X)))
    C = group_centroids(X, groups)
    dist = np.linalg.norm(C[:, :, None, :] - C[:, None, :, :], axis=3)
    ok = np.isfinite(dist)
    cnt = ok.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        Dp = np.where(cnt >= MIN_FRAMES, np.where(ok, dist, 0.0).sum(0) / np.maximum(cnt, 1), np.inf)
    np.fill_diagonal(Dp, 0.0)
    mean, sq, n_pair = distance_moments(X)
    far = mean + SPREAD_SD * np.sqrt(sq / np.maximum(n_pair - 1, 1))
    far[n_pair < MIN_FRAMES] = np.inf

    frames = {k: rigid_fit(X[:, list(g)]) for k, g in enumerate(groups) if len(g) >= 3}
    edges: list[Edge] = []
    for a in range(L):
        for b in range(a + 1, L):
            ref, other = (a, b) if len(groups[a]) >= len(groups[b]) else (b, a)
            rms = np.nan
            if ref in frames and len(groups[other]) >= 2 and np.isfinite(Dp[a, b]):
                local = frames[ref].to_local(X[:, list(groups[other])])
                if np.sum(np.all(np.isfinite(local), axis=2)) >= 3 * len(groups[other]) + 3:
                    try:
                        rms = sphere_fit(local).rms
                    except (ValueError, np.linalg.LinAlgError):
                        rms = np.nan
            spread = float(np.mean(far[np.ix_(groups[a], groups[b])]))
            edges.append(Edge(a, b, float(Dp[a, b]), float(rms), spread))

    greedy_tree, _ = _kruskal(L, sorted(edges, key=lambda e: e.mean_distance))
    joints = sorted((e for e in edges if e.joint(sigma) == "consistent"), key=lambda e: e.joint_rms)
    others = sorted((e for e in edges if e.joint(sigma) != "consistent"), key=lambda e: e.spread)
    tree, rest = _kruskal(L, joints + others)
    return Adjacency(tuple(tree), tuple(rest), tuple(greedy_tree), Dp, float(sigma))


def _kruskal(n: int, edges: list[Edge]) -> tuple[list[Edge], list[Edge]]:
    """Edges taken in the given order unless they close a cycle (those are the inconsistencies)."""
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    tree, rest = [], []
    for e in edges:
        ra, rb = find(e.a), find(e.b)
        if ra == rb or not (np.isfinite(e.mean_distance) and np.isfinite(e.spread)):
            rest.append(e)
        else:
            parent[ra] = rb
            tree.append(e)
    return tree, rest


# ---------------------------------------------------------------------------- both stages
@dataclass(frozen=True)
class Association:
    """Unlabelled markers grouped into segments and the groups joined into a tree."""

    best: Hypothesis
    hypotheses: list[Hypothesis]  # best first (best is hypotheses[0])
    greedy: Grouping  # the paper's single greedy grouping
    adjacency: Adjacency  # tree of the best hypothesis's groups
    sigma: float  # marker noise σ per coordinate implied by the rigidity threshold (m)
    ambiguous: tuple[int, ...]  # markers placed differently by a hypothesis the data cannot tell from the best
    labels: tuple[str, ...] | None

    @property
    def groups(self) -> tuple[tuple[int, ...], ...]:
        return self.best.groups

    def named_groups(self) -> list[list[str]]:
        """The best groups as marker labels (or 'm<index>' without labels)."""
        n = sum(len(g) for g in self.best.groups)
        names = self.labels or tuple(f"m{i}" for i in range(n))
        return [[names[i] for i in g] for g in self.best.groups]


def associate(markers: np.ndarray, labels=None, threshold: float | None = None) -> Association:
    """Group unlabelled marker trajectories (F, N, 3) into segments and join the groups into a tree."""
    X = np.asarray(markers, dtype=float)
    greedy, hyps, sigma = marker_hypotheses(X, threshold, labels)
    adj = group_adjacency(X, hyps[0].groups, sigma=sigma)
    return Association(hyps[0], hyps, greedy, adj, sigma, ambiguous_markers(hyps, sigma),
                       tuple(labels) if labels is not None else None)


# ---------------------------------------------------------------------------- against a model
@dataclass(frozen=True)
class MarkerAssignment:
    """Where one trial marker goes on the model, and why."""

    label: str
    segment: str | None
    status: str  # 'known' (model label), 'suspect' (model label, not rigid with its segment),
    #              'assigned' (unknown label placed by rigidity), 'unassigned'
    spread: float  # std (m) of its distance to the segment's markers: the worst pair (NaN if none)
    reason: str


@dataclass(frozen=True)
class ModelAssociation:
    """Every trial marker placed on a model segment, or left off with a reason."""

    markers: tuple[MarkerAssignment, ...]  # in trial label order
    threshold: float  # rigidity threshold (m²)

    def segment_of(self, label: str) -> str | None:
        return self[label].segment

    def __getitem__(self, label: str) -> MarkerAssignment:
        for m in self.markers:
            if m.label == label:
                return m
        raise KeyError(label)

    @property
    def suspects(self) -> list[str]:
        return [m.label for m in self.markers if m.status == "suspect"]

    @property
    def unassigned(self) -> list[str]:
        return [m.label for m in self.markers if m.segment is None]


def associate_to_model(model: Model, trial: Trial, threshold: float | None = None) -> ModelAssociation:
    """Place each trial marker on a segment of `model`.

    Labels the model knows go on their model segment.  A known marker whose distance to
    at least half of its segment's other known markers varies beyond the threshold is
    reported as 'suspect' (mislabelled, or loose) but not moved; suspects are not used to
    place unknown markers.  Every other label goes to the segment whose known markers it
    is rigid with — all of them (complete linkage on D), two or more (a marker across a joint
    keeps its distance to one marker beside that joint: stairdown's forearm markers to a
    lateral elbow marker's) and, for segments with ≥ 3 known markers, the rigid fit of the
    segment plus the marker must stay within the noise —
    the segment with the smallest worst-pair variance winning.  Otherwise the marker is
    left unassigned with the figure that ruled it out.  Segments without markers (the
    talus) cannot receive markers: nothing on them can be tested.
    """
    X = np.asarray(trial.markers, dtype=float)
    labels = list(trial.labels)
    N = len(labels)
    D = distance_variance(X)
    n_typ = typical_count(pair_counts(X))
    if threshold is None:
        threshold = rigid_threshold(D, n_typ)
    sigma = noise_sigma(D, n_typ)
    scorer = _Scorer(X, D, sigma)
    known = {m.name: m.segment for m in model.markers}
    seen = np.isfinite(X).all(axis=2).any(axis=0)
    seg_members: dict[str, list[int]] = {}
    for k, lab in enumerate(labels):
        if lab in known and seen[k]:  # a model marker the trial never shows can neither check nor place another
            seg_members.setdefault(known[lab], []).append(k)

    out: dict[int, MarkerAssignment] = {}
    reference: dict[str, list[int]] = {}
    for seg, members in seg_members.items():
        good = []
        for k in members:
            others = [m for m in members if m != k and np.isfinite(D[k, m])]  # pairs seen together long enough
            if not others:
                out[k] = MarkerAssignment(labels[k], seg, "known", np.nan,
                                          f"model marker on {seg} (no other marker of {seg} in the trial to check)")
                good.append(k)
                continue
            bad = [m for m in others if not D[k, m] <= threshold]
            worst = float(np.sqrt(np.max(D[k, others])))
            if bad and 2 * len(bad) >= len(others):
                figure = float(np.sqrt(np.median(D[k, others])))
                out[k] = MarkerAssignment(
                    labels[k], seg, "suspect", worst,
                    f"model marker on {seg}, but its distance to {', '.join(labels[m] for m in bad)} varies "
                    f"by {_mm(figure)} std (rigid: ≤ {_mm(np.sqrt(threshold))}); mislabelled or loose?")
            else:
                out[k] = MarkerAssignment(labels[k], seg, "known", worst, f"model marker on {seg}")
                good.append(k)
        reference[seg] = good

    empty = [s.name for s in model.segments if not s.markers]
    for k in range(N):
        if k in out:
            continue
        if labels[k] in known:  # a model marker the trial never shows
            out[k] = MarkerAssignment(labels[k], known[labels[k]], "known", np.nan,
                                      f"model marker on {known[labels[k]]} (not in the trial)")
            continue
        cands = []
        closest = (np.inf, "")
        single = []  # segments it is rigid with by their one marker
        for seg, members in reference.items():
            ref = [m for m in members if np.isfinite(D[k, m])]  # those seen together with it long enough
            if not ref:
                continue
            worst = float(np.max(D[k, ref]))
            if worst < closest[0]:
                closest = (worst, seg)
            if worst > threshold:
                continue
            if len(ref) < 2:  # a marker beside a joint keeps its distance to the segments on both sides of it
                single.append((seg, labels[ref[0]]))
                continue
            if len(ref) >= 3 and not scorer.admissible(tuple(sorted(ref + [k]))):
                continue
            cands.append((worst, seg))
        if not cands and len(single) == 1 and (alone := _alone_across(model, D, k, *single[0], reference, seg_members,
                                                                          empty)):
            seg, ref_label = single[0]
            out[k] = MarkerAssignment(labels[k], seg, "assigned", float(np.sqrt(D[k, labels.index(ref_label)])),
                                      f"rigid with {ref_label}, the one marker of {seg} the trial shows, and {alone}")
            continue
        if cands:
            cands.sort()
            worst, seg = cands[0]
            # Rigid with several segments alike, to within the noise (a static moves no segment against another): the
            # nearest segment's, not the one whose variance the noise made the smallest (BTKData's FunctionalStatic
            # put the left shank's cluster marker LT01 on tibia_r, 150 mm off in the walk after it)
            tied = [seg_ for w, seg_ in cands if w - worst <= Z_TIE * 2.0 * sigma**2]
            if len(tied) > 1:
                seg = min(tied, key=lambda t: _median_distance(X, k, reference[t]))
                worst = next(w for w, seg_ in cands if seg_ == seg)
                cands = [(worst, seg)] + [c for c in cands if c[1] != seg]
            also = f"; also rigid with {', '.join(s for _, s in cands[1:])}" if len(cands) > 1 else ""
            out[k] = MarkerAssignment(labels[k], seg, "assigned", float(np.sqrt(worst)),
                                      f"rigid with every marker of {seg} (worst {_mm(np.sqrt(worst))} std){also}")
            continue
        if single:
            why = (f"rigid only with the one marker of {', '.join(f'{s} ({m})' for s, m in single)} the trial shows "
                   f"there, which a marker across a joint beside it stays rigid with too")
        elif np.isfinite(closest[0]):
            why = (f"varies by {_mm(np.sqrt(closest[0]))} std or more against every segment "
                   f"(closest: {closest[1]}; rigid: ≤ {_mm(np.sqrt(threshold))})")
            if closest[0] <= threshold:
                why = f"distances to {closest[1]} are steady but its rigid fit with them is not"
        elif not seen[k]:  # a label of the lab's marker set this session did not use (Vicon exports them all)
            why = "no position in any frame of the trial"
        else:
            why = "never seen long enough together with any model marker"
        if empty and seen[k]:
            why += "; " + UNMARKED.format(", ".join(empty))
        out[k] = MarkerAssignment(labels[k], None, "unassigned",
                                  float(np.sqrt(closest[0])) if np.isfinite(closest[0]) else np.nan, why)
    return ModelAssociation(tuple(out[k] for k in range(N)), float(threshold))


# A label rigid with the one marker a segment shows may ride across a joint beside that marker (a marker on a hinge's
# axis keeps its distance to everything on the next segment), so the rigidity test leaves it out.  A lab's anatomical
# landmarks reconstructed from one cluster keep their distances to each other exactly (MOtoNMS's UNIPD walks: the
# greater trochanter 0.01 mm SD against the lateral epicondyle, the tibial tuberosity 0.00 against the lateral
# malleolus), closer than markers' noise lets two markers keep theirs, across a joint or not: where a label keeps its
# distance to that one marker within ACROSS_EXACT SD, and its distances to each segment's markers across the segment's
# joints vary (their median) by ACROSS_FLOOR SD at least (60 times as much), it rides on the segment (those
# landmarks had been left out, a femur posed by its knee marker alone).  Markers are not judged so: AddBiomechanics'
# stairdown keeps its forearm markers within 0.1-0.3 mm of the lateral elbow marker across the elbow, ADemo1 its calf
# markers within 2 mm of the lateral femoral condyle across the knee (8-10 mm against their own shank's malleolus).
ACROSS_EXACT = 5e-5  # m
ACROSS_FLOOR = 3e-3  # m


def _alone_across(model: Model, D: np.ndarray, k: int, seg: str, ref_label: str,
                  reference: Mapping[str, Sequence[int]], shown: Mapping[str, Sequence[int]],
                  empty: Collection[str]) -> str:
    """Why marker k, rigid with `seg`'s one shown marker `ref_label` (of `reference`), rides on `seg` and not across
    one of its joints (ACROSS_EXACT, ACROSS_FLOOR): the segments across them, each judged by the
    markers the trial shows there (`shown`, the suspects among them too: a trial whose most rigid pairs are
    reconstructed landmarks holds skin markers to 0.1 mm, and makes suspects of a whole pelvis); '' where k keeps its
    distance to that marker less exactly, or any segment across cannot be judged (no markers the trial shows there,
    none seen long enough with k) or may carry k.  Segments the model marks nowhere (a talus) are passed through to
    theirs: no marker can ride on them."""
    ref = next(m for m in reference[seg] if np.isfinite(D[k, m]))
    if D[k, ref] > ACROSS_EXACT ** 2:
        return ""
    near = {seg}
    todo = [seg]
    judged = []
    while todo:
        s = todo.pop()
        for j in model.joints:
            other = j.child if j.parent == s else j.parent if j.child == s else None
            if other is None or other in near:
                continue
            near.add(other)
            if other in empty:
                todo.append(other)
                continue
            seen = [m for m in shown.get(other, ()) if np.isfinite(D[k, m])]
            if not seen:
                return ""
            spread = float(np.sqrt(np.median([D[k, m] for m in seen])))
            if spread < ACROSS_FLOOR:
                return ""
            judged.append(f"{other} {_mm(spread)}")
    return f"its distances vary against every segment's across the joints ({', '.join(judged)} std, the median)" \
        if judged else ""


def _median_distance(X: np.ndarray, k: int, members: Sequence[int]) -> float:
    """The median over frames and `members` of marker k's distance to them (m; NaN-free frames only)."""
    d = np.linalg.norm(X[:, list(members)] - X[:, k:k + 1], axis=2)
    return float(np.nanmedian(d)) if np.isfinite(d).any() else np.inf


UNMARKED = "segments without markers ({}) cannot receive markers"  # the last clause of a left-out marker's reason


def split_reason(reason: str) -> tuple[str, str | None]:
    """A left-out marker's reason as its own part and the clause naming the model's segments without markers
    (UNMARKED: the same for every marker left out on one model, so a listing says it once), or None."""
    own, sep, clause = reason.rpartition("; ")
    head = UNMARKED.split("{}")[0]
    return (own, clause) if sep and clause.startswith(head) else (reason, None)


def shared_clause(reasons: list[str]) -> tuple[list[str], str | None]:
    """Left-out markers' reasons without the UNMARKED clause when every one ends with the same (it then said
    once, returned second); else the reasons whole and None."""
    parts = [split_reason(r) for r in reasons]
    if parts and all(c is not None and c == parts[0][1] for _, c in parts):
        return [own for own, _ in parts], parts[0][1]
    return list(reasons), None


def _mm(x: float) -> str:
    return f"{1000.0 * x:.1f} mm"


# A label the rigidity test leaves out still rides on a segment when its distances to that segment's markers vary
# (worst pair's SD over the frames) no more than MARGIN_OWN times as much as theirs to each other, and MARGIN_RATIO
# times less than to any other segment's.  The rigidity threshold is one figure for the whole trial, set by its most
# rigid pairs (a plate's markers, 0.5-1 mm); on skin a segment's own markers move more than that against each other
# (a treadmill walk's heel and toe 1.6 mm, pelvis 1.7, torso 3-5), so a marker beside them is "not rigid" with any.
# Measured (2026-11-29): AddBiomechanics' initial_off_treadmill (SACR, LMT5, RMT5: 0.9-1.3 mm against their
# segment's, 3.5-4.3x less than the next) and stairdown (the feet's lateral markers: 2.5-2.8 mm, 6x).  The ratio
# keeps gait2392's elbow markers (its model has no arms) off the torso: 5.7 mm against the torso's, 2.4x less than
# against the next segment's (stairdown's SACR and Pelvis3, 2.8-2.9x, stay out with them).
MARGIN_OWN = 2.0
MARGIN_RATIO = 3.0


@dataclass(frozen=True)
class MarginHost:
    """Where a label's distances to a segment's markers vary least (`best`; SDs over the frames, worst pair, m):
    `segment` is `best` when the margins hold (MARGIN_OWN, MARGIN_RATIO), else None."""

    label: str
    segment: str | None
    best: str
    spread: float  # against best's markers
    own: float  # best's markers against each other
    runner_up: str
    runner_up_spread: float

    def reason(self) -> str:
        """Why it was placed there, in the words of the rigidity test's reasons."""
        return (f"its distances to {self.best}'s markers vary by {_mm(self.spread)} std, theirs to each other by "
                f"{_mm(self.own)}, to {self.runner_up}'s by {_mm(self.runner_up_spread)} "
                f"({self.runner_up_spread / self.spread:.1f}x)")


def margin_hosts(model: Model, trial: Trial, labels: Sequence[str],
                 placed: Mapping[str, str] | None = None) -> dict[str, MarginHost]:
    """Each of `labels` (trial markers `model` does not know) -> its MarginHost, from the distances' SDs over
    `trial`'s frames.  A segment can host when the trial shows two or more of its markers — the model's (suspects
    too: on skin they are what the segment is) and the new labels already `placed` on it (label -> segment) —; every
    segment with one counts as a runner-up.  Labels no segment's markers are seen with long enough are left out of
    the result."""
    X = np.asarray(trial.markers, dtype=float)
    index = {lab: k for k, lab in enumerate(trial.labels)}
    seen = np.isfinite(X).all(axis=2).any(axis=0)
    members: dict[str, list[int]] = {}
    for name, segment in [*((m.name, m.segment) for m in model.markers), *(placed or {}).items()]:
        k = index.get(name)
        if k is not None and seen[k]:
            members.setdefault(segment, []).append(k)
    want = [index[lab] for lab in labels if lab in index]
    cols = sorted({k for ks in members.values() for k in ks} | set(want))
    at = {k: i for i, k in enumerate(cols)}
    sd = np.sqrt(distance_variance(X[:, cols]))
    own = {}
    for seg, ks in members.items():
        pairs = [sd[at[a], at[b]] for i, a in enumerate(ks) for b in ks[i + 1:] if np.isfinite(sd[at[a], at[b]])]
        if pairs:
            own[seg] = max(pairs)
    out = {}
    for lab in labels:
        if lab not in index:
            continue
        k = at[index[lab]]
        rows = []
        for seg, ks in members.items():
            vals = [sd[k, at[m]] for m in ks if np.isfinite(sd[k, at[m]])]
            if vals:
                rows.append((max(vals), seg, len(vals)))
        hosts = sorted(r for r in rows if r[2] >= 2 and r[1] in own)
        if not hosts:
            continue
        spread, seg, _ = hosts[0]
        runner = min(((v, s) for v, s, _ in rows if s != seg), default=(np.inf, ""))
        ok = spread <= MARGIN_OWN * own[seg] and runner[0] >= MARGIN_RATIO * spread
        out[lab] = MarginHost(lab, seg if ok else None, seg, float(spread), float(own[seg]), runner[1],
                              float(runner[0]))
    return out


# A model marker is taken for another segment's when its distances to its own segment's other markers vary
# MISPLACED_RATIO times more (SD over the frames) than to some other segment's, and by more than MISPLACED_FLOOR:
# a label exchanged for the whole trial (a knee marker named as the ankle's) rides with the wrong segment in
# every frame.  Measured (2026-11-27): no marker so taken on pig_walk (static, walk), gait2392, Rajagopal or
# simulated squats with 3-10 mm soft-tissue artefact; exchanged across segments on those squats, the marker
# on the wrong segment rides with it 10-20 times closer (RKNE/RANK 81 against 4 mm, RELB/RWRA 65 against 2).
# Exchanges within one segment, or across a joint that hardly moves in the trial, cannot be seen this way.
MISPLACED_RATIO = 3.0
MISPLACED_FLOOR = 0.005  # m
EXCHANGE_TRIES = 5  # exchanges of two labels verified (misplaced_labels), the most promising first
MISPLACED_FRAMES = 150  # about this many evenly spaced frames of a trial are read (the SDs need no more)


@dataclass(frozen=True)
class Misplaced:
    """A trial label whose marker rides with another segment than the model's for it."""

    label: str
    segment: str  # the model's segment for the label
    rides_with: str  # the segment whose markers keep the steadiest distances to it
    sd_own: float  # m: median SD over frames of its distances to its own segment's other markers
    sd_other: float  # m: the same against `rides_with`'s markers
    partners: tuple[str, ...] = ()  # its segment's other labels it was judged against (one may be the wrong one)
    # pairs of labels each of whose exchange leaves no label of the trial misplaced (rigidity alone cannot choose
    # between them when two segments carry two markers each: exchanging either pair restores both)
    exchanges: tuple[tuple[str, str], ...] = ()

    def text(self) -> str:
        out = (f"{self.label} moves with {self.rides_with}'s markers (distances steady to "
               f"{1e3 * self.sd_other:.1f} mm SD), not with {self.segment}'s ({', '.join(self.partners)}: "
               f"{1e3 * self.sd_own:.1f} mm)")
        if self.exchanges:
            out += "; with " + " or ".join(f"{a} and {b}" for a, b in self.exchanges) + \
                " exchanged every label moves with its segment"
        return out


def misplaced_labels(model: Model, trials: Sequence[Trial], ratio: float = MISPLACED_RATIO,
                     floor: float = MISPLACED_FLOOR, skip: Collection[str] = (), clean: bool = True
                     ) -> tuple[Misplaced, ...]:
    """The trials' labels of model markers that ride with another segment than the model's: a label exchanged
    for the whole trial, or put on the wrong marker.  Per label, the median SD over frames of its distances to
    its segment's other markers against the same to each other segment's; the worst taken first and left out
    of every segment's markers before the others are judged again (a label exchanged with one of them makes its
    partners look misplaced too).  Frames of all `trials` together: pass one trial to judge its labelling alone.
    Which label of an exchanged pair is named can be its partner's (a segment with two markers: each looks
    misplaced against the other), so the result is labels to check, not a correction; where exchanging two
    labels (a named one or its segment's partner, with a marker of another segment) leaves none misplaced,
    every entry carries those pairs (`exchanges`).  `skip`: labels not judged (a joint-centre marker rides with
    both segments of its joint).  `clean`: the samples that jump away and back or break their segment's distances
    (seeding.without_broken: spikes, a ghost before a gap, swapped labels) left out first: one frame of a ghost a
    metre off set the SD of every distance of its marker, and a correct label rode "with another segment"; False
    where the trials are so cleaned already."""
    if clean:
        trials = [without_broken(model, t)[0] for t in trials]
    labels = [m.name for m in model.markers if m.name not in skip and any(m.name in t.labels for t in trials)]
    if not labels:
        return ()
    segment = {m.name: m.segment for m in model.markers}
    parts, noise = [], []
    for t in trials:
        X = t.columns(labels)
        parts.append(X[:: max(1, t.n_frames // MISPLACED_FRAMES)])
        noise.append(jitter_sd(X))
    # A marker's white noise (seed.jitter: what its fourth differences read) adds its variance to every distance of
    # it; its excess over the markers' median is taken out, so that a noisy mate does not make a steady label look
    # loose on its own segment (pig_walk's LUPA with 5 mm of noise: LELB, the humerus's other marker, "rode with the
    # forearm", 5.8 mm SD against 1.9).  Only the excess: where every marker jitters alike (video keypoints), taking
    # it all out leaves the variances' own sampling error, a few mm, to name a label at random.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        white = np.nan_to_num(np.nanmedian(np.concatenate(noise), axis=0))
    white = np.sqrt(np.maximum(white**2 - float(np.median(white)) ** 2, 0.0))
    sd = np.sqrt(np.maximum(distance_variance(np.concatenate(parts)) - white[:, None] ** 2 - white[None, :] ** 2, 0.0))
    seg = [segment[n] for n in labels]
    found = _misplaced(sd, labels, seg, ratio, floor)
    if not found:
        return ()
    pairs = _exchanges(sd, labels, seg, found, ratio, floor)
    return tuple(replace(m, exchanges=pairs) for m in found) if pairs else found


def _misplaced(sd: np.ndarray, labels: list[str], seg: list[str], ratio: float, floor: float) -> tuple[Misplaced, ...]:
    """misplaced_labels on the distance SDs `sd` (labels x labels) of labels on segments `seg`."""
    members: dict[str, list[int]] = {}
    for k, s in enumerate(seg):
        members.setdefault(s, []).append(k)
    out: list[Misplaced] = []
    while True:
        worst = None
        for k, n in enumerate(labels):
            own = [m for m in members.get(seg[k], []) if m != k]
            if k not in members.get(seg[k], []) or not own:
                continue
            s_own = float(np.median(sd[k, own]))
            others = [(float(np.median(sd[k, ms])), s) for s, ms in members.items() if s != seg[k] and ms]
            if not others or not np.isfinite(s_own):
                continue
            s_other, other = min(others)
            against = s_own / max(s_other, 1e-12)  # (white noise taken out, a pair can read 0)
            if s_own > floor and s_other * ratio < s_own and (worst is None or against > worst[0]):
                worst = (against, Misplaced(n, seg[k], other, s_own, s_other, tuple(labels[m] for m in own)), k)
        if worst is None:
            return tuple(out)
        out.append(worst[1])
        members[seg[worst[2]]].remove(worst[2])


def _exchanges(sd: np.ndarray, labels: list[str], seg: list[str], found: tuple[Misplaced, ...], ratio: float,
               floor: float) -> tuple[tuple[str, str], ...]:
    """Pairs of labels whose exchange leaves no label misplaced: one of the named labels or its segment's
    partners, and a label of another segment; the EXCHANGE_TRIES candidates that make every segment steadiest
    (the sum of its markers' distance SDs) tried, and of those that pass, the steadiest kept."""
    at = {n: k for k, n in enumerate(labels)}
    same = np.equal.outer(np.array(seg), np.array(seg)) & ~np.eye(len(seg), dtype=bool)
    firsts = dict.fromkeys(at[x] for m in found for x in (m.label, *m.partners))
    cands = []
    for a in firsts:
        for b in range(len(labels)):
            if seg[b] == seg[a]:
                continue
            order = np.arange(len(labels))
            order[[a, b]] = order[[b, a]]
            swapped = sd[np.ix_(order, order)]
            cands.append((float(np.sum(np.where(same & np.isfinite(swapped), swapped, 0.0))), a, b, order))
    cands.sort(key=lambda c: c[0])
    out: dict = {}
    for score, a, b, order in cands[:EXCHANGE_TRIES]:
        if not _misplaced(sd[np.ix_(order, order)], labels, seg, ratio, floor):
            out.setdefault(frozenset((a, b)), (score, labels[a], labels[b]))
    # Only the steadiest: an exchange that restores the trial's labelling gives exactly the steadiness of the
    # right labels, and so does its twin where two segments carry two markers each (the same pairs within each
    # segment); others that also leave none misplaced are 3-12 % less steady (on squats and pig_walk).
    best = min((v[0] for v in out.values()), default=0.0)
    return tuple((a, b) for score, a, b in out.values() if score <= best * (1 + 1e-9))



# Two labels of one segment's markers exchanged in one trial and not in another (a walk labelled with the heel and
# toe exchanged, its static right): rigidity cannot see it (both ride with their segment), and with two markers on
# the segment the fit turns the segment round rather than showing either marker elsewhere on it.  Their distances to
# the markers near them that keep steady (the segment's others, else across a joint near its axis) can: in one trial
# they are the other trial's with the two exchanged; exchanged alike in every trial, the base model's.  Measured
# (2026-11-29, median distances over the frames, RMS over those markers): pig_walk with RHEE and RTOE exchanged in
# the walk, 86 mm as labelled against 4 mm exchanged (their distances to RANK); on the recorded trials of pig_walk,
# gait2392 and Rajagopal2016, together or alone, nothing named (docs/calibration.md).
EXCHANGE_RATIO = 2.5  # as labelled, the distances differ between the trials this many times more than exchanged ...
EXCHANGE_SIGNIFICANT = 3.0  # ... and this many times their spread over the frames (each trial's, added) ...
EXCHANGE_GAIN = 0.03  # ... and by this much more (m, RMS over the markers near them)
EXCHANGE_SPREAD_FLOOR = 0.005  # m, added to the spreads (a rigid pair's is the noise alone)
EXCHANGE_STEADY = 0.015  # m: markers whose distances to the pair spread over frames by more are not compared
EXCHANGE_JOINTS = 2  # markers on segments within this many joints of the pair's are compared
EXCHANGE_FRAMES = 60  # about this many evenly spaced frames of a trial are read (medians need no more)
#: Against the base model, an exchange is the labels' only where it turns the pair round: two labels that point the
#: way the base model's do (b − a in the root segment's frame, posed on its markers in each frame, at a median cosine
#: of at least this with the base model's neutral b − a) sit where the lab puts them, the model's places elsewhere
#: along the same line; not named.  pyCGM2's CGM2.3 marker set on its gait2392 puts the heel 113 mm behind the ankle
#: and the toe 34 mm ahead of it; pig_walk's sit about 60 mm behind and 150 ahead: their distances to the ankle miss
#: the model's by 84 mm as labelled, by 18 exchanged, while heel-to-toe points forward in both (median cosine 0.97 and
#: 1.00); taken for the lab's protocol the fit flipped the foot (calcn scaled 0.20).  With the two exchanged in both of
#: pig_walk's trials: -0.90 (the exchange named, the protocol taken, as before).
EXCHANGE_ALONG = 0.5


@dataclass(frozen=True)
class Exchanged:
    """Two labels of one segment's markers exchanged: between two trials, or against the base model in trials that
    all have them alike (exchanged_between)."""

    labels: tuple[str, str]
    segment: str
    # two trials compared (indices), the second with them exchanged against the first; or the trials whose
    # distances are the base model's exchanged (then every trial that shows them has them alike)
    trials: tuple[int, ...]
    kept: float  # m: RMS difference of the pair's distances to the markers near them, as labelled
    exchanged: float  # m: the same with the two labels exchanged
    references: tuple[str, ...]  # the markers near them compared
    odd: int | None = None  # between two trials: the one the base model's distances say has them exchanged
    against_model: bool = False  # compared with the base model's distances, not between trials
    # against the model, the only such pair on its segment: the fit took the lab's protocol, the base model's places
    # of the two exchanged where it starts and where its priors hold them (the labels kept; calibrate.calibration.
    # pipeline)
    protocol: bool = False

    def text(self, names: Sequence[str]) -> str:
        a, b = self.labels
        near = f"{', '.join(self.references[:4])}{', ...' if len(self.references) > 4 else ''}"
        if self.against_model:
            where = " and ".join(names[k] for k in self.trials)
            return (f"{a} and {b} (both on {self.segment}) sit each where the other belongs in {where}: their "
                    f"distances to {near} differ from the base model's by {1e3 * self.kept:.0f} mm as labelled, "
                    f"{1e3 * self.exchanged:.0f} mm exchanged (the trials alike: no trial tells which is right; a "
                    f"lab's marker protocol may differ from the model's)")
        i, j = (names[k] for k in self.trials)
        out = (f"{a} and {b} (both on {self.segment}) are exchanged between {i} and {j}: their distances to {near} "
               f"differ by {1e3 * self.kept:.0f} mm between the two as labelled, {1e3 * self.exchanged:.0f} mm "
               f"exchanged")
        if self.odd is not None:
            out += f"; against the base model's, {names[self.odd]}'s are the exchanged ones"
        return out


def exchanged_between(model: Model, trials: Sequence[Trial], skip: Collection[str] = ()) -> tuple[Exchanged, ...]:
    """Pairs of labels of one segment's markers exchanged (see EXCHANGE_RATIO): per trial the median over frames of
    each marker pair's distance and its spread; for each pair of labels on one segment, its distances to the markers
    near it that keep steady (EXCHANGE_STEADY) compared between every two trials, as labelled and with the two
    exchanged in the second (`odd`: the trial whose distances fit the base model's, in its neutral pose scaled by the
    median ratio of the trial's same-segment distances to the model's, better exchanged, when just one of the two
    does); a pair not so found, compared in each trial with the base model's (`against_model`: the trials where
    it fits them better exchanged, all alike).  `skip`: labels not judged (joint-centre markers)."""
    names = [m.name for m in model.markers if m.name not in skip and all(m.name in t.labels for t in trials)]
    if not trials or len(names) < 4:
        return ()
    seg = [model.markers[model.marker_index(n)].segment for n in names]
    stats = []  # per trial: (median distances, their spreads)
    for t in trials:
        X = t.select(names).markers[:: max(1, t.n_frames // EXCHANGE_FRAMES)]
        stats.append(_median_distances(np.linalg.norm(X[:, :, None] - X[:, None], axis=-1)))
    ref = _model_distances(model, names)
    same = np.equal.outer(np.array(seg), np.array(seg)) & ~np.eye(len(names), dtype=bool)
    scaled = [(_trial_scale(D, ref, same) * ref, np.zeros_like(S)) for D, S in stats]  # the base model's, per trial
    out = []
    for s in dict.fromkeys(seg):
        on = [k for k in range(len(names)) if seg[k] == s]
        near = _within_joints(model, s, EXCHANGE_JOINTS)
        for x, a in enumerate(on):
            for b in on[x + 1:]:
                # The segment's other markers where it has any (rigid: the pose cannot move their distances between
                # trials), else those within EXCHANGE_JOINTS joints.
                refs = [c for c in on if c not in (a, b)] or [c for c in range(len(names))
                                                             if c not in (a, b) and seg[c] in near]
                found = []
                for i in range(len(trials)):
                    for j in range(i + 1, len(trials)):
                        hit = _exchange(stats[i], stats[j], a, b, refs)
                        if hit is None:
                            continue
                        steady, kept, swapped = hit
                        worse = [k for k in (i, j) if _fits_exchanged(scaled[k], stats[k], a, b, steady)]
                        found.append(Exchanged((names[a], names[b]), s, (i, j), kept, swapped,
                                               tuple(names[c] for c in steady), worse[0] if len(worse) == 1 else None))
                if not found:  # alike in every trial: each against the base model
                    hits = [(k, h) for k in range(len(trials))
                            if (h := _exchange(scaled[k], stats[k], a, b, refs)) is not None]
                    if hits and not _points_as_model(model, trials, names, seg, a, b):
                        first = hits[0][1]
                        found.append(Exchanged((names[a], names[b]), s, tuple(k for k, _ in hits),
                                               float(np.mean([h[1] for _, h in hits])),
                                               float(np.mean([h[2] for _, h in hits])),
                                               tuple(names[c] for c in first[0]), None, True))
                out += found
    # Exchanges on one segment between the same trials that each explain the distances: a mirror image (the
    # pelvis's PSIS exchanged reads as its ASIS exchanged, distances cannot tell handedness): named, none left out.
    twins = Counter((x.segment, x.trials) for x in out if not x.against_model)
    return tuple(replace(x, odd=None) if not x.against_model and twins[(x.segment, x.trials)] > 1 else x for x in out)


def _points_as_model(model: Model, trials: Sequence[Trial], names: list[str], seg: list[str], a: int, b: int) -> bool:
    """Whether labels a and b point the way the base model's do (EXCHANGE_ALONG): b − a in the root segment's frame,
    posed in each frame of every trial on the root's other markers (three or more; else False: not judged), against
    the base model's neutral b − a, at a median cosine of EXCHANGE_ALONG or more."""
    root = [c for c in range(len(names)) if seg[c] == model.root and c not in (a, b)]
    if len(root) < 3:
        return False
    P = model.neutral_positions([names[c] for c in (*root, a, b)])
    along = P[-1] - P[-2]
    cosines = []
    for t in trials:
        X = t.select([names[c] for c in (*root, a, b)]).markers
        w = np.all(np.isfinite(X[:, :-2]), axis=2).astype(float)
        R, _ = kabsch_batch(P[:-2], np.where(w[..., None] > 0, X[:, :-2], 0.0), w)
        v = np.einsum("fji,fj->fi", R, X[:, -1] - X[:, -2])  # Rᵀ (b − a): in the base model's neutral frame
        with np.errstate(invalid="ignore"):
            c = v @ along / (np.linalg.norm(v, axis=1) * np.linalg.norm(along))
        cosines.append(c[np.isfinite(c)])
    c = np.concatenate(cosines)
    return bool(c.size and np.median(c) >= EXCHANGE_ALONG)


def _fits_exchanged(first: tuple[np.ndarray, np.ndarray], second: tuple[np.ndarray, np.ndarray], a: int, b: int,
                    refs: list[int]) -> bool:
    """Whether the second (distances, spreads)' a and b fit the first's better exchanged (in units of the spreads)."""
    (Di, Si), (Dj, Sj) = first, second
    return _mismatch(Di, Dj, a, b, refs, True, (Si, Sj)) < _mismatch(Di, Dj, a, b, refs, False, (Si, Sj))


def _trial_scale(D: np.ndarray, ref: np.ndarray, same: np.ndarray) -> float:
    """The median ratio of a trial's same-segment marker distances to the base model's."""
    ok = same & np.isfinite(D) & (ref > 0.02)
    return float(np.median(D[ok] / ref[ok])) if ok.any() else 1.0


def _exchange(first: tuple[np.ndarray, np.ndarray], second: tuple[np.ndarray, np.ndarray], a: int, b: int,
              refs: list[int]) -> tuple[list[int], float, float] | None:
    """Whether labels a and b are exchanged in the second trial against the first (exchanged_between): the markers
    of `refs` whose distances to both keep steady in both trials, and the RMS mismatch (m) of those distances as
    labelled and exchanged; None if not."""
    (Di, Si), (Dj, Sj) = first, second
    # On the segment, or across a joint near its axis: across a joint that turns far (a squat's knee) the distances
    # move with the pose, not with the labels.
    steady = [c for c in refs if max(Si[a, c], Si[b, c], Sj[a, c], Sj[b, c]) <= EXCHANGE_STEADY]
    if not steady:
        return None
    z = [_mismatch(Di, Dj, a, b, steady, e, (Si, Sj)) for e in (False, True)]
    kept, swapped = (_mismatch(Di, Dj, a, b, steady, e) for e in (False, True))
    if z[0] >= EXCHANGE_SIGNIFICANT and z[0] >= EXCHANGE_RATIO * z[1] and kept - swapped >= EXCHANGE_GAIN:
        return steady, kept, swapped
    return None


def _median_distances(D: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, n) median over frames of (frames, n, n) distances and their spread (MAD_SD times the median absolute
    deviation), NaN where a pair is never seen together."""
    seen = np.isfinite(D).any(axis=0)
    med, sd = np.full(D.shape[1:], np.nan), np.full(D.shape[1:], np.nan)
    med[seen] = np.nanmedian(D[:, seen], axis=0)
    sd[seen] = MAD_SD * np.nanmedian(np.abs(D[:, seen] - med[seen]), axis=0)
    return med, sd


def _model_distances(model: Model, names: Sequence[str]) -> np.ndarray:
    """(n, n) distances between the named markers of the base model in its neutral pose (Pinocchio)."""
    P = model.neutral_positions(names)
    return np.linalg.norm(P[:, None] - P[None], axis=-1)


def _within_joints(model: Model, segment: str, joints: int) -> set[str]:
    """The segments at most `joints` joints from `segment` (itself included)."""
    adj: dict[str, set[str]] = {}
    for j in model.joints:
        adj.setdefault(j.parent, set()).add(j.child)
        adj.setdefault(j.child, set()).add(j.parent)
    out, front = {segment}, {segment}
    for _ in range(joints):
        front = {n for s in front for n in adj.get(s, ())} - out
        out |= front
    return out


def _mismatch(Di: np.ndarray, Dj: np.ndarray, a: int, b: int, refs: list[int], exchanged: bool,
              spread: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """RMS difference (m) of a's and b's distances to `refs` between two trials (b's and a's in the second); with
    `spread` (each trial's distance spreads), each difference over the root sum of the two spreads and
    EXCHANGE_SPREAD_FLOOR squared (dimensionless)."""
    x, y = (b, a) if exchanged else (a, b)
    d = np.concatenate([Dj[x, refs] - Di[a, refs], Dj[y, refs] - Di[b, refs]])
    if spread is not None:
        Si, Sj = spread
        d = d / np.sqrt(np.concatenate([Sj[x, refs] ** 2 + Si[a, refs] ** 2, Sj[y, refs] ** 2 + Si[b, refs] ** 2])
                        + EXCHANGE_SPREAD_FLOOR ** 2)
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan")
