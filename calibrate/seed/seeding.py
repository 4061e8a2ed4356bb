"""The calibration's seed: the subject's size from pose-independent marker distances, MTB joint centres
turned into segment scales, centres and axes, with swapped labels and spikes left out first."""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..errors import CalibrateError
from ..io.trial import Trial
from ..model.model import Model, Parameters
from ..seed.geometry import kabsch_batch
from ..solve.ik import marker_columns
from .jitter import Jittery, jittery_samples, nanmedian_first
from .joints import JointEstimates, estimate_model_joints, lowpass, model_geometry

MIN_FRAMES = 3  # fewer frames with markers than this: nothing to calibrate


SEED_MAX_SHIFT = 0.06  # m: a seeded joint centre further than this from the (scaled) base model is not used


SEED_MARKER_LEVER = 0.15  # m: a marker this far from a segment's only estimated centre may scale it


SEED_MAX_TILT = math.radians(30.0)  # a seeded hinge axis further than this from the base model's is not used


SEED_FRAMES = 150  # the MTB seed uses at most about this many evenly spaced (low-passed) frames


SEED_CUTOFF_HZ = 6.0  # low-pass of the markers before the MTB seed (as calibrate.seed.joints does by default)


MAD_SD = 1.4826  # SD of a Gaussian per unit median absolute deviation


@dataclass(frozen=True)
class Seed:
    """Starting geometry from the MTB joint centres, and what was not seeded (and why)."""

    params: Parameters
    notes: tuple[str, ...]
    joints: JointEstimates | None
    seconds: float
    # whether the calibration started from this geometry (calibration.start.choose_start may take the base model's)
    taken: bool = True


# ---------------------------------------------------------------------- seed
def seed_parameters(model: Model, trial: Trial, joints: JointEstimates | None = None,
                    extra_markers: Mapping[str, str] | None = None, size: Size | None = None,
                    progress: Callable[[float], None] | None = None, jumps: np.ndarray | None = None) -> Seed:
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
    `progress(share done)` after each of its steps (a long trial's take seconds).  `jumps`: the trial's episodes, if
    found already (without_broken's).
    """
    t0 = time.perf_counter()
    notes: list[str] = []
    tick = progress or (lambda done: None)
    trial, broken = without_broken(model, trial, jumps)
    tick(0.5)
    if broken:
        notes.append(f"{broken} marker samples left out of the seed (swapped labels or spikes: jumps and back, or "
                     f"distances to markers on the same segment broken)")
    if joints is None:
        thinned = seed_trial(trial, SEED_FRAMES)
        cutoff = SEED_CUTOFF_HZ if thinned is trial else None  # a thinned trial is low-passed already
        trial = thinned
        tick(0.7)
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
    scale = segment_range(scale, overall if size is None else size.overall)
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


GHOST_BREAK = 0.2  # m: a sample that breaks its segment's steady distances by this much is no skin's, and is left out
# of the solve too (jumped_samples), not only of the seed: a ghost 2 m off at the trial's third frame, a gap after it,
# which the jumps misread (Rajagopal's L.Ankle: the frame before it taken, the ghost kept; hip_l 66 mm off)


SEED_JUMP_MIN = 0.02  # m: a marker's frame-to-frame step this far from the steps around it is a jump ...


SEED_JUMP_SDS = 8.0  # ... if also this many robust SDs of the marker's own (jump_episodes)


SEED_JUMP_WINDOW = 3  # frames each side whose steps' median predicts a step


SEED_JUMP_UNDO = 0.5  # two jumps undo each other when their sum is shorter than this fraction of the larger


SEED_EPISODE_S = 1.0  # s: a spike or swapped-label episode lasts at most this long


SEED_GHOST_FRAMES = 3  # a jump with at most this many seen frames between it and a gap: a ghost at the gap's edge ...
SEED_GHOST_MIN = 0.10  # m ... if the jump is this far from the steps around it (a fast arm read at 50 Hz jumps 50 mm)


SEED_BROKEN_GROUP = 12  # a segment with more markers is not checked (2^n candidate sets)


SIZE_TOLERANCE = 0.15  # a seeded segment scale further than this fraction from its limb's is replaced by the limb's
# A seeded segment's scale against the subject's overall size (the median of the marker pairs' or the joint centres'
# ratios): outside this band it is clipped to it (a wand or an MTB centre misread on a short segment).  Relative to
# the subject, not to the base model: the band was 0.7-1.4 of the base model's, and a 1.05 m child on a 1.75 m model
# (0.60, which the marker pairs measure to 0.59-0.60) was started at 0.70 throughout, its arms posed in the start's
# frame-wise fits 17 % too long: one simulated walk of eight ended with a humerus spun half a turn about its length
# (docs/benchmarks.md).  The subject's size itself is checked elsewhere (pipeline.SIZE_RANGE: the units).
SEGMENT_RANGE = (0.7, 1.4)


def segment_range(scale: np.ndarray, overall: float) -> np.ndarray:
    """Segment scales clipped to SEGMENT_RANGE times the subject's overall size `overall` (the band about 1 where
    `overall` is not a positive finite number)."""
    ref = overall if math.isfinite(overall) and overall > 0 else 1.0
    return np.clip(scale, SEGMENT_RANGE[0] * ref, SEGMENT_RANGE[1] * ref)


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


def model_poses(model: Model, names: Sequence[str], n: int, seed: int = 0) -> np.ndarray:
    """(n + 1, markers, 3): where the base model puts the markers `names` in its default pose and in `n` random poses
    (every angle anywhere in its range, a range without limits as a whole turn), the root at the origin."""
    import pinocchio as pin

    pm = model.pin
    data = pm.createData()
    fid = [pm.getFrameId(name) for name in names]
    rng = np.random.default_rng(seed)
    lo = np.array([d.lower if np.isfinite(d.lower) else -math.pi for d in model.dofs])
    hi = np.array([d.upper if np.isfinite(d.upper) else math.pi for d in model.dofs])
    poses = []
    for i in range(n + 1):
        a = np.zeros(model.n_dofs) if i == 0 else rng.uniform(lo, hi)
        pin.framesForwardKinematics(pm, data, model.pin_configuration(np.zeros(3), [0, 0, 0, 1], a))
        poses.append(np.array([data.oMf[f].translation for f in fid]))
    return np.array(poses)


HANDED_QUADS = 20000  # marker quadruples drawn; those whose handedness every pose of the base model keeps are used ...
HANDED_MIN_VOLUME = 0.05  # ... with a volume (signed, over their longest edge cubed) at least this in every pose ...
HANDED_MIN = 20  # ... if at least this many, over at least HANDED_SEGMENTS segments (fewer: not judged; a trial's
HANDED_SEGMENTS = 3  # labels exchanged in one cluster turn its few quadruples: Rajagopal's running arms)
HANDED_SHARE = 0.9  # a trial is a mirror image when this share of them turn the other way in most of its frames


@dataclass(frozen=True)
class Handedness:
    """How a trial's markers turn against the base model's: of `quadruples` marker quadruples whose handedness (the
    sign of their tetrahedron's volume) every pose of the base model keeps, `turned` turn the other way in most of
    the trial's frames.  A rotation keeps every one; a mirror image (left-handed axes, one axis negated) turns all."""

    quadruples: int
    turned: int
    segments: int  # segments the quadruples' markers ride on

    @property
    def mirrored(self) -> bool:
        return (self.quadruples >= HANDED_MIN and self.segments >= HANDED_SEGMENTS
                and self.turned >= HANDED_SHARE * self.quadruples)


def _volumes(P: np.ndarray) -> np.ndarray:
    """Signed volume of each tetrahedron (..., 4, 3) over its longest edge cubed (scale-free)."""
    a, b, c, d = (P[..., k, :] for k in range(4))
    v = np.einsum("...i,...i", b - a, np.cross(c - a, d - a))
    edges = [np.linalg.norm(x - y, axis=-1) for x, y in ((a, b), (a, c), (a, d), (b, c), (b, d), (c, d))]
    return v / np.maximum(np.max(edges, axis=0), 1e-9) ** 3


def handedness(model: Model, trials: Sequence[Trial], frames: int = 100, seed: int = 0) -> list[Handedness | None]:
    """Each trial's handedness against the base model (Handedness), judged on about `frames` evenly spaced frames of
    it, on quadruples of the markers the trials show drawn once for all; None for a trial that shows fewer than 4."""
    names = [m.name for m in model.markers if any(m.name in t.labels for t in trials)]
    if len(names) < 4:
        return [None] * len(trials)
    P = model_poses(model, names, SIZE_POSES, seed)
    rng = np.random.default_rng(seed)
    quads = rng.integers(0, len(names), (HANDED_QUADS, 4))
    quads = quads[np.all(np.diff(np.sort(quads, axis=1), axis=1) > 0, axis=1)]  # four different markers
    _, first = np.unique(np.sort(quads, axis=1), axis=0, return_index=True)  # each set of four once
    quads = quads[np.sort(first)]
    v = _volumes(P[0, quads])
    big = np.abs(v) >= HANDED_MIN_VOLUME
    quads, sign = quads[big], np.sign(v[big])
    for k in range(1, P.shape[0], 8):  # a few poses at a time: most quadruples turn in the first few
        keep = np.all(_volumes(P[k:k + 8, quads]) * sign >= HANDED_MIN_VOLUME, axis=0)
        quads, sign = quads[keep], sign[keep]
    segment = [model.markers[model.marker_index(n)].segment for n in names]
    out: list[Handedness | None] = []
    for t in trials:
        X = np.full((t.n_frames, len(names), 3), np.nan)
        have = [k for k, n in enumerate(names) if n in t.labels]
        if len(have) < 4:
            out.append(None)
            continue
        X[:, have] = t.select([names[k] for k in have]).markers
        idx = np.unique(np.linspace(0, t.n_frames - 1, min(frames, t.n_frames)).astype(int))
        w = _volumes(X[idx][:, quads])  # (frames, quadruples)
        seen = np.isfinite(w).sum(axis=0)
        used = seen > 0
        turned = used & ((np.sign(w) == -sign).sum(axis=0) > seen / 2)
        out.append(Handedness(int(used.sum()), int(turned.sum()),
                              len({segment[k] for k in np.unique(quads[used])}) if used.any() else 0))
    return out


def size_from_markers(model: Model, trials: Sequence[Trial], seed: int = 0,
                      model_cv: float = SIZE_MODEL_CV) -> Size | None:
    """The subject's size against the base model, from marker distances only (before any joint
    centre is known): every pair of model markers whose distance is the same in any pose of the base
    model (the same segment, or across a joint near its axis: knee to ankle markers) and steady over
    the trials' frames, compared with the base model's (median over frames / neutral pose); a limb's
    factor is the median of the ratios of its pairs (a leg: thigh, shank and foot markers), the
    overall factor the median of all.  `model_cv`: how much a pair's distance may vary over the base model's
    poses (a fraction).  None if no pair qualifies."""
    # The model's markers that some trial shows (a model may carry many more: Rajagopal2016.osim 131,
    # its trials 64; the distances of the rest are all NaN and slow to take medians of).
    shown = {lab for t in trials for lab in t.labels}
    names = [m.name for m in model.markers if m.name in shown]
    if len(names) < 2:  # (a trial of clusters the model lacks, beside a static with its landmarks: no pair)
        return None
    seg = np.array([model.segment_index(m.segment) for m in model.markers if m.name in shown], dtype=int)
    P = model_poses(model, names, SIZE_POSES, seed)  # (poses, markers, 3)
    D = np.linalg.norm(P[:, :, None] - P[:, None, :], axis=3)
    d0 = D[0]
    pose_cv = D.std(axis=0) / np.maximum(d0, 1e-9)
    # The trials' distances, on at most ~300 frames of each.
    parts = []
    for t in trials:
        X = np.full((t.n_frames, len(names), 3), np.nan)
        have = [k for k, n in enumerate(names) if n in t.labels]
        X[:, have] = t.select([names[k] for k in have]).markers
        parts.append(X[:: max(1, t.n_frames // 300)])
    X = np.concatenate(parts)
    # The trial's distances of the pairs the base model keeps steady (the medians over frames are most
    # of this function's time: only those pairs').
    a, b = np.nonzero((pose_cv < model_cv) & (d0 >= SIZE_MIN_DISTANCE) & np.triu(np.ones_like(d0, dtype=bool), 1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        Dt = np.linalg.norm(X[:, a] - X[:, b], axis=2)
        med = np.nanmedian(Dt, axis=0)
        mad = MAD_SD * np.nanmedian(np.abs(Dt - med), axis=0)
        n = np.sum(np.isfinite(Dt), axis=0)
    ok = (n >= 3) & (mad < SIZE_TRIAL_CV * med)
    a, b, med = a[ok], b[ok], med[ok]
    if a.size == 0:
        return None
    ratio = med / d0[a, b]
    # A marker sits a few centimetres from where the base model puts it (wands above all: Plug-in
    # Gait's TIB marker is 10 cm lower than ours), which changes a pair's ratio by about that over its
    # length: the weighted median, weight d0², trusts the long pairs (knee to ankle) most.
    wt = d0[a, b] ** 2
    overall = weighted_median(ratio, wt)
    limbs = limb_groups(model)
    scale = np.full(len(model.segments), overall)
    factors: dict[str, float] = {}
    for name, segs in limbs.items():
        inside = np.isin(seg[a], segs) & np.isin(seg[b], segs)
        if inside.sum() >= 1:
            factors[name] = weighted_median(ratio[inside], wt[inside])
            scale[segs] = factors[name]
            # A segment of the limb that none of its pairs reach, but a pair across the limb's joint does, takes that
            # pair's ratio, not the far segments': Rajagopal2016's shank (its femur counted as trunk, the patella its
            # second branch) with one marker, the lateral malleolus, had taken the foot's alone, a toe marker at the
            # tip against the model's at the metatarsal heads (x1.26; knee to ankle x1.18), and the long shank
            # tilted the pelvis 65 deg in gait2392's static.
            for si in segs:
                mine = (seg[a] == si) | (seg[b] == si)
                if not (mine & inside).any() and mine.any():
                    scale[si] = weighted_median(ratio[mine], wt[mine])
    return Size(segment_range(scale, overall), factors, overall, int(a.size))


def broken_samples(model: Model, trial: Trial, least: float = SEED_BROKEN_MIN) -> np.ndarray:
    """(n_frames, n_model_markers) True where a marker sample breaks the distances it keeps to the other
    markers of its segment: a swapped label or a spike.

    A pair is broken in a frame when its distance is further than SEED_BROKEN_SDS robust SDs (and
    `least`, SEED_BROKEN_MIN; GHOST_BREAK for a ghost) from its median over the trial (pairs whose
    distance is not steady over the trial, SIZE_TRIAL_CV, are not used).  Within a segment (its markers
    the trial shows), a frame keeps the markers common to every largest set with no broken pair among
    them: one marker off is flagged alone, two swapped labels both, and when the distances cannot tell
    which markers are wrong (two markers alone, or a swap on a near-symmetric segment) all of them."""
    X = marker_columns(model, trial)
    flagged = np.zeros(X.shape[:2], dtype=bool)
    seen = np.all(np.isfinite(X), axis=2)
    shown = seen.any(axis=0)
    for sg in model.segments:
        # the segment's markers the trial shows: a model with a lab's full marker set carries more on a segment than
        # a trial does (Rajagopal2016's tibia 14, its walk 5), and a group over SEED_BROKEN_GROUP is not checked
        members = np.array([k for k in (model.marker_index(m) for m in sg.markers) if shown[k]], dtype=int)
        if members.size < 2 or members.size > SEED_BROKEN_GROUP:
            continue
        ia, ib = np.triu_indices(members.size, 1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            d = np.linalg.norm(X[:, members[ia]] - X[:, members[ib]], axis=2)  # (F, pairs)
            med = np.nanmedian(d, axis=0)
            mad = MAD_SD * np.nanmedian(np.abs(d - med), axis=0)
            steady = (np.sum(np.isfinite(d), axis=0) >= MIN_FRAMES) & (mad < SIZE_TRIAL_CV * med)
            broken = (np.abs(d - med) > np.maximum(SEED_BROKEN_SDS * mad, least)) & steady
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


def jump_episodes(trial: Trial, progress: Callable[[float], None] | None = None,
                  lone: list[tuple[int, int, int]] | None = None) -> np.ndarray:
    """(n_frames, n_markers) True where a marker trajectory sits between a jump and the jump that undoes
    it (a spike: one frame; a swapped label: until the labels swap back).  A jump is a frame-to-frame
    step further than SEED_JUMP_MIN (and SEED_JUMP_SDS robust SDs of the marker's own) from the median
    of the steps around it (SEED_JUMP_WINDOW frames each side: constant acceleration cancels); two
    jumps of one marker at most SEED_EPISODE_S apart, with no gap between, that undo each other (their
    sum shorter than SEED_JUMP_UNDO of the larger) bound an episode.  `progress(share of the markers
    done)` after each marker (100 000 frames take about a second).  `lone`: gets the labels exchanged once
    (_exchanged_stretches), which the jumps cannot judge."""
    X = np.asarray(trial.markers)
    F = X.shape[0]
    out = np.zeros(X.shape[:2], dtype=bool)
    if F < 2 * SEED_JUMP_WINDOW + 2:
        return out
    longest = max(1, int(round(SEED_EPISODE_S * trial.rate)))
    W = SEED_JUMP_WINDOW
    pad = np.full((W, 3), np.nan)
    loose: dict[int, list[tuple[int, np.ndarray]]] = {}  # step -> (marker, its jump) of the jumps no episode took
    ghosts: list[tuple[int, int, slice]] = []  # (marker, step, frames) of each ghost at a gap's edge
    for k in range(X.shape[1]):  # one marker at a time: memory stays 2W x the trajectory
        x = X[:, k]
        d = np.diff(x, axis=0)  # (F-1, 3): step into frame f+1; NaN across gaps
        dp = np.concatenate([pad, d, pad])
        around = np.stack([dp[W + o: W + o + len(d)] for o in range(-W, W + 1) if o], axis=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            s = d - nanmedian_first(around)  # (F-1, 3)
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
        # A ghost at a gap's edge: a jump of SEED_GHOST_MIN or more with at most SEED_GHOST_FRAMES seen frames between
        # it and a gap (or the trial's end) on one side and more on the other has no jump back; those few frames are the
        # ghost (taken after the exchanges below: a jump that exchanges two labels is not a ghost's).
        for a in steps:
            if out[a, k] or out[a + 1, k]:
                continue
            loose.setdefault(int(a), []).append((k, s[a]))
            if size[a] < SEED_GHOST_MIN:
                continue
            after = _seen_run(seen, a + 1, +1, SEED_GHOST_FRAMES + 1)  # seen frames from a+1 on, up to a gap
            before = _seen_run(seen, a, -1, SEED_GHOST_FRAMES + 1)  # ... from a back
            if after <= SEED_GHOST_FRAMES < before and not jump[a + 1:a + after].any():
                ghosts.append((k, int(a), slice(a + 1, a + 1 + after)))
            elif before <= SEED_GHOST_FRAMES < after and not jump[a - before + 1:a].any():
                ghosts.append((k, int(a), slice(a - before + 1, a + 1)))
        if progress is not None:
            progress((k + 1) / X.shape[1])
    exchanges = _exchanged_stretches(X, loose, out, lone)
    for k, a, frames in ghosts:
        if (k, a) not in exchanges:
            out[frames, k] = True
    return out


def _exchanged_stretches(X: np.ndarray, loose: dict[int, list[tuple[int, np.ndarray]]],
                         out: np.ndarray, lone: list[tuple[int, int, int]] | None = None) -> set[tuple[int, int]]:
    """Two labels exchanged for longer than an episode (SEED_EPISODE_S), set in `out` (frames, markers): two markers
    that jump at the same step by about each other's separation and in opposite ways have exchanged labels there (a
    limb cannot do that).  Between two such exchanges of one pair, both seen throughout, the labels are exchanged.  A
    pair's one exchange left over is not judged: which side holds the right labels the jumps cannot say (taking the
    shorter side took 196 frames of a 50 Hz tennis serve's right arm, where its elbow, forearm and upper-arm markers
    cross in a blur and are right before).  pig_walk with two labels exchanged for 0.5 s to half its 300 frames put a
    centre 93-370 mm off in 7 of 16 copies (scripts/damage_values.py, longswap).  Returns every (marker, step) of an
    exchange, taken or not; `lone` gets each pair's one exchange left over, (marker, marker, step), where the pair has
    no other (lone_exchanges judges it against a model)."""
    events: dict[tuple[int, int], list[int]] = {}
    for a, jumps in loose.items():
        for i, (k, sk) in enumerate(jumps):
            for m, sm in jumps[i + 1:]:
                big = max(float(np.linalg.norm(sk)), float(np.linalg.norm(sm)))
                apart = X[a, m] - X[a, k]  # the separation the exchange crosses
                if (np.linalg.norm(sk + sm) <= SEED_JUMP_UNDO * big
                        and np.linalg.norm(sk - apart) <= SEED_JUMP_UNDO * big):
                    events.setdefault((k, m), []).append(a)
    for (k, m), steps in events.items():
        seen = np.all(np.isfinite(X[:, [k, m]]), axis=(1, 2))
        steps = sorted(steps)
        while len(steps) >= 2 and seen[steps[0] + 1:steps[1] + 1].all():
            out[steps[0] + 1:steps[1] + 1, [k, m]] = True
            steps = steps[2:]
        if lone is not None and len(steps) == 1 and len(events[(k, m)]) == 1:
            lone.append((k, m, steps[0]))
    return {(k, a) for (k, m), steps in events.items() for a in steps} | \
        {(m, a) for (k, m), steps in events.items() for a in steps}


def episodes(trial: Trial, progress: Callable[[float], None] | None = None, model: Model | None = None,
             back: list[ExchangedBack] | None = None) -> tuple[np.ndarray, tuple[Jittery, ...]]:
    """(n_frames, n_markers) True where a marker's samples are damaged: jump_episodes (spikes, swapped labels, a ghost
    at a gap's edge) and jittery_samples (white noise), and the jittery markers.  With `model`, also the side of a
    label exchange its markers' distances put against the model's (lone_exchanges); with `back` too, those are not
    in the mask but added to `back`, for the caller to exchange them back (exchanged_back: the mask holds for the
    trial so mended).  `progress`: jump_episodes'."""
    jitter, jittery = jittery_samples(trial)
    lone: list[tuple[int, int, int]] = []
    out = jump_episodes(trial, progress, lone if model is not None else None) | jitter
    if lone:
        found = lone_exchanges(model, trial, lone, out)
        if back is not None:
            back.extend(found)
        else:
            for x in found:
                out[x.start:x.stop, [trial.labels.index(lab) for lab in x.labels]] = True
    return out, jittery


@dataclass(frozen=True)
class ExchangedBack:
    """Two labels exchanged once in a trial and not back (to its end, or from its start), on the frames where they
    ride with each other's segment, or the model's distances say they are the wrong way round (lone_exchanges):
    exchanged back."""

    labels: tuple[str, str]
    start: int  # the first frame of the side exchanged
    stop: int  # one past its last
    labelled: float  # m: RMS misfit of that side's distances to the model's as labelled (by "rigidity": the RMS of
    exchanged: float  # their spreads over the side) ... and exchanged
    by: str = "distances"  # what told the sides apart: the model's "distances", or "rigidity"

    def text(self) -> str:
        a, b = self.labels
        how = ("keep steady to {x:.0f} mm RMS exchanged, to {l:.0f} as labelled" if self.by == "rigidity" else
               "fit the base model's {x:.0f} mm RMS exchanged, {l:.0f} as labelled")
        return (f"{a} and {b} exchanged in frames {self.start}-{self.stop - 1} and not back (their distances to their "
                f"segments' markers " + how.format(x=1e3 * self.exchanged, l=1e3 * self.labelled)
                + "): exchanged back there")

    def to_json(self) -> dict:
        return {"labels": list(self.labels), "frames": [self.start, self.stop - 1], "judged_by": self.by,
                "misfit_as_labelled_mm": 1e3 * self.labelled, "misfit_exchanged_mm": 1e3 * self.exchanged}


def exchanged_back(trial: Trial, found: Sequence[ExchangedBack]) -> Trial:
    """`trial` with each of `found`'s two labels' positions exchanged on its frames."""
    if not found:
        return trial
    X = np.array(trial.markers)
    for x in found:
        i, j = (trial.labels.index(lab) for lab in x.labels)
        X[x.start:x.stop, [i, j]] = X[x.start:x.stop, [j, i]]
    return replace(trial, markers=X)


SEGMENT_PAIR_MIN = 0.05  # m: segment_distances reads the pairs of one segment's markers this far apart or more


def segment_distances(model: Model, trial: Trial, frames: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """(n_model_markers, n_model_markers) each two model markers' median distance over about `frames` evenly spaced
    frames of `trial`, for the pairs on one segment SEGMENT_PAIR_MIN or more apart in the model's neutral pose (upper
    triangle; NaN elsewhere, and where the trial never shows both), and those pairs' distances in the model.  A
    segment's markers keep their distances in any pose (skin aside): the trial's against the model's, or another
    trial's, tell one subject's size and marker places from another's."""
    names = model.marker_names
    seg = np.array([mk.segment for mk in model.markers])
    P = model.neutral_positions(names)
    ref = np.linalg.norm(P[:, None] - P[None], axis=-1)
    pairs = np.equal.outer(seg, seg) & (ref >= SEGMENT_PAIR_MIN) & np.triu(np.ones((len(names),) * 2, dtype=bool), 1)
    index = {lab: i for i, lab in enumerate(trial.labels)}
    at = np.array([index.get(n, -1) for n in names])
    X = np.where(at[None, :, None] >= 0, np.asarray(trial.markers)[::max(1, trial.n_frames // frames)][:, at], np.nan)
    # The pairs read only, not every two markers (Rajagopal's 88 are 7 700 pairs; its static keeps 132).
    i, j = np.nonzero(pairs & (at[:, None] >= 0) & (at[None, :] >= 0))
    D = np.full(pairs.shape, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        D[i, j] = np.nanmedian(np.linalg.norm(X[:, i] - X[:, j], axis=-1), axis=0)
    return D, np.where(pairs, ref, np.nan)


LONE_MARGIN = 0.020  # m: a side of a lone exchange is taken where its distances fit the model's this much better ...
LONE_RATIO = 1.5  # ... and this many times better exchanged (RMS over the markers near the two), the other side as
# labelled likewise
LONE_FRAMES = 60  # about this many evenly spaced frames of a side are read
LONE_RIGID = 0.010  # m: by rigidity, a side is taken where its distances keep LONE_RATIO times and this much steadier
# (RMS of their spreads over the side) exchanged than as labelled, the other side as labelled likewise


def lone_exchanges(model: Model, trial: Trial, lone: Sequence[tuple[int, int, int]],
                   taken: np.ndarray) -> tuple[ExchangedBack, ...]:
    """The side of each lone label exchange (markers k and m exchanged at step a, into frame a + 1, with no exchange
    back: jump_episodes' `lone`) where the two labels are the wrong way round.  The jumps cannot say which side that
    is; the model can.  Labels of two segments: on the side where they are the wrong way round each position keeps
    its distances to the other segment's markers (LONE_RIGID: their spreads over the side), whatever the lab's
    marker places.  Else (one segment, or segments that stay together in the trial): on each side, the two
    positions' median distances to the other markers of their segments
    against the model's in its neutral pose, at the trial's size, each position read against the markers on the
    segment of the marker it is taken for (as labelled, then exchanged); none there, against the markers of the
    segments next to them that both keep steady to (LONE_STEADY).  A side is named where exchanged they fit LONE_RATIO
    times and LONE_MARGIN better than as labelled while the other side fits as labelled likewise; else neither (a
    tennis serve's arm markers crossing in a blur jump so, and are right on both sides).  pig_walk with LHEE and LTOE,
    or RASI and LASI, exchanged from a frame to its end put centres 80-103 mm off.  `taken`: samples already left
    out (not read)."""
    F = taken.shape[0]
    out: list[ExchangedBack] = []
    index = {lab: i for i, lab in enumerate(trial.labels)}
    names = [n for n in model.marker_names if n in index]
    if len(names) < 4:
        return ()
    seg = {mk.name: mk.segment for mk in model.markers}
    near = _marked_neighbours(model)
    P = model.neutral_positions(names)
    ref = np.linalg.norm(P[:, None] - P[None], axis=-1)
    at = {n: i for i, n in enumerate(names)}
    X = np.where(taken[..., None], np.nan, np.asarray(trial.markers))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sub = X[::max(1, F // (4 * LONE_FRAMES)), [index[n] for n in names]]
        D = np.nanmedian(np.linalg.norm(sub[:, :, None] - sub[:, None], axis=-1), axis=0)
    same = np.equal.outer(np.array([seg[n] for n in names]), np.array([seg[n] for n in names]))
    ok = same & ~np.eye(len(names), dtype=bool) & np.isfinite(D) & (ref > 0.02)
    scale = float(np.median(D[ok] / ref[ok])) if ok.any() else 1.0
    for k, m, a in lone:
        lk, lm = trial.labels[k], trial.labels[m]
        if lk not in at or lm not in at:
            continue
        around = {seg[lk], seg[lm]}
        refs = [n for n in names if n not in (lk, lm) and seg[n] in around] or [
            n for n in names if n not in (lk, lm) and seg[n] in near.get(seg[lk], set()) | near.get(seg[lm], set())]
        if not refs:
            continue
        seen = np.all(np.isfinite(X[:, [k, m]]), axis=(1, 2))
        fits = []
        for frames in (np.arange(0, a + 1), np.arange(a + 1, F)):
            frames = frames[seen[frames]]
            if frames.size < 3:
                fits.append(None)
                continue
            x = X[frames[::max(1, frames.size // LONE_FRAMES)]]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                dk = np.linalg.norm(x[:, [index[n] for n in refs]] - x[:, k:k + 1], axis=2)
                dm = np.linalg.norm(x[:, [index[n] for n in refs]] - x[:, m:m + 1], axis=2)
                med_k, med_m = np.nanmedian(dk, axis=0), np.nanmedian(dm, axis=0)
                sd_k = MAD_SD * np.nanmedian(np.abs(dk - med_k), axis=0)  # each distance's spread over the side
                sd_m = MAD_SD * np.nanmedian(np.abs(dm - med_m), axis=0)
                steady_k, steady_m = sd_k <= LONE_STEADY, sd_m <= LONE_STEADY
            # A distance is read against the model's in its neutral pose where no pose moves it: to a reference on
            # the segment of the marker it is taken for; where neither position has one, those that keep steady (the
            # segments next to them).  A distance across a joint can keep steady in a trial and still be far from the
            # neutral pose's (pig_walk's walk: RFIN to RKNE 377 mm, 13 mm spread, 270 in the neutral pose): read with
            # RTHI's and RFIN's labels exchanged from frame 173 on, neither side was named and the wrist was then
            # fitted 81 deg off.
            on = np.array([seg[n] for n in refs])
            model_k = scale * ref[at[lk], [at[n] for n in refs]]
            model_m = scale * ref[at[lm], [at[n] for n in refs]]
            ok_k, ok_m = np.isfinite(med_k), np.isfinite(med_m)
            rms, spread = [], []  # as labelled (position k taken for lk, m for lm), then exchanged
            for k_as, m_as, want_k, want_m in ((lk, lm, model_k, model_m), (lm, lk, model_m, model_k)):
                use_k, use_m = ok_k & (on == seg[k_as]), ok_m & (on == seg[m_as])
                # A position rides with the segment of the marker it is taken for: its distances to that segment's
                # markers keep steady over the side, where the marker's own places on the segment do not count.
                r = np.r_[sd_k[use_k], sd_m[use_m]]
                spread.append(float(np.sqrt(np.mean(r ** 2))) if r.size and seg[lk] != seg[lm] else math.nan)
                if not (use_k.any() or use_m.any()):  # the references both keep steady to, as for the two
                    use_k = use_m = ok_k & ok_m & steady_k & steady_m
                r = np.r_[(med_k - want_k)[use_k], (med_m - want_m)[use_m]]
                rms.append(float(np.sqrt(np.mean(r ** 2))) if r.size else math.nan)
            labelled, exchanged = rms
            if math.isnan(labelled) or math.isnan(exchanged):
                fits.append(None)
                continue
            fits.append((labelled, exchanged, *spread))
        if fits[0] is None or fits[1] is None:
            continue

        def better(one: float, other: float, margin: float = LONE_MARGIN) -> bool:
            return one * LONE_RATIO <= other and one + margin <= other

        (l0, x0, rl0, rx0), (l1, x1, rl1, rx1) = fits
        # Two segments that move apart over the trial say it by rigidity, whatever the lab's marker places (the model's
        # distances misjudged Rajagopal's walk with R.Knee and R.Wrist exchanged from its start: its thigh cluster
        # sits elsewhere than the generic model's, and the labelled side was exchanged, the knee centre 188 mm off);
        # a side that rigidity shows labelled right is never exchanged by the distances.
        if better(rl0, rx0, LONE_RIGID) and better(rx1, rl1, LONE_RIGID):
            out.append(ExchangedBack((lk, lm), int(a + 1), F, rl1, rx1, "rigidity"))
        elif better(rx0, rl0, LONE_RIGID) and better(rl1, rx1, LONE_RIGID):
            out.append(ExchangedBack((lk, lm), 0, int(a + 1), rl0, rx0, "rigidity"))
        elif better(l0, x0) and better(x1, l1) and not better(rl1, rx1, LONE_RIGID):
            out.append(ExchangedBack((lk, lm), int(a + 1), F, l1, x1))
        elif better(x0, l0) and better(l1, x1) and not better(rl0, rx0, LONE_RIGID):
            out.append(ExchangedBack((lk, lm), 0, int(a + 1), l0, x0))
    return tuple(out)


def _seen_run(seen: np.ndarray, f: int, way: int, most: int) -> int:
    """How many frames from `f` on (`way` +1) or back (-1), `f` included, are seen in a row, counted up to `most`
    (a longer run is not walked to its end: a trial without gaps would take its length for every jump)."""
    n = 0
    while n < most and 0 <= f < seen.size and seen[f]:
        n, f = n + 1, f + way
    return n


def jumped_samples(model: Model, trials: Sequence[Trial], progress: Callable[[float], None] | None = None,
                   found: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """(frames of all trials, n_model_markers): each trial's episodes in the model's marker order, its
    fallen_samples (a marker left behind at one place) and its ghosts (broken_samples by GHOST_BREAK or more),
    stacked as the calibration stacks the trials; `progress(share of the frames done)`; `found`: each trial's
    episodes, if found already."""
    parts = []
    total, before = max(1, sum(t.n_frames for t in trials)), 0  # frames, and those of the trials done
    for i, t in enumerate(trials):
        jumps = found[i] if found is not None else episodes(
            t, None if progress is None else
            lambda done, t=t, before=before: progress((before + done * t.n_frames) / total), model)[0]
        before += t.n_frames
        index = {lab: i for i, lab in enumerate(t.labels)}
        cleaned = _gapped(t, jumps)
        out = fallen_samples(model, cleaned)
        out |= _ghosts(model, cleaned, out)
        for k, name in enumerate(model.marker_names):
            if name in index:
                out[:, k] |= jumps[:, index[name]]
        parts.append(out)
    return np.concatenate(parts)


LONE_STEADY = 0.015  # m: a marker of a segment next to the two is read where its distances to them spread no more

FALLEN_BLOCK_S = 0.5  # s: fallen_samples judges a trial in windows this long, a quarter of one apart ...
FALLEN_STILL = 0.010  # m ... where a marker stays within this of one place in the lab ...
FALLEN_TURN = 0.030  # m ... while most markers of its segment and of the segments next to it travel (their mean
# places in the window's two halves) and change their distances to it by more than this (every other one of its own;
# a segment's only marker: every one of the segments next to it)
FALLEN_ALONE_S = 1.0  # s: a segment's only marker so judged is taken where it stays at least this long
FALLEN_MATES = 0.020  # m: ... its own markers' distances to it change by more than this (a rigid turn about it keeps
# them to the skin's few mm; gait2392's R.Thigh.Rear on the floor 0.5 m below its thigh, the subject slowing at the
# walk's end: 24-27 mm, under FALLEN_TURN, and the fit ended 48.7 mm RMS)
# A marker that moved alone in a still trial keeps the frames where it sits at its segment's markers as the base model
# places it (the median of its distances to one or more of them over the base model's within these factors: a
# subject's size and a lab's own marker places; real statics' shapes spread up to 3.6x marker by marker, their median
# 0.5-2x) when every other frame it is seen in puts it further than FALLEN_FAR times those distances (off the body:
# a torso marker on the floor, 5x).
FALLEN_SIZES = (0.5, 2.0)
FALLEN_FAR = 3.0
FALLEN_OFF = 0.15  # m: a segment's only marker whose distance to every marker of its neighbours ranges this far in a
# still trial moved alone (a static's drift across one joint moves them 50 mm apart at most in the trials at hand)


def fallen_samples(model: Model, trial: Trial) -> np.ndarray:
    """(n_frames, n_model_markers) True where a marker stays at one place in the lab while its segment moves: one fallen
    off onto the floor, or stuck to an object.  In windows of FALLEN_BLOCK_S seconds a quarter of one apart, a
    marker that keeps within FALLEN_STILL of one place while most markers of its segment and of the segments next to
    it (the nearest with markers; two or more seen there), and every other marker of its own, travel and change
    their distances to it by more than FALLEN_TURN (its own: FALLEN_MATES) is not on the segment (a segment's only
    marker: where every marker next to it does so, and it stays FALLEN_ALONE_S or more, or lies FALLEN_FAR times
    further from them than elsewhere; its neighbours' neighbours join where those show under two markers; the trial's
    last steps judged too, where a fall shorter than a window lies): a marker on a thigh or a
    forearm cannot stay put while the markers around it travel away from it and back (pig_walk's RFRM frozen: the
    right elbow centre 687 mm off). A stance foot or a squat's feet stand still with the markers beside them (a
    one-marker foot's ankle marker barely travels in a stance); in a still trial nothing travels (a static's
    jittering keypoints change their distances, but their mean places stay). A knee marker lying on the floor from
    half-way through a walk otherwise pulled the left hip 185 mm from its place (pig_walk: marker RMS 3.0 -> 46.9
    mm). Windows overlap: a tibia marker fallen late in a walk lies there through blocks that each hold a stance,
    where its segment's ankle marker stands still (knee_l 101 mm off). A stretch so taken gives back, at its ends,
    the samples where the marker keeps its rigid distances to its segment's other markers (_on_their_segment: a toe
    standing beside a heel that fell)."""
    X = marker_columns(model, trial)
    F, M, _ = X.shape
    out = np.zeros((F, M), dtype=bool)
    step = max(1, int(round(FALLEN_BLOCK_S * trial.rate)) // 4)
    width = 4 * step  # a window: four steps
    if F < width:
        return out
    seg = [mk.segment for mk in model.markers]
    near = _marked_neighbours(model, np.isfinite(X).all(axis=2).any(axis=0))
    alone = np.zeros((F, M), dtype=bool)  # flagged with no other marker of its segment seen
    loose = np.zeros((F, M), dtype=bool)  # ... still while its neighbours travel, their distances to it changing less
    # Each window's spread of every marker (max - min over its frames; unseen in a frame: infinite), from the maxima
    # and minima of its four steps; and the last four, three, two and one steps at the trial's end (below).
    S = F // step
    seen_x = np.isfinite(X)
    top = np.where(seen_x, X, np.inf)[:S * step].reshape(S, step, M, 3).max(axis=1)
    bottom = np.where(seen_x, X, -np.inf)[:S * step].reshape(S, step, M, 3).min(axis=1)
    starts = [w * step for w in range(S - 3)]
    widths = [width] * len(starts)
    spreads = [np.linalg.norm(np.max([top[w:S - 3 + w] for w in range(4)], axis=0)
                              - np.min([bottom[w:S - 3 + w] for w in range(4)], axis=0), axis=2)]  # (S-3, M)
    # A fall lasts to the trial's end: one in its last window is also judged in the last three, two and one steps
    # (Rajagopal's L.Forearm on the floor for the walk's last 0.33-0.40 s, unseen by whole windows: the left arm's
    # centres 258-506 mm off).
    ends = [n * step for n in (4, 3, 2, 1)] if starts[-1] + width < F else [n * step for n in (3, 2, 1)]
    for n in ends:
        x = X[F - n:]
        starts.append(F - n)
        widths.append(n)
        spreads.append(np.where(seen_x[F - n:].all(axis=(0, 2)),
                                np.linalg.norm(np.max(x, axis=0) - np.min(x, axis=0), axis=1), np.inf)[None])
    spread = np.concatenate(spreads)
    # each marker's segment and those next to it, as a mask over the markers
    around = {g: np.array([s in {g, *near.get(g, ())} for s in seg]) for g in set(seg)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for w in np.flatnonzero((spread < FALLEN_STILL).any(axis=1)):
            a, b = starts[w], starts[w] + widths[w]
            x = X[a:b]
            seen = np.all(seen_x[a:b], axis=(0, 2))  # seen in every frame of the window
            # every marker's travel: its mean places in the window's halves (jitter averages out)
            h = x.shape[0] // 2
            moved = np.linalg.norm(np.ascontiguousarray(x[h:]).mean(axis=0)
                                   - np.ascontiguousarray(x[:h]).mean(axis=0), axis=1)
            if not np.any(moved[seen] > FALLEN_TURN):
                continue  # nothing travels here (a static): no marker is left behind
            seen_some = np.any(np.all(seen_x[a:b], axis=2), axis=0)  # ... in one frame or more
            for k in np.flatnonzero(spread[w] < FALLEN_STILL):
                refs = np.flatnonzero(around[seg[k]] & seen)
                refs = refs[refs != k].tolist()
                if len(refs) < 2:
                    continue
                travel = moved[refs]
                if np.median(travel) <= FALLEN_TURN:
                    continue
                d = np.linalg.norm(x[:, refs] - x[:, k:k + 1], axis=2)  # (frames, refs)
                change = d.max(axis=0) - d.min(axis=0)
                mates = [i for i, m in enumerate(refs) if seg[m] == seg[k]]
                if not mates:  # judged by the segments next to it alone: a one-marker foot in stance looks so to most
                    if any(seg[m] == seg[k] and seen_some[m] for m in range(M) if m != k):
                        continue  # ... but not a marker whose mate is unseen in part of the window (a heel's ghost
                        # left out made the toe beside it, standing in a stance, a foot's only marker)
                    if np.all(travel > FALLEN_TURN):  # ... so every one of them
                        if np.all(change > FALLEN_TURN):
                            alone[a:b, k] = True
                        else:  # a marker far off changes its distances little over a short window
                            loose[a:b, k] = True
                elif np.median(change) > FALLEN_TURN and np.all((travel[mates] > FALLEN_TURN)
                                                                 & (change[mates] > FALLEN_MATES)):  # and all its own
                    out[a:b, k] = True
    # A marker that moves alone in a still trial (most markers keep within FALLEN_TURN of one place, 5th to 95th
    # percentile over the trial: a static's marker dropping to the floor): it moves, and its distances to its
    # segment's other markers change by more, wherever the segment itself drifted (a static's arms drift 40-50 mm in
    # Rajagopal's static_walk_1, and a wrist or a biceps marker fallen there was kept: the forearm's pronation centre
    # 0.7-1.4 m off).  A segment's only marker: its distances to most of its neighbours' markers that stay put change
    # by more, or to every one of its neighbours' markers by FALLEN_OFF.  Which of its places was the segment's the
    # trial cannot say but by the base model (_where_modelled): the others are left out (a fallen thigh marker in
    # pig_walk's static had put the right knee centre 361 mm off).
    seen_all = np.all(np.isfinite(X), axis=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = np.nanpercentile(X, 5, axis=0), np.nanpercentile(X, 95, axis=0)  # (M, 3)
    moved = np.linalg.norm(hi - lo, axis=1)  # NaN for a marker never seen
    still_trial = bool(np.any(np.isfinite(moved))) and float(np.nanmedian(moved)) < FALLEN_TURN  # most markers stay
    seen_long = seen_all.sum(axis=0) >= width

    def change_to(k: int, refs: list[int]) -> np.ndarray:
        """How far each of marker k's distances to `refs` ranges over the trial (5th to 95th percentile)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            d = np.linalg.norm(X[:, refs] - X[:, k:k + 1], axis=2)  # (frames, refs), NaN where either is unseen
            return np.nanpercentile(d, 95, axis=0) - np.nanpercentile(d, 5, axis=0)

    for k in np.flatnonzero(moved > FALLEN_TURN) if still_trial else ():
        mates = [m for m in range(M) if m != k and seg[m] == seg[k] and seen_long[m]]
        others = [m for m in range(M) if seg[m] in near.get(seg[k], ()) and seen_long[m]]
        steady = [m for m in others if moved[m] <= FALLEN_TURN]
        if any(moved[m] > FALLEN_TURN for m in mates):
            # The segment drifted: most of its markers keep their distances to one another and break them with k
            # (a pair broken is k's where it moved the more of the two).
            change = change_to(k, mates)
            broken = sum(c > FALLEN_TURN and moved[m] < moved[k] for c, m in zip(change, mates, strict=True))
            hit = 2 * broken > len(mates)
        elif mates or len(steady) >= 2:  # its segment's and its neighbours' markers that stay put
            hit = np.median(change_to(k, mates + steady)) > FALLEN_TURN
        else:  # a segment's only marker beside drifting neighbours
            hit = bool(others) and bool(np.all(change_to(k, others) > FALLEN_OFF))
        if hit:
            out[:, k] = seen_all[:, k] & ~_where_modelled(X, k, mates, model.parameters().marker, width)
    # A segment's only marker judged by its neighbours alone is taken where it stays FALLEN_ALONE_S or more (a foot
    # with one marker stands still through a stance, under a second, while the shank's markers travel over it).
    # Shorter, it is taken where it lies FALLEN_FAR times or more further from every marker of its neighbours than it
    # does elsewhere in the trial: off the body (Rajagopal's L.Forearm on the floor for the walk's last 0.67 s, 1.0-1.3
    # m from the elbow's and wrist's markers it keeps 0.11-0.25 m from; the left arm's centres 340 mm off).  So is one
    # still where its neighbours travel without changing their distances to it by FALLEN_TURN: a marker a metre away
    # barely changes its distances as they pass (Rajagopal's R.Wrist on the floor for the walk's last 0.37 s, 21-29
    # mm; the right forearm's centres 377 mm off).
    longest = int(round(FALLEN_ALONE_S * trial.rate))
    for k in np.flatnonzero((alone | loose).any(axis=0)):
        runs = _runs(_grown(alone[:, k], X[:, k]))
        far_only = _runs(_grown(loose[:, k] & ~alone[:, k], X[:, k]))
        elsewhere = seen_all[:, k].copy()
        for a, b in runs + far_only:
            elsewhere[a:b] = False
        refs = [m for m in range(M) if seg[m] in near.get(seg[k], ())]
        for a, b in runs:
            if b - a >= longest or _far_from_neighbours(X, k, refs, slice(a, b), elsewhere, width):
                out[a:b, k] = True
        for a, b in far_only:
            if _far_from_neighbours(X, k, refs, slice(a, b), elsewhere, width):
                out[a:b, k] = True
    for k in np.flatnonzero(out.any(axis=0)):
        out[:, k] = _grown(out[:, k], X[:, k])
    return _on_their_segment(out, X, seg, width)


def _far_from_neighbours(X: np.ndarray, k: int, refs: list[int], run: slice, elsewhere: np.ndarray,
                         width: int) -> bool:
    """True when marker k lies, over the frames `run`, FALLEN_FAR times or more further from each of two or more
    markers `refs` (its neighbours' markers) than it does over the frames `elsewhere` (the median distance of each;
    pairs seen together in `width` frames or more there and in one frame or more of the run): no turn of a joint
    moves a marker so far from the markers across it."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        d = np.linalg.norm(X[:, refs] - X[:, k:k + 1], axis=2)  # (frames, refs), NaN where either is unseen
        judged = (np.sum(np.isfinite(d[elsewhere]), axis=0) >= width) & np.any(np.isfinite(d[run]), axis=0)
        if judged.sum() < 2:
            return False
        ratio = np.nanmedian(d[run][:, judged], axis=0) / np.nanmedian(d[elsewhere][:, judged], axis=0)
    return bool(np.all(ratio >= FALLEN_FAR))


def _where_modelled(X: np.ndarray, k: int, mates: list[int], base: np.ndarray, width: int) -> np.ndarray:
    """(frames,) True where marker k, moved alone in a still trial, sits among `mates` (its segment's other markers)
    as the base model (`base`: every marker's offset on its segment) places it, up to a size
    (FALLEN_SIZES), if those are `width` frames or more and every other frame it is seen in puts it FALLEN_FAR times
    further from them or more: there it was on its segment, elsewhere off the body (a torso marker fallen to the
    floor half-way through pig_walk's static: all its positions left out moved the left shoulder 14 mm).  Otherwise
    none: where both places could be the segment's (a marker dropped along the body, a shank's or a foot's marker
    dropped to the floor beside it), the trial cannot say which."""
    none = np.zeros(X.shape[0], dtype=bool)
    mates = [m for m in mates if np.linalg.norm(base[m] - base[k]) > SEGMENT_PAIR_MIN / 5]  # not at its own place
    if not mates:
        return none
    model_d = np.linalg.norm(base[mates] - base[k], axis=1)  # (mates,)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        size = np.nanmedian(np.linalg.norm(X[:, mates] - X[:, k:k + 1], axis=2) / model_d, axis=1)  # (frames,)
    seen = np.isfinite(size)
    lo, hi = FALLEN_SIZES
    fits = seen & (size >= lo) & (size <= hi)
    far = seen & (size >= FALLEN_FAR)
    if fits.sum() >= width and far.any() and np.all(fits | far | ~seen):
        return fits
    return none


def _on_their_segment(out: np.ndarray, X: np.ndarray, seg: list[str], width: int) -> np.ndarray:
    """`out` less the samples at each end of a flagged stretch where the marker keeps its distance to every other
    marker of its segment, as it has in the frames where neither is flagged (within FALLEN_STILL, or the pair's own
    scatter there): there its segment carries it.  A window judges a marker by its mates' travel over the whole
    window, so a toe standing through a stance was taken from the stance's start for its heel lying elsewhere from the
    stance's end (pig_walk's LTOE: 69 frames of the rigid 237 mm to LHEE left out, the left ankle then turned 25 deg on
    the heel alone).  Inside a stretch a fallen marker's one distance can pass through its rigid value as its mate
    swings by (a tibia's two markers): only the ends that hold it from the stretch's edge are kept."""
    kept = out.copy()
    seen = np.all(np.isfinite(X), axis=2)
    for k in np.flatnonzero(out.any(axis=0)):
        rigid, judged = np.ones(out.shape[0], dtype=bool), False
        for m in (m for m in range(X.shape[1]) if m != k and seg[m] == seg[k]):
            both = seen[:, k] & seen[:, m] & ~out[:, k] & ~out[:, m]
            if both.sum() < width:  # too few frames to know the pair's distance
                continue
            d = np.linalg.norm(X[:, k] - X[:, m], axis=1)
            ref = float(np.median(d[both]))
            tol = max(FALLEN_STILL, float(np.percentile(np.abs(d[both] - ref), 99)))
            with np.errstate(invalid="ignore"):
                rigid &= np.abs(d - ref) <= tol  # False where either is unseen
            judged = True
        if not judged:
            continue
        for a, b in _runs(out[:, k]):
            f = a
            while f < b and rigid[f]:
                kept[f, k], f = False, f + 1
            f = b - 1
            while f >= a and rigid[f]:
                kept[f, k], f = False, f - 1
    return kept


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """The (start, stop) of each run of True in `mask`."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _grown(mask: np.ndarray, x: np.ndarray) -> np.ndarray:
    """`mask` (frames,) with each run grown to the frames next to it where the marker `x` (frames, 3) is still within
    FALLEN_STILL of the run's place (a fall lies inside a block: its frames after the fall)."""
    out = mask.copy()
    for a, b in _runs(mask):
        there = np.linalg.norm(x - np.median(x[a:b], axis=0), axis=1) < FALLEN_STILL  # False where unseen
        f = a - 1
        while f >= 0 and there[f]:
            out[f], f = True, f - 1
        f = b
        while f < out.size and there[f]:
            out[f], f = True, f + 1
    return out


def _marked_neighbours(model: Model, shown: np.ndarray | None = None) -> dict[str, set[str]]:
    """Each segment's nearest segments with markers across its joints, through any without (a calcaneus's: the
    tibia, past the markerless talus).  With `shown` (the model's markers a trial shows): markers it shows, and where
    those segments show fewer than two, the segments with markers next to them too (a radius whose only marker is the
    wrist's, next to an ulna with one: the humerus's; Rajagopal's forearms)."""
    adjacent: dict[str, set[str]] = {}
    for j in model.joints:
        adjacent.setdefault(j.parent, set()).add(j.child)
        adjacent.setdefault(j.child, set()).add(j.parent)
    on = [mk.segment for k, mk in enumerate(model.markers) if shown is None or shown[k]]
    marked = set(on)

    def nearest(start: str, done: set[str]) -> set[str]:
        found, todo = set(), list(adjacent.get(start, ()))
        while todo:
            sg = todo.pop()
            if sg in done:
                continue
            done.add(sg)
            if sg in marked:
                found.add(sg)
            else:
                todo.extend(adjacent.get(sg, ()))
        return found

    out: dict[str, set[str]] = {}
    for start in adjacent:
        done = {start}
        found = nearest(start, done)
        if shown is not None and sum(on.count(sg) for sg in found) < 2:
            for sg in list(found):
                found |= nearest(sg, done)
        out[start] = found
    return out


def without_broken(model: Model, trial: Trial, jumps: np.ndarray | None = None,
                   broken: bool = True) -> tuple[Trial, int]:
    """`trial` with the samples broken_samples, fallen_samples and episodes flag set to gaps, and how many there were.
    `jumps`: the trial's episodes, if found already.  `broken` False: broken_samples' by GHOST_BREAK only (the
    samples the calibration leaves out before its start, jumped_samples', as `calibrate ik` leaves them out)."""
    index = {lab: i for i, lab in enumerate(trial.labels)}
    bad = episodes(trial, model=model)[0] if jumps is None else jumps.copy()
    cleaned = _gapped(trial, bad)
    rigid = fallen_samples(model, cleaned)
    rigid |= _ghosts(model, cleaned, rigid)
    if broken:
        rigid |= broken_samples(model, cleaned)
    for k, name in enumerate(model.marker_names):
        if name in index:
            bad[:, index[name]] |= rigid[:, k]
    if not bad.any():
        return trial, 0
    return _gapped(trial, bad), int(bad.sum())


def _ghosts(model: Model, trial: Trial, fallen: np.ndarray) -> np.ndarray:
    """broken_samples by GHOST_BREAK (frames, model markers) of `trial` judged without its `fallen` samples (frames,
    model markers): a marker fallen off for most of a trial would put its pairs' medians on the floor, and its frames
    on the body would read broken (pig_walk's static with T10 on the floor from frame 96 of 240)."""
    index = {lab: i for i, lab in enumerate(trial.labels)}
    bad = np.zeros((trial.n_frames, len(trial.labels)), dtype=bool)
    for k, name in enumerate(model.marker_names):
        if name in index:
            bad[:, index[name]] = fallen[:, k]
    return broken_samples(model, _gapped(trial, bad), GHOST_BREAK)


def _gapped(trial: Trial, bad: np.ndarray) -> Trial:
    """`trial` with the samples `bad` (n_frames, n_markers) set to gaps: the checks by rigidity judge a trial without
    its jumps (a heel's ghost of two frames 1.5 m off, in a window's mean, made the toe beside it look left behind
    by its foot: pig_walk's LTOE left out for 83 frames)."""
    if not bad.any():
        return trial
    markers = np.array(trial.markers)
    markers[bad] = np.nan
    return replace(trial, markers=markers)


def weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The value below and above which lie at most half the total weight."""
    order = np.argsort(x)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def seed_trial(trial: Trial, max_frames: int) -> Trial:
    """The trial low-passed at SEED_CUTOFF_HZ and thinned to about `max_frames` evenly spaced
    frames: the MTB seed's cost grows with the frames and it needs only a few hundred."""
    k = trial.n_frames // max_frames
    if k < 2 or not SEED_CUTOFF_HZ < trial.rate / 2:
        return trial
    markers = lowpass(trial.markers, trial.rate, SEED_CUTOFF_HZ)[::k]
    return Trial(trial.labels, markers, trial.rate / k, trial.first_frame, trial.source)
