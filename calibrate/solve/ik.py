"""Frame-wise inverse kinematics: the coordinates z_f that best fit each frame's markers
for fixed geometric parameters p.

Each frame is a small least-squares problem  min_z Σ_k |h_k(z, p) − r_k|²  over the
markers seen in that frame, solved by Levenberg–Marquardt on the exact CasADi
Jacobian; the root rotation and every ball joint's are updated on SO(3) (the solver's form
of calibrate.model.kinematics: a pose is z with the refs vector of reference rotations).  Frames
are solved in order, each warm-started from the previous one.  The first frame (and any
frame whose fit jumps) gets a global start: the root from its markers (Kabsch), then
joint by joint down the tree, each joint's angles from a small grid of starts, so a
limb far from the neutral pose is not caught in a mirror-image minimum.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import CalibrateError
from ..io.motion import Motion
from ..io.trial import Trial
from ..model.blocks import FrameLayout
from ..model.kinematics import IDENTITY, Kinematics
from ..model.model import Model, Parameters
from ..model.resolve import descendants, unplaced_frames
from ..model.rotations import matrix_quats, retract_root
from ..problem.options import SolverOptions
from ..seed.geometry import kabsch, marker_rms
from .lm import marquardt_diagonal, minimise

LIMIT_WEIGHT = 1.0  # m per rad beyond a joint limit, in the per-frame fit
REINIT_RMS = 0.005  # m: a frame fitting worse than this (and RESTART_RATIO x the running median) is restarted
# A frame fitting RESTART_RATIO times worse than the median of the 50 before it is fitted again from scratch
# (FrameSolver.global_start), at most every RESTART_GAP frames while the restarts fail (then every 20, 40, ...).
# A track warm-started frame to frame can drift into another basin slowly (Pose2Sim's right arm, straight at the
# trial's start, turned about its length: marker RMS 13 -> 55 mm over 70 frames; BTKData's PiG_Motion-FlatFoot-Full,
# the right arm turned at 12 mm where the calibration's own motion fits 4), which a 5x test over 20 mm never sees.
# When the restart fits better, the frames before it are fitted again backwards from it while they fit better so.
RESTART_RATIO = 1.5
RESTART_GAP = 10
RESTART_GAP_MAX = 160  # the wait doubles with each restart in a row that finds nothing better, up to this
RESTART_GAIN = 0.9  # a restart fitting below this share of the tracked fit's cost found another basin
GLOBAL_KEEP = 4  # grid starts per joint that the global start solves (the best-fitting as they stand)
# ... each this many steps, then the one that fits best on to GLOBAL_STEPS in all: on 165 frames of gait2392's,
# Rajagopal's and pig_walk's walks (base models) every frame so ended at the minimum it reached with each start solved
# GLOBAL_STEPS steps (costs within 1e-8), in 0.64-0.87 of the time (docs/benchmarks.md)
GLOBAL_SCREEN = 3
GLOBAL_STEPS = 12
STEP_TOL = 1e-8  # a frame's fit stops when its step is shorter than this (relative to |z|)
# A frame's fit for a decision (which labels a labelling gives its tracks, which segment a new label rides on) ends
# at a relative cost decrease of 1e-5, not the default 1e-8: on gait2392's walk (base model, every 4th frame) in half
# the steps, the model's markers within 1.5 mm of the converged fit's (median 0.04 mm; docs/benchmarks.md)
DECISION_TOLERANCE = 1e-5
TINY = 1e-300  # the absolute-decrease and gradient tests, off for a frame (its cost is in m², not χ²)


@dataclass(frozen=True)
class IKResult:
    """Per-frame coordinates and fit."""

    motion: Motion
    marker_rms: np.ndarray  # (n_frames,) RMS 3-D marker error per frame (m); NaN if too few markers
    residuals: np.ndarray  # (n_frames, n_markers, 3) model minus trial (m); NaN where not seen
    iterations: np.ndarray  # (n_frames,) LM iterations used
    # frames whose markers do not place the root, their poses bridged (inverse_kinematics' `bridge`)
    unplaced_frames: tuple[int, ...] = ()

    @property
    def rms(self) -> float:
        """RMS 3-D marker error over every observed marker in every frame (m)."""
        return marker_rms(self.residuals)


def _locked_columns(kin: Kinematics, locked: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """The frame-coordinate columns of the `locked` coordinates and their values; CalibrateError with one line
    for a name the model lacks or a ball joint's coordinate (its angles are increments about a reference)."""
    model = kin.model
    unknown = [n for n in locked if n not in model.dof_names]
    if unknown:
        raise CalibrateError(f"locked coordinate {unknown[0]!r} is not one of {model.path.name}'s "
                             f"({', '.join(model.dof_names[:6])}, ...); check the name")
    ball_of = {d: b for b in kin.balls for d in b.dofs}
    at = {model.dof_index(n): float(v) for n, v in locked.items()}
    cols, vals = [], []
    for name, value in locked.items():
        d = model.dof_index(name)
        if d in ball_of:
            # A whole ball held at zero (calibrate locks so the joints into segments no marker places: a lower-body
            # marker set's trunk and arms): its increments held at zero about an unturned reference.  Part of a ball,
            # or a ball held turned, is not (its angles are increments about a reference that the solve moves).
            dofs = ball_of[d].dofs
            if not all(k in at and abs(at[k]) < 1e-12 for k in dofs):
                raise CalibrateError(f"locked coordinate {name!r} belongs to a ball joint of {model.path.name} solved "
                                     "on SO(3), where only all of its angles can be held, at 0 "
                                     f"({', '.join(model.dof_names[k] for k in dofs)}); build the kinematics with "
                                     "build_kinematics(model, euler=locked_balls(model, locked)) to hold one")
        cols.append(FrameLayout.angle(d))
        vals.append(float(value))
    return np.array(cols, dtype=int), np.array(vals)


def marker_columns(model: Model, trial: Trial) -> np.ndarray:
    """Trial markers in the model's marker order, (n_frames, n_model_markers, 3); NaN where absent."""
    out = np.full((trial.n_frames, len(model.markers), 3), np.nan)
    index = {lab: i for i, lab in enumerate(trial.labels)}
    for k, name in enumerate(model.marker_names):
        if name in index:
            out[:, k] = trial.markers[:, index[name]]
    return out


class _FrameFit:
    """One frame's fit as a calibrate.solve.lm.StepProblem, x = (z, q): the markers `seen_mk` of the
    frame `obs` by the coordinates `free`, with the soft joint limits (FrameSolver.solve).  Cost |r|²."""

    def __init__(self, solver: FrameSolver, obs: np.ndarray, seen_mk, free, weight: np.ndarray | None = None):
        self.evaluate = solver.evaluate
        self.rows = (3 * np.asarray(seen_mk)[:, None] + np.arange(3)).ravel()
        self.target = obs[seen_mk].ravel()
        # each marker's rows times the square root of its weight (an IK setup's), or all alike
        self.scale = None if weight is None else np.repeat(np.sqrt(np.asarray(weight, float)[seen_mk]), 3)
        self.free = free = np.asarray(free)
        self.every = free.size == solver.nz and bool(np.all(free == np.arange(solver.nz)))  # J's rows only
        self.pick = self.rows if self.every else np.ix_(self.rows, free)  # the Jacobian's entries fitted
        # The columns' roles (root rotation, balls, limited DoFs), made once per set of coordinates.
        self.rot, self.balls, self.dof_cols, self.lo, self.hi, self.col_of = solver.columns(free, self.every)
        self.last: tuple | None = None  # (x, residuals, Jacobian, beyond limits) at the last point costed
        self.g = self.A = np.zeros(0)
        # linearize's Jacobian, markers' rows then one row per limited DoF (its one entry rewritten each time)
        self.Jf = np.zeros((self.rows.size + self.dof_cols.size, free.size))
        self.limit_rows = self.rows.size + np.arange(self.dof_cols.size)

    def residuals(self, x: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        m, J = self.evaluate(*x)
        th = x[0][self.dof_cols]
        out = (th < self.lo) | (th > self.hi)
        # np.minimum(np.maximum(...)) is np.clip's arithmetic, without its wrapper's checks
        fit = m[self.rows] - self.target
        J = J[self.pick]
        if self.scale is not None:
            fit, J = fit * self.scale, J * self.scale[:, None]
        r = np.concatenate([fit, LIMIT_WEIGHT * (th - np.minimum(np.maximum(th, self.lo), self.hi))])
        return r, J, out

    def linearize(self, x: tuple[np.ndarray, np.ndarray], lam: float = 0.0) -> float:
        r, J, out = self.last[1:] if self.last is not None and self.last[0] is x else self.residuals(x)
        Jf = self.Jf
        Jf[:self.rows.size] = J
        Jf[self.limit_rows, self.col_of] = LIMIT_WEIGHT * out
        self.g, self.A = Jf.T @ r, Jf.T @ Jf
        return float(r @ r)

    def gradient_max(self) -> float:
        return 2.0 * float(np.abs(self.g).max(initial=0.0))

    def step(self, x: tuple[np.ndarray, np.ndarray], lam: float) -> tuple[tuple, float, float] | None:
        A, g = self.A, self.g
        d = A.diagonal()
        D = marquardt_diagonal(d, float(A.max(initial=0.0)))
        damped = A.copy()
        np.fill_diagonal(damped, d + lam * D)
        try:
            step = -np.linalg.solve(damped, g)
        except np.linalg.LinAlgError:
            return None
        z, q = x
        zn = z.copy()
        zn[self.free] += step
        if self.rot:
            q = q.copy()
            q[:4] = retract_root(q[:4], zn[FrameLayout.rotation])
            zn[FrameLayout.rotation] = 0.0
        predicted = -(2.0 * float(g @ step) + float(step @ A @ step))
        return (zn, q), predicted, math.sqrt(float(step @ step))  # np.linalg.norm's arithmetic, without its checks

    def cost(self, x: tuple[np.ndarray, np.ndarray]) -> float:
        r, J, out = self.residuals(x)
        self.last = (x, r, J, out)  # the linearization there, if the step is accepted
        return float(r @ r)

    def norm(self, x: tuple[np.ndarray, np.ndarray]) -> float:
        return math.sqrt(float(x[0] @ x[0]))


class FrameSolver:
    """Levenberg–Marquardt on a subset of one frame's coordinates and markers."""

    def __init__(self, kin: Kinematics, p: np.ndarray, evaluator=None, margin: float = 0.0):
        """`margin` (rad): the joint limits this much wider than the model's (the global problem's
        calibrate.problem.problem.LIMIT_MARGIN, for poses that must agree with it)."""
        self.kin, self.p = kin, p
        self.evaluate = evaluator or kin.frame_evaluator(p, reference=True)
        model = kin.model
        self.identity = kin.refs(IDENTITY, None)[0]  # refs of the root and every ball unturned
        ref_slot = {FrameLayout.angle(b.dofs[0]): 4 + 4 * i for i, b in enumerate(kin.balls)}
        self.ball_cols = np.array(sorted(FrameLayout.angle(d) for b in kin.balls for d in b.dofs), dtype=int)
        self.nz = model.nz
        seg_joint = {j.child: j for j in model.joints}
        children: dict[str, list[str]] = {s.name: [] for s in model.segments}
        for j in model.joints:
            children[j.parent].append(j.child)
        # For each joint: its own DoF columns, the subtree's DoF columns and marker indices.
        self.plan = []
        for j in model.joints:
            own = [FrameLayout.angle(model.dof_index(d)) for d in j.dofs]
            stack, sub_dofs, sub_mk = [j.child], [], []
            while stack:
                s = stack.pop()
                sub_dofs += [FrameLayout.angle(model.dof_index(d)) for d in seg_joint[s].dofs]
                sub_mk += [model.marker_index(m) for m in model.segments[model.segment_index(s)].markers]
                stack += children[s]
            child_mk = [model.marker_index(m) for m in model.segments[model.segment_index(j.child)].markers]
            lims = [(max(d.lower, -np.pi), min(d.upper, np.pi)) for d in (model.dofs[FrameLayout.dof(c)] for c in own)]
            # reference slots of the balls in the subtree: reset with its angles before a grid search
            slots = [ref_slot[c] for c in sub_dofs if c in ref_slot]
            self.plan.append((own, sorted(sub_dofs), sub_mk, child_mk, lims, slots))
        self.root_markers = [model.marker_index(m) for m in model.segments[0].markers]
        # Each coordinate's start below a joint placed by a grid: zero, unless zero is in the outer quarters of
        # the range (an elbow or knee straight at its limit), then the nearer quarter point.  A hinge started at
        # its limit straight leaves the joints above it to point the limb, and a straight limb's turn about its
        # length is then free: Pose2Sim's arm found raised and turned, its elbow held straight by the limit.
        lo = np.array([max(d.lower, -np.pi) for d in model.dofs])
        hi = np.array([min(d.upper, np.pi) for d in model.dofs])
        self.rest = np.zeros(model.nz)
        self.rest[FrameLayout.angle(0):] = np.clip(0.0, lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo))
        self.rest[self.ball_cols] = 0.0
        self.lower = np.array([d.lower for d in model.dofs]) - margin
        self.upper = np.array([d.upper for d in model.dofs]) + margin
        self._columns: dict[tuple[int, ...] | None, tuple] = {}  # columns(), by the coordinates solved for

    def columns(self, free: np.ndarray, every: bool = False) -> tuple[bool, bool, np.ndarray, np.ndarray,
                                                                      np.ndarray, np.ndarray]:
        """The roles of the coordinates `free` (`every`: all of them, in order) in a frame's fit: whether
        the root's rotation and any ball is among them, the limited DoFs' columns (hinge and universal
        angles: a ball is on SO(3), without limits), their lower and upper limits, and each one's place
        among `free`.  Made once per set of coordinates (the global start solves each joint's many times)."""
        key = None if every else tuple(int(c) for c in free)
        if key not in self._columns:
            self._columns[key] = self._roles(np.arange(self.nz) if every else np.asarray(free, dtype=int))
        return self._columns[key]

    def _roles(self, free: np.ndarray) -> tuple[bool, bool, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        rot = bool(np.isin(np.arange(FrameLayout.n_root)[FrameLayout.rotation], free).any())
        balls = bool(np.isin(self.ball_cols, free).any())
        dof_cols = np.setdiff1d(free[free >= FrameLayout.angle(0)], self.ball_cols).astype(int)
        position = {int(c): i for i, c in enumerate(free)}
        col_of = np.array([position[int(c)] for c in dof_cols], dtype=int)  # limit rows -> columns
        return (rot, balls, dof_cols, self.lower[FrameLayout.dof(dof_cols)], self.upper[FrameLayout.dof(dof_cols)],
                col_of)

    def solve(self, z, q, obs, seen_mk, free, budget, tol=1e-8, weight: np.ndarray | None = None):
        """Levenberg–Marquardt (calibrate.solve.lm.minimise) over coordinates `free` fitting markers
        `seen_mk` (each weighted by `weight`, per model marker, if given), at most `budget` steps, stopping when a
        step lowers the cost by less than the fraction `tol`; returns (z, q, cost, steps).

        Joint limits enter as soft residuals LIMIT_WEIGHT * (theta - clip(theta, lower, upper)):
        zero inside the range of motion, so they never bias a pose that respects it, but
        they keep a poorly fitting model out of mirror-image branches.
        """
        fit = _FrameFit(self, obs, seen_mk, free, weight)
        options = SolverOptions(max_iterations=budget, ftol=tol, atol=TINY, xtol=STEP_TOL, gtol=TINY, geodesic=False)
        (z, q), summary = minimise(fit, (z, q), options)
        if fit.balls:  # the balls' increments folded once per solve: the next starts at full rank
            z, q = self.kin.retract_one(z, q)
        return z, q, summary.final_cost, summary.iterations

    def global_start(self, obs, seen, local: bool = False, free=None, weight=None, held=None):
        """A pose for one frame from scratch: root by Kabsch, then joint by joint with multi-starts.  With
        `local`, also every coordinate solved at once from the model's default pose (root by Kabsch), and
        the one of the two that fits the frame better, each solved to convergence.  A segment with two
        markers (and its joint centre) fixes its own rotation, and on a base model whose marker places differ
        from the subject's that rotation can point to a basin the segments below fit little worse
        (Rajagopal2016's humerus: arm_rot -95 deg, the elbow at its limit, 0.5 % above the anatomical pose's
        cost); the local solve from the default pose, as OpenSim's IK starts, stays near the anatomical one.
        The two local solves over the coordinates `free` (default all), the markers weighted by `weight`, from
        starts passed through `held` (the locked coordinates set; calibrate.solve.ik.inverse_kinematics)."""
        root = self._root_start(obs, seen)
        z, q = self._joint_by_joint(*root, obs, seen)
        if not local:
            return z, q
        idx = np.flatnonzero(seen)
        every = np.arange(self.nz) if free is None else free
        held = held or (lambda z: z)
        best = self.solve(held(z), q, obs, idx, every, 200, weight=weight)
        roots = [root]
        if sum(seen[k] for k in self.root_markers) < 3 and seen.sum() >= 3:
            # The root placed by every marker (_root_start) or, as before, unturned at their mean: a squat's bent
            # body turns the first; the better fit of the two's local solves is kept.
            roots.append(self._root_start(obs, seen, whole=False))
        for zr, qr in roots:
            other = self.solve(held(zr), qr, obs, idx, every, 200, weight=weight)
            if other[2] < best[2]:
                best = other
        return best[0], best[1]

    def _root_start(self, obs, seen, whole: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The default pose with the root placed on its markers (Kabsch); where fewer than three of them are seen
        (a markerless pelvis's two hip keypoints), the default pose placed on every seen marker as one rigid body
        (the body's heading and up, not the lab's axes: Pose2Sim's subject, started unturned, folded a foot to 106 deg
        at the ankle and stayed so); with fewer than three seen in all, or not `whole`, unturned at their mean."""
        z = np.zeros(self.nz)
        q = self.identity.copy()
        root_seen = [k for k in self.root_markers if seen[k]]
        if len(root_seen) >= 3:
            a = self.evaluate(z, q)[0].reshape(-1, 3)[root_seen]
            R0, t0 = kabsch(a, obs[root_seen])
            q[:4] = matrix_quats(R0)
            z[FrameLayout.translation] = t0
            z, q, _, _ = self.solve(z, q, obs, root_seen, np.arange(FrameLayout.n_root), 50)
        elif whole and seen.sum() >= 3:
            every = np.flatnonzero(seen)
            a = self.evaluate(z, q)[0].reshape(-1, 3)[every]
            R0, t0 = kabsch(a, obs[every])
            q[:4] = matrix_quats(R0)
            z[FrameLayout.translation] = t0
        else:
            z[FrameLayout.translation] = np.nanmean(obs[seen], axis=0)
        return z, q

    def _joint_by_joint(self, z, q, obs, seen) -> tuple[np.ndarray, np.ndarray]:
        """From the root's pose, each joint down the tree from the best of a grid of starts."""
        for own, sub_dofs, sub_mk, child_mk, lims, slots in self.plan:
            fit_mk = [k for k in child_mk if seen[k]]
            free = own
            if 3 * len(fit_mk) < len(own) + 3:  # too few on the child itself: use the whole subtree
                fit_mk, free = [k for k in sub_mk if seen[k]], sub_dofs
            if not fit_mk or not free:  # nothing seen, or a weld: its child's markers ride (the joints below follow)
                continue
            n_grid = {1: 7, 2: 5}.get(len(own), 3)
            rows = (3 * np.asarray(fit_mk)[:, None] + np.arange(3)).ravel()
            target = obs[fit_mk].ravel()
            q0 = q.copy()  # the subtree's balls unturned: their grid angles are then absolute
            for s in slots:
                q0[s:s + 4] = IDENTITY
            starts = []  # every grid point scored as it stands; the most promising few are solved
            for start in itertools.product(*[np.linspace(lo, hi, n_grid) for lo, hi in lims]):
                zz = z.copy()
                zz[sub_dofs] = self.rest[sub_dofs]
                zz[own] = start
                m, _ = self.evaluate(zz, q0)
                starts.append((float(np.sum((m[rows] - target) ** 2)), zz))
            starts.sort(key=lambda s: s[0])
            best = None
            for _, zz in starts[:GLOBAL_KEEP]:
                zz, qq, c, _ = self.solve(zz, q0, obs, fit_mk, free, GLOBAL_SCREEN)
                if best is None or c < best[2]:
                    best = (zz, qq, c)
            z, q = best[0], best[1]
            if GLOBAL_STEPS > GLOBAL_SCREEN:
                z, q, _, _ = self.solve(z, q, obs, fit_mk, free, GLOBAL_STEPS - GLOBAL_SCREEN)
        return z, q


def _refit_backwards(solver: FrameSolver, obs: np.ndarray, f: int, z: np.ndarray, q: np.ndarray, Z: np.ndarray,
                     Q: np.ndarray, costs: np.ndarray, iters: np.ndarray, frame_rms: list[float], free: np.ndarray,
                     budget: int, tolerance: float, weight: np.ndarray | None) -> None:
    """The frames before `f` fitted again, backwards, each warm-started from the frame after it (frame f's pose
    (z, q) first), while the fit is better than the one they have; Z, Q, costs, iters and frame_rms (the fitted
    frames' RMS, in order) updated in place."""
    fitted = np.flatnonzero(np.isfinite(costs[:f]))  # frame_rms[i] is the RMS of frame fitted[i]
    for i in range(fitted.size - 1, -1, -1):
        g = fitted[i]
        idx = np.flatnonzero(~np.isnan(obs[g, :, 0]))
        z, q, cost, it = solver.solve(z, q, obs[g], idx, free, budget, tolerance, weight)
        if not cost < costs[g]:
            return
        Z[g], Q[g], costs[g], iters[g] = z, q, cost, iters[g] + it
        frame_rms[i] = float(np.sqrt(cost / idx.size))


def unseen_coordinates(model: Model, seen: np.ndarray) -> np.ndarray:
    """(n_frames, n_dofs) True where no marker on a coordinate's child segment or below it is seen (`seen`: n_frames,
    n_markers): that coordinate moves no marker of the frame, and its fit keeps whatever it started from."""
    below = descendants(model)
    seg = np.array([mk.segment for mk in model.markers])
    out = np.zeros((seen.shape[0], model.n_dofs), dtype=bool)
    for d, dof in enumerate(model.dofs):
        child = model.joints[model.joint_index(dof.joint)].child
        on = np.isin(seg, below[child])
        out[:, d] = ~seen[:, on].any(axis=1) if on.any() else True
    return out


def bridge_unseen(kin: Kinematics, seen: np.ndarray, Z: np.ndarray, held: np.ndarray = ()) -> None:
    """A coordinate's angles in frames where no marker below it is seen (unseen_coordinates: a hand's one marker
    hidden), linear between the frames on either side that see one, or held at the nearest such frame at the trial's
    edge; Z (n_frames, frame coordinates) updated in place; `seen` (n_frames, n_markers); `held`: columns of Z left
    as they are.  The fit leaves them where each frame started: the previous frame's at its last speed,
    and in 0.6 s of a simulated walk's hand marker hidden the wrist flexed 81 deg off.  A ball solved on SO(3), whose
    angles are increments about a reference, and the held coordinates are left as they are."""
    model = kin.model
    unseen = unseen_coordinates(model, seen)
    on_ball = {d for b in kin.balls for d in b.dofs}
    for d in range(model.n_dofs):
        col = FrameLayout.angle(d)
        if d in on_ball or col in held or not unseen[:, d].any() or unseen[:, d].all():
            continue
        seen = np.flatnonzero(~unseen[:, d])
        gaps = np.flatnonzero(unseen[:, d])
        Z[gaps, col] = np.interp(gaps, seen, Z[seen, col])


def bridge_unplaced(root: np.ndarray, dofs: np.ndarray, Z: np.ndarray, Q: np.ndarray) -> None:
    """The frames' coordinates their markers do not place (calibrate.model.resolve.unplaced_frames: `root` (n_frames,)
    where they do not place the root, `dofs` (n_frames, n_dofs) the coordinates to blame for a segment they leave
    unplaced) linear between the frames on either side that place them, held at the nearest at the trial's edges:
    where the root is not placed, every coordinate and the root's quaternion (normalised); Z (n_frames, frame
    coordinates, a ball's angles absolute) and Q (n_frames, 4) updated in place.  A coordinate no frame places is
    left as it is."""
    root = np.asarray(root, dtype=bool)
    if root.any() and not root.all():
        good, bad = np.flatnonzero(~root), np.flatnonzero(root)
        for c in range(FrameLayout.n_root):
            Z[bad, c] = np.interp(bad, good, Z[good, c])
        q = Q[good].copy()
        for k in range(1, len(q)):  # one hemisphere along the placed frames: neighbours interpolate the short way
            if q[k] @ q[k - 1] < 0:
                q[k] = -q[k]
        between = np.stack([np.interp(bad, good, q[:, i]) for i in range(4)], axis=1)
        Q[bad] = between / np.linalg.norm(between, axis=1, keepdims=True)
    for d in range(dofs.shape[1]):
        off = dofs[:, d] | root
        if off.any() and not off.all():
            col = FrameLayout.angle(d)
            good, bad = np.flatnonzero(~off), np.flatnonzero(off)
            Z[bad, col] = np.interp(bad, good, Z[good, col])


def refit_bridged(solver: FrameSolver, dofs: np.ndarray, root: np.ndarray, Z: np.ndarray, Q: np.ndarray,
                  observed: np.ndarray, seen: np.ndarray, held: np.ndarray = (),
                  weight: np.ndarray | None = None) -> None:
    """After bridge_unplaced: in each frame that places the root (`root` False) and where it bridged coordinates
    (`dofs` (n_frames, n_dofs), those blamed for a segment the frame's markers leave unplaced), the other coordinates
    of the joints below the topmost bridged joint fitted again to the markers the frame shows (`observed` (n_frames,
    n_markers, 3), `seen` (n_frames, n_markers); each weighted by `weight`, per model marker, if given) at the
    solver's geometry, the bridged ones and the columns `held` (locked coordinates) kept; Z (absolute angles) and Q
    (n_frames, 4) updated in place.  A bridge of part of a chain moves the markers below it: PiG_Motion-FlatFoot-
    Full's left elbow and finger markers rejected in four frames left the humerus unseen, its shoulder's flexion and
    rotation, the forearm's rotation and the wrist bridged, the shoulder's adduction and the elbow as fitted, and the
    written pose put the wrist markers the frame shows 72-79 mm from them (docs/benchmarks.md)."""
    root = np.asarray(root, dtype=bool)
    dofs = np.asarray(dofs, dtype=bool) & ~root[:, None]
    kin, model = solver.kin, solver.kin.model
    joint_of = {model.dof_index(d): ji for ji, j in enumerate(model.joints) for d in j.dofs}
    held = set(np.asarray(held, dtype=int).tolist())
    for f in np.flatnonzero(dofs.any(axis=1)):
        below = set().union(*(solver.plan[joint_of[d]][1] for d in np.flatnonzero(dofs[f])))  # their subtrees
        free = np.array(sorted(c for c in below if c not in held and not dofs[f, FrameLayout.dof(c)]), dtype=int)
        shown = np.flatnonzero(seen[f])
        if not free.size or not shown.size:
            continue
        refs = kin.refs(Q[f], None)[0]  # every ball at the identity: its angles in Z are absolute
        z, q, _, _ = solver.solve(Z[f].copy(), refs, observed[f], shown, free, 20, weight=weight)
        Zf, Qf = kin.absolute(z[None], q[None, :4], q[4:].reshape(1, -1, 4) if kin.balls else None,
                              previous=FrameLayout.angles(Z[f][None])[0])
        Z[f], Q[f] = Zf[0], Qf[0]


def _carried(solver: FrameSolver, z: np.ndarray, q: np.ndarray, obs: np.ndarray, seen_idx: np.ndarray,
             weight: np.ndarray | None, tolerance: float) -> np.ndarray:
    """A frame that shows one or two markers, too few to turn a segment: the pose `z` (references `q`) of the frame
    beside it, its root translated onto the markers it shows (a least-squares shift; its turns and angles kept).
    Before, such a frame kept the pose beside it where it stood, or the model's default pose at the lab's origin
    before the first fitted frame (c3d.org's sample10 walk: 1.6 m off at its first frame, 84-192 mm at its last)."""
    if seen_idx.size == 0:
        return z
    z, _, _, _ = solver.solve(z, q, obs, seen_idx, np.arange(FrameLayout.translation.stop), 20, tolerance, weight)
    return z


def inverse_kinematics(kin: Kinematics, trial: Trial, params: Parameters, max_iterations: int = 30,
                       tolerance: float = 1e-8, progress: Callable[[int, int], None] | None = None,
                       locked: Mapping[str, float] | None = None, weights: Mapping[str, float] | None = None,
                       default_weight: float = 1.0, start: Motion | None = None, margin: float = 0.0,
                       bridge: bool = False) -> IKResult:
    """Solve every frame of `trial` for the model of `kin` with geometry `params`.

    Markers are matched by label; model markers absent from the trial are ignored.
    Each frame stops when the relative cost decrease falls below `tolerance` or the step
    below 1e-8 (m, rad), after at most `max_iterations` (200 for a frame started from scratch).
    `locked`: coordinates held at a value (rad or m) in every frame, as OpenSim's locked coordinates and
    its IK's heavily weighted coordinate tasks hold them (a hinge's or universal joint's; all of a ball joint's at 0).
    `weights`: each marker's weight in the fit (an IK setup's marker tasks), `default_weight` for a marker it does
    not name; a weight of 0 leaves the marker out (its residuals NaN).  None: every marker alike.
    `start`: a motion with the trial's frames (an earlier fit of the same frames, e.g. with one or two labels
    changed); each frame then starts at its pose, not at the previous frame's, and no frame from scratch but one
    whose fit stays far worse than the frames before it.
    A frame fitting RESTART_RATIO times worse than the median of the 50 fitted before it (and worse than
    REINIT_RMS) is also fitted from scratch, and the better taken; when the restart finds another basin, the frames
    before it are fitted again backwards from it while they fit better so.
    `margin` (rad): the joint limits this much wider than the model's (the calibration's
    calibrate.problem.problem.LIMIT_MARGIN: a subject's other trials fitted under its calibration's limits).
    `bridge`: the frames whose markers do not place the root, or a segment (calibrate.model.resolve.unplaced_frames),
    bridged from the frames either side that do (bridge_unplaced; `IKResult.unplaced_frames` lists the first kind),
    their residuals then the bridged pose's.
    `progress(done, total)` is called every 100 frames.
    """
    model = kin.model
    obs = marker_columns(model, trial)
    if start is not None and start.angles.shape != (obs.shape[0], model.nz - 6):
        raise CalibrateError(f"the start motion has {start.angles.shape[0]} frames of {start.angles.shape[1]} "
                             f"coordinates; the trial has {obs.shape[0]} frames and the model {model.nz - 6}: "
                             "give a motion fitted to the same frames with the same model")
    weight = None
    if weights is not None:
        weight = np.array([float(weights.get(n, default_weight)) for n in model.marker_names])
        if not np.all(np.isfinite(weight) & (weight >= 0)):
            raise CalibrateError("marker weights must be finite numbers >= 0")
        obs = obs.copy()
        obs[:, weight <= 0] = np.nan  # weight 0: not fitted, as OpenSim's IK leaves such a marker out
    nf = obs.shape[0]
    p = params.vector()
    solver = FrameSolver(kin, p, margin=margin)
    lock_cols, lock_vals = _locked_columns(kin, locked or {})
    all_free = np.setdiff1d(np.arange(model.nz), lock_cols)

    def held(z: np.ndarray) -> np.ndarray:
        if lock_cols.size:
            z = z.copy()
            z[lock_cols] = lock_vals
        return z
    Z = np.zeros((nf, model.nz))
    Q = np.tile(solver.identity, (nf, 1))  # refs (root, balls) per frame
    iters = np.zeros(nf, dtype=int)
    frame_rms: list[float] = []
    costs = np.full(nf, np.nan)  # each fitted frame's cost (m²)
    z, q = None, None
    z_prev = None
    next_try, gap = 0, RESTART_GAP  # the first frame a restart may be tried at; the wait after the next one fails
    if start is not None:  # the start motion in the solver's form (root and balls as references)
        Zs, Qs, Bs = kin.retract(FrameLayout.coordinates(start.root_translation, start.angles),
                                 start.root_quaternion, None)
        starts = kin.refs(Qs, Bs)
    for f in range(nf):
        seen = ~np.isnan(obs[f, :, 0])
        seen_idx = np.flatnonzero(seen)
        if start is not None:
            z, q, budget = held(Zs[f]), starts[f], max_iterations
            if seen.sum() < 3:
                Z[f], Q[f] = z, q
                continue
        elif seen.sum() < 3:  # too few to turn anything: the previous pose carried, moved onto the markers it shows
            if z is not None:
                z, z_prev = _carried(solver, z, q, obs[f], seen_idx, weight, tolerance), None
                Z[f], Q[f] = z, q
            continue
        elif z is None:
            # from scratch, also from the default pose as OpenSim's IK starts (the better): Rajagopal2016's humerus
            # otherwise turns 166 deg about its length on calibrate's subject, held there by every later frame
            z, q = solver.global_start(obs[f], seen, local=True, free=all_free, weight=weight, held=held)
            z = held(z)
            budget = 200
        else:
            budget = max_iterations
            if z_prev is not None:  # constant-velocity prediction of the joint angles and position
                z_guess = 2 * z - z_prev
                z_prev = z
                z = z_guess
            else:
                z_prev = z
        z, q, cost, it = solver.solve(z, q, obs[f], seen_idx, all_free, budget, tolerance, weight)
        rms = np.sqrt(cost / seen.sum())
        if f >= next_try and frame_rms and rms > REINIT_RMS and rms > RESTART_RATIO * np.median(frame_rms[-50:]):
            z2, q2 = solver.global_start(obs[f], seen, local=True, free=all_free, weight=weight, held=held)
            z2, q2, cost2, it2 = solver.solve(held(z2), q2, obs[f], seen_idx, all_free, 200, tolerance, weight)
            other_basin = cost2 < RESTART_GAIN * cost  # the frames before may have drifted with this one
            if cost2 < cost:
                z, q, cost, it = z2, q2, cost2, it + it2
                rms = np.sqrt(cost / seen.sum())
            if other_basin:
                z_prev, gap = None, RESTART_GAP
                _refit_backwards(solver, obs, f, z, q, Z, Q, costs, iters, frame_rms, all_free, max_iterations,
                                 tolerance, weight)
            else:  # the same basin, or a worse one: wait, the longer the more restarts fail in a row
                next_try, gap = f + gap, min(2 * gap, RESTART_GAP_MAX)
        frame_rms.append(rms)
        Z[f], Q[f], iters[f], costs[f] = z, q, it, cost
        if progress is not None and (f + 1) % 100 == 0:
            progress(f + 1, nf)
    fitted = np.flatnonzero(np.isfinite(costs))
    if start is None and fitted.size and fitted[0] > 0:  # the frames before the first with three markers or more:
        for f in range(fitted[0] - 1, -1, -1):  # the first fitted pose carried back, moved onto what each shows
            seen_idx = np.flatnonzero(~np.isnan(obs[f, :, 0]))
            Z[f], Q[f] = _carried(solver, Z[f + 1], Q[f + 1], obs[f], seen_idx, weight, tolerance), Q[f + 1]
    bridge_unseen(kin, np.isfinite(obs[..., 0]), Z, lock_cols)
    Z, Q = kin.absolute(Z, Q[:, :4], Q[:, 4:].reshape(nf, -1, 4))
    unplaced: tuple[int, ...] = ()
    seen_all = np.isfinite(obs[..., 0])
    if bridge and nf and not (seen_all == seen_all[0]).all():
        root_off, dofs_off = unplaced_frames(model, seen_all, locked=list(locked or {}))
        bridge_unplaced(root_off, dofs_off, Z, Q)
        refit_bridged(solver, dofs_off, root_off, Z, Q, obs, seen_all, lock_cols, weight)
        unplaced = tuple(int(f) for f in np.flatnonzero(root_off)) if not root_off.all() else ()
    M, _ = kin.batch(Z, Q, p)
    res = M - obs
    rms_f = marker_rms(res, axis=1)  # NaN in frames with no marker, on purpose
    motion = Motion(trial.times.copy(), Z[:, FrameLayout.translation].copy(), Q, FrameLayout.angles(Z).copy(),
                    model.dof_names)
    return IKResult(motion, rms_f, res, iters, unplaced)
