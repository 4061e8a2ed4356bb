"""Which markers ride on one rigid segment (seed 002, Section 3.1): the variance of every pair's distance
over the frames, the noise level it is judged against, and the greedy grouping by it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_FRAMES = 10  # pairs seen together in fewer frames get D = +inf (no evidence of rigidity)


RIGID_FLOOR = (0.1e-3) ** 2  # m²: smallest rigidity threshold (0.1 mm std), so noise-free data works


Z_RIGID = 5.0  # standard errors of a sample variance allowed above the noise level


LOOSE_FACTOR = 9.0  # threshold / noise level when the frame count is unknown (3x in standard deviation)


# ---------------------------------------------------------------------------- distances
def distance_variance(markers: np.ndarray, min_frames: int = MIN_FRAMES) -> np.ndarray:
    """D (N, N): variance over frames of the distance |y_i − y_j| between markers (m²).

    markers (F, N, 3), NaN in gaps.  Each pair uses only the frames in which both markers
    are seen (sample variance, ddof=1).  The diagonal is 0.  A pair seen together in fewer
    than `min_frames` frames gets +inf: there is no evidence that it is rigid.
    """
    _, d_sq, n = distance_moments(markers)
    with np.errstate(invalid="ignore", divide="ignore"):
        D = d_sq / (n - 1)
    D[n < max(min_frames, 2)] = np.inf
    np.fill_diagonal(D, 0.0)
    return D


def pair_counts(markers: np.ndarray) -> np.ndarray:
    """(N, N) number of frames in which both markers of a pair are seen."""
    seen = np.all(np.isfinite(np.asarray(markers, dtype=float)), axis=2).astype(float)
    return (seen.T @ seen).astype(int)


def distance_moments(markers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pair: mean distance, sum of squared deviations from it, frame count (two passes, chunked)."""
    X = np.asarray(markers, dtype=float)
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError(f"markers: expected shape (frames, markers, 3), got {X.shape}")
    F, N, _ = X.shape
    seen = np.all(np.isfinite(X), axis=2)
    X = np.where(seen[..., None], X, 0.0)
    n = seen.T.astype(float) @ seen.astype(float)
    step = max(1, int(2_000_000 // max(N * N, 1)))

    def chunks():
        for a in range(0, F, step):
            x, s = X[a:a + step], seen[a:a + step]
            both = s[:, :, None] & s[:, None, :]
            sq = x[:, :, None, :] - x[:, None, :, :]
            sq *= sq  # |x_i - x_j| as np.linalg.norm(…, axis=3) forms it (the same bits), 9x sooner
            d = np.sqrt(sq[..., 0] + sq[..., 1] + sq[..., 2])
            yield d, both

    total = np.zeros((N, N))
    for d, both in chunks():
        total += np.where(both, d, 0.0).sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    sq = np.zeros((N, N))
    for d, both in chunks():
        sq += np.where(both, (d - np.nan_to_num(mean)) ** 2, 0.0).sum(0)
    return mean, sq, n


def pair_distance_level(D: np.ndarray) -> float:
    """The variance D of a rigid pair in this data (m²), i.e. 2σ² for marker noise σ per coordinate.

    First guess: the median over markers of each marker's smallest off-diagonal D entry
    (most markers share a segment with at least one other).  That minimum is biased low,
    so the estimate is refined as the median of all pairs with D below three times the
    first guess (mostly same-segment pairs).
    """
    D = np.asarray(D, dtype=float)
    off = D + np.diag(np.full(len(D), np.inf))
    smallest = off.min(1)
    smallest = smallest[np.isfinite(smallest)]
    if smallest.size == 0:
        return 0.0
    guess = float(np.median(smallest))
    iu = np.triu_indices(len(D), 1)
    close = D[iu][D[iu] <= 3.0 * guess]
    return float(np.median(close)) if close.size else guess


def rigid_threshold(D: np.ndarray, n_frames: float | None = None, *, z: float = Z_RIGID,
                    factor: float | None = None, floor: float = RIGID_FLOOR) -> float:
    """Largest D (m²) for which a pair of markers counts as rigid (on one segment).

    A rigid pair's distance varies only by the marker noise: D ≈ 2σ² (σ per coordinate),
    estimated by :func:`pair_distance_level`.  The threshold is that level times

    * `factor`, if given (e.g. 9 = 3x in standard deviation, for skin markers with
      soft-tissue artefact, which is not white noise);
    * otherwise, with `n_frames` (frames per pair; :func:`associate` passes the median
      pair count) the sampling spread of a sample variance: 1 + z·sqrt(2 / (n − 1)), about
      1.41 at 300 frames (1.19x in standard deviation).  Tight on purpose: across the
      radioulnar joint the forearm marker FRM keeps its distances to WRA/WRB within
      1-3.5 mm std during ±50° of pronation, and near a hinge axis KNE, ELB and ANK keep
      theirs to the next segment within a few mm; with 9x (3x in std) FRM joins the radius
      or the hand in every one of simulated subjects 0-3 at 1 mm noise;
    * otherwise 9.

    The result is at least `floor`, (0.1 mm)² by default: well above round-off, and small
    enough for noise-free data (with (0.5 mm)² FRM joins the radius in some noise-free
    subjects, whose FRM-WRA/WRB distances vary by only 0.2-0.6 mm std).
    """
    level = pair_distance_level(D)
    if factor is None:
        factor = LOOSE_FACTOR if n_frames is None else sampling_factor(n_frames, z)
    return max(float(floor), level * float(factor))


def sampling_factor(n: float, z: float) -> float:
    return 1.0 + z * np.sqrt(2.0 / max(float(n) - 1.0, 1.0))


def noise_sigma(D: np.ndarray, n_frames: float | None = None, *, floor: float = RIGID_FLOOR) -> float:
    """Marker noise σ per coordinate (m): sqrt(level / 2) with the level of
    :func:`pair_distance_level`, but not below what the threshold floor implies (so that
    noise-free data gets a small positive σ rather than round-off)."""
    factor = LOOSE_FACTOR if n_frames is None else sampling_factor(n_frames, Z_RIGID)
    return float(np.sqrt(max(pair_distance_level(D), floor / factor) / 2.0))


# ---------------------------------------------------------------------------- stage 1: groups
@dataclass(frozen=True)
class Grouping:
    """Markers grouped by the greedy of Ringer & Lasenby (one group per presumed segment)."""

    groups: tuple[tuple[int, ...], ...]  # marker indices; each sorted, groups ordered by first index
    inconsistencies: tuple[tuple[int, int, float], ...]  # (i, j, D_ij) pairs the greedy could not honour
    threshold: float  # rigidity threshold used (m²)

    def label(self, n_markers: int) -> np.ndarray:
        """(n_markers,) group index of every marker."""
        return group_labels(self.groups, n_markers)


def group_labels(groups, n: int) -> np.ndarray:
    out = np.full(n, -1)
    for g, members in enumerate(groups):
        out[list(members)] = g
    return out


def canonical_groups(groups) -> tuple[tuple[int, ...], ...]:
    return tuple(sorted(tuple(sorted(g)) for g in groups if len(g)))


def greedy_groups(D: np.ndarray, threshold: float, forced: tuple[tuple[int, int], ...] = ()) -> Grouping:
    """The greedy grouping with complete linkage; `forced` pairs start as groups of their own."""
    N = len(D)
    label = np.full(N, -1)
    groups: list[list[int]] = []
    inconsistent: list[tuple[int, int, float]] = []

    def add(i: int, j: int) -> None:
        gi, gj = label[i], label[j]
        if gi < 0 and gj < 0:
            label[[i, j]] = len(groups)
            groups.append([i, j])
        elif gi >= 0 and gj >= 0:
            if gi != gj:
                inconsistent.append((i, j, float(D[i, j])))
        else:
            g, new = (gi, j) if gi >= 0 else (gj, i)
            if np.all(D[new, groups[g]] <= threshold):  # complete linkage: rigid with every member
                label[new] = g
                groups[g].append(new)
            else:
                inconsistent.append((i, j, float(D[i, j])))

    for i, j in forced:
        add(int(i), int(j))
    iu, ju = np.triu_indices(N, 1)
    vals = D[iu, ju]
    ok = np.flatnonzero(vals <= threshold)
    for k in ok[np.argsort(vals[ok], kind="stable")]:
        add(int(iu[k]), int(ju[k]))
    groups += [[i] for i in np.flatnonzero(label < 0)]
    return Grouping(canonical_groups(groups), tuple(inconsistent), float(threshold))


def group_markers(markers_or_D: np.ndarray, threshold: float | None = None) -> Grouping:
    """Group markers that move rigidly together: the greedy of Ringer & Lasenby, Section 3.

    Input: trajectories (F, N, 3) or a distance-variance matrix D (N, N); without a
    threshold, :func:`rigid_threshold` gives one (from D alone the frame count is unknown,
    so the loose 9x factor is used).  Repeatedly take
    the smallest remaining D entry (i, j) with D_ij ≤ threshold: neither marker grouped →
    new group; one grouped → the other joins, but only if it is rigid (D ≤ threshold)
    with *every* member (complete linkage), else the pair is an inconsistency; both
    grouped in different groups → inconsistency.  Markers with no rigid partner become
    singleton groups (e.g. FRM, the only marker on the ulna).

    Complete linkage matters near hinges: the lateral knee marker (KNE, femur) lies almost
    on the knee axis, so its distances to the tibia markers hardly vary either; it can
    only join a group whose every member it is rigid with.
    """
    A = np.asarray(markers_or_D, dtype=float)
    if A.ndim == 3:
        D = distance_variance(A)
        if threshold is None:
            threshold = rigid_threshold(D, typical_count(pair_counts(A)))
    elif A.ndim == 2 and A.shape[0] == A.shape[1]:
        D = A
        if threshold is None:
            threshold = rigid_threshold(D)
    else:
        raise ValueError(f"group_markers: expected trajectories (F, N, 3) or D (N, N), got shape {A.shape}")
    return greedy_groups(D, float(threshold))


def typical_count(n: np.ndarray) -> float:
    iu = np.triu_indices(len(n), 1)
    counts = n[iu][n[iu] > 0]
    return float(np.median(counts)) if counts.size else 0.0
