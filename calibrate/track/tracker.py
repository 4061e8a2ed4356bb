"""Seed 002's 3-D point tracker (Ringer & Lasenby, Section 2): unlabelled 2-D detections of M calibrated
cameras -> 3-D marker trajectories.

Per frame k:

1. **Predict** every live track's position ŷ_n(k) by linear extrapolation of its last two estimates
   (constant velocity; the paper's "linear interpolation").
2. **Associate** by the (M+1)-dimensional assignment of tracks × detections of camera 1 × … × camera M.
   A candidate hyperedge joins a track with at most one detection per camera; its cost is the paper's
   Eq. (2), in units of the detection noise σ (``pixel_sd``):

       c = r(i_1..i_M) / σ² + g Σ_m d(n, i_m)² / σ² + |X − ŷ_n|² / s_n² − κ · (number of detections)

   r: the squared reprojection error (px², first order) of the point triangulated from the detections;
   d: the pixel distance of a detection from the track's predicted projection; g = σ² / σ_p², the ratio
   of the detection noise to the prediction's (``prediction_sd``, growing linearly while a track is
   unseen, up to ``max_spread`` times: a wider gate lets a lost track jump onto a neighbour's
   detections); κ (``reward``): what explaining one detection is worth against calling it a false
   detection (it also gates: a detection further than √κ σ_p from the prediction is never a candidate).
   The third term is the paper's distance to the prediction taken in 3-D as well: X, the point
   triangulated from two or more of the detections, against ŷ_n, with s_n the prediction's spread σ_p
   carried to metres at the track's depth in its nearest camera.  Pixel distances alone miss a
   discrepancy in depth: two cameras looking along the line between two neighbouring markers (the
   wrist pair) see one where the other was predicted, and a track whose marker is hidden there would
   take its neighbour's rays.
   Without κ every cost is ≥ 0 and the empty association would be best.  Candidates per track: the
   nearest gated detection of every camera; in the cameras where the choice is open (another gated
   detection, or one another track also gates) every combination of the nearest options and none (at
   most ``MAX_COMBINATIONS``); and the settled cameras left out one at a time.  Solved by Lagrangian
   relaxation (calibrate.track.assignment), the primal–dual gap kept per frame.
3. **Estimate** y_n(k): two or more cameras — weighted least-squares triangulation; one camera — the
   compromise between ŷ_n(k) and that camera's ray (the track's state; reported only with
   ``single_view_positions``, else a gap: a wrong ray drags it far); none — ŷ_n(k) (a gap).

The first frame has no prediction: the M-dimensional assignment between the cameras' detections alone
(candidates from pairs of rays that meet within ``epipolar_px`` and the detections of the other cameras
near their point).  Later, detections no track took start new tracks the same way when ``new_views``
cameras agree; a track unseen (by two or more cameras) for longer than ``max_lost`` seconds is dropped, and
of two tracks closer than ``merge_distance`` (one marker whose rays were split between them: the
per-detection reward does not prefer one track of six rays to two of three) the one fewer cameras see
(on a tie the younger) is dropped.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..io.cameras import Camera, Detections
from ..io.trial import Trial
from .assignment import solve_assignment
from .geometry import ray_compromise, ray_terms, solve_points

MAX_COMBINATIONS = 64  # candidate hyperedges per track from the cameras where its choice is open


STITCH_FRAMES = 3  # frames over which an ended track's last velocity is taken
STITCH_AHEAD = 0.2  # s: the longest stretch of a gap over which that velocity is carried


@dataclass(frozen=True)
class TrackSettings:
    """The tracker's constants (pixels unless said)."""

    pixel_sd: float = 0.3  # σ: detection noise
    prediction_sd: float = 2.0  # σ_p: spread of a predicted projection one frame ahead
    max_spread: float = 4.0  # σ_p grows with the frames a track goes unseen, (1 + frames), up to this factor
    reward: float = 25.0  # κ: worth of one detection explained (also the gate: d < √κ σ_p)
    epipolar_px: float = 1.5  # first frame / new tracks: RMS reprojection error of a pair of rays
    new_views: int = 3  # cameras that must agree to start a track (the paper: 2, in the first frame)
    max_lost: float = 0.3  # s: a track unseen for longer is dropped
    merge_distance: float = 0.008  # m: two tracks this close are one marker; the one fewer cameras see (or the
    #                                 younger) is dropped
    max_iterations: int = 20  # Lagrangian-relaxation iterations per frame
    single_view_positions: bool = False  # report the one-camera compromise (else a gap; it is still the state)
    method: str = "lagrangian"  # or "greedy": the baseline (nearest prediction per camera; pairs greedily)


@dataclass
class Tracks:
    """What the tracker found."""

    positions: np.ndarray  # (F, T, 3) m; NaN where no camera saw the track (or it was not alive)
    views: np.ndarray  # (F, T) cameras that saw each track
    detection_track: np.ndarray  # (n,) track of every detection row of the input (-1: none)
    primal: np.ndarray  # (F,) cost of the association kept
    dual: np.ndarray  # (F,) the Lagrangian lower bound
    iterations: np.ndarray  # (F,)
    seconds: np.ndarray  # (F,) time per frame
    rate: float
    started: list[int] = field(default_factory=list)  # frame each track started

    @property
    def gap(self) -> np.ndarray:
        """(F,) primal − dual per frame (0: the association is proved optimal)."""
        return np.maximum(self.primal - self.dual, 0.0)

    @property
    def n_tracks(self) -> int:
        return self.positions.shape[1]

    def figures(self) -> dict:
        """Tracks, share of detections assigned, mean/max gap, share of frames solved optimally, time."""
        seen = np.isfinite(self.positions[..., 0])
        return {"tracks": int(self.n_tracks), "frames": int(self.positions.shape[0]),
                "assigned_share": float(np.mean(self.detection_track >= 0)) if self.detection_track.size else 0.0,
                "mean_gap": float(self.gap.mean()), "max_gap": float(self.gap.max()),
                "optimal_frames": float(np.mean(self.gap <= 1e-6 * (1 + np.abs(self.primal)))),
                "mean_iterations": float(self.iterations.mean()),
                "seen_share": float(seen.mean()), "ms_per_frame": float(1e3 * self.seconds.mean())}

    def stitched(self, max_gap: float = 1.0, speed: float = 1.5) -> tuple[np.ndarray, list[list[int]]]:
        """Broken tracks joined: a track that starts after another ended (at most `max_gap` s later) and
        within reach of its last position (`speed` m/s over the gap, plus 2 cm) continues it, the nearest
        first — nearest to where the ended track was heading (its last velocity carried over at most
        ``STITCH_AHEAD`` s of the gap: two neighbouring markers lost together and found again are told
        apart by where each was going).  Returns positions (F, T', 3) and the tracks joined into each."""
        P = self.positions
        seen = np.isfinite(P[..., 0])
        has = np.flatnonzero(seen.any(0))
        first = {j: int(np.flatnonzero(seen[:, j])[0]) for j in has}
        last = {j: int(np.flatnonzero(seen[:, j])[-1]) for j in has}
        velocity = {}  # m per frame over the track's last frames, where they are consecutive
        for j in has:
            k = last[j] - STITCH_FRAMES
            velocity[j] = (P[last[j], j] - P[k, j]) / STITCH_FRAMES if k >= 0 and seen[k:last[j] + 1, j].all() \
                else np.zeros(3)
        ahead = int(round(STITCH_AHEAD * self.rate))
        chains: list[list[int]] = []
        end_of: dict[int, int] = {}  # chain index -> its last track
        for j in sorted(has, key=lambda j: first[j]):
            best, where = np.inf, None
            for c, tail in end_of.items():
                gap = first[j] - last[tail]
                if 0 < gap <= max_gap * self.rate:
                    heading = P[last[tail], tail] + velocity[tail] * min(gap, ahead)
                    d = float(np.linalg.norm(P[first[j], j] - heading))
                    if d <= speed * gap / self.rate + 0.02 and d < best:
                        best, where = d, c
            if where is None:
                chains.append([j])
                end_of[len(chains) - 1] = j
            else:
                chains[where].append(j)
                end_of[where] = j
        out = np.full((P.shape[0], len(chains), 3), np.nan)
        for c, chain in enumerate(chains):
            for j in chain:
                out[seen[:, j], c] = P[seen[:, j], j]
        return out, chains

    def trial(self, min_frames: int = 10, prefix: str = "T", stitch: bool = True) -> Trial:
        """The tracks (broken ones joined, `stitched`; brief jumps removed, `despiked`) seen in at least
        `min_frames` frames as an unlabelled trial (labels T1, T2, ...: the first track of each)."""
        if stitch:
            P, chains = self.stitched()
        else:
            P, chains = self.positions, [[j] for j in range(self.n_tracks)]
        P = despiked(P)
        keep = np.flatnonzero(np.isfinite(P[..., 0]).sum(0) >= min_frames)
        labels = [f"{prefix}{chains[i][0] + 1}" for i in keep]
        return Trial(labels=labels, markers=P[:, keep], rate=self.rate, first_frame=0, source=None)


def despiked(P: np.ndarray, window: int = 5, limit: float = 0.008) -> np.ndarray:
    """Trajectories (F, T, 3) with the samples further than `limit` (m) from the running median of
    `window` frames made gaps: a track that briefly took another marker's rays must not break the
    rigidity its segment's grouping relies on."""
    F = P.shape[0]
    h = window // 2
    pad = np.concatenate([np.full((h,) + P.shape[1:], np.nan), P, np.full((h,) + P.shape[1:], np.nan)])
    stack = np.stack([pad[i:i + F] for i in range(window)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(stack, axis=0)
    out = P.copy()
    out[np.linalg.norm(P - med, axis=2) > limit] = np.nan
    return out


class _Frame:
    """One frame's detections with their rays, camera by camera."""

    def __init__(self, cameras: Sequence[Camera], det: Detections, k: int, rays: RayTable):
        self.spans = [det.span(k, m) for m in range(len(cameras))]
        self.rows = np.arange(self.spans[0].start, self.spans[-1].stop)
        self.cam = det.camera[self.rows]
        self.local = self.rows - np.array([self.spans[m].start for m in self.cam], dtype=np.int64)
        self.uv = det.uv[self.rows]
        self.sizes = [s.stop - s.start for s in self.spans]
        self.offset = np.array([s.start - self.spans[0].start for s in self.spans], dtype=np.int64)
        sl = slice(self.spans[0].start, self.spans[-1].stop)
        self.centres = rays.centres[sl]
        self.dirs = rays.dirs[sl]
        self.P, self.Pc, self.s = rays.P[sl], rays.Pc[sl], rays.s[sl]


@dataclass(frozen=True)
class RayTable:
    """The ray of every detection of a recording (computed once, all frames of a camera at a time)."""

    centres: np.ndarray  # (n, 3)
    dirs: np.ndarray  # (n, 3) unit
    P: np.ndarray  # (n, 3, 3) I − d dᵀ
    Pc: np.ndarray  # (n, 3)
    s: np.ndarray  # (n,)

    @classmethod
    def of(cls, cameras: Sequence[Camera], det: Detections) -> RayTable:
        dirs = np.zeros((len(det.frame), 3))
        for m, cam in enumerate(cameras):
            rows = det.camera == m
            if rows.any():
                dirs[rows] = cam.rays(det.uv[rows])
        centres = np.array([c.centre for c in cameras])[det.camera] if len(det.frame) else np.zeros((0, 3))
        return cls(centres, dirs, *ray_terms(centres, dirs))


def _edge_points(fr: _Frame, edges: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For hyperedges (h, M) of local detection indices (-1 none) with weights (h, M): the triangulated
    points (h, 3), their weighted squared ray distances r (h,), and the number of detections (h,)."""
    used = edges >= 0
    rows = np.where(used, fr.offset[None, :] + np.maximum(edges, 0), 0)
    ww = np.where(used, w, 0.0)
    A = np.einsum("hm,hmij->hij", ww, fr.P[rows])
    b = np.einsum("hm,hmi->hi", ww, fr.Pc[rows])
    s = np.einsum("hm,hm->h", ww, fr.s[rows])
    n = used.sum(1)
    X = np.full((len(edges), 3), np.nan)
    r = np.zeros(len(edges))
    ok = n >= 2
    if ok.any():
        X[ok], r[ok] = solve_points(A[ok], b[ok], s[ok])
    return X, r, n


class Tracker:
    """Seed 002's tracker over calibrated cameras (module docstring)."""

    def __init__(self, cameras: Sequence[Camera], settings: TrackSettings | None = None):
        self.cameras = list(cameras)
        self.settings = settings or TrackSettings()
        self.focal = np.array([c.focal for c in self.cameras])
        self.R = np.array([c.R for c in self.cameras])
        self.t = np.array([c.t for c in self.cameras])

    # ----------------------------------------------------------------------------- helpers

    def _weights(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(f / depth)² of points (n, 3) in every camera (n, M), and the depths."""
        z = np.einsum("mij,nj->nmi", self.R, X)[..., 2] + self.t[None, :, 2]
        with np.errstate(divide="ignore"):
            return np.where(z > 0, (self.focal[None] / np.maximum(z, 1e-9)) ** 2, 0.0), z

    def _project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (M, n, 2) and depths (M, n) of points (n, 3)."""
        out = [c.project(X) for c in self.cameras]
        return np.array([o[0] for o in out]), np.array([o[1] for o in out])

    def _views(self, fr: _Frame, free: np.ndarray, min_views: int) -> tuple[np.ndarray, np.ndarray]:
        """The M-dimensional association of the detections `free` (bool per frame row) between cameras:
        (points (p, 3), their hyperedges (p, M) of local indices)."""
        st = self.settings
        M = len(self.cameras)
        cand = []
        for a in range(M):
            ia = np.flatnonzero(free & (fr.cam == a))
            if ia.size == 0:
                continue
            for b in range(a + 1, M):
                ib = np.flatnonzero(free & (fr.cam == b))
                if ib.size == 0:
                    continue
                I, J = np.meshgrid(ia, ib, indexing="ij")
                I, J = I.ravel(), J.ravel()
                A = fr.P[I] + fr.P[J]
                bb = fr.Pc[I] + fr.Pc[J]
                with np.errstate(all="ignore"):
                    X, _ = solve_points(A, bb, fr.s[I] + fr.s[J])
                w, z = self._weights(X)
                da = np.einsum("nij,nj->ni", fr.P[I], X) - fr.Pc[I]
                db = np.einsum("nij,nj->ni", fr.P[J], X) - fr.Pc[J]
                r = w[:, a] * np.einsum("ni,ni->n", da, da) + w[:, b] * np.einsum("ni,ni->n", db, db)
                ok = (z[:, a] > 0) & (z[:, b] > 0) & (r < 2 * st.epipolar_px ** 2)
                if ok.any():
                    e = np.full((int(ok.sum()), M), -1, dtype=np.int64)
                    e[:, a] = fr.local[I[ok]]
                    e[:, b] = fr.local[J[ok]]
                    cand.append((e, X[ok]))
        if not cand:
            return np.zeros((0, 3)), np.zeros((0, M), dtype=np.int64)
        edges = np.concatenate([c[0] for c in cand])
        X = np.concatenate([c[1] for c in cand])
        uvp, z = self._project(X)
        gate = 3 * st.epipolar_px
        for m in range(M):  # the detections of the other cameras near each pair's point
            im = np.flatnonzero(free & (fr.cam == m))
            if im.size == 0:
                continue
            d = np.linalg.norm(uvp[m][:, None, :] - fr.uv[im][None], axis=2)
            j = np.argmin(d, axis=1)
            near = (d[np.arange(len(X)), j] < gate) & (z[m] > 0) & (edges[:, m] < 0)
            edges[near, m] = fr.local[im[j[near]]]
        edges = np.unique(edges, axis=0)
        n = (edges >= 0).sum(1)
        # the pair's point again, now from all its rays, for the weights
        X0, _, _ = _edge_points(fr, edges, np.ones(edges.shape))
        w, _ = self._weights(X0)
        X, r, n = _edge_points(fr, edges, w)
        cost = r / st.pixel_sd ** 2 - st.reward * n
        keep = (n >= min_views) & np.isfinite(cost) & (r / np.maximum(n, 1) < 2 * st.epipolar_px ** 2)
        edges, cost, X = edges[keep], cost[keep], X[keep]
        if st.method == "greedy":
            chosen = _greedy(edges, cost)
        else:
            chosen = solve_assignment(edges, cost, fr.sizes, st.max_iterations).chosen
        return X[chosen], edges[chosen]

    # ----------------------------------------------------------------------------- the loop

    def run(self, det: Detections, progress: Callable[[int, int], None] | None = None) -> Tracks:
        """Track every marker through the detections (module docstring); `progress(frames done, frames)` every
        200 frames."""
        st = self.settings
        M = len(self.cameras)
        if det.n_cameras != M:
            raise ValueError(f"detections of {det.n_cameras} cameras for {M} calibrated cameras")
        F = det.n_frames
        max_lost = max(1, int(round(st.max_lost * det.rate)))
        pos: list[np.ndarray] = []  # per track: (F, 3) estimates (NaN unseen)
        views: list[np.ndarray] = []
        started: list[int] = []
        y = np.zeros((0, 3))  # current estimate of every track (predictions when unseen)
        v = np.zeros((0, 3))  # velocity per frame
        lost = np.zeros(0, dtype=np.int64)
        alive = np.zeros(0, dtype=bool)
        det_track = np.full(len(det.frame), -1, dtype=np.int64)
        t_rays = time.perf_counter()
        rays = RayTable.of(self.cameras, det)
        t_rays = time.perf_counter() - t_rays  # shared out over the frames' times below
        primal, dual = np.zeros(F), np.zeros(F)
        iters, secs = np.zeros(F, dtype=np.int64), np.zeros(F)
        for k in range(F):
            t0 = time.perf_counter()
            fr = _Frame(self.cameras, det, k, rays)
            free = np.ones(len(fr.rows), dtype=bool)
            live = np.flatnonzero(alive)
            if live.size:
                pred = y[live] + v[live]
                sd = st.prediction_sd * np.minimum(1.0 + lost[live], st.max_spread)
                res = self._associate(fr, pred, sd)
                chosen_edges, primal[k], dual[k], iters[k], gated = res
                for m in range(M):  # detections near a live track never start another one
                    if fr.sizes[m]:
                        free[fr.offset[m]:fr.offset[m] + fr.sizes[m]] &= ~gated[m]
                newpos = pred.copy()
                nview = np.zeros(live.size, dtype=np.int64)
                if len(chosen_edges):
                    tr = chosen_edges[:, 0]
                    e = chosen_edges[:, 1:]
                    w, _ = self._weights(pred[tr])
                    X, _, n = _edge_points(fr, e, w)
                    nview[tr] = n
                    multi = n >= 2
                    newpos[tr[multi]] = X[multi]
                    for i in np.flatnonzero(n == 1):
                        m = int(np.flatnonzero(e[i] >= 0)[0])
                        row = fr.offset[m] + e[i, m]
                        wr = w[i, m] / st.pixel_sd ** 2
                        wp = (self.focal[m] ** 2 / max(1e-9, _depth(self.cameras[m], pred[tr[i]])) ** 2
                              / (sd[tr[i]] ** 2))
                        newpos[tr[i]] = ray_compromise(pred[tr[i]], fr.centres[row], fr.dirs[row], wp, wr)
                    for i in range(len(e)):
                        rows = fr.offset[np.flatnonzero(e[i] >= 0)] + e[i][e[i] >= 0]
                        det_track[fr.rows[rows]] = live[tr[i]]
                seen = nview > 0
                v[live[seen]] = np.where(lost[live[seen], None] == 0, newpos[seen] - y[live[seen]], v[live[seen]])
                y[live] = newpos
                lost[live] = np.where(nview >= 2, 0, lost[live] + 1)  # one ray alone does not keep a track
                for j, n_ in zip(live, nview, strict=True):
                    if n_ >= (1 if st.single_view_positions else 2):
                        pos[j][k] = y[j]
                    views[j][k] = n_
                alive[live[lost[live] > max_lost]] = False
                # two tracks on one marker (each with some of its rays): the younger is merged into the older
                on = live[(nview >= 2) & alive[live]]  # triangulated both: the same point in space
                if on.size > 1:
                    d = np.linalg.norm(y[on][:, None] - y[on][None], axis=2)
                    close = np.argwhere(np.triu(d < st.merge_distance, 1))
                    vis = dict(zip(live, nview, strict=True))
                    for i, j in close:
                        old, young = on[i], on[j]
                        if vis[young] > vis[old]:  # the one more cameras see stays
                            old, young = young, old
                        if alive[old] and alive[young]:
                            alive[young] = False
                            det_track[fr.rows[det_track[fr.rows] == young]] = old
                            pos[young][k] = np.nan
                            views[young][k] = 0
            if free.any():
                X, edges = self._views(fr, free, st.new_views)
                for X_, e in zip(X, edges, strict=True):
                    j = len(pos)
                    pos.append(np.full((F, 3), np.nan))
                    views.append(np.zeros(F, dtype=np.int64))
                    pos[j][k] = X_
                    views[j][k] = int((e >= 0).sum())
                    rows = fr.offset[np.flatnonzero(e >= 0)] + e[e >= 0]
                    det_track[fr.rows[rows]] = j
                    started.append(k)
                if len(X):
                    y = np.vstack([y, X])
                    v = np.vstack([v, np.zeros((len(X), 3))])
                    lost = np.concatenate([lost, np.zeros(len(X), dtype=np.int64)])
                    alive = np.concatenate([alive, np.ones(len(X), dtype=bool)])
            secs[k] = time.perf_counter() - t0 + t_rays / max(F, 1)
            if progress is not None and (k + 1) % 200 == 0:
                progress(k + 1, F)
        positions = np.stack(pos, axis=1) if pos else np.zeros((F, 0, 3))
        vw = np.stack(views, axis=1) if views else np.zeros((F, 0), dtype=np.int64)
        return Tracks(positions, vw, det_track, primal, dual, iters, secs, det.rate, started)

    def _associate(self, fr: _Frame, pred: np.ndarray, sd: np.ndarray):
        """The (M+1)-dimensional assignment of tracks (predictions `pred`, spreads `sd` px) to the frame's
        detections: (chosen hyperedges (h, 1+M): track, then a local detection per camera), primal, dual,
        iterations, and per camera a mask of the detections some track gates."""
        st = self.settings
        M = len(self.cameras)
        T = len(pred)
        uvp, z = self._project(pred)
        near = np.full((T, M, 3), -1, dtype=np.int64)  # per track and camera: the 3 nearest gated detections
        count = np.zeros((T, M), dtype=np.int64)  # how many detections each track gates in each camera
        contested = np.zeros((T, M), dtype=bool)  # its nearest is gated by another track too
        dist: list[np.ndarray] = []
        gated_mask: list[np.ndarray] = []
        for m in range(M):
            q = fr.sizes[m]
            if q == 0:
                dist.append(np.zeros((T, 0)))
                gated_mask.append(np.zeros(0, dtype=bool))
                continue
            uv = fr.uv[fr.offset[m]:fr.offset[m] + q]
            d2 = np.sum((uvp[m][:, None, :] - uv[None]) ** 2, axis=2) / sd[:, None] ** 2
            d2[z[m] <= 0] = np.inf
            dist.append(d2)
            inside = d2 < st.reward
            count[:, m] = inside.sum(1)
            taken = inside.sum(0)
            gated_mask.append(taken > 0)
            k = min(3, q)
            order = np.argsort(d2, axis=1)[:, :k]
            ok = np.take_along_axis(inside, order, axis=1)
            near[:, m, :k] = np.where(ok, order, -1)
            contested[:, m] = (near[:, m, 0] >= 0) & (taken[np.maximum(near[:, m, 0], 0)] > 1)
        if st.method == "greedy":
            return (*_greedy_tracks(near, dist, T, M), gated_mask)
        base = near[:, :, 0]
        open_ = (count > 1) | contested  # cameras where the choice is open
        simple = ~open_.any(1)
        edges = []
        # tracks with nothing open: their nearest detections, and each of them left out in turn
        n_s = np.flatnonzero(simple)
        if n_s.size:
            edges.append(np.column_stack([n_s, base[n_s]]))
            tt, mm = np.nonzero(base[n_s] >= 0)
            drop = base[n_s[tt]].copy()
            drop[np.arange(tt.size), mm] = -1
            edges.append(np.column_stack([n_s[tt], drop]))
        for n in np.flatnonzero(~simple):
            opened = list(np.flatnonzero(open_[n]))
            width = 3 if 3 ** len(opened) <= MAX_COMBINATIONS else 2
            if width ** len(opened) > MAX_COMBINATIONS:
                opened = opened[:int(np.log(MAX_COMBINATIONS) / np.log(2))]
            combos = base[n][None].copy()
            for m in opened:  # every combination of the open cameras' options (nearest ones, or none)
                opts = np.concatenate([near[n, m, :width - 1][near[n, m, :width - 1] >= 0], [-1]])
                combos = np.repeat(combos, len(opts), axis=0)
                combos[:, m] = np.tile(opts, len(combos) // len(opts))
            rows = [combos]
            for m in np.flatnonzero(base[n] >= 0):  # each settled camera left out in turn
                if m not in opened:
                    e = combos.copy()
                    e[:, m] = -1
                    rows.append(e)
            E = np.concatenate(rows)
            edges.append(np.column_stack([np.full(len(E), n), E]))
        if not edges:
            return np.zeros((0, M + 1), dtype=np.int64), 0.0, 0.0, 0, gated_mask
        edges = np.concatenate(edges)  # a repeated hyperedge does no harm
        edges = edges[(edges[:, 1:] >= 0).any(1)]
        if len(edges) == 0:
            return np.zeros((0, M + 1), dtype=np.int64), 0.0, 0.0, 0, gated_mask
        tr, e = edges[:, 0], edges[:, 1:]
        w, _ = self._weights(pred)
        X, r, n = _edge_points(fr, e, w[tr])
        d = np.zeros(len(edges))
        # the triangulated point against the prediction in 3-D, at the prediction's spread in metres: a
        # camera pair looking along the line between two markers sees one where the other was predicted
        sd3 = sd[tr] * np.sqrt(1.0 / np.maximum(w[tr].max(1), 1e-12))
        multi = n >= 2
        d[multi] += np.sum((X[multi] - pred[tr[multi]]) ** 2, axis=1) / sd3[multi] ** 2
        for m in range(M):
            has = e[:, m] >= 0
            d[has] += dist[m][tr[has], e[has, m]]
        # c = r/σ² + g Σ d²/σ² − κ n with g = σ²/σ_p²: the d term is Σ d²/σ_p² (`dist` is already scaled)
        cost = r / st.pixel_sd ** 2 + d - st.reward * n
        a = solve_assignment(edges, cost, [T, *fr.sizes], st.max_iterations)
        return edges[a.chosen], a.primal, a.dual, a.iterations, gated_mask


def _depth(cam: Camera, X: np.ndarray) -> float:
    return float(cam.to_camera(X)[2])


def _greedy(edges: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Hyperedges taken in order of cost while they conflict with none taken (the baseline)."""
    used: set = set()
    out = []
    for h in np.argsort(cost):
        if cost[h] >= 0:
            break
        keys = {(d, int(i)) for d, i in enumerate(edges[h]) if i >= 0}
        if not keys & used:
            used |= keys
            out.append(h)
    return np.array(out, dtype=np.int64)


def _greedy_tracks(near: np.ndarray, dist, T: int, M: int):
    """The baseline association: in every camera, (track, detection) pairs within the gate taken greedily by
    distance to the prediction."""
    E = np.full((T, M), -1, dtype=np.int64)
    for m in range(M):
        pairs = [(dist[m][n, j], n, int(j)) for n in range(T) for j in near[n, m] if j >= 0]
        taken: set = set()
        for _, n, j in sorted(pairs):
            if E[n, m] < 0 and j not in taken:
                E[n, m] = j
                taken.add(j)
    keep = (E >= 0).any(1)
    edges = np.column_stack([np.arange(T), E])[keep]
    return edges, 0.0, 0.0, 0
