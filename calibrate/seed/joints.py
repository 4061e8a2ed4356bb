"""Joint-centre trajectories from marker trajectories alone: the MTB framework (seed 000)
with closed-form centres and axes of rotation (seed 002, Gamage & Lasenby 2002).

A joint connects two segments.  If one of them (the *anchor*) carries three or more
non-collinear points — its markers, plus joint centres already solved on it — the joint
is fixed in the anchor's frame, so its trajectory is a linear combination of the
anchor's point trajectories (marker-trajectory bases, MTB): only three numbers λ are
unknown, whatever the number of frames.  λ starts from the closed-form centre of
rotation of the other segment's points seen from the anchor (Gamage & Lasenby) and is
refined by Newton's method on the joint–marker-variance (JMV) cost of seed 000 Eq. 8,
with an analytic gradient and Hessian evaluated over all frames at once.

A hinge has no unique centre: every point of its axis keeps a constant distance to both
segments.  For a hinge (declared, or detected because the other segment's points move
in planes only) the axis is the direction in which those points do not move, and the
centre is the point of the axis nearest a prior: the base model's joint centre carried
into the anchor's frame, else the middle of the two segments' points.

A solved joint becomes a point of both its segments (solvability propagation), which
can give a segment with one or two markers a frame.  The loop runs until nothing
changes; if joints remain, the one with most points around it is solved by per-frame
JMV optimisation (joint position free in every frame; the hybrid scheme of seed 000
Section III-C) and propagation resumes.  A segment with no markers at all (the talus)
is seen through: its joints are estimated against the segments beyond it, and flagged.

Entry points: :func:`estimate_joints` (trajectories + groups + topology) and
:func:`estimate_model_joints` (a model and a trial).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from calibrate.seed.mtb import (
    MIN_FRAMES,
    affine_basis,
    affine_triangle,
    jmv_multistart,
    jmv_rms,
    mtb_refine,
    reference_shape,
    rigid_basis,
    solve_direction,
    solve_lambda,
)

from ..io.text import atomic_write_text
from ..io.trial import Trial
from ..model.model import Model
from .geometry import RigidFrames, rigid_fit, similarity_fit, sphere_fit, triad_frames

HINGE_RATIO = 0.01  # smallest/middle eigenvalue of the rotation fit below this: the joint moved as a hinge


MIN_MOTION = 0.005  # m: RMS relative motion below this means the joint did not move enough to locate it


MIN_WIDTH = 0.005  # m: a segment's points must lie this far (RMS) from their best-fit line to give it a frame


KINDS = ("ball", "hinge", "universal")


@dataclass(frozen=True)
class JointSpec:
    """One joint of the topology: the segments (marker groups) it connects."""

    name: str
    parent: str
    child: str
    kind: str | None = None  # 'ball', 'hinge', 'universal' (treated as ball) or None: decide from the data


@dataclass(frozen=True)
class JointEstimate:
    """The estimated trajectory of one joint centre, and how it was found."""

    name: str
    parent: str
    child: str
    kind: str  # 'ball' or 'hinge' as estimated (a declared ball that moved about one axis becomes 'hinge')
    method: str  # 'MTB', 'MTB (propagated)', 'JMV' or 'failed'
    centre: np.ndarray  # (F, 3) m, world; NaN where not estimated
    axis: np.ndarray | None  # (F, 3) unit hinge axis in the world per frame; None unless kind == 'hinge'
    anchor: str | None  # segment whose frame holds the centre fixed (None for JMV)
    rms: float  # m: RMS over frames and points of (joint–point distance − its mean): the JMV residual
    frames: int  # frames with an estimate
    ok: bool
    reason: str = ""  # why not ok
    note: str = ""  # caveats of an ok estimate (e.g. seen through a markerless segment)
    axis_local: np.ndarray | None = field(default=None, repr=False)  # hinge axis in the anchor frame
    centre_local: np.ndarray | None = field(default=None, repr=False)  # centre in the anchor frame

    @property
    def mtb(self) -> bool:
        """Estimated by the MTB framework (directly or propagated), not by JMV alone."""
        return self.method in ("MTB", "MTB (propagated)")


@dataclass(frozen=True)
class JointEstimates:
    """All joints of a trial, in the order of the topology, plus the solve order and time."""

    joints: tuple[JointEstimate, ...]
    order: tuple[str, ...]  # names in the order they were solved
    seconds: float
    times: np.ndarray | None = None  # (F,) s, if known

    def __getitem__(self, name: str) -> JointEstimate:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(f"no joint named '{name}'; joints are: {', '.join(self.names)}")

    def __iter__(self):
        return iter(self.joints)

    def __len__(self) -> int:
        return len(self.joints)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def centres(self) -> np.ndarray:
        """(F, n_joints, 3) every joint's trajectory (NaN where not estimated)."""
        return np.stack([j.centre for j in self.joints], axis=1)

    def table(self) -> str:
        """A plain-text table: joint, segments, kind, method, frames, JMV residual, axis."""
        rows = [("joint", "parent -> child", "kind", "method", "frames", "resid mm", "axis (anchor frame)", "note")]
        for j in self.joints:
            if j.axis_local is not None:
                ax = "[" + " ".join(f"{v:+.3f}" for v in j.axis_local) + "]"
            else:
                ax = "-"
            rows.append((j.name, f"{j.parent} -> {j.child}", j.kind, j.method, str(j.frames),
                         f"{1000 * j.rms:.2f}" if math.isfinite(j.rms) else "-", ax,
                         j.reason if not j.ok else j.note))
        widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r[:-1], widths, strict=True)) + ("  " + r[-1] if r[-1] else "")
                 for r in rows]
        lines.insert(1, "-" * len(lines[0]))
        return "\n".join(line.rstrip() for line in lines)


# --------------------------------------------------------------------------- framework
@dataclass
class _Point:
    name: str
    traj: np.ndarray  # (F, 3)
    is_joint: bool


class _Framework:
    """The system state of seed 000 Section III: points per segment, solved joints, the loop."""

    def __init__(self, points: Mapping[str, np.ndarray], groups: Mapping[str, Sequence[str]],
                 specs: Sequence[JointSpec], alpha: float, geometry: Mapping[str, Mapping[str, np.ndarray]] | None,
                 basis: str):
        self.alpha = alpha
        self.basis = basis
        self.geometry = geometry or {}
        self.specs = list(specs)
        self.F = _n_frames(points)
        self.seg: dict[str, list[_Point]] = {s: [] for s in groups}
        for spec in self.specs:
            for s in (spec.parent, spec.child):
                self.seg.setdefault(s, [])
        for s, labels in groups.items():
            for lab in labels:
                self.seg[s].append(_Point(lab, np.asarray(points[lab], dtype=float), False))
        self.joints_of: dict[str, list[JointSpec]] = {s: [] for s in self.seg}
        for spec in self.specs:
            self.joints_of[spec.parent].append(spec)
            self.joints_of[spec.child].append(spec)
        self.solved: dict[str, JointEstimate] = {}
        self.order: list[str] = []
        self.n_markers = {s: sum(not p.is_joint for p in pts) for s, pts in self.seg.items()}

    # --- state helpers
    def other(self, spec: JointSpec, s: str) -> str:
        return spec.child if s == spec.parent else spec.parent

    def has_frame(self, s: str, without: str = "") -> bool:
        """Whether the segment's points (less `without`) span a frame: 3 or more, not (nearly) collinear."""
        pts = [p for p in self.seg[s] if p.name != without]
        return len(pts) >= 3 and _frame_width(reference_shape(np.stack([p.traj for p in pts], axis=1))) > MIN_WIDTH

    def other_points(self, spec: JointSpec, anchor: str) -> tuple[list[_Point], str]:
        """Points that move with the far side of the joint; looks through a markerless segment."""
        o = self.other(spec, anchor)
        pts = [p for p in self.seg[o] if p.name != spec.name]
        note = ""
        if self.n_markers[o] == 0:
            beyond = [j for j in self.joints_of[o] if j.name != spec.name]
            names = {p.name for p in pts}
            for j in beyond:
                far = self.other(j, o)
                pts += [p for p in self.seg[far] if p.name not in names and p.name != spec.name]
            if beyond:
                note = f"{o} carries no markers: estimated against " + ", ".join(self.other(j, o) for j in beyond)
        return pts, note

    def add_solution(self, est: JointEstimate, spec: JointSpec) -> None:
        self.solved[spec.name] = est
        if spec.name not in self.order:  # a joint solved again (polish) keeps its place
            self.order.append(spec.name)
        for s in (spec.parent, spec.child):
            self.seg[s] = [p for p in self.seg[s] if p.name != spec.name]
            if est.ok:
                self.seg[s].append(_Point(spec.name, est.centre, True))

    def polish(self) -> None:
        """Joints found by per-frame JMV are solved again by MTB once one of their segments has a frame
        without them (propagation from the other side gave it one): a hinge then gets its axis."""
        for spec in self.specs:
            est = self.solved.get(spec.name)
            if est is None or est.method != "JMV":
                continue
            sides = [s for s in (spec.parent, spec.child) if self.has_frame(s, without=spec.name)]
            if not sides:
                continue
            anchor = max(sides, key=lambda s: len(self.seg[s]))
            new = self.solve_mtb(spec, anchor)
            if new is not None and new.ok:
                note = "; ".join(filter(None, [new.note, "started from per-frame JMV (hybrid scheme)"]))
                self.add_solution(replace(new, note=note), spec)

    # --- solvers
    def solve_mtb(self, spec: JointSpec, anchor: str) -> JointEstimate | None:
        apts = [p for p in self.seg[anchor] if p.name != spec.name]
        opts, note = self.other_points(spec, anchor)
        if not opts:
            return None
        A = np.stack([p.traj for p in apts], axis=1)
        O = np.stack([p.traj for p in opts], axis=1)
        paper = self.basis == "affine" and len(apts) <= 4
        frames = triad_frames(A, affine_triangle(A)) if paper else rigid_fit(A)
        Q = frames.to_local(O)
        Q[~frames.valid] = np.nan
        usable = frames.valid & np.any(np.all(np.isfinite(O), axis=2), axis=1)
        if usable.sum() < MIN_FRAMES:
            return self._fail(spec, f"only {int(usable.sum())} frames see {anchor}'s frame and a point of "
                              f"{self.other(spec, anchor)}; need {MIN_FRAMES}")
        try:
            fit = sphere_fit(Q)
        except ValueError:
            return self._fail(spec, f"no point of {self.other(spec, anchor)} seen in enough frames")
        motion = math.sqrt(fit.eigenvalues[-1] / max(fit.n_samples, 1))
        if motion < MIN_MOTION:
            return self._fail(spec, f"{self.other(spec, anchor)} barely moves relative to {anchor} "
                              f"({1000 * motion:.1f} mm RMS); record a trial that moves this joint")
        declared = spec.kind if not note else None  # seen through a markerless segment: two joints in one
        hinge = declared == "hinge" or fit.hinge_ratio < HINGE_RATIO
        if hinge and declared != "hinge":
            note = "; ".join(filter(None, [note, f"moved about one axis only (eigenvalue ratio {fit.hinge_ratio:.1e}): "
                                                 "centre placed on that axis"]))
        near = self.prior_local(spec, anchor, apts, frames)
        if near is None:
            near = np.nanmean(np.concatenate([frames.local, Q.reshape(-1, 3)]), axis=0)
        if hinge:
            fit = sphere_fit(Q, hinge=True, near=near)
        # MTB refinement (Eq. 8) in the paper's basis of at most four points, else the rigid frame
        basis = affine_basis(A) if paper else rigid_basis(frames)
        c_world = frames.to_world(fit.centre)
        lam0 = solve_lambda(basis, c_world)
        allpts = np.concatenate([A, O], axis=1)
        fixed = None
        if hinge:
            fixed = solve_direction(basis, frames, fit.axis)
        lam, _, _ = mtb_refine(basis, allpts, lam0, self.alpha, fixed=fixed)
        centre = basis.point(lam)
        centre[~usable] = np.nan
        axis_world = None
        if hinge:
            axis_world = frames.R @ fit.axis
            axis_world[~usable] = np.nan
        propagated = any(p.is_joint for p in apts)

        c_local = np.nanmean(frames.to_local(centre[:, None, :])[:, 0], axis=0)
        return JointEstimate(
            spec.name, spec.parent, spec.child, "hinge" if hinge else "ball",
            "MTB (propagated)" if propagated else "MTB", centre, axis_world, anchor,
            jmv_rms(centre, allpts), int(np.isfinite(centre[:, 0]).sum()), True, "", note,
            axis_local=fit.axis if hinge else None, centre_local=c_local)

    def prior_local(self, spec: JointSpec, anchor: str, apts: list[_Point], frames: RigidFrames) -> np.ndarray | None:
        """The base model's joint centre in the anchor's rigid frame (similarity fit on the points both know)."""
        geo = self.geometry.get(anchor)
        if not geo or spec.name not in geo:
            return None
        idx = [i for i, p in enumerate(apts) if p.name in geo]
        if len(idx) < 3:
            return None
        src = np.array([geo[apts[i].name] for i in idx])
        dst = frames.local[idx]
        if _frame_width(src) <= MIN_WIDTH:
            return None
        s, R, t = similarity_fit(src, dst)
        if not 0.7 <= s <= 1.4:  # an implausible size change means the fit is ill-conditioned: the prior is unknown
            return None
        return s * R @ np.asarray(geo[spec.name]) + t

    def solve_jmv(self, spec: JointSpec, markers_only: bool = False) -> JointEstimate:
        a, b = spec.parent, spec.child
        pts = [p for s in (a, b) for p in self.seg[s] if p.name != spec.name and not (markers_only and p.is_joint)]
        note = ""
        side = {s: [p for p in self.seg[s] if p.name != spec.name] for s in (a, b)}
        for s in (a, b):
            if self.n_markers[s] == 0 and not markers_only:
                extra, note = self.other_points(spec, self.other(spec, s))
                names = {p.name for p in pts}
                pts += [p for p in extra if p.name not in names]
                side[s] = extra
        if bare := [s for s in (a, b) if not any(not p.is_joint and np.isfinite(p.traj).any() for p in side[s])]:
            # Nothing the trial shows moves with that side (a lower-body trial's torso, and the arms beyond it, or its
            # labels kept with no position): its points are the other side's and joint estimates made from them, which
            # turn with it.  Per-frame JMV on them took 2.2 s of kineticstoolkit's lower-body walk (lumbar, neck,
            # shoulders) for seeds then refused.
            return self._fail(spec, f"no marker the trial shows moves with {bare[0]} (nor beyond it)")
        if len(pts) < 4:
            return self._fail(spec, f"JMV needs 4 or more points around the joint; {a} and {b} have {len(pts)}")
        X = np.stack([p.traj for p in pts], axis=1)
        # jmv_frames places the joint only in frames that show 3 or more of the points: with too few such frames the
        # multistart's grid search is not run for a seed refused anyway (BTKData's FunctionalWalk, no marker on the
        # torso or head: the neck's search, 0.4 s, then "only 0 frames")
        n = int((np.isfinite(X).all(axis=2).sum(axis=1) >= 3).sum())
        if n < MIN_FRAMES:
            return self._fail(spec, f"only {n} frames see 3 or more points around the joint; need {MIN_FRAMES}")
        ga = [p.traj for p in self.seg[a] if p.name != spec.name]
        gb = [p.traj for p in self.seg[b] if p.name != spec.name]
        # a hinge's JMV optimum is a whole line, so the global search for the one true point is skipped
        centre = jmv_multistart(X, ga, gb, self.F, search=spec.kind != "hinge")
        n = int(np.isfinite(centre[:, 0]).sum())
        if n < MIN_FRAMES:
            return self._fail(spec, f"only {n} frames see 3 or more points around the joint; need {MIN_FRAMES}")
        if spec.kind == "hinge":
            note = "; ".join(filter(None, [note, "a hinge solved by per-frame JMV: where the centre lies along the "
                                                  "axis is not determined by the data"]))
        return JointEstimate(spec.name, a, b, spec.kind or "ball", "JMV", centre, None, None, jmv_rms(centre, X),
                             n, True, "", note)

    def _fail(self, spec: JointSpec, reason: str) -> JointEstimate:
        return JointEstimate(spec.name, spec.parent, spec.child, spec.kind or "ball", "failed",
                             np.full((self.F, 3), np.nan), None, None, math.nan, 0, False, reason)

    # --- the loop
    def run(self, mode: str) -> None:
        if mode == "jmv":
            for spec in self.specs:
                self.add_solution(self.solve_jmv(spec, markers_only=True), spec)
            return
        while True:
            self.propagate()
            pending = [s for s in self.specs if s.name not in self.solved]
            if not pending:
                self.polish()
                return
            # hybrid scheme: JMV for the pending joint with most points around it, then propagate again
            def n_points(spec: JointSpec) -> int:
                return len(self.seg[spec.parent]) + len(self.seg[spec.child])

            spec = max(pending, key=n_points)
            self.add_solution(self.solve_jmv(spec), spec)  # solved or failed with a reason: one fewer pending

    def propagate(self) -> None:
        """Joint solvability and its propagation, until the system state stops changing."""
        changed = True
        while changed:
            changed = False
            segments = sorted(self.seg, key=lambda s: (-len(self.seg[s]), s))
            for s in segments:
                pending = [j for j in self.joints_of[s] if j.name not in self.solved]
                if not pending or not self.has_frame(s):
                    continue
                for spec in pending:
                    other = self.other(spec, s)
                    if self.has_frame(other) and len(self.seg[other]) > len(self.seg[s]):
                        continue  # the better-marked side anchors it
                    est = self.solve_mtb(spec, s)
                    if est is not None:
                        self.add_solution(est, spec)
                        changed = True
                if changed:
                    break


def _frame_width(ref: np.ndarray) -> float:
    """RMS distance (m) of points (P, 3) from their best-fit line; 0 if fewer than 3 are seen."""
    pts = ref[np.all(np.isfinite(ref), axis=1)]
    if len(pts) < 3:
        return 0.0
    sv = np.linalg.svd(pts - pts.mean(0), compute_uv=False)
    return float(np.sqrt(np.sum(sv[1:] ** 2) / len(pts)))


def _n_frames(points: Mapping[str, np.ndarray]) -> int:
    sizes = {np.asarray(v).shape[0] for v in points.values()}
    if len(sizes) != 1:
        raise ValueError(f"points: every trajectory needs the same number of frames, got {sorted(sizes)}")
    return sizes.pop()


def _check(points: Mapping[str, np.ndarray], groups: Mapping[str, Sequence[str]], specs: Sequence[JointSpec],
           mode: str, alpha: float) -> None:
    if mode not in ("framework", "jmv"):
        raise ValueError(f"mode: expected 'framework' or 'jmv', got {mode!r}")
    if not (alpha >= 0 and math.isfinite(alpha)):
        raise ValueError(f"alpha: must be a finite number >= 0, got {alpha}")
    for name, traj in points.items():
        if np.ndim(traj) != 2 or np.shape(traj)[1] != 3:
            raise ValueError(f"points['{name}']: expected an (F, 3) trajectory, got shape {np.shape(traj)}")
    owner: dict[str, str] = {}
    for s, labels in groups.items():
        for lab in labels:
            if lab not in points:
                raise ValueError(f"groups['{s}']: marker '{lab}' has no trajectory in points")
            if lab in owner:
                raise ValueError(f"marker '{lab}' is in two groups ('{owner[lab]}' and '{s}'); a marker rides on "
                                 "one segment")
            owner[lab] = s
    seen: set[str] = set()
    for spec in specs:
        if spec.name in seen:
            raise ValueError(f"joints: the name '{spec.name}' is used twice")
        seen.add(spec.name)
        if spec.kind is not None and spec.kind not in KINDS:
            raise ValueError(f"joint '{spec.name}': kind must be one of {KINDS} or None, got {spec.kind!r}")
        if spec.parent == spec.child:
            raise ValueError(f"joint '{spec.name}': parent and child are the same segment '{spec.parent}'")


def estimate_joints(points: Mapping[str, np.ndarray], groups: Mapping[str, Sequence[str]],
                    joints: Sequence[JointSpec], *, mode: str = "framework", alpha: float = 0.0,
                    basis: str = "rigid", geometry: Mapping[str, Mapping[str, np.ndarray]] | None = None,
                    rate: float | None = None, cutoff_hz: float | None = None,
                    times: np.ndarray | None = None) -> JointEstimates:
    """Estimate every joint-centre trajectory of a topology from marker trajectories.

    points: marker label -> (F, 3) trajectory (m; NaN in gaps).
    groups: segment -> the labels of the markers riding on it (a segment may have none).
    joints: the topology, one JointSpec per joint (parent and child are segment names).
    mode: 'framework' (MTB, propagation, hybrid JMV; seed 000) or 'jmv' (every joint by
      per-frame JMV from its two segments' markers only: the baseline the paper compares with).
    alpha: weight of the mean joint–marker distance in Eq. 8 (0: pure variance, unbiased).
    basis: 'rigid' (default) writes a point fixed on the anchor as t_f + R_f λ with the anchor's
      least-squares rigid frame (all its points); 'affine' uses seed 000's basis of four points
      (or three plus Eq. 9's auxiliary point), r4 + Σ λ_i (r_i − r4).  Both are exact without
      noise; with marker noise the rigid frame is measurably more accurate (docs/benchmarks.md).
    rate, cutoff_hz: if both are given, markers are low-passed first (zero-lag 4th-order
      Butterworth, each gap-free run separately), as is usual for marker data.
    geometry: optional base-model positions, segment -> {marker label or joint name -> (3,)
      position in that segment's frame}; it places a hinge's centre on its axis (nearest the
      model's centre).  Without it the hinge centre is the point of the axis nearest the middle
      of the two segments' points.
    """
    _check(points, groups, joints, mode, alpha)
    if basis not in ("rigid", "affine"):
        raise ValueError(f"basis: expected 'rigid' or 'affine', got {basis!r}")
    t0 = time.perf_counter()
    if cutoff_hz is not None:
        if rate is None or not (0 < cutoff_hz < rate / 2):
            raise ValueError(f"cutoff_hz: needs the sampling rate and 0 < cutoff_hz < rate/2; got {cutoff_hz} at "
                             f"rate {rate}")
        points = lowpass_each(points, rate, cutoff_hz)
    fw = _Framework(points, groups, joints, alpha, geometry, basis)
    fw.run(mode)
    out = tuple(fw.solved[s.name] for s in joints)
    return JointEstimates(out, tuple(fw.order), time.perf_counter() - t0, times)


def lowpass(traj: np.ndarray, rate: float, cutoff_hz: float, order: int = 4) -> np.ndarray:
    """Zero-lag Butterworth low-pass of a trajectory (F, ...) along frames; each gap-free run is
    filtered on its own, runs too short to filter are kept as they are, gaps stay NaN."""
    b, a = butter_lowpass(order, cutoff_hz / (rate / 2))
    pad = 3 * max(len(a), len(b))
    out = np.array(traj, dtype=float)
    flat = out.reshape(len(out), -1)
    ok = np.all(np.isfinite(flat), axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if stop - start > pad:
            flat[start:stop] = filtfilt(b, a, flat[start:stop])
    return out


def lowpass_each(points: Mapping[str, np.ndarray], rate: float, cutoff_hz: float,
                 order: int = 4) -> dict[str, np.ndarray]:
    """lowpass of every marker's trajectory (F, ...) on its own gap-free runs, the same numbers as one
    call per marker, but the markers whose runs coincide (most markers of a trial without gaps) filtered
    together: the filter's loop over frames is then run once for them all, not once per marker."""
    b, a = butter_lowpass(order, cutoff_hz / (rate / 2))
    pad = 3 * max(len(a), len(b))
    out = {k: np.array(v, dtype=float) for k, v in points.items()}
    runs: dict[tuple[int, int], list[tuple[str, np.ndarray]]] = {}
    for k, v in out.items():
        flat = v.reshape(len(v), -1)
        ok = np.all(np.isfinite(flat), axis=1)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            if stop - start > pad:
                runs.setdefault((int(start), int(stop)), []).append((k, flat))
    for (start, stop), members in runs.items():
        filtered = filtfilt(b, a, np.concatenate([flat[start:stop] for _, flat in members], axis=1))
        at = 0
        for _, flat in members:
            flat[start:stop] = filtered[:, at:at + flat.shape[1]]
            at += flat.shape[1]
    return out


# scipy.signal's butter and filtfilt, written out: importing scipy.signal (and scipy.stats with it) took
# 0.35 s of every command's 1 s of imports; the seed needs only these two (tests/test_joints.py checks
# them against scipy.signal's to 1e-12).
def butter_lowpass(order: int, wn: float) -> tuple[np.ndarray, np.ndarray]:
    """Digital Butterworth low-pass (b, a) of `order` at `wn` (the cutoff over the Nyquist frequency,
    0 < wn < 1): the analogue prototype's poles, pre-warped and carried over by the bilinear
    transform, as scipy.signal.butter(order, wn) designs it."""
    if not 0 < wn < 1:
        raise ValueError(f"butter_lowpass: the cutoff must lie between 0 and the Nyquist frequency, got {wn}")
    poles = -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order))  # analogue prototype, cutoff 1
    warped = 4.0 * math.tan(math.pi * wn / 2.0)  # the cutoff pre-warped (sampling rate 2)
    poles = warped * poles
    gain = warped**order / np.real(np.prod(4.0 - poles))
    zd = (4.0 + poles) / (4.0 - poles)  # bilinear transform; every zero goes to z = -1
    return gain * np.real(np.poly(-np.ones(order))), np.real(np.poly(zd))


def _lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray, zi: np.ndarray) -> np.ndarray:
    """The IIR filter (b, a) (a[0] = 1) along axis 0 of x (n, m) from the initial state zi (order, m), as
    scipy.signal.lfilter: the difference equation Σ a_k y[n-k] = Σ b_k x[n-k] (+ zi in the first
    rows), run forward for every column at once."""
    order, n = len(a) - 1, len(x)
    y = np.zeros((n + order,) + x.shape[1:])  # `order` zero rows ahead of the output
    for k in range(order + 1):
        y[order + k:] += b[k] * x[:n - k]
    y[order:2 * order] += zi[:n]
    for i in range(order, n + order):
        for k in range(1, order + 1):
            y[i] -= a[k] * y[i - k]
    return y[order:]


def filtfilt(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Zero-phase filtering of x (n, ...) along axis 0, forward then backward, as
    scipy.signal.filtfilt(b, a, x, axis=0) with its defaults: odd extension by 3 × the filter's length
    at both ends, each pass started from the steady state of a step (lfilter_zi)."""
    b, a = np.asarray(b, float) / a[0], np.asarray(a, float) / a[0]
    order = len(a) - 1
    # The steady-state initial condition of a unit step (scipy.signal.lfilter_zi).
    companion = np.zeros((order, order))
    companion[0] = -a[1:]
    companion[1:, :-1] = np.eye(order - 1)
    zi = np.linalg.solve(np.eye(order) - companion.T, b[1:] - a[1:] * b[0])
    x = np.asarray(x, dtype=float)
    flat = x.reshape(len(x), -1)
    pad = 3 * max(len(a), len(b))
    if len(flat) <= pad:
        raise ValueError(f"filtfilt: {len(flat)} samples, need more than {pad}")
    ext = np.concatenate([2 * flat[:1] - flat[pad:0:-1], flat, 2 * flat[-1:] - flat[-2:-pad - 2:-1]])
    y = _lfilter(b, a, ext, np.outer(zi, ext[0]))
    y = _lfilter(b, a, y[::-1], np.outer(zi, y[-1]))[::-1]
    return y[pad:len(y) - pad].reshape(x.shape)


# --------------------------------------------------------------------------- models and trials
def model_geometry(model: Model) -> dict[str, dict[str, np.ndarray]]:
    """Base-model positions of markers and joint centres in each segment's frame (neutral pose)."""
    pm = model.pin
    data = pm.createData()
    pin.framesForwardKinematics(pm, data, pin.neutral(pm))
    place = {}
    for s in model.segments:
        place[s.name] = data.oMf[pm.getFrameId(s.name)]
    geo: dict[str, dict[str, np.ndarray]] = {s.name: {} for s in model.segments}
    for m in model.markers:
        geo[m.segment][m.name] = np.asarray(m.offset, dtype=float)
    for j in model.joints:
        world = data.oMf[pm.getFrameId(j.urdf_joints[0])].translation
        for s in (j.parent, j.child):
            geo[s][j.name] = place[s].actInv(world).copy()
    return geo


def estimate_model_joints(model: Model, trial: Trial, *, mode: str = "framework", alpha: float = 0.0,
                          basis: str = "rigid", cutoff_hz: float | None = 6.0,
                          extra_markers: Mapping[str, str] | None = None) -> JointEstimates:
    """Every joint of `model` from a trial: groups are the model's markers per segment (those the
    trial has), the topology is the model's joint tree, hinges come from the model, and the base
    model's centres choose the point on each hinge axis.  Markers are low-passed at `cutoff_hz`
    (None: raw) unless the trial's rate is too low for it.  `extra_markers` (trial label ->
    segment, e.g. from calibrate.seed.association.associate_to_model) adds markers the model does not
    know to the segments they ride on."""
    if cutoff_hz is not None and not cutoff_hz < trial.rate / 2:
        cutoff_hz = None
    labels = set(trial.labels)
    known = {m.name for m in model.markers}
    points = {lab: trial.marker(lab) for lab in trial.labels if lab in known}
    groups = {s.name: [m for m in s.markers if m in labels] for s in model.segments}
    for lab, seg in (extra_markers or {}).items():
        if lab in known or lab not in labels:
            continue
        if seg not in groups:
            raise ValueError(f"extra_markers['{lab}']: '{seg}' is not a segment of {model.path}")
        points[lab] = trial.marker(lab)
        groups[seg].append(lab)
    kinds = {"hinge": "hinge", "ball": "ball", "universal": "universal"}
    specs = [JointSpec(j.name, j.parent, j.child, kinds.get(j.kind)) for j in model.joints if j.kind != "fixed"]
    est = estimate_joints(points, groups, specs, mode=mode, alpha=alpha, basis=basis,
                          geometry=model_geometry(model), rate=trial.rate, cutoff_hz=cutoff_hz, times=trial.times)
    return est


def write_centres_csv(path: str | Path, est: JointEstimates, overwrite: bool = True) -> Path:
    """Joint-centre trajectories as CSV: time, then <joint>_x, _y, _z (m) per joint; hinges add
    <joint>_axis_x, _y, _z (unit, world).  Empty cells where a joint is not estimated."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: exists; pass overwrite=True (CLI: --overwrite) to replace it")
    F = len(est.joints[0].centre) if est.joints else 0
    times = est.times if est.times is not None else np.arange(F, dtype=float)
    header = ["time"]
    cols = [np.asarray(times, dtype=float)[:, None]]
    for j in est.joints:
        header += [f"{j.name}_{c}" for c in "xyz"]
        cols.append(j.centre)
        if j.axis is not None:
            header += [f"{j.name}_axis_{c}" for c in "xyz"]
            cols.append(j.axis)
    data = np.hstack(cols) if cols else np.zeros((0, 1))
    lines = [",".join(header)]
    for row in data:
        lines.append(",".join("" if not np.isfinite(v) else f"{v:.6f}" if k else f"{v:.6g}" for k, v in enumerate(row)))
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path
