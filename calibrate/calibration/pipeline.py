"""Subject calibration from one trial: seed, start, global solve, result (seed 003).

    calibrate(model, trial, settings)  ->  Calibration
      1. seed    MTB joint centres (calibrate.seed.joints) -> segment scale factors, joint centres
                 and hinge axes in segment frames; the base model where the seed fails.
      2. start   frame-wise inverse kinematics with the seeded geometry on key frames (every
                 `stride`-th, warm-started key frame to key frame), interpolated between
                 them, then refined for all frames at once with the geometry held.
      3. solve   one Levenberg–Marquardt over every frame's coordinates and the free
                 parameters (calibrate.problem.problem, calibrate.solve.lm).
      4. result  parameters, motion, marker errors, posterior standard deviations and the
                 parameters the trial could not identify (held by their priors).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace

import numpy as np
from scipy.spatial.transform import Rotation, Slerp
from threadpoolctl import threadpool_limits

from ..errors import CalibrateError
from ..io.labels import UNLABELLED
from ..io.motion import Motion
from ..io.osim import with_locked
from ..io.trial import Trial
from ..model.blocks import FrameLayout, perpendicular_basis
from ..model.kinematics import IDENTITY, Kinematics, build_kinematics
from ..model.model import Model, Parameters, add_markers, mass_factor
from ..problem.problem import Problem, Settings, State
from ..seed.association import associate_to_model, distance_variance
from ..seed.geometry import kabsch_batch, marker_max, marker_rms
from ..seed.joints import JointEstimates, estimate_model_joints, lowpass, model_geometry
from ..solve.ik import _FrameSolver, marker_columns
from ..solve.lm import SolverSummary, covariance, levenberg_marquardt
from .records import CoordinateNote, Identified, LimitNote, ParameterChange, Progress, StillNote
from .report import calibration_report, summary_text, write_outputs

MIN_FRAMES = 3  # fewer frames with markers than this: nothing to calibrate
SEED_MAX_SHIFT = 0.06  # m: a seeded joint centre further than this from the (scaled) base model is not used
SEED_MARKER_LEVER = 0.15  # m: a marker this far from a segment's only estimated centre may scale it
SEED_MAX_TILT = math.radians(30.0)  # a seeded hinge axis further than this from the base model's is not used
START_FRAMES = 60  # frames of the subsample on which choose_start solves each candidate start
START_ITERATIONS = 30  # ... for at most this many iterations
START_GOOD_FIT = 1.5  # a candidate whose chi-square per observed coordinate is below this is taken at once
STILL_RATIO = 3.0  # a coordinate whose spread over frames is below this many per-frame SDs is noted (still_notes)
HOLD_ROUNDS = 2  # rounds of holding the axes of still coordinates (Settings.auto_hold), each a new subsample solve
LIMIT_NOTE_DEG = 5.0  # a coordinate this far beyond the base model's limits ...
LIMIT_NOTE_FRACTION = 0.05  # ... in more than this fraction of the frames is noted (limit_notes)
IDENTIFIED = 0.5  # posterior std / prior-only std above this (worst direction): the trial did not identify it
STRIDE = 10  # key-frame spacing of the start (frames of the trial)
COARSE_FRAMES = 120  # the geometry's basin is found on about this many evenly spaced frames first
SEED_FRAMES = 150  # the MTB seed uses at most about this many evenly spaced (low-passed) frames
OUTLIER_ROUNDS = 8  # rejection rounds (each takes at most one marker per frame)
OUTLIER_PASSES = 2  # rejection rounds, solve, noise learnt again: at most this many times
SEED_CUTOFF_HZ = 6.0  # low-pass of the markers before the MTB seed (as calibrate.seed.joints does by default)
NOISE_FLOOR = 0.0005  # m: a learnt marker noise SD is never below this (sub-millimetre: a camera system's floor)
NOISE_CAP = 0.015  # m: ... nor above this (beyond it a marker is mislabelled, not noisy: outliers catch it)
NOISE_MIN_FRAMES = 20  # a marker seen in fewer frames takes its segment's (or all markers') median learnt SD
NOISE_ROUNDS = 3  # learn-and-solve rounds on the subsample (then once more on every frame)
NOISE_CHANGE = 0.1  # stop re-learning when no marker's SD changes by more than this fraction
MAD_SD = 1.4826  # SD of a Gaussian per unit median absolute deviation
NOISE_TAU_MAX = 16.0  # frames: a marker's residual correlation time counts up to this (its weight SD: 4 x its SD)
NOISE_CLIP = 4.0  # a residual counts in the learnt SD up to this many robust SDs per coordinate (spikes: no more)


@dataclass(frozen=True)
class Seed:
    """Starting geometry from the MTB joint centres, and what was not seeded (and why)."""

    params: Parameters
    notes: tuple[str, ...]
    joints: JointEstimates | None
    seconds: float


@dataclass(frozen=True)
class NewMarker:
    """A trial marker the base model does not know, and where calibration put it."""

    label: str
    segment: str | None  # None: it rides on no segment (left out)
    position: np.ndarray | None  # (3,) m in the segment frame at the start (subject scale); None if left out
    reason: str  # why this segment (or why none)


@dataclass(frozen=True)
class Outlier:
    """One marker position left out of the fit: too far from where the fitted model puts it."""

    trial: int  # index into Calibration.trials
    frame: int  # frame of that trial (0-based)
    marker: str
    error: float  # m, when it was rejected


@dataclass(frozen=True)
class Calibration:
    """Everything `calibrate` found.  Units: metres, radians, seconds.

    Several trials share `params`; each has its own motion (`motions`, in trial order), and
    `residuals` stacks their frames in that order (`trial_frames(i)` is trial i's slice).
    """

    model: Model  # the subject model's structure: the base model plus any new markers
    trials: tuple[Trial, ...]
    settings: Settings
    params: Parameters  # the subject's geometric parameters
    motions: tuple[Motion, ...]  # coordinates of every frame, per trial
    residuals: np.ndarray  # (F, n_model_markers, 3) model − trial markers (m); NaN where not seen
    initial_residuals: np.ndarray  # the same at the start: seeded geometry, key-frame inverse kinematics
    summary: SolverSummary
    seed: Seed
    changes: list[ParameterChange]
    times: dict[str, float] = field(default_factory=dict)  # stage -> seconds
    ignored_labels: tuple[str, ...] = ()  # trial labels left out (unknown to the model and on no segment)
    unused_markers: tuple[str, ...] = ()  # model markers the trials never show
    compiled: bool = False
    base_model: Model | None = None  # the model calibrated (without the new markers)
    new_markers: tuple[NewMarker, ...] = ()  # trial markers the base model did not know
    outliers: tuple[Outlier, ...] = ()  # marker positions rejected from the fit
    label_maps: tuple = ()  # per trial: calibrate.io.labels.LabelMapping (trial label -> model label), if mapped
    mass: float | None = None  # subject's body mass (kg): segment masses scaled to it on writing; None: kept
    coordinate_notes: tuple[CoordinateNote, ...] = ()  # what the user should look at (e.g. coordinates driven
    # beyond their limits); `notes` is their text
    held_axes: tuple[str, ...] = ()  # DoFs whose axis calibrate held at the base model's (Settings.auto_hold)
    neutral: int | None = None  # the trial whose mean joint angles the segment frames were turned to zero
    unresolved: tuple = ()  # calibrate.model.resolve.UnresolvedSegment per segment the markers cannot place (locked)
    noise: dict[str, float] = field(default_factory=dict)  # marker -> noise SD used (m): learnt or the user's
    noise_learnt: bool = False  # whether `noise` was learnt from the residuals (Settings.learn_noise)
    noise_weight: dict[str, float] = field(default_factory=dict)  # marker -> SD its residuals were weighted by
    # (m): the noise SD times the square root of its residuals' correlation time in frames (learnt noise only)

    @property
    def notes(self) -> tuple[str, ...]:
        """The coordinate notes as the user reads them."""
        return tuple(n.text() for n in self.coordinate_notes)

    @property
    def trial(self) -> Trial:
        """The first (or only) trial."""
        return self.trials[0]

    @property
    def motion(self) -> Motion:
        """The first (or only) trial's motion; see `motions` for several trials."""
        return self.motions[0]

    def trial_frames(self, i: int) -> slice:
        """Rows of `residuals` that belong to trial i."""
        return _spans(self.trials)[i]

    @property
    def marker_rms(self) -> float:
        """RMS 3-D marker error over every observed marker in every frame (m)."""
        return marker_rms(self.residuals)

    @property
    def marker_max(self) -> float:
        """Largest 3-D marker error (m)."""
        return marker_max(self.residuals)

    @property
    def converged(self) -> bool:
        return self.summary.converged

    @property
    def unidentified(self) -> list[ParameterChange]:
        return [c for c in self.changes if not c.identified]

    def per_marker(self) -> dict[str, tuple[float, float, int]]:
        """Marker name -> (RMS m, max m, frames seen)."""
        out = {}
        err = np.linalg.norm(self.residuals, axis=2)
        for k, name in enumerate(self.model.marker_names):
            e = err[:, k]
            seen = np.isfinite(e)
            if seen.any():
                out[name] = (float(np.sqrt(np.mean(e[seen] ** 2))), float(e[seen].max()), int(seen.sum()))
        return out

    def report(self) -> dict:
        """The report as plain JSON-ready data (mm, degrees, seconds at the edges)."""
        return calibration_report(self)

    def text(self) -> str:
        """A human-readable summary (what the CLI prints)."""
        return summary_text(self)

    def write(self, urdf=None, motion=None, report=None, overwrite: bool = False,
              extra_times: dict[str, float] | None = None) -> dict:
        """Write the subject URDF, motion CSV and report JSON (those given); see report.write_outputs."""
        return write_outputs(self, urdf=urdf, motion=motion, report=report, overwrite=overwrite,
                             extra_times=extra_times)


_rms = marker_rms  # the name tests and scripts import


# ---------------------------------------------------------------------- seed
def seed_parameters(model: Model, trial: Trial, joints: JointEstimates | None = None,
                    extra_markers: Mapping[str, str] | None = None, size: Size | None = None) -> Seed:
    """Scale factors, joint centres and hinge axes from MTB joint-centre trajectories.

    * scale of a segment: the median over frames of the distances between its estimated joint
      centres, over the base model's distances (the subject's median scale where a segment
      has fewer than two estimated centres);
    * each segment's pose per frame: least-squares fit of its base-model markers and joint
      centres (scaled) to the observed markers and estimated centres;
    * a joint centre: its trajectory carried into the parent segment's frame and averaged;
      a hinge axis likewise.  A joint whose estimate failed, or lands further than
      SEED_MAX_SHIFT from the scaled base model, keeps the base model's (and the note says so).

    `extra_markers` (trial label -> segment) adds markers the model does not know to the MTB
    estimate of the joint centres (they are placed on their segments later, in `calibrate`).
    `size` (size_from_markers): the subject's limb sizes from marker distances; a segment without
    estimated centres takes its limb's factor, and so does one whose centres give a factor further
    than SIZE_TOLERANCE from it (an MTB centre off by a few centimetres on a short segment).
    """
    t0 = time.perf_counter()
    notes: list[str] = []
    trial, broken = _without_broken(model, trial)
    if broken:
        notes.append(f"{broken} marker samples left out of the seed (swapped labels or spikes: jumps and back, or "
                     f"distances to markers on the same segment broken)")
    if joints is None:
        thinned = _seed_trial(trial, SEED_FRAMES)
        cutoff = SEED_CUTOFF_HZ if thinned is trial else None  # a thinned trial is low-passed already
        trial = thinned
        try:
            joints = estimate_model_joints(model, trial, cutoff_hz=cutoff, extra_markers=extra_markers)
        except (ValueError, CalibrateError) as e:
            notes.append(f"joint-centre seed unavailable ({e}); starting from the base model"
                         + (" scaled to the markers" if size is not None else ""))
            p0 = model.parameters()
            if size is not None:
                p0.scale[:] = size.scale
            return Seed(p0, tuple(notes), None, time.perf_counter() - t0)
    base = model.parameters()
    geo = model_geometry(model)
    # Only direct MTB solutions seed the geometry: JMV fallbacks and joints seen through a
    # markerless segment are flagged by the joint-centre stage as 10-60 mm uncertain.
    ok = {j.name: j for j in joints if j.ok and j.mtb and not j.note}
    for j in joints:
        if not j.ok:
            notes.append(f"{j.name}: no joint-centre seed ({j.reason}); base model used")
        elif j.name not in ok:
            notes.append(f"{j.name}: joint-centre seed too uncertain ({j.note or j.method}); base model used")
    obs = marker_columns(model, trial)
    # Scale factors from distances between estimated centres within each segment.
    ratios: dict[str, list[float]] = {s.name: [] for s in model.segments}
    for s in model.segments:
        names = [n for n in geo[s.name] if n in ok]
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                d0 = np.linalg.norm(geo[s.name][names[a]] - geo[s.name][names[b]])
                if d0 < 0.05:
                    continue
                d = np.linalg.norm(ok[names[a]].centre - ok[names[b]].centre, axis=1)
                if np.isfinite(d).sum() >= 3:
                    ratios[s.name].append(float(np.nanmedian(d)) / d0)
        if not ratios[s.name]:
            # One estimated centre only (e.g. a shank whose ankle is seen through the markerless
            # talus): its distances to the segment's far markers, each known to about a centimetre.
            for n in names:
                for mk in s.markers:
                    d0 = np.linalg.norm(geo[s.name][mk] - geo[s.name][n])
                    d = np.linalg.norm(obs[:, model.marker_index(mk)] - ok[n].centre, axis=1)
                    if d0 >= SEED_MARKER_LEVER and np.isfinite(d).sum() >= 3:
                        ratios[s.name].append(float(np.nanmedian(d)) / d0)
    known = [np.median(r) for r in ratios.values() if r]
    overall = float(np.median(known)) if known else 1.0
    scale = np.array([float(np.median(ratios[s.name])) if ratios[s.name] else overall for s in model.segments])
    if size is not None:
        for si, sg in enumerate(model.segments):
            if not ratios[sg.name]:
                scale[si] = size.scale[si]
            elif abs(scale[si] / size.scale[si] - 1.0) > SIZE_TOLERANCE:
                notes.append(f"{sg.name}: scale {scale[si]:.2f} from its joint centres is more than "
                             f"{100 * SIZE_TOLERANCE:.0f} % from its limb's {size.scale[si]:.2f} (marker distances); "
                             f"the limb's used")
                scale[si] = size.scale[si]
    scale = np.clip(scale, 0.7, 1.4)
    centre = base.centre.copy()
    axis = base.axis.copy()
    marker = base.marker.copy()
    for si, s in enumerate(model.segments):
        pts_local, pts_world = [], []
        for mk in s.markers:
            k = model.marker_index(mk)
            pts_local.append(scale[si] * base.marker[k])
            pts_world.append(obs[:, k])
        for n, pos in geo[s.name].items():
            if n in ok:
                pts_local.append(scale[si] * pos)
                pts_world.append(ok[n].centre)
        if len(pts_local) < 3:
            continue
        local = np.array(pts_local)
        world = np.stack(pts_world, axis=1)
        w = np.all(np.isfinite(world), axis=2).astype(float)
        R, t = kabsch_batch(local, np.where(w[..., None] > 0, world, 0.0), w)
        valid = np.isfinite(t[:, 0])
        if valid.sum() < 3:
            continue
        # Each marker where the trial shows it in this frame (seed 002's closed form): the global
        # solve then starts near the data instead of at the base model's ~1 cm guesses.
        for mk in s.markers:
            k = model.marker_index(mk)
            use = valid & np.all(np.isfinite(obs[:, k]), axis=1)
            if use.sum() >= 3:
                m_loc = np.einsum("fji,fj->fi", R[use], obs[use, k] - t[use]).mean(0) / scale[si]
                if scale[si] * np.linalg.norm(m_loc - base.marker[k]) <= SEED_MAX_SHIFT:
                    marker[k] = m_loc
        for ji, j in enumerate(model.joints):
            if j.parent != s.name or j.name not in ok:
                continue
            est = ok[j.name]
            use = valid & np.isfinite(est.centre[:, 0])
            if use.sum() < 3:
                continue
            c_loc = np.einsum("fji,fj->fi", R[use], est.centre[use] - t[use]).mean(0)
            c = c_loc / scale[si]
            shift = float(np.linalg.norm(scale[si] * (c - base.centre[ji])))
            if shift > SEED_MAX_SHIFT:
                notes.append(f"{j.name}: seeded centre {1000 * shift:.0f} mm from the scaled base model; "
                             "base model used")
                continue
            centre[ji] = c
            if j.kind == "hinge" and est.axis is not None:
                a_loc = np.einsum("fji,fj->fi", R[use], est.axis[use])
                d = model.dof_index(j.dofs[0])
                u = next(u for u in model.urdf_joints if u.name == j.dofs[0])
                a0 = base.axis[d] / np.linalg.norm(base.axis[d])
                a_loc = a_loc * np.sign(a_loc @ (u.rotation @ a0))[:, None]
                a = u.rotation.T @ np.nanmean(a_loc, axis=0)
                a /= np.linalg.norm(a)
                if math.acos(min(1.0, abs(float(a @ a0)))) <= SEED_MAX_TILT:
                    axis[d] = a
                else:
                    notes.append(f"{j.name}: seeded axis more than {math.degrees(SEED_MAX_TILT):.0f} deg from the "
                                 f"base model's; base model axis used")
    params = Parameters(scale, centre, axis, marker)
    return Seed(params, tuple(notes), joints, time.perf_counter() - t0)


@dataclass(frozen=True)
class Size:
    """The subject's size from the markers alone (size_from_markers): per segment, limb and overall."""

    scale: np.ndarray  # (n_segments,) factor of each segment: its limb's
    limbs: dict[str, float]  # limb (named by its first segment) -> factor (median of its pairs' ratios)
    overall: float  # median ratio over every pair
    pairs: int  # marker pairs used


SIZE_POSES = 60  # random poses (angles anywhere in their ranges): is a marker pair's distance pose-independent?
SIZE_MODEL_CV = 0.01  # a pair is used if its distance varies by less than this fraction over those poses ...
SIZE_TRIAL_CV = 0.05  # ... and over the trial's frames (robust: 1.4826 MAD / median)
SIZE_MIN_DISTANCE = 0.10  # m: closer pairs (a centimetre of marker placement is 10 % of them) are not used
SEED_BROKEN_SDS = 6.0  # a rigid marker pair's distance this many robust SDs from its median over the trial ...
SEED_BROKEN_MIN = 0.010  # m ... and at least this far: a swapped label or a spike (broken_samples)
SEED_JUMP_MIN = 0.02  # m: a marker's frame-to-frame step this far from the steps around it is a jump ...
SEED_JUMP_SDS = 8.0  # ... if also this many robust SDs of the marker's own (jump_episodes)
SEED_JUMP_WINDOW = 3  # frames each side whose steps' median predicts a step
SEED_JUMP_UNDO = 0.5  # two jumps undo each other when their sum is shorter than this fraction of the larger
SEED_EPISODE_S = 1.0  # s: a spike or swapped-label episode lasts at most this long
SEED_BROKEN_GROUP = 12  # a segment with more markers is not checked (2^n candidate sets)
SIZE_TOLERANCE = 0.15  # a seeded segment scale further than this fraction from its limb's is replaced by the limb's


def limb_groups(model: Model) -> dict[str, list[int]]:
    """Segments grouped into limbs: each trunk segment alone (the root and every segment with two or
    more child joints: pelvis, torso) and each chain hanging from them (a leg, an arm, the head), named
    by its first segment."""
    kids: dict[str, list[str]] = {s.name: [] for s in model.segments}
    for j in model.joints:
        kids[j.parent].append(j.child)
    trunk = {model.segments[0].name} | {n for n, k in kids.items() if len(k) >= 2}
    out: dict[str, list[int]] = {n: [model.segment_index(n)] for n in sorted(trunk, key=model.segment_index)}

    def walk(name: str, into: list[int]) -> None:
        into.append(model.segment_index(name))
        for k in kids[name]:
            if k not in trunk:
                walk(k, into)

    for t in trunk:
        for k in kids[t]:
            if k not in trunk:
                out[k] = []
                walk(k, out[k])
    return out


def size_from_markers(model: Model, trials: Sequence[Trial], seed: int = 0) -> Size | None:
    """The subject's size against the base model, from marker distances only (before any joint
    centre is known): every pair of model markers whose distance is the same in any pose of the base
    model (the same segment, or across a joint near its axis: knee to ankle markers) and steady over
    the trials' frames, compared with the base model's (median over frames / neutral pose); a limb's
    factor is the median of the ratios of its pairs (a leg: thigh, shank and foot markers), the
    overall factor the median of all.  None if no pair qualifies."""
    import pinocchio as pin

    names = [m.name for m in model.markers]
    seg = np.array([model.segment_index(m.segment) for m in model.markers])
    pm = model.pin
    data = pm.createData()
    fid = [pm.getFrameId(n) for n in names]
    rng = np.random.default_rng(seed)
    lo = np.array([d.lower if np.isfinite(d.lower) else -math.pi for d in model.dofs])
    hi = np.array([d.upper if np.isfinite(d.upper) else math.pi for d in model.dofs])
    poses = []
    for i in range(SIZE_POSES + 1):
        a = np.zeros(model.n_dofs) if i == 0 else rng.uniform(lo, hi)
        pin.framesForwardKinematics(pm, data, model.pin_configuration(np.zeros(3), [0, 0, 0, 1], a))
        poses.append(np.array([data.oMf[f].translation for f in fid]))
    P = np.array(poses)  # (poses, markers, 3)
    D = np.linalg.norm(P[:, :, None] - P[:, None, :], axis=3)
    d0 = D[0]
    model_cv = D.std(axis=0) / np.maximum(d0, 1e-9)
    # The trials' distances, on at most ~300 frames of each.
    parts = []
    for t in trials:
        X = np.full((t.n_frames, len(names), 3), np.nan)
        have = [k for k, n in enumerate(names) if n in t.labels]
        X[:, have] = t.select([names[k] for k in have]).markers
        parts.append(X[:: max(1, t.n_frames // 300)])
    X = np.concatenate(parts)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        Dt = np.linalg.norm(X[:, :, None] - X[:, None, :], axis=3)
        med = np.nanmedian(Dt, axis=0)
        mad = MAD_SD * np.nanmedian(np.abs(Dt - med), axis=0)
        n = np.sum(np.isfinite(Dt), axis=0)
    ok = ((model_cv < SIZE_MODEL_CV) & (n >= 3) & (mad < SIZE_TRIAL_CV * med) & (d0 >= SIZE_MIN_DISTANCE)
          & np.triu(np.ones_like(d0, dtype=bool), 1))
    a, b = np.nonzero(ok)
    if a.size == 0:
        return None
    ratio = med[a, b] / d0[a, b]
    # A marker sits a few centimetres from where the base model puts it (wands above all: Plug-in
    # Gait's TIB marker is 10 cm lower than ours), which changes a pair's ratio by about that over its
    # length: the weighted median, weight d0², trusts the long pairs (knee to ankle) most.
    wt = d0[a, b] ** 2
    overall = _weighted_median(ratio, wt)
    limbs = limb_groups(model)
    scale = np.full(len(model.segments), overall)
    factors: dict[str, float] = {}
    for name, segs in limbs.items():
        inside = np.isin(seg[a], segs) & np.isin(seg[b], segs)
        if inside.sum() >= 1:
            factors[name] = _weighted_median(ratio[inside], wt[inside])
            scale[segs] = factors[name]
    return Size(np.clip(scale, 0.7, 1.4), factors, overall, int(a.size))


def broken_samples(model: Model, trial: Trial) -> np.ndarray:
    """(n_frames, n_model_markers) True where a marker sample breaks the distances it keeps to the other
    markers of its segment: a swapped label or a spike.

    A pair is broken in a frame when its distance is further than SEED_BROKEN_SDS robust SDs (and
    SEED_BROKEN_MIN) from its median over the trial (pairs whose distance is not steady over the
    trial, SIZE_TRIAL_CV, are not used).  Within a segment, a frame keeps the markers common to every
    largest set with no broken pair among them: one marker off is flagged alone, two swapped labels
    both, and when the distances cannot tell which markers are wrong (two markers alone, or a swap on
    a near-symmetric segment) all of them."""
    X = marker_columns(model, trial)
    flagged = np.zeros(X.shape[:2], dtype=bool)
    seen = np.all(np.isfinite(X), axis=2)
    for sg in model.segments:
        members = np.array([model.marker_index(m) for m in sg.markers])
        if members.size < 2 or members.size > SEED_BROKEN_GROUP:
            continue
        ia, ib = np.triu_indices(members.size, 1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            d = np.linalg.norm(X[:, members[ia]] - X[:, members[ib]], axis=2)  # (F, pairs)
            med = np.nanmedian(d, axis=0)
            mad = MAD_SD * np.nanmedian(np.abs(d - med), axis=0)
            steady = (np.sum(np.isfinite(d), axis=0) >= MIN_FRAMES) & (mad < SIZE_TRIAL_CV * med)
            broken = (np.abs(d - med) > np.maximum(SEED_BROKEN_SDS * mad, SEED_BROKEN_MIN)) & steady
        frames = np.flatnonzero(broken.any(axis=1))
        if frames.size == 0:
            continue
        subsets = (np.arange(2 ** members.size)[:, None] >> np.arange(members.size)) & 1  # (S, n)
        both = (subsets[:, ia] & subsets[:, ib]).T.astype(float)  # (pairs, S): pair inside the subset
        consistent = (broken[frames].astype(float) @ both) == 0  # (frames, S)
        vis = seen[np.ix_(frames, members)]
        size = np.where(consistent, vis.astype(float) @ subsets.T, -1.0)
        largest = size == size.max(axis=1, keepdims=True)
        keep = (largest.astype(float) @ (1 - subsets)) == 0  # in every largest consistent set
        flagged[np.ix_(frames, members)] = vis & ~keep
    return flagged


def jump_episodes(trial: Trial) -> np.ndarray:
    """(n_frames, n_markers) True where a marker trajectory sits between a jump and the jump that undoes
    it (a spike: one frame; a swapped label: until the labels swap back).  A jump is a frame-to-frame
    step further than SEED_JUMP_MIN (and SEED_JUMP_SDS robust SDs of the marker's own) from the median
    of the steps around it (SEED_JUMP_WINDOW frames each side: constant acceleration cancels); two
    jumps of one marker at most SEED_EPISODE_S apart, with no gap between, that undo each other (their
    sum shorter than SEED_JUMP_UNDO of the larger) bound an episode."""
    X = np.asarray(trial.markers)
    F = X.shape[0]
    out = np.zeros(X.shape[:2], dtype=bool)
    if F < 2 * SEED_JUMP_WINDOW + 2:
        return out
    longest = max(1, int(round(SEED_EPISODE_S * trial.rate)))
    W = SEED_JUMP_WINDOW
    pad = np.full((W, 3), np.nan)
    for k in range(X.shape[1]):  # one marker at a time: memory stays 2W x the trajectory
        x = X[:, k]
        d = np.diff(x, axis=0)  # (F-1, 3): step into frame f+1; NaN across gaps
        dp = np.concatenate([pad, d, pad])
        around = np.stack([dp[W + o: W + o + len(d)] for o in range(-W, W + 1) if o], axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            s = d - np.nanmedian(around, axis=0)  # (F-1, 3)
            size = np.linalg.norm(s, axis=1)
            sd = MAD_SD * np.nanmedian(size)
        jump = np.isfinite(size) & (size > max(SEED_JUMP_SDS * float(np.nan_to_num(sd)), SEED_JUMP_MIN))
        steps = np.flatnonzero(jump)
        seen = np.all(np.isfinite(x), axis=1)
        i = 0
        while i < steps.size - 1:
            a, b = steps[i], steps[i + 1]  # jumps into frames a+1 and b+1
            undo = np.linalg.norm(s[a] + s[b]) <= SEED_JUMP_UNDO * max(size[a], size[b])
            if undo and b - a <= longest and seen[a + 1:b + 1].all():
                out[a + 1:b + 1, k] = True
                i += 2
            else:
                i += 1
    return out


def jumped_samples(model: Model, trials: Sequence[Trial]) -> np.ndarray:
    """(frames of all trials, n_model_markers): each trial's jump_episodes in the model's marker order,
    stacked as the calibration stacks the trials."""
    parts = []
    for t in trials:
        jumps = jump_episodes(t)
        index = {lab: i for i, lab in enumerate(t.labels)}
        out = np.zeros((t.n_frames, len(model.markers)), dtype=bool)
        for k, name in enumerate(model.marker_names):
            if name in index:
                out[:, k] = jumps[:, index[name]]
        parts.append(out)
    return np.concatenate(parts)


def _without_broken(model: Model, trial: Trial) -> tuple[Trial, int]:
    """`trial` with the samples broken_samples and jump_episodes flag set to gaps, and how many there were."""
    index = {lab: i for i, lab in enumerate(trial.labels)}
    bad = jump_episodes(trial)
    rigid = broken_samples(model, trial)
    for k, name in enumerate(model.marker_names):
        if name in index:
            bad[:, index[name]] |= rigid[:, k]
    if not bad.any():
        return trial, 0
    markers = np.array(trial.markers)
    markers[bad] = np.nan
    return replace(trial, markers=markers), int(bad.sum())


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The value below and above which lie at most half the total weight."""
    order = np.argsort(x)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def _seed_trial(trial: Trial, max_frames: int) -> Trial:
    """The trial low-passed at SEED_CUTOFF_HZ and thinned to about `max_frames` evenly spaced
    frames: the MTB seed's cost grows with the frames and it needs only a few hundred."""
    k = trial.n_frames // max_frames
    if k < 2 or not SEED_CUTOFF_HZ < trial.rate / 2:
        return trial
    markers = lowpass(trial.markers, trial.rate, SEED_CUTOFF_HZ)[::k]
    return Trial(trial.labels, markers, trial.rate / k, trial.first_frame, trial.source)


# ---------------------------------------------------------------------- start
def start_poses(kin: Kinematics, observed: np.ndarray, params: Parameters, stride: int = STRIDE,
                evaluator: Callable | None = None) -> State:
    """Per-frame coordinates for fixed geometry: frame-wise IK on every `stride`-th frame (warm-started
    key frame to key frame, the first from a global search), interpolated in between (slerp for
    the root rotation).  Frames with fewer than 3 markers take the nearest key frame's pose.
    `evaluator`: a faster per-frame (markers, d markers/dz) at `params` (Problem.frame_evaluator)."""
    model = kin.model
    F = observed.shape[0]
    p = params.vector()
    solver = _FrameSolver(kin, p, evaluator)
    seen = np.all(np.isfinite(observed), axis=2)
    usable = np.flatnonzero(seen.sum(1) >= 3)
    keys = usable[::stride]
    if keys.size and keys[-1] != usable[-1]:
        keys = np.append(keys, usable[-1])
    Zk = np.zeros((keys.size, model.nz))
    Qk = np.zeros((keys.size, kin.n_refs))  # refs: root, then every SO(3) ball (calibrate.model.kinematics)
    z = q = None
    fits: list[float] = []
    for i, f in enumerate(keys):
        idx = np.flatnonzero(seen[f])
        if z is None:
            z, q = solver.global_start(observed[f], seen[f])
            budget = 200
        else:
            budget = 30
        z, q, cost, _ = solver.solve(z, q, observed[f], idx, np.arange(model.nz), budget, 1e-8)
        fits.append(math.sqrt(cost / idx.size))
        Zk[i], Qk[i] = z, q
    frames = np.arange(F)
    Z = np.zeros((F, model.nz))
    if keys.size == 1:
        Z[:] = Zk[0]
        Q = np.tile(Qk[0], (F, 1))
    else:
        for c in range(model.nz):
            Z[:, c] = np.interp(frames, keys, Zk[:, c])
        Q = np.empty((F, Qk.shape[1]))
        inside = np.clip(frames, keys[0], keys[-1])
        for s in range(0, Qk.shape[1], 4):  # slerp each reference rotation
            Q[:, s:s + 4] = Slerp(keys, Rotation.from_quat(Qk[:, s:s + 4]))(inside).as_quat()
    Q = Q.reshape(F, -1, 4)
    Q = np.where(Q[..., 3:4] < 0, -Q, Q)
    Z[:, FrameLayout.rotation] = 0.0
    return State(Z, Q[:, 0].copy(), p.copy(), Q[:, 1:].copy())


# ---------------------------------------------------------------------- calibrate
def calibrate(model: Model, trials: Trial | Sequence[Trial], settings: Settings | None = None, *,
              marker_map: Mapping[str, Sequence[str]] | None = None, aliases: bool = True,
              kinematics: Kinematics | None = None, mass: float | None = None, neutral: int | None = None,
              progress: Callable[[Progress], None] | None = None) -> Calibration:
    """Calibrate `model` to one trial or several trials of one subject: the subject's scales, joint
    centres, hinge axes and marker positions (shared by every trial), and every frame's
    coordinates, in one least-squares problem (module docstring).

    Trial labels are first renamed to the model's: by `marker_map` (model label -> trial labels,
    calibrate.io.labels.load_marker_map) and, with `aliases`, the common spellings of the same
    landmarks (R.ASIS, RASIS -> RASI; calibrate.io.labels).  Labels the model still does not know are
    placed on segments by rigidity and fitted like the model's markers (``Settings.new_markers``);
    those that fit no segment are left out and listed.
    `mass`: the subject's body mass (kg); the written model's segment masses (and inertias) are
    the base model's scaled to it, as OpenSim's Scale tool does (None: the base model's kept).
    `neutral`: index of the trial in which the subject stands in the model's neutral pose (a static
    trial): every segment frame that markers do not fix (see docs/calibration.md, gauges) is turned
    so that the joint angles of that trial are zero on average, as a lab's static calibration
    defines them (None: the frames sit where the priors put them).
    `progress` receives a Progress record (calibrate.calibration.records) per step (its stage and
    text; str() is the line to show).
    Raises CalibrateError with one line if the trials and model share too few markers or frames.
    """
    trials = (trials,) if isinstance(trials, Trial) else tuple(trials)
    mass_factor(model, mass)  # a bad mass fails now, not after the solve
    if not trials:
        raise CalibrateError("no trial given; pass at least one Trial")
    for t in trials:
        if not isinstance(t, Trial):
            raise CalibrateError(f"expected Trial objects (calibrate.read_trial), got {type(t).__name__}")
    # The linear algebra here is many small blocks plus one Schur complement: one BLAS thread is
    # faster than several (which also fight CasADi's two evaluation threads for the cores).
    label_maps: tuple = ()
    if marker_map or aliases:
        from ..io.labels import map_labels

        mapped = [map_labels(t, model.marker_names, marker_map, aliases=aliases) for t in trials]
        trials = tuple(t for t, _ in mapped)
        label_maps = tuple(m for _, m in mapped)
    # A model imported from OpenSim locks its locked coordinates (calibrate.io.osim), unless settings lock them.
    settings = with_locked(model, settings or Settings())
    known = set(model.marker_names).union(*(t.labels for t in trials))
    unknown = [label for label, _ in settings.marker_noise if label not in known]
    if unknown:
        raise CalibrateError(f"marker_noise: '{unknown[0]}' is neither a marker of {model.path.name} nor a trial "
                             f"label; use one of their labels ({', '.join(model.marker_names[:6])}, ...)")
    bad = [name for name, _ in settings.lock if name not in model.dof_names]
    if bad:
        raise CalibrateError(f"lock: '{bad[0]}' is not a coordinate of {model.path.name}; use one of its DoF names "
                             f"({', '.join(model.dof_names[:6])}, ...; see calibrate inspect)")
    axis_dofs = [d for j in model.joints if j.kind in ("hinge", "universal") for d in j.dofs]
    bad = [name for name in settings.hold_axes if name not in axis_dofs]
    if bad:
        raise CalibrateError(f"hold_axes: '{bad[0]}' is not a hinge or universal-joint coordinate of "
                             f"{model.path.name}; use one of {', '.join(axis_dofs[:6])}, ... (see calibrate inspect)")
    if neutral is not None and not (isinstance(neutral, int) and 0 <= neutral < len(trials)):
        raise CalibrateError(f"neutral: {neutral!r} is not the index of one of the {len(trials)} trials "
                             f"(0 for the first)")
    with threadpool_limits(limits=1, user_api="blas"):
        cal = _calibrate(model, trials, settings, kinematics, progress, neutral)
    return replace(cal, label_maps=label_maps, mass=None if mass is None else float(mass), neutral=neutral)


def _calibrate(model: Model, trials: tuple[Trial, ...], settings: Settings, kinematics: Kinematics | None,
               progress: Callable[[Progress], None] | None, neutral: int | None = None) -> Calibration:
    say = _announcer(progress)
    times: dict[str, float] = {}
    where = ", ".join(t.source or "trial" for t in trials)
    if len(model.markers) == 0:
        raise CalibrateError(f"{model.path}: the model has no markers; add marker links (see docs/model-format.md)")
    known = set(model.marker_names)
    labels = list(dict.fromkeys(lab for t in trials for lab in t.labels))  # first trial's order first
    shared = [lab for lab in model.marker_names if lab in set(labels)]
    if len(shared) < 3:
        raise CalibrateError(f"{where}: only {len(shared)} of its labels match markers of {model.path.name} "
                             f"(model markers: {', '.join(model.marker_names[:6])}, ...); rename the labels "
                             f"(--markers map.toml) or use a model with this marker set")
    t0 = time.perf_counter()
    # Unlabelled trajectories (Vicon's '*115'): ghosts, reflections or markers the operator left
    # unnamed; nothing says which landmark they are, so they are never placed as new markers.
    unknown = [lab for lab in labels if lab not in known and not UNLABELLED.fullmatch(lab)]
    placed: list[NewMarker] = []
    if unknown and settings.new_markers:
        say(Progress("markers", f"placing {len(unknown)} trial markers the model does not know"))
        placed = _assign_new_markers(model, trials, unknown)
    new = {m.label: m.segment for m in placed if m.segment is not None}
    ignored = tuple(lab for lab in labels if lab not in known and lab not in new)
    subject = add_markers(model, {lab: (seg, np.zeros(3)) for lab, seg in new.items()}) if new else model
    # Segments the markers cannot place (calibrate.model.resolve): refuse without a root pose, else lock
    # the coordinates the markers do not see (their segments ride on their parents).
    from ..model.resolve import resolve

    res = resolve(subject, [*shared, *new], locked=[d for d, _ in settings.lock])
    if not res.root_resolved:
        raise CalibrateError(f"{where}: its {len(shared)} markers shared with {model.path.name} cannot place the "
                             f"{model.root} (unresolved: {', '.join(res.names)}); rename the trial labels "
                             f"(--markers map.toml) or use a model with this marker set")
    if res.lock:
        say(Progress("markers", f"{len(res.segments)} segments unresolved ({', '.join(res.names)}); locking "
                                f"{', '.join(res.lock)}"))
        settings = replace(settings, lock=settings.lock + tuple(
            (d, float(np.clip(0.0, subject.dofs[subject.dof_index(d)].lower, subject.dofs[subject.dof_index(d)].upper)))
            for d in res.lock))
    obs = np.concatenate([marker_columns(subject, t) for t in trials])
    spans = _spans(trials)
    seen = np.all(np.isfinite(obs), axis=2)
    unused = tuple(n for k, n in enumerate(subject.marker_names) if not seen[:, k].any() and n in known)
    blind = _segments_without_data(subject, {n for k, n in enumerate(subject.marker_names) if seen[:, k].any()})
    if blind:  # nothing in the data reaches their geometry: held at the base model's (Settings.hold_segments)
        settings = replace(settings, hold_segments=tuple(sorted(set(settings.hold_segments) | set(blind))))
    n_good = int(np.sum(seen.sum(1) >= 3))
    if n_good < MIN_FRAMES:
        raise CalibrateError(f"{where}: only {n_good} frames show 3 or more of the model's markers; "
                             f"need at least {MIN_FRAMES} (check the labels and gaps)")
    if settings.seed:
        say(Progress("seed", "the subject's size from marker distances, then joint centres (MTB)"))
        size = size_from_markers(model, trials)
        pick = _most_motion(model, trials)
        seed = seed_parameters(model, trials[pick], extra_markers=new, size=size)
        if len(trials) > 1:
            seed = Seed(seed.params, (f"seeded from {trials[pick].source or f'trial {pick + 1}'} (the trial with "
                                      f"the most joint motion)", *seed.notes), seed.joints, seed.seconds)
    else:
        seed = Seed(model.parameters(), ("seed switched off; starting from the base model",), None, 0.0)
    if "scale" not in settings.free:
        seed = Seed(Parameters(np.ones_like(seed.params.scale), *(getattr(seed.params, b) for b in ("centre", "axis",
                                                                                                     "marker"))),
                    seed.notes, seed.joints, seed.seconds)
    params0 = _on_model(subject, model, _fixed_groups(model.parameters(), seed.params, settings.free))
    params0 = _hold_segments(subject, params0, settings.hold_segments)
    times["seed"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(Progress("build", "residuals and Jacobian (CasADi)"))
    kin = kinematics if kinematics is not None and subject is model else build_kinematics(subject)
    # Swapped labels and spikes that jump away and back are left out before the start and the solve (as
    # from the seed): a few frames of a knee and an ankle label exchanged drag a leg into a wrong minimum
    # before the solve's own outlier rejection can see them.  They are reported with the other outliers.
    jumped = jumped_samples(subject, trials) if settings.outliers > 0 else np.zeros(obs.shape[:2], dtype=bool)
    raw = obs
    if jumped.any():
        say(Progress("markers", f"{int(jumped.sum())} positions jump away and back (swapped labels, spikes); "
                                "left out"))
        obs = np.where(jumped[..., None], np.nan, obs)
    problem = Problem(subject, obs, settings, kin, progress=say)
    times["build"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(Progress("start", "frame-wise inverse kinematics"))
    is_new = np.array([n in new for n in subject.marker_names])
    known_obs = np.where(is_new[None, :, None], np.nan, obs)  # new markers have no place yet: poses from the others
    if settings.seed:
        base0 = _hold_segments(subject, _on_model(subject, model, model.parameters()), settings.hold_segments)
        params0, choice = choose_start(problem, known_obs, spans, {"the MTB seed": params0, "the base model": base0},
                                       say)
        seed = replace(seed, notes=(*seed.notes, choice))
    evaluator = problem.frame_evaluator(params0.vector())
    start = _stack_states([start_poses(problem.kin, known_obs[sl], params0, evaluator=evaluator) for sl in spans])
    if new:
        params0, base, placed = _place_new_markers(subject, problem.kin, start, obs, params0, placed)
        problem = problem.with_base(base)
        start = replace(start, p=params0.vector())
    times["start"] = time.perf_counter() - t0
    initial = problem.marker_residuals(start)
    t0 = time.perf_counter()
    in_neutral = None
    if neutral is not None:
        in_neutral = np.zeros(problem.F, dtype=bool)
        in_neutral[spans[neutral]] = True
    problem, state, summary, scatter = _solve(problem, start, spans, say)
    held = tuple(d for d in problem.settings.hold_axes if d not in settings.hold_axes)
    settings = problem.settings
    rejected: list[Outlier] = []
    hit = np.zeros(problem.F, dtype=bool)  # frames with a rejected marker position
    fixed = _fixed_noise(subject, settings)
    trial_of = np.concatenate([np.full(sl.stop - sl.start, i) for i, sl in enumerate(spans)])
    reweighed = False  # the noise was learnt again and nothing solved since
    for _ in range(OUTLIER_PASSES if settings.outliers > 0 else 0):
        # One spike drags its frame's pose, so every marker of that frame looks bad: reject only the
        # worst marker of each frame, re-solve those poses, and look again.
        found = 0
        for _ in range(OUTLIER_ROUNDS):
            bad, err = _outliers(problem, state, settings, scatter, trial_of)
            if not bad.any():
                break
            worst = np.where(bad, err, -1.0).argmax(axis=1)
            frames = np.flatnonzero(bad.any(axis=1))
            bad = np.zeros_like(bad)
            bad[frames, worst[frames]] = True
            for f, k in zip(frames, worst[frames], strict=True):
                i = next(i for i, sl in enumerate(spans) if sl.start <= f < sl.stop)
                rejected.append(Outlier(i, int(f - spans[i].start), subject.marker_names[k], float(err[f, k])))
            found += frames.size
            say(Progress("solve", f"{frames.size} marker positions rejected as outliers"))
            problem = problem.without(bad)
            # A spike or a swapped label drags its frame's pose (a leg folded to reach a swapped ankle
            # marker) further than a few steps undo: such frames restart from their unaffected neighbours'.
            new_hit = np.zeros_like(hit)
            new_hit[frames[~hit[frames]]] = True
            hit |= new_hit
            state = _bridge(state, new_hit, hit, spans)
            state, _ = levenberg_marquardt(problem, state, settings.solver, pose_only=True, max_iterations=10)
        if not found and not reweighed:
            break
        say(Progress("solve", "again without the outliers" if found else "again with the noise learnt again"))
        state, again = levenberg_marquardt(problem, state, settings.solver)
        summary = _merge(summary, again)
        reweighed = False
        if fixed is None or not found:
            break
        # The scatter measured before, at a fit dragged by what is now left out, was too large: measure
        # it again and, if it changed, look for outliers against it and solve again.
        sigma, scatter = _relearn(problem, state, fixed, say, trial_of)
        if sigma is None:
            break
        problem = problem.with_noise(sigma)
        reweighed = True
    if reweighed:
        state, again = levenberg_marquardt(problem, state, settings.solver)
        summary = _merge(summary, again)
    if in_neutral is not None:
        # Last: a change of gauge (the data fit stays), so no solve may follow and undo it.
        say(Progress("solve", f"segment frames turned to zero joint angles in "
                              f"{trials[neutral].source or 'the neutral trial'}"))
        state = align_neutral(problem, state, in_neutral)
        summary = replace(summary, final_cost=problem.cost(state), termination=summary.termination
                          + "; then the segment frames turned to the neutral trial (the priors' cost changes)")
    times["solve"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    lin = problem.linearize(state, reuse=True)
    cov = covariance(problem, state, lin)
    params = subject.unpack(state.p)
    changes = parameter_changes(problem, state.p, cov.matrix, cov.prior_only)
    Z, Q = absolute(problem.kin, state, spans)
    notes = coordinate_notes(subject, FrameLayout.angles(Z), lin.A, settings)
    times["covariance"] = time.perf_counter() - t0
    if jumped.any():  # their distance from where the fitted model puts them
        Zr = FrameLayout.coordinates(Z[:, FrameLayout.translation], FrameLayout.angles(Z))
        err = np.linalg.norm(problem.kin.batch(Zr, Q, params)[0] - raw, axis=2)
        rejected = [Outlier(int(trial_of[f]), int(f - spans[trial_of[f]].start), subject.marker_names[k],
                            float(err[f, k])) for f, k in np.argwhere(jumped)] + rejected
    residuals = problem.marker_residuals(state)
    motions = tuple(Motion(t.times.copy(), Z[sl, FrameLayout.translation].copy(), Q[sl].copy(),
                           FrameLayout.angles(Z[sl]).copy(),
                           subject.dof_names) for t, sl in zip(trials, spans, strict=True))
    return Calibration(subject, trials, settings, params, motions, residuals, initial, summary, seed, changes,
                       times, ignored, unused, problem.compiled, base_model=model, new_markers=tuple(placed),
                       outliers=tuple(rejected), coordinate_notes=notes, held_axes=held, unresolved=res.segments,
                       noise={n: float(v) for n, v in zip(subject.marker_names, scatter, strict=True)},
                       noise_weight={n: float(v) for n, v in zip(subject.marker_names, problem.sigma, strict=True)},
                       noise_learnt=settings.learns_noise)


def coordinate_notes(model: Model, angles: np.ndarray, A: np.ndarray,
                     settings: Settings) -> tuple[CoordinateNote, ...]:
    """still_records, then limit_records for the coordinates not already named."""
    still = still_records(model, angles, A, settings)
    named = {n.coordinate for n in still}
    return still + tuple(n for n in limit_records(model, angles, settings) if n.coordinate not in named)


def still_coordinates(model: Model, angles: np.ndarray, A: np.ndarray,
                      settings: Settings) -> list[tuple[str, float, float]]:
    """The coordinates (not locked) whose estimated motion is no larger than the noise: their spread
    over the frames (SD) below STILL_RATIO times the SD with which one frame's markers fix them (the
    median over frames of sqrt((A_f⁻¹)_kk), A_f the frame's normal-equation block).  Such a joint
    did not move as far as the trial shows, so nothing pins its axis or its angle's zero, and the
    fit can trade them for noise (a still subtalar joint under a two-marker foot ends at its
    widened limit with its axis turned tens of degrees).  (name, spread, per-frame SD) in rad."""
    locked = {n for n, _ in settings.lock}
    nz = A.shape[1]
    A = A[np.unique(np.linspace(0, len(A) - 1, min(len(A), 500)).astype(int))]  # a median needs no more
    # A ridge at one global scale: a frame (or direction) with no data gets a huge SD, not a failure.
    ridge = 1e-12 * max(float(np.max(np.abs(np.diagonal(A, axis1=1, axis2=2)), initial=0.0)), 1e-300)
    cov = np.linalg.inv(A + ridge * np.eye(nz))
    sd = np.sqrt(np.maximum(FrameLayout.angles(np.diagonal(cov, axis1=1, axis2=2)), 0.0))
    out = []
    for k, d in enumerate(model.dofs):
        if d.name in locked:
            continue
        spread, per_frame = float(np.std(angles[:, k])), float(np.median(sd[:, k]))
        if spread < STILL_RATIO * per_frame:
            out.append((d.name, spread, per_frame))
    return out


def still_records(model: Model, angles: np.ndarray, A: np.ndarray, settings: Settings) -> tuple[StillNote, ...]:
    """A note per coordinate that still_coordinates names, with what was done and what to do."""
    return tuple(StillNote(name, spread, per_frame, name in settings.hold_axes)
                 for name, spread, per_frame in still_coordinates(model, angles, A, settings))


def still_notes(model: Model, angles: np.ndarray, A: np.ndarray, settings: Settings) -> tuple[str, ...]:
    """still_records as the user reads them."""
    return tuple(n.text() for n in still_records(model, angles, A, settings))


def limit_records(model: Model, angles: np.ndarray, settings: Settings) -> tuple[LimitNote, ...]:
    """A note per coordinate that the fit drove beyond the base model's joint limits (by more than
    LIMIT_NOTE_DEG) in more than LIMIT_NOTE_FRACTION of the frames.  A coordinate the markers cannot
    resolve (a joint that did not move, under a segment with too few markers) drifts like this, and
    the geometry around it with it; one the subject really moved past the model's range does too."""
    locked = {n for n, _ in settings.lock}
    tol = math.radians(LIMIT_NOTE_DEG)
    out = []
    for k, d in enumerate(model.dofs):
        if d.name in locked or not (np.isfinite(d.lower) and np.isfinite(d.upper)):
            continue
        th = angles[:, k]
        beyond = (th < d.lower - tol) | (th > d.upper + tol)
        if beyond.mean() > LIMIT_NOTE_FRACTION:
            out.append(LimitNote(d.name, float(beyond.mean()), float(np.max(np.maximum(d.lower - th, th - d.upper)))))
    return tuple(out)


def limit_notes(model: Model, angles: np.ndarray, settings: Settings) -> tuple[str, ...]:
    """limit_records as the user reads them."""
    return tuple(n.text() for n in limit_records(model, angles, settings))


def _spans(trials: Sequence[Trial]) -> list[slice]:
    """Each trial's frames in the stacked problem."""
    out, at = [], 0
    for t in trials:
        out.append(slice(at, at + t.n_frames))
        at += t.n_frames
    return out


def _stack_states(states: Sequence[State]) -> State:
    B = None if any(s.B is None for s in states) else np.concatenate([s.B for s in states])
    return State(np.concatenate([s.Z for s in states]), np.concatenate([s.Q for s in states]), states[0].p.copy(), B)


def _hold_segments(model: Model, params: Parameters, segments: Sequence[str]) -> Parameters:
    """`params` with the base model's geometry on `segments` (Settings.hold_segments): their scale, the
    joint centres and markers in them, the axes of the joints into them."""
    if not segments:
        return params
    out, base, held = params.copy(), model.parameters(), set(segments)
    for i, sg in enumerate(model.segments):
        if sg.name in held:
            out.scale[i] = base.scale[i]
    for ji, j in enumerate(model.joints):
        if j.parent in held:
            out.centre[ji] = base.centre[ji]
        if j.child in held:
            for d in j.dofs:
                out.axis[model.dof_index(d)] = base.axis[model.dof_index(d)]
    for k, mk in enumerate(model.markers):
        if mk.segment in held:
            out.marker[k] = base.marker[k]
    return out


def _segments_without_data(model: Model, seen: set[str]) -> list[str]:
    """Segments with no seen marker on them or on any segment below them in the tree."""
    below: dict[str, bool] = {}
    for j in reversed(model.joints):  # children after parents in model order: walk leaves first
        below[j.child] = below.get(j.child, False) or any(m in seen for m in model.segments[
            model.segment_index(j.child)].markers)
        below[j.parent] = below.get(j.parent, False) or below[j.child]
    root = model.segments[0].name
    below[root] = below.get(root, False) or any(m in seen for m in model.segments[0].markers)
    return [s.name for s in model.segments if not below.get(s.name, False)]


def _frames(state: State, idx) -> State:
    """`state` on some of its frames (an index array or a slice)."""
    return State(state.Z[idx], state.Q[idx], state.p, None if state.B is None else state.B[idx])


def absolute(kin: Kinematics, state: State, spans: Sequence[slice] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's URDF coordinates (Z with absolute joint angles, root quaternions Q) of a solver
    state of a problem with kinematics `kin`, the ball angles continuous within each trial of
    `spans` (Kinematics.absolute)."""
    spans = spans or [slice(0, state.Z.shape[0])]
    parts = [kin.absolute(state.Z[sl], state.Q[sl], None if state.B is None else state.B[sl])
             for sl in spans]
    return np.concatenate([z for z, _ in parts]), np.concatenate([q for _, q in parts])


def choose_start(problem: Problem, observed: np.ndarray, spans: Sequence[slice], candidates: Mapping[str, Parameters],
                 say: Callable[[str], None]) -> tuple[Parameters, str]:
    """The start whose basin fits best: each candidate geometry (e.g. the MTB seed and the base
    model) solved with its poses on the subsample of frames the global solve starts from (the
    markers the model knows; the problem's settings before any noise is learnt), and the one that
    ends at the lowest cost kept.  Real trials need this: the MTB seed is only as good as the
    joints' motion lets it be (a walking trial's elbows flex 10-15 deg), and an arm started a few
    per cent too long or short settles in a basin with its elbow tens of degrees off, which no
    later step leaves; the cost, the same objective on the same frames, tells the basins apart.
    Returns the chosen geometry and a note naming each candidate's cost."""
    names = list(candidates)
    if len(names) == 1:
        return candidates[names[0]], f"started from {names[0]}"
    seen = np.all(np.isfinite(observed), axis=2)
    coarse = spread_frames(seen, spans, START_FRAMES)
    sub = Problem(problem.model, observed[coarse], problem.settings, problem.kin, problem.base)
    costs = {}
    for name in names:
        params = candidates[name]
        say(f"start: {name}, solved on {coarse.size} frames")
        state = start_poses(problem.kin, observed[coarse], params, stride=1,
                            evaluator=sub.frame_evaluator(params.vector()))
        with_p = replace(state, p=params.vector())
        _, summary = levenberg_marquardt(sub, with_p, sub.settings.solver, max_iterations=START_ITERATIONS)
        costs[name] = summary.final_cost
        # A start that fits the subsample to the stated noise (chi-square per coordinate near 1:
        # clean data) has nothing to gain from another.
        if 2.0 * summary.final_cost / (3 * max(int(sub.seen.sum()), 1)) <= START_GOOD_FIT:
            note = (f"started from {name}: solved on {coarse.size} frames it fits them to the stated noise "
                    f"(cost {summary.final_cost:.4g}), so no other start was tried")
            say("start: " + note)
            return params, note
    best = min(costs, key=costs.get)
    note = (f"started from {best}: of " + ", ".join(f"{n} (cost {c:.4g})" for n, c in costs.items())
            + f", solved on {coarse.size} frames, its basin fits best")
    say("start: " + note)
    return candidates[best], note


def _solve(problem: Problem, start: State, spans: list[slice],
           say: Callable[[str], None]) -> tuple[Problem, State, SolverSummary]:
    """The global solve: the geometry's basin on about COARSE_FRAMES evenly spaced frames (spread over
    the trials by their length), then every frame.  With Settings.auto_hold, the axes of the
    coordinates that the subsample's solution shows still are held at the base model's and the
    subsample solved again (returns the problem with those settings)."""
    settings = problem.settings
    seen = problem.seen
    coarse = spread_frames(seen, spans, COARSE_FRAMES)
    fixed = _fixed_noise(problem.model, settings)
    scatter = problem.sigma.copy()  # the markers' noise SDs (learnt: without the correlation time)
    trial_of = np.concatenate([np.full(sl.stop - sl.start, i) for i, sl in enumerate(spans)])
    for round_ in range(HOLD_ROUNDS + 1):
        sub = problem if coarse.size == problem.F else problem.subset(coarse)
        # On a subsample the polish after the gauge alignment is left to the run on every frame.
        state, coarse_summary = _solve_geometry(sub, _frames(start, coarse), settings,
                                                say, polish=sub is problem)
        for _ in range(NOISE_ROUNDS if fixed is not None else 0):
            # The trial's own scatter, measured at this solution: re-weigh and solve again from here.
            sigma, scatter = _relearn(sub, state, fixed, say, trial_of[coarse] if sub is not problem else trial_of)
            if sigma is None:
                break
            problem = problem.with_noise(sigma)
            sub = problem if coarse.size == problem.F else problem.subset(coarse)
            state, again = _solve_geometry(sub, state, settings, say, polish=sub is problem)
            coarse_summary = _merge(coarse_summary, again)
        if not settings.auto_hold or round_ == HOLD_ROUNDS:
            break
        axes = {problem.model.dofs[d].name for d in sub.axis_dofs}
        lin = sub.linearize(state, with_parameters=False)
        angles = FrameLayout.angles(absolute(sub.kin, state)[0])
        still = [name for name, _, _ in still_coordinates(sub.model, angles, lin.A, settings) if name in axes]
        if not still:
            break
        say(f"solve: the trial does not show {', '.join(still)} moving: holding "
            f"{'its axis' if len(still) == 1 else 'their axes'} at the base model's, solving again")
        settings = replace(settings, hold_axes=settings.hold_axes + tuple(still))
        problem = problem.with_settings(settings, sigma=problem.sigma)
        # A held axis is the base model's (the seed's estimate of a still joint's axis is noise).
        p, base = start.p.copy(), problem.base.vector()
        for name in still:
            k = problem.layout.axis(problem.model.dof_index(name))
            p[k] = base[k]
        start = replace(start, p=p)
    coarse_summary.rounds = round_ + 1
    if sub is problem:
        return problem, state, coarse_summary, scatter
    # The geometry's basin is found on the subsample; every frame then joins for the last steps.
    say(f"solve: all {problem.F} frames")
    parts = []
    for sl in spans:
        mine = np.flatnonzero((coarse >= sl.start) & (coarse < sl.stop))
        parts.append(spread_poses(_frames(state, mine), coarse[mine] - sl.start, _frames(start, sl)))
    state = replace(_stack_states(parts), p=state.p.copy())
    state, summary = levenberg_marquardt(
        problem, state, settings.solver,
        progress=lambda it, c, lam: say(f"solve: all frames, iteration {it:3d}  cost {c:.6e}  lambda {lam:.1e}"))
    if fixed is not None:
        sigma, scatter = _relearn(problem, state, fixed, say, trial_of)
    if fixed is not None and sigma is not None:  # every frame shows another scatter than the subsample did
        problem = problem.with_noise(sigma)
        state, again = levenberg_marquardt(problem, state, settings.solver)
        summary = _merge(summary, again)
    summary.coarse = coarse_summary
    summary.coarse_frames = int(coarse.size)
    return problem, state, summary, scatter


def _bridge(state: State, redo: np.ndarray, hit: np.ndarray, spans: list[slice]) -> State:
    """The poses of the frames marked `redo` (F,) interpolated, within each trial, from the nearest
    frames not marked `hit` (slerp for the root's and the balls' reference rotations; held beyond
    the ends)."""
    Z = state.Z.copy()
    rots = [state.Q.copy()] + ([] if state.B is None else [state.B[:, i].copy() for i in range(state.B.shape[1])])
    for sl in spans:
        good = np.flatnonzero(~hit[sl])
        bad = np.flatnonzero(redo[sl])
        if bad.size == 0 or good.size == 0:
            continue
        for c in range(Z.shape[1]):
            Z[sl.start + bad, c] = np.interp(bad, good, Z[sl.start + good, c])
        for Q in rots:
            if good.size == 1:
                Q[sl.start + bad] = Q[sl.start + good[0]]
            else:
                rot = Slerp(good, Rotation.from_quat(Q[sl.start + good]))(np.clip(bad, good[0], good[-1])).as_quat()
                Q[sl.start + bad] = np.where(rot[:, 3:4] < 0, -rot, rot)
    B = None if state.B is None else np.stack(rots[1:], axis=1) if rots[1:] else state.B.copy()
    return State(Z, rots[0], state.p, B)


def _fixed_noise(model: Model, settings: Settings) -> np.ndarray | None:
    """Markers whose noise SD is the user's (Settings.marker_noise), or None when nothing is learnt."""
    if not settings.learns_noise:
        return None
    named = {label for label, _ in settings.marker_noise}
    return np.array([n in named for n in model.marker_names])


def _relearn(problem: Problem, state: State, fixed: np.ndarray, say: Callable[[str | Progress], None],
             trial_of: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """learned_noise at `state`: the weights' SDs sigma sqrt(τ) (a marker whose residuals are correlated
    over τ frames carries the information of 1/τ of its frames) and the noise SDs sigma.  The first is
    None if nine markers in ten changed their weights' SD by no more than NOISE_CHANGE (a few poorly
    seen markers may go on wavering without moving the geometry)."""
    scatter, tau = learned_noise(problem, state, fixed, trial_of, correlation=True)
    sigma = scatter * np.sqrt(tau)
    change = float(np.quantile(np.abs(sigma / problem.sigma - 1.0), 0.9))
    say(Progress("noise", f"learnt marker SDs {1000 * np.median(scatter):.2f} mm median ({1000 * scatter.min():.2f}-"
                          f"{1000 * scatter.max():.2f}), correlation times {np.median(tau):.1f} frames median (up to "
                          f"{tau.max():.1f}); 9 in 10 weights changed by <= {100 * change:.0f} %"))
    return (sigma if change > NOISE_CHANGE else None), scatter


def leverage(problem: Problem, state: State) -> tuple[np.ndarray, np.ndarray]:
    """(F, n_markers) leverage of each observed marker in its frame — the trace of the weighted hat
    matrix J_z A_f⁻¹ J_zᵀ W over its three rows, / 3: the fraction of its error the frame's pose
    absorbs — and the raw residuals (F, 3 n_markers) at `state`."""
    nm = len(problem.model.markers)
    lin = problem.linearize(state, with_parameters=False)
    d, jz, _, wrow = lin.jacobian[:4]
    zr, zc, nrows, nz = problem._jz_pattern
    F = problem.F
    ridge = 1e-12 * max(float(np.max(np.abs(np.diagonal(lin.A, axis1=1, axis2=2)), initial=0.0)), 1e-300)
    h = np.zeros((F, nm))
    for s in range(0, F, 128):  # frames in blocks: the dense per-frame Jacobians are (rows x nz)
        e = min(F, s + 128)
        J = np.zeros((e - s, nrows, nz))
        J[:, zr, zc] = jz[s:e]
        J *= wrow[s:e, :, None]
        Ainv = np.linalg.inv(lin.A[s:e] + ridge * np.eye(nz))
        # diag(J A⁻¹ J') row by row: a batched matrix product (BLAS), then a row-wise dot product
        h[s:e] = np.sum(np.matmul(J, Ainv) * J, axis=2).reshape(e - s, nm, 3).sum(axis=2) / 3
    return np.where(problem.seen, h, 0.0), d


def learned_noise(problem: Problem, state: State, fixed: np.ndarray | None = None,
                  trial_of: np.ndarray | None = None, correlation: bool = False):
    """Each marker's noise SD (m) from the residuals at `state`: the root mean square of its 3-D
    residuals over the frames, each winsorised at NOISE_CLIP robust SDs per coordinate (MAD_SD times
    the median absolute deviation of its components in the same trial: `trial_of` (F,) gives each
    frame's trial; a static trial's scatter is smaller than a walk's), so that skin-motion scatter
    counts and spikes count no more than a few SDs.  A residual is smaller than the noise by the
    part of it the fit absorbs, so each is first divided by sqrt(1 − h): h its frame's leverage
    (the trace of the weighted hat matrix J_z A_f⁻¹ J_zᵀ W over the marker's three rows, / 3:
    one frame's 38 coordinates absorb about a third of 39 markers' 117 coordinates) plus 1/n for
    the marker's own offset, fitted over its n frames.  Markers seen in fewer than NOISE_MIN_FRAMES
    frames or almost wholly absorbed (h > 0.8) take the median of their segment's (else of all
    markers'); `fixed` markers (the user's marker_noise) keep problem.sigma.  Clipped to
    [NOISE_FLOOR, NOISE_CAP].

    `correlation`: also return each marker's correlation time τ (frames of `problem`; 1 for white
    noise): (1 + ρ)/(1 − ρ), ρ the lag-1 autocorrelation of its standardised residuals within each
    trial, in [1, NOISE_TAU_MAX] (a fixed marker: 1)."""
    model = problem.model
    nm = len(model.markers)
    F = problem.F
    h, d = leverage(problem, state)
    res = d.reshape(F, nm, 3)
    seen = problem.seen
    n = seen.sum(axis=0)
    sigma = problem.sigma.copy()
    learnt = np.full(nm, np.nan)
    trial_of = np.zeros(F, dtype=int) if trial_of is None else np.asarray(trial_of)
    for k in range(nm):
        use = seen[:, k]
        if n[k] < NOISE_MIN_FRAMES:
            continue
        lev = h[use, k] + 1.0 / n[k]
        if np.median(lev) > 0.8:
            continue
        r = res[use, k]
        keep = np.clip(1.0 - lev, 0.2, 1.0)
        u = r / np.sqrt(keep)[:, None]
        cap = np.empty(use.sum())
        for t in np.unique(trial_of[use]):
            mine = trial_of[use] == t
            s0 = MAD_SD * float(np.median(np.abs(u[mine] - np.median(u[mine], axis=0))))
            cap[mine] = 3 * (NOISE_CLIP * s0) ** 2 * keep[mine]
        # The mean square, winsorised at NOISE_CLIP robust SDs: a marker whose residual the fit confines
        # to fewer than 3 directions (a single hand marker: 1) has no Gaussian components for the MAD,
        # but E|r|^2 = 3 sigma^2 (1 - h) whatever the rank.
        sq = np.minimum(np.sum(r**2, axis=1), cap)
        learnt[k] = math.sqrt(float(np.sum(sq)) / float(np.sum(3 * keep)))
    seg = problem.marker_segment
    overall = float(np.nanmedian(learnt)) if np.isfinite(learnt).any() else float(np.median(sigma))
    for k in np.flatnonzero(~np.isfinite(learnt)):
        mine = learnt[(seg == seg[k]) & np.isfinite(learnt)]
        learnt[k] = float(np.median(mine)) if mine.size else overall
    learnt = np.clip(learnt, NOISE_FLOOR, NOISE_CAP)
    if fixed is not None:
        learnt = np.where(fixed, sigma, learnt)
    if not correlation:
        return learnt
    tau = np.ones(nm)
    lag = seen[1:] & seen[:-1] & (trial_of[1:] == trial_of[:-1])[:, None]  # (F-1, nm): consecutive pairs
    for k in range(nm):
        if lag[:, k].sum() < NOISE_MIN_FRAMES or (fixed is not None and fixed[k]):
            continue
        u = np.where(seen[:, k, None], res[:, k], 0.0)
        for t in np.unique(trial_of):
            mine = (trial_of == t) & seen[:, k]
            if mine.any():
                u[mine] -= u[mine].mean(axis=0)
        a, b = u[:-1][lag[:, k]], u[1:][lag[:, k]]
        rho = float(np.sum(a * b)) / max(math.sqrt(float(np.sum(a * a)) * float(np.sum(b * b))), 1e-300)
        tau[k] = float(np.clip((1 + rho) / max(1 - rho, 1e-9), 1.0, NOISE_TAU_MAX))
    return learnt, tau


def _outliers(problem: Problem, state: State, settings: Settings, sigma: np.ndarray | None = None,
              trial_of: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Observations (F, n_markers) whose studentised 3-D error |r| / (σ sqrt(1 − h)) exceeds
    `settings.outliers` (σ: `sigma`, default problem.sigma, scaled up if the fit shows more noise than
    that: median / 1.538, a 3-D Gaussian's; h: the leverage): a spike on a marker whose frame's pose
    absorbs most of it (one of a foot's two markers) keeps its small residual but not its studentised
    one.  Returns the mask and the studentised errors times σ (m: comparable across markers)."""
    err = np.linalg.norm(problem.marker_residuals(state), axis=2)
    ok = np.isfinite(err)
    if not ok.any():
        return np.zeros_like(ok), err
    h, _ = leverage(problem, state)
    err = err / np.sqrt(np.clip(1.0 - h, 0.05, 1.0))
    sigma = problem.sigma if sigma is None else sigma
    scale = max(1.0, float(np.median((err / sigma)[ok])) / 1.538)
    sd = np.broadcast_to(scale * sigma, err.shape).copy()
    # Per trial and marker, never below what its own median error shows: a shoulder marker riding the
    # scapula scatters 10-20 mm in a walk and 1 mm in the static trial, and its noise SD, learnt over
    # both, would otherwise reject every walking frame of it (outliers are the rare exceptions).
    trial_of = np.zeros(problem.F, dtype=int) if trial_of is None else trial_of
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for t in np.unique(trial_of):
            rows = trial_of == t
            med = np.nanmedian(np.where(ok[rows], err[rows], np.nan), axis=0) / 1.538
            sd[rows] = np.maximum(sd[rows], np.where(np.isfinite(med), med, 0.0)[None, :])
    return ok & (err > settings.outliers * sd), err


def _most_motion(model: Model, trials: Sequence[Trial]) -> int:
    """The trial whose markers on different segments move most relative to each other (a static
    trial's barely do): the one the joint-centre seed can use."""
    if len(trials) == 1:
        return 0
    seg = {m.name: m.segment for m in model.markers}
    best, pick = -1.0, 0
    for i, t in enumerate(trials):
        labs = [lab for lab in t.labels if lab in seg]
        X = t.select(labs).markers[:: max(1, t.n_frames // 200)]
        D = distance_variance(X, min_frames=3)
        other = np.array([[seg[a] != seg[b] for b in labs] for a in labs])
        vals = np.sqrt(D[other & np.isfinite(D)])
        amount = float(np.median(vals)) if vals.size else 0.0
        if amount > best:
            best, pick = amount, i
    return pick


def _assign_new_markers(model: Model, trials: Sequence[Trial], unknown: list[str]) -> list[NewMarker]:
    """Segments for the trial markers the model does not know (seed 002's rigidity, against the
    model's known markers: calibrate.seed.association.associate_to_model over all trials' frames)."""
    labels = (*model.marker_names, *unknown)
    parts = []
    for t in trials:
        cols = np.full((t.n_frames, len(labels), 3), np.nan)
        have = [k for k, lab in enumerate(labels) if lab in t.labels]
        cols[:, have] = t.select([labels[k] for k in have]).markers
        parts.append(cols)
    assoc = associate_to_model(model, Trial(labels, np.concatenate(parts), trials[0].rate))
    return [NewMarker(lab, assoc[lab].segment, None, assoc[lab].reason) for lab in unknown]


def _on_model(subject: Model, model: Model, params: Parameters) -> Parameters:
    """`params` of `model` on `subject` (the model with new markers, zero offsets for those)."""
    if subject is model:
        return params
    marker = np.zeros((len(subject.markers), 3))
    for k, name in enumerate(subject.marker_names):
        if name in model.marker_names:
            marker[k] = params.marker[model.marker_index(name)]
    return Parameters(params.scale.copy(), params.centre.copy(), params.axis.copy(), marker)


def _place_new_markers(subject: Model, kin: Kinematics, start: State, obs: np.ndarray, params: Parameters,
                       placed: list[NewMarker]) -> tuple[Parameters, Parameters, list[NewMarker]]:
    """Each new marker's position on its segment from the start poses (seed 002's closed form: the
    median over frames of the marker in the segment's frame); these positions are also the centre
    of its prior.  Returns the start parameters, the prior's base parameters and the placements."""
    new = [k for k, n in enumerate(subject.marker_names) if n in {m.label for m in placed if m.segment}]
    seen = np.all(np.isfinite(obs[:, new]), axis=2)
    # Up to about 100 frames per marker, wherever in the trials it is seen (some are seen briefly).
    frames = np.unique(np.concatenate([np.flatnonzero(seen[:, i])[:: max(1, int(seen[:, i].sum()) // 100)]
                                       for i in range(len(new))]))
    Z, Q = absolute(kin, _frames(start, frames))
    p = params.copy()
    s = np.array([p.scale[subject.segment_index(subject.markers[k].segment)] for k in new])
    p.marker[new] = 0.0
    origin, _ = kin.batch(Z, Q, p)
    axes = []
    for c in range(3):
        p.marker[new] = 0.0
        p.marker[new, c] = 1.0 / s
        M, _ = kin.batch(Z, Q, p)
        axes.append(M[:, new] - origin[:, new])  # (frames, new, 3): the segment's axis c in the lab
    R = np.stack(axes, axis=3)  # (frames, new, 3 lab, 3 segment)
    local = np.einsum("fnij,fni->fnj", R, obs[frames][:, new] - origin[:, new])
    out = params.copy()
    base = subject.parameters()
    by_label = {m.label: m for m in placed}
    for i, k in enumerate(new):
        use = np.isfinite(local[:, i, 0])
        name = subject.marker_names[k]
        offset = np.median(local[use, i], axis=0) / s[i]
        out.marker[k] = offset
        base.marker[k] = offset
        m = by_label[name]
        by_label[name] = NewMarker(name, m.segment, s[i] * offset, m.reason)
    result = [by_label[m.label] for m in placed]
    return out, base, result


def spread_frames(seen: np.ndarray, spans: Sequence[slice], target: int) -> np.ndarray:
    """About `target` frames (indices into all trials' frames) spread over the trials of `spans` by
    their length, evenly within each (coarse_frames; at least 2 per trial)."""
    total = sum(sl.stop - sl.start for sl in spans)
    return np.concatenate([sl.start + coarse_frames(seen[sl], max(2, round(target * (sl.stop - sl.start) / total)))
                           for sl in spans])


def coarse_frames(seen: np.ndarray, target: int = COARSE_FRAMES) -> np.ndarray:
    """Evenly spaced frames (about `target`, always the first and last usable ones) on which the
    geometry is solved before every frame joins; every frame when the trial is not much longer."""
    usable = np.flatnonzero(seen.sum(1) >= 3)
    k = usable.size // target
    if k < 2:
        return np.arange(seen.shape[0])
    idx = usable[::k]
    return idx if idx[-1] == usable[-1] else np.append(idx, usable[-1])


def spread_poses(solved: State, frames: np.ndarray, start: State) -> State:
    """Poses solved on `frames` carried to every frame of `start` (the key-frame start): what the
    solve changed (angles and root position added, root rotation composed) is interpolated
    between the solved frames (slerp for the rotation, held beyond the ends) and applied to the
    start, whose key frames follow the motion closely even where the solved frames are far apart."""
    F = start.Z.shape[0]
    if frames.size == F:
        return solved
    every = np.arange(F)
    change = solved.Z - start.Z[frames]
    Z = start.Z + np.column_stack([np.interp(every, frames, change[:, c]) for c in range(change.shape[1])])

    def carry(q_solved: np.ndarray, q_start: np.ndarray) -> np.ndarray:
        """Rotations: the solve's change (a turn on the left) slerped between the solved frames."""
        turn = Rotation.from_quat(q_solved) * Rotation.from_quat(q_start[frames]).inv()
        if frames.size == 1:
            turns = Rotation.from_quat(np.tile(turn.as_quat()[0], (F, 1)))
        else:
            turns = Slerp(frames, turn)(np.clip(every, frames[0], frames[-1]))
        q = (turns * Rotation.from_quat(q_start)).as_quat()
        return np.where(q[:, 3:4] < 0, -q, q)

    Q = carry(solved.Q, start.Q)
    B = None
    if solved.B is not None:
        nb = solved.B.shape[1]
        sb = start.B if start.B is not None else np.broadcast_to(IDENTITY, (F, nb, 4))
        B = np.zeros((F, 0, 4)) if nb == 0 else np.stack([carry(solved.B[:, i], sb[:, i]) for i in range(nb)], axis=1)
    Z[:, FrameLayout.rotation] = 0.0
    return State(Z, Q, solved.p.copy(), B)


def _solve_geometry(problem: Problem, state: State, settings: Settings,
                    say: Callable[[str], None], polish: bool = True) -> tuple[State, SolverSummary]:
    """Poses, then poses and geometry together, then the segment frames turned to where the
    priors want them and (`polish`) a last run from there: the whole solve on the frames of `problem`."""
    say(f"solve: refine poses ({problem.F} frames)")
    options = settings.solver
    state, _ = levenberg_marquardt(problem, state, options, pose_only=True, max_iterations=2)
    if settings.loss != "linear":
        # A robust loss is not convex: reach its basin with plain least squares first.
        say("solve: least squares before the robust loss")
        state, _ = levenberg_marquardt(problem.with_loss("linear"), state, options, max_iterations=30)
    say(f"solve: global Levenberg-Marquardt ({problem.F} frames)")
    state, summary = levenberg_marquardt(
        problem, state, options,
        progress=lambda it, c, lam: say(f"solve: iteration {it:3d}  cost {c:.6e}  lambda {lam:.1e}"))
    say("solve: align segment frames with the base model (gauge)")
    state = align_gauge(problem, state)
    if not polish:
        return state, summary
    state, polished = levenberg_marquardt(problem, state, options)
    return state, _merge(summary, polished)


def align_gauge(problem: Problem, state: State) -> State:
    """Turn every free segment frame to the orientation the priors prefer (Problem.align_frames)
    and re-solve the frame coordinates for it (the data fit is unchanged by construction)."""
    model = problem.model
    p, moves = problem.align_frames(state.p)
    Z, Q = state.Z.copy(), state.Q.copy()
    for si, kind, G, t in moves:
        if kind == "rigid":
            R = Rotation.from_quat(Q).as_matrix()
            Z[:, FrameLayout.translation] += np.einsum("fij,j->fi", R, t)
            Q = Rotation.from_matrix(R @ G).as_quat()
        elif kind == "axis":
            j = next(j for j in model.joints if j.child == model.segments[si].name)
            d = model.dof_index(j.dofs[-1])
            a = problem.axis_direction(state.p, d)
            Z[:, FrameLayout.angle(d)] += float(Rotation.from_matrix(G).as_rotvec() @ a)  # G turns about the hinge axis
    Q = np.where(Q[:, 3:4] < 0, -Q, Q)
    aligned = State(Z, Q, p, state.B)
    aligned, _ = levenberg_marquardt(problem, aligned, problem.settings.solver, pose_only=True, max_iterations=20)
    return aligned


def align_neutral(problem: Problem, state: State, neutral: np.ndarray) -> State:
    """Turn every free segment frame but the root's (Problem.neutral_frames) so that the frames
    marked `neutral` have zero joint angles on average, a tree level at a time (a turn changes the
    ball angles below it, which are re-solved before the next level); the data fit is unchanged."""
    model = problem.model
    depth = {model.segments[0].name: 0}
    for j in model.joints:  # parents come first
        depth[j.child] = depth[j.parent] + 1
    segs = [(si, kind) for si, kind in problem.neutral_gauges() if kind != "rigid"]
    into = {j.child: j for j in model.joints}
    for level in sorted({depth[model.segments[si].name] for si, _ in segs}):
        here = [(si, kind) for si, kind in segs if depth[model.segments[si].name] == level]
        p, moves = problem.neutral_frames(state.p, absolute(problem.kin, _frames(state, neutral))[0], here)
        Z = state.Z.copy()
        for si, kind, G, _ in moves:
            if kind == "axis":  # G turns about the hinge's (last) axis: its angle follows
                d = model.dof_index(into[model.segments[si].name].dofs[-1])
                Z[:, FrameLayout.angle(d)] += float(Rotation.from_matrix(G).as_rotvec()
                                                    @ problem.axis_direction(state.p, d))
        state, _ = levenberg_marquardt(problem, State(Z, state.Q, p, state.B), problem.settings.solver,
                                       pose_only=True, max_iterations=20)
    return state


_SUMMED = ("iterations", "accepted", "seconds", "linearize_seconds", "linear_solver_seconds", "evaluate_seconds")
_FROM_FIRST = ("initial_cost", "coarse", "coarse_frames")  # the start, and any subsample solve before it
_FROM_SECOND = ("final_cost", "termination", "converged")  # the end


def merge_summaries(a: SolverSummary, b: SolverSummary) -> SolverSummary:
    """One summary for two consecutive solver runs: counts and times added, the cost histories joined,
    the start from the first run, the end from the second; any other field as a fresh summary has it."""
    parts = {"cost_history": a.cost_history + b.cost_history[1:]}
    for f in fields(SolverSummary):
        if f.name in _SUMMED:
            parts[f.name] = getattr(a, f.name) + getattr(b, f.name)
        elif f.name in _FROM_FIRST:
            parts[f.name] = getattr(a, f.name)
        elif f.name in _FROM_SECOND:
            parts[f.name] = getattr(b, f.name)
    return SolverSummary(**parts)


_merge = merge_summaries  # the name the solve steps call


def _announcer(progress: Callable[[Progress], None] | None) -> Callable[[str | Progress], None]:
    """What the pipeline's steps call with a progress message (a Progress, or its text as Problem and the
    solve steps still word it): `progress` receives it as a Progress record."""
    if progress is None:
        return lambda message: None
    return lambda message: progress(Progress.of(message))


def _fixed_groups(base: Parameters, seeded: Parameters, free) -> Parameters:
    """Seeded values for the free groups; base values for the groups that are held."""
    parts = {}
    for b in Parameters.BLOCKS:
        parts[b] = np.array(getattr(seeded if b in free else base, b), dtype=float)
    return Parameters(**parts)


def worst_ratio(C: np.ndarray, C0: np.ndarray) -> tuple[float, np.ndarray]:
    """Largest posterior/prior-only std ratio over directions, and that direction."""
    ev0, U = np.linalg.eigh(0.5 * (C0 + C0.T))
    keep = ev0 > 1e-12 * max(float(ev0.max(initial=0.0)), 1e-300)  # directions the priors alone leave open
    if not keep.any():
        return 0.0, U[:, -1]
    Wh = U[:, keep] / np.sqrt(ev0[keep])  # whitening by the prior-only covariance on its range
    ev, V = np.linalg.eigh(Wh.T @ C @ Wh)
    v = U[:, keep] @ (np.sqrt(ev0[keep]) * V[:, -1])
    return math.sqrt(max(float(ev[-1]), 0.0)), v / np.linalg.norm(v)


def parameter_changes(problem: Problem, p: np.ndarray, cov: np.ndarray, prior_cov: np.ndarray) -> list[ParameterChange]:
    """Per joint centre, hinge axis, marker and scale: change from the base model, posterior std,
    and whether the trial identified it: in its worst direction, the posterior std must be below
    IDENTIFIED times the std the priors alone would leave (else the prior holds it)."""
    model = problem.model
    P = model.unpack(p)
    B = problem.base
    col = {n: k for k, n in enumerate(problem.free_names)}
    names = model.parameter_names()
    L = problem.layout
    out: list[ParameterChange] = []
    seg_scale = P.scale

    # A segment without markers (the talus) is seen only through its neighbours: its two joints trade
    # off along a curved valley that the linearised posterior SD understates (on squats the subtalar
    # axes end 5-10 deg from the truth with a 1-2 deg SD), so they are never called identified.
    bare = {sg.name for sg in model.segments if not sg.markers}
    blind = {j.name: (f"next to {j.parent if j.parent in bare else j.child}, which carries no markers: this joint "
                      f"and its neighbour trade off beyond what the posterior SD shows; held by the prior")
             for j in model.joints if j.parent in bare or j.child in bare}

    still = set(problem.settings.hold_segments)  # no marker seen on or below: held at the base model's

    def unseen(segment: str) -> str:
        return f"no marker seen on or below {segment}: held at the base model's"

    def block_cov(idx: list[str]) -> tuple[np.ndarray, np.ndarray] | None:
        """Posterior and prior-only covariance of a position at the subject's scale (its free
        coordinates, see Problem.tangent_map: what the data see)."""
        if not all(n in col for n in idx):
            return None
        c = [col[n] for n in idx]
        return cov[np.ix_(c, c)], prior_cov[np.ix_(c, c)]


    for ji, j in enumerate(model.joints):
        s = seg_scale[problem.centre_segment[ji]]
        CC = block_cov(names[L.centre(ji)])
        value, base = s * P.centre[ji], B.centre[ji]
        if CC is None and j.parent in still:
            std, status, note = np.full(3, np.nan), Identified.UNSEEN, unseen(j.parent)
        elif CC is None:
            std, status, note = np.full(3, np.nan), Identified.FIXED, "held (not free)"
        else:
            std = 1000 * np.sqrt(np.clip(np.diag(CC[0]), 0, None))
            if j.kind == "hinge":
                # Along its axis a hinge centre is a gauge: no motion moves the markers when it
                # slides there (the child's contents slide back), so the prior alone holds it.
                d = model.dof_index(j.dofs[0])
                u = next(u for u in model.urdf_joints if u.name == j.urdf_joints[0])
                a = u.rotation @ (P.axis[d] / np.linalg.norm(P.axis[d]))
                Qp = perpendicular_basis(a)
                ratio, _ = worst_ratio(Qp.T @ CC[0] @ Qp, Qp.T @ CC[1] @ Qp)
                status = Identified.ACROSS_AXIS if ratio < IDENTIFIED else Identified.NO
                axis_txt = ", ".join(f"{x:+.2f}" for x in a)
                note = (f"along its axis ({axis_txt}) in the {j.parent} frame it is held by the prior (no motion "
                        f"defines it); across the axis " + ("identified" if ratio < IDENTIFIED else "not identified"
                                                             " either: held by the prior"))
            else:
                ratio, v = worst_ratio(*CC)
                status = Identified.YES if ratio < IDENTIFIED else Identified.NO
                note = "" if status.identified else (f"not identified along ({', '.join(f'{x:+.2f}' for x in v)}) "
                                         f"in the {j.parent} frame: held by the prior")
        if CC is not None and j.name in blind:
            status, note = Identified.NO, blind[j.name]
        out.append(ParameterChange("centre", j.name, base, value, 1000 * float(np.linalg.norm(value - base)),
                                   std, status, note, ratio if CC is not None else float("nan")))
    for d in problem.axis_dofs:
        a = P.axis[d] / np.linalg.norm(P.axis[d])
        a0 = B.axis[d] / np.linalg.norm(B.axis[d])
        cols = L.axis_cols(d)
        C = cov[np.ix_(cols, cols)]
        std = np.degrees(np.sqrt(np.clip(np.diag(C), 0, None)))
        ratio = worst_ratio(C, prior_cov[np.ix_(cols, cols)])[0]
        status = Identified.YES if ratio < IDENTIFIED else Identified.NO
        ang = math.degrees(math.acos(min(1.0, abs(float(a @ a0)))))
        note = "" if status.identified else "the joint did not turn enough about it: held by the prior"
        if model.dofs[d].joint in blind:
            status, note = Identified.NO, blind[model.dofs[d].joint]
        out.append(ParameterChange("axis", model.dofs[d].name, a0, a, ang, std, status, note, ratio))
    for k, mk in enumerate(model.markers):
        s = seg_scale[problem.marker_segment[k]]
        CC = block_cov(names[L.marker(k)])
        value, base = s * P.marker[k], B.marker[k]
        seen = bool(problem.seen[:, k].any())
        if CC is None and mk.segment in still:
            std, status, note = np.full(3, np.nan), Identified.UNSEEN, unseen(mk.segment)
        elif CC is None:
            std, status, note = np.full(3, np.nan), Identified.FIXED, "held (not free)"
        else:
            std = 1000 * np.sqrt(np.clip(np.diag(CC[0]), 0, None))
            ratio = worst_ratio(*CC)[0]
            status = Identified.YES if seen and ratio < IDENTIFIED else Identified.NO
            note = "" if status.identified else ("never seen in the trial: base model kept" if not seen
                                     else "poorly seen: held by the prior")
        out.append(ParameterChange("marker", mk.name, base, value, 1000 * float(np.linalg.norm(value - base)),
                                   std, status, note, ratio if CC is not None else float("nan")))
    for si, sg in enumerate(model.segments):
        name = names[si]
        free = name in col
        std = np.array([math.sqrt(max(cov[col[name], col[name]], 0.0))]) if free else np.array([np.nan])
        ratio = float(std[0] / math.sqrt(prior_cov[col[name], col[name]])) if free else float("nan")
        status = (Identified.UNSEEN if sg.name in still else Identified.FIXED if not free
                  else Identified.YES if ratio < IDENTIFIED else Identified.NO)
        note = (unseen(sg.name) if sg.name in still else "held (not free)" if not free else "" if status.identified
                else "the trial barely sizes this segment: held by the prior")
        out.append(ParameterChange("scale", sg.name, np.array([1.0]), np.array([seg_scale[si]]),
                                   float(seg_scale[si] - 1.0), std, status, note, ratio))
    return out
