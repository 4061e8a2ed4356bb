"""The segment a trial marker the model does not know rides on, from the model's own poses.

Seed 002's rigidity (calibrate.seed.association) places a new label on the segment whose known markers it keeps
its distances to, within the trial's noise.  Real clusters defeat it: a thigh plate's markers keep their distances
to each other to a fraction of a millimetre, which sets the threshold, while the skin under the plate moves them
2-5 mm against the segment's anatomical markers (Camargo et al.'s 2021 level-ground walk, in AddBiomechanics' data:
all twelve thigh and shank cluster markers and the four toe markers left out on human.urdf).  And a segment with one
known marker near a joint (a lateral knee marker) cannot tell a shank marker from a thigh one by distances at all:
both turn about the knee, near that marker.

Here the model says where each segment is: every segment's pose from the known markers (frame-wise inverse
kinematics of the base model on a few dozen frames of the moving trials), and each new label's position in each
segment's frame over those frames.  On its own segment the label stays put up to the skin's motion and the
poses' error; on any other, a joint's turn carries it through tens of centimetres.  The label goes to the segment
where its place spreads least, if that spread is under HOST_SPREAD and at most HOST_RATIO of the next segment's."""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..io.labels import plug_in_gait_name
from ..io.motion import Motion
from ..io.trial import Trial
from ..model.model import Joint, Model
from ..model.sides import named_side, unsided

HOST_FRAMES = 40  # about this many evenly spaced frames of the moving trials are posed (about 0.1 s a round)
HOST_SPREAD = 0.020  # m: RMS spread of a label's place on its segment (skin, the few markers' poses) at most
HOST_RATIO = 0.5  # ... and at most this share of its spread on the next-best segment
#: m: a Plug-in Gait wand the poses leave out goes on the segment its name says where its place spreads least there
#: and, as its distance from and along the segment's long axis (axial_spread), at most this: as a host's (HOST_SPREAD)
AXIAL_SPREAD = 0.020
HOST_ROUNDS = 3  # rounds: the labels placed join the known markers, the others judged again
PLACEHOLDER_TAG = "placeholder:"  # a placeholder marker's label while trial_exchanges hosts it as new
TURNING = np.radians(1.0)  # a markerless segment whose joint turns less (SD over the poses) rides on its parent


# The medial markers a lab puts beside a lateral one, by the joint whose axis they straddle, as their names spell
# them (the side token and separators removed, lower case): the femoral epicondyle, the medial malleolus, the humeral
# epicondyle (Plug-in Gait's add-ons, CAST's FME / TAM / HME, OpenCap's, OpenSim's marker sets; the medial twins of
# the lateral spellings calibrate.io.labels reads as KNE, ANK and ELB: a treadmill lab's LMEE beside its LLEE; Plug-in
# Gait's and the CGM's LMED / RMED, its medial malleoli as pyCGM2 reads them; clinical labs' LKNEMED, RMed_kn, LMKN).  A
# static often carries them alone (taken off for the walk), where no motion shows which segment they ride on; the name
# does: the segment the joint hangs from.
MEDIAL_NAMES = {
    "knee": {"mkne", "mknee", "kneem", "knem", "knm", "kneemed", "medknee", "medkne", "kneemedial", "medialknee",
             "fme", "mfc", "mfe", "mek", "knemed", "medkn", "mkn", "medfemepicondyle", "medialfemoralepicondyle",
             "femurmedialepicondyle", "medfemcondyle", "medialfemoralcondyle", "kneein", "mepi", "medepi", "cm", "me"},
    "ankle": {"mank", "mankle", "ankm", "anklem", "anklemed", "medankle", "ankmed", "anklemedial", "medialankle",
              "mmal", "mma", "mm", "mmall", "med", "medank", "tam", "medmal", "malmed", "medmalleolus",
              "medialmalleolus", "malleolusmed", "anklein"},
    "elbow": {"melb", "melbow", "elbm", "elbowm", "elbowmed", "medelbow", "elbmed", "elbowmedial", "medialelbow",
              "mel", "hme", "mhe", "mee", "medialhumeralepicondyle", "humeralmedialepicondyle",
              "humerusmedialepicondyle", "elbowin"},
}


# Plug-in Gait's leg wand names (its labels without their side, as calibrate.io.labels' alias table reads a label:
# LTHI, L_Thigh and RightThighWand alike) and the segment each rides on, and how models name those segments
# (models/human.urdf, gait2392, Rajagopal2016: femur_r, tibia_l).  Where the model's poses cannot tell a label's
# segment from its neighbour by the twice they ask (HOST_RATIO), the name decides between them: pig_walk's RTHI on
# Rajagopal2016, 14.6 mm on femur_r against 28 on the pelvis (a walk turns the hip little).  Not the trunk's or the
# arms' (docs/benchmarks.md, "Plug-in Gait names"): pig_walk's PSIS markers on gait2392 (whose pelvis has a V.Sacral
# instead), put on the pelvis by their names, carried its lumbar centre 135-252 mm from the scaled base model's; its
# LUPA on Rajagopal's humerus_l freed the forearm's pronation, which the walk then turned 60 deg, the elbow 59 deg.
NAMED_SEGMENTS = {
    "thigh": {"THI"},
    "shank": {"TIB"},
}
SEGMENT_NAMES = {
    "thigh": ("femur", "thigh"),
    "shank": ("tibia", "shank"),
    "pelvis": ("pelvis",),
}
#: Midline Plug-in Gait markers the name decides for likewise (no side): the sacral marker on the pelvis, where a
#: walk or a run turns the trunk little over it (AddBiomechanics' Expert2: SACR 10.6 mm on the pelvis against the
#: torso's 20, its pelvis's only marker behind the ASIS).
NAMED_MIDLINE = {"SACR": "pelvis"}
#: The named segment is taken unless another segment holds the label twice as still: the data decide only what
#: they separate (HOST_RATIO), the name the rest.
NAME_TIE = 1 / HOST_RATIO


def _named(label: str, description: str | None = None) -> tuple[str, str | None] | None:
    """(kind, side) of a Plug-in Gait wand's name (NAMED_SEGMENTS: ('thigh', 'left') for LTHI, L_Thigh), or of a
    midline marker's (NAMED_MIDLINE: ('pelvis', None) for SACR, V.Sacral), or None.  A label no alias reads is read
    by the trial's `description` of it (c3d.org's sample10: VSAC, "V.Sacral")."""
    code = plug_in_gait_name(label) or (plug_in_gait_name(description) if description else None)
    if code in NAMED_MIDLINE:
        return NAMED_MIDLINE[code], None
    if code is None or code[0] not in "LR":
        return None
    kind = next((kind for kind, names in NAMED_SEGMENTS.items() if code[1:] in names), None)
    return None if kind is None else (kind, "left" if code[0] == "L" else "right")


def described_labels(trials: Sequence[Trial]) -> dict[str, str]:
    """Each label the trials' files describe -> its description (Trial.descriptions, the last trial's where several
    describe it), which a name-reading test reads where the label's own name says nothing."""
    return {lab: said for t in trials for lab, said in t.descriptions.items()}


def named_kind(label: str, description: str | None = None) -> str | None:
    """The segment a Plug-in Gait wand's name says (NAMED_SEGMENTS: 'thigh' for LTHI, L_Thigh or RightThighWand,
    'shank' for RTIB; NAMED_MIDLINE: 'pelvis' for SACR, V.Sacral), or None (another name, or a wand's without its
    side); by the trial's `description` of the label where its name says nothing."""
    named = _named(label, description)
    return None if named is None else named[0]


def named_segments(model: Model, label: str, description: str | None = None) -> tuple[str, ...]:
    """The model's segments of the kind `label`'s name (or its `description`) says (named_kind), on its side; () for
    none."""
    named = _named(label, description)
    if named is None:
        return ()
    kind, side = named
    return tuple(s.name for s in model.segments
                 if any(n in s.name.lower() for n in SEGMENT_NAMES[kind]) and named_side(s.name) == side)


# The names a lab gives a joint's centre (a point its software computed and wrote as a marker: Expert1's and OpenCap's
# R_HJC and R_HJC_reg), by the joint, as they spell them without the side token and separators, lower case.  Such a
# point is fixed in both segments of its joint and in no other; the model's poses, which fit a base model of another
# size, can leave it stiller on a third (Expert1's L_HJC on the torso, 20 mm, against the pelvis's 44).
CENTRE_NAMES = {
    "hip": {"hjc", "hipjc", "hipjointcentre", "hipjointcenter", "hipcentre", "hipcenter", "hjcreg"},
    "knee": {"kjc", "kneejc", "kneejointcentre", "kneejointcenter", "kneecentre", "kneecenter"},
    "ankle": {"ajc", "anklejc", "anklejointcentre", "anklejointcenter", "anklecentre", "anklecenter"},
    "shoulder": {"sjc", "shoulderjc", "shoulderjointcentre", "shoulderjointcenter", "shouldercentre",
                 "shouldercenter", "gh", "ghjc"},
    "elbow": {"ejc", "elbowjc", "elbowjointcentre", "elbowjointcenter", "elbowcentre", "elbowcenter"},
    "wrist": {"wjc", "wristjc", "wristjointcentre", "wristjointcenter", "wristcentre", "wristcenter"},
}


def _name_body(label: str) -> str:
    """A label's name without its side token and separators, lower case, OpenCap's `study` suffix dropped."""
    return re.sub(r"[._\- ]", "", unsided(label)).lower().removesuffix("study")


def centre_joint(model: Model, label: str) -> Joint | None:
    """The joint whose centre `label`'s name says it marks (CENTRE_NAMES: R_HJC, the right hip), on the name's side;
    None for any other name, no side, or a model without that joint."""
    side = named_side(label)
    part = next((p for p, names in CENTRE_NAMES.items() if _name_body(label) in names), None)
    if side is None or part is None:
        return None
    return next((j for j in model.joints if part in j.name.lower() and named_side(j.name) == side), None)


def centre_segments(model: Model, label: str) -> tuple[str, str] | None:
    """(parent, child) of the joint whose centre `label`'s name says it marks (centre_joint), or None."""
    joint = centre_joint(model, label)
    return None if joint is None else (joint.parent, joint.child)


def centre_labels(model: Model, labels: Sequence[str], skip: Sequence[str] = ()) -> dict[str, Joint]:
    """The trial `labels` `model` lacks that name a joint's centre (centre_joint) -> that joint, one per joint and none
    for the joints in `skip`: where a lab wrote several points for one centre (Expert1's and OpenCap's R_HJC and
    R_HJC_reg, 13-45 mm apart), the plainest name (the shortest without its side and separators), its chosen one;
    the others stay unknown labels."""
    known = set(model.marker_names)
    by_joint: dict[str, list[tuple[int, str, Joint]]] = {}
    for lab in dict.fromkeys(labels):
        joint = centre_joint(model, lab) if lab not in known else None
        if joint is not None and joint.name not in skip:
            by_joint.setdefault(joint.name, []).append((len(_name_body(lab)), lab, joint))
    return {lab: joint for _, lab, joint in map(min, by_joint.values())}


def medial_host(model: Model, label: str) -> tuple[str, str] | None:
    """(segment, joint) where a medial marker's name puts it (MEDIAL_NAMES): the segment the model's knee, ankle or
    elbow hinge of the side the name says hangs from (the hinge's name has the joint's and its side's, as
    models/human.urdf's knee_l, gait2392's knee_r, Rajagopal2016's walker_knee_r); None for any other name, no side,
    or a model without that hinge."""
    side = named_side(label)
    part = next((p for p, names in MEDIAL_NAMES.items() if _name_body(label) in names), None)
    if side is None or part is None:
        return None
    for j in model.joints:
        if j.kind == "hinge" and part in j.name.lower() and named_side(j.name) == side:
            return j.parent, j.name
    return None


@dataclass(frozen=True)
class Host:
    """Where a new label's place spreads least: `segment` (None: no segment qualifies), its RMS spread there
    and on the `runner_up` segment (m), and the label's median place in `segment`'s frame (m)."""

    label: str
    segment: str | None
    best: str  # the segment where its place spreads least (`segment` when that qualifies)
    spread: float
    runner_up: str
    runner_up_spread: float
    place: np.ndarray
    named: str = ""  # the segment kind its name says, where that decided between near ties (named_kind)
    # m: its place's RMS spread on `best` as its distance from and along that segment's long axis (axial_spread)
    axial: float = math.inf

    def reason(self) -> str:
        """Why it was placed there, or (no segment) left out, in the words of the rigidity test's reasons."""
        if self.segment:
            by = f"; its name says the {self.named}, which decides" if self.named else ""
            return (f"on the model's poses its place on {self.segment} spreads {1e3 * self.spread:.1f} mm RMS "
                    f"(on {self.runner_up}, the next: {1e3 * self.runner_up_spread:.0f} mm){by}")
        return (f"on the model's poses its place spreads {1e3 * self.spread:.1f} mm RMS on {self.best} at best, "
                f"{1e3 * self.runner_up_spread:.0f} on {self.runner_up} (a host: under "
                f"{1e3 * HOST_SPREAD:.0f} mm and half the next)")


def kinematic_hosts(model: Model, trials: Sequence[Trial], labels: Sequence[str],
                    frames: int = HOST_FRAMES, rounds: int = HOST_ROUNDS,
                    cache: BasePoses | None = None) -> dict[str, Host]:
    """Each of `labels` (trial markers `model` does not know) -> its Host, judged over about `frames` evenly spaced
    frames of `trials` (the moving ones) posed by the base model's known markers; labels no posed frame shows
    are left out of the result.  Candidates: the segments that carry a known marker the trials show, and the
    markerless ones whose joint turns in those poses (TURNING).  Up to `rounds` times, the labels placed so far join
    the known markers at their places and the others are judged again on the better poses (a thigh with one known
    marker, a lateral knee's, is posed about its long axis by its first cluster marker found).  `cache`: the
    association's BasePoses (the first round's poses are the base model's)."""
    from ..model.model import add_markers

    picked = pick_frames(trials, frames)
    out: dict[str, Host] = {}
    posed = model
    poses: dict[int, Motion] = {}
    for _ in range(rounds):
        todo = [lab for lab in labels if lab not in out or out[lab].segment is None]
        found = _hosts(posed, picked, todo, poses, cache)
        out.update(found)
        placed = {lab: (h.segment, h.place) for lab, h in found.items() if h.segment is not None}
        if not placed or all(h.segment is not None for h in out.values()):
            break
        posed = add_markers(posed, placed)
    return out


def pick_frames(trials: Sequence[Trial], frames: int) -> list[Trial]:
    """About `frames` evenly spaced frames of `trials`, shared among them by their lengths."""
    total = sum(t.n_frames for t in trials)
    picked = []
    for t in trials:
        n = max(2, round(frames * t.n_frames / total))
        idx = np.unique(np.linspace(0, t.n_frames - 1, min(n, t.n_frames)).astype(int))
        picked.append(replace(t, markers=t.markers[idx], model_outputs={}, output_kinds={}, output_units={}))
    return picked


class BasePoses:
    """The base model's frame-wise fits to its known markers (calibrate.solve.ik, DECISION_TOLERANCE), each made once
    per model and frames: one association's host tests (kinematic_hosts' first round, past_joints, beyond_joints) pose
    the same model on the same picked frames (c3d.org's sample28 walk: 8 fits, 4 of them repeats, 1.0 s of its 7.8).
    Scratch for one association, as Pinocchio's Data is for its Model; a fit from a given start is not kept."""

    def __init__(self) -> None:
        self._fits: dict[tuple, object] = {}

    def fit(self, model: Model, trial: Trial, start: Motion | None = None):
        """The model's fit to `trial`'s frames (an IKResult), from `start` (a motion of those frames) if given
        (its kinematics from build_kinematics, which keeps each structure's)."""
        from ..model.kinematics import build_kinematics
        from ..solve.ik import DECISION_TOLERANCE, inverse_kinematics

        if start is not None:
            return inverse_kinematics(build_kinematics(model), trial, model.parameters(), tolerance=DECISION_TOLERANCE,
                                      start=start)
        known = set(model.marker_names)
        key = (id(model.pin), tuple(model.marker_names), model.parameters().vector().tobytes(),
               tuple(lab for lab in trial.labels if lab in known), trial.markers.shape,
               hashlib.blake2b(np.ascontiguousarray(trial.markers).tobytes(), digest_size=16).digest())
        if key not in self._fits:
            self._fits[key] = inverse_kinematics(build_kinematics(model), trial, model.parameters(),
                                                 tolerance=DECISION_TOLERANCE)
        return self._fits[key]


def _posed(model: Model, trials: Sequence[Trial], labels: Sequence[str],
           poses: dict[int, Motion] | None = None, cache: BasePoses | None = None) -> list[tuple[Trial, object]]:
    """The base model's frame-wise fits (calibrate.solve.ik) to its known markers in those of `trials` (already
    picked) that show any of `labels`, as (trial, fit).  `poses`: the last round's poses of those trials (by index),
    where each frame's fit starts; the new ones are written there.  `cache`: where fits from no start are kept and
    found again (BasePoses; a new one, used once, if None)."""
    known = set(model.marker_names)
    if not labels or not any(lab in known for t in trials for lab in t.labels):
        return []
    cache = BasePoses() if cache is None else cache
    poses = {} if poses is None else poses
    fits = []
    for i, t in enumerate(trials):
        if any(lab in t.labels for lab in labels):
            fit = cache.fit(model, t, poses.get(i))
            poses[i] = fit.motion
            fits.append((t, fit))
    return fits


def local_places(model: Model, fits: Sequence[tuple[Trial, object]], labels: Sequence[str],
                  segments: Sequence[str]) -> dict[str, np.ndarray]:
    """Each of `labels` -> its positions in each of `segments`' frames over the posed frames that show it
    ((frames, segments, 3), m); labels seen in fewer than three posed frames are left out."""
    import pinocchio as pin

    data = model.pin.createData()
    fids = [model.pin.getFrameId(s) for s in segments]
    local: dict[str, list[np.ndarray]] = {lab: [] for lab in labels}
    for t, fit in fits:
        have = [lab for lab in labels if lab in t.labels]
        m = fit.motion
        X = t.select(have).markers  # (F, n, 3)
        for f in range(m.n_frames):
            if not np.isfinite(fit.marker_rms[f]):
                continue
            pin.framesForwardKinematics(model.pin, data, model.pin_configuration(m.root_translation[f],
                                                                                 m.root_quaternion[f], m.angles[f]))
            R = np.array([data.oMf[i].rotation for i in fids])  # (segments, 3, 3)
            o = np.array([data.oMf[i].translation for i in fids])
            for k, lab in enumerate(have):
                if np.all(np.isfinite(X[f, k])):
                    local[lab].append(np.einsum("sji,sj->si", R, X[f, k] - o))  # (segments, 3)
    return {lab: np.array(rows) for lab, rows in local.items() if len(rows) >= 3}


def _hosts(model: Model, trials: Sequence[Trial], labels: Sequence[str],
           poses: dict[int, Motion] | None = None, cache: BasePoses | None = None) -> dict[str, Host]:
    """One round of kinematic_hosts on the frames `trials` (already picked).  `poses`: the last round's poses of
    those trials (by index), where each frame's fit starts (a round only adds the labels placed to the known
    markers: the poses move little, and from scratch each frame took 5-10 steps, on gait2392 half of the hosts'
    time); the new ones are written there."""
    fits = _posed(model, trials, labels, poses, cache)
    if not fits:
        return {}
    candidates = _candidates(model, trials, fits)
    out = {}
    described = described_labels(trials)
    for lab, P in local_places(model, fits, labels, candidates).items():
        mid = np.median(P, axis=0)
        spread = np.sqrt(np.mean(np.sum((P - mid) ** 2, axis=2), axis=0))  # (segments,)
        joint = centre_segments(model, lab)
        if joint is not None:  # a joint's centre, as its name says: on one of that joint's segments or none
            spread = np.where(np.isin(candidates, joint), spread, np.inf)
            if not np.isfinite(spread).any():
                continue
        order = [k for k in np.argsort(spread) if np.isfinite(spread[k])]
        best, second = int(order[0]), int(order[1]) if len(order) > 1 else int(order[0])
        ok = spread[best] <= HOST_SPREAD and (len(order) == 1 or spread[best] <= HOST_RATIO * spread[second])
        pick = None if ok else _named_host(model, lab, candidates, spread, described.get(lab))
        by_name = pick is not None
        if by_name:  # a near tie the name decides: the named segment, against the best of the others
            best, second = pick, next(k for k in order if k != pick)
            ok = True
        out[lab] = Host(lab, candidates[best] if ok else None, candidates[best], float(spread[best]),
                        candidates[second], float(spread[second]), mid[best],
                        named_kind(lab, described.get(lab)) if by_name else "",
                        axial_spread(model, candidates[best], P[:, best]))
    return out


def axial_spread(model: Model, segment: str, places: np.ndarray) -> float:
    """The RMS spread (m) of a label's `places` in `segment`'s frame (frames, 3) as its distance from the segment's
    long axis (from its origin to its farthest child joint: a femur's hip to its knee) and its place along it: what
    stays of the spread when the poses leave the segment's turn about that axis loose (a thigh posed by its knee
    marker and its hip alone).  inf for a segment without a child joint."""
    offsets = [np.asarray(u.xyz, dtype=float) for j in model.joints if j.parent == segment
               for u in model.urdf_joints if u.name == j.urdf_joints[0]]
    far = max(offsets, key=np.linalg.norm, default=None)
    if far is None or np.linalg.norm(far) < 1e-9:
        return math.inf
    axis = far / np.linalg.norm(far)
    along = places @ axis
    across = np.linalg.norm(places - along[:, None] * axis, axis=1)
    return float(np.sqrt(np.mean((along - np.median(along)) ** 2 + (across - np.median(across)) ** 2)))


def _candidates(model: Model, trials: Sequence[Trial], fits: Sequence[tuple[Trial, object]]) -> list[str]:
    """The segments a new label may ride on, on the posed frames `fits` (_posed) of `trials`: every segment with a known
    marker the trials show, and every markerless one that turns against its parent in these poses (a forearm marker
    may ride on the ulna, where the radius's pronation carries it 1-2 mm further: the two then tie, and it is left out
    rather than put on the radius); a segment welded or locked to its parent (a patella, an OpenSim model's toes)
    rides on it and would only tie with it."""
    known = set(model.marker_names)
    shown = {lab for t in trials for lab in t.labels if lab in known}
    angles = np.concatenate([f.motion.angles for _, f in fits])
    turning = {j.child for j in model.joints
               if any(np.nanstd(angles[:, model.dof_index(d)]) >= TURNING for d in j.dofs)}
    return [s.name for s in model.segments if any(m in shown for m in s.markers) or s.name in turning]


def place_spreads(model: Model, trials: Sequence[Trial], labels: Sequence[str], segments: Sequence[str] = (),
                  frames: int = HOST_FRAMES) -> dict[str, dict[str, float]]:
    """Each of `labels` -> segment -> the RMS spread (m) of its place in that segment's frame over about `frames` evenly
    spaced frames of `trials` posed by the base model's known markers (kinematic_hosts' measure), on the candidate
    segments and `segments`; labels seen in fewer than three posed frames are left out."""
    picked = pick_frames(trials, frames)
    fits = _posed(model, picked, labels)
    if not fits:
        return {}
    names = list(dict.fromkeys([*_candidates(model, picked, fits), *segments]))
    out = {}
    for lab, P in local_places(model, fits, labels, names).items():
        spread = np.sqrt(np.mean(np.sum((P - np.median(P, axis=0)) ** 2, axis=2), axis=0))
        out[lab] = dict(zip(names, map(float, spread), strict=True))
    return out


def _named_host(model: Model, label: str, candidates: Sequence[str], spread: np.ndarray,
                description: str | None = None) -> int | None:
    """The candidate `label`'s name (or the trial's `description` of it) decides for where the spreads alone do not
    (NAMED_SEGMENTS), or None: a segment of the kind it names, its place spreading there under HOST_SPREAD and at most
    NAME_TIE times the best, and no other segment of that kind within 1 / HOST_RATIO of it."""
    named = named_segments(model, label, description)
    own = sorted((spread[k], k) for k, c in enumerate(candidates) if c in named)
    if len(candidates) < 2 or not own or len(own) > 1 and own[0][0] > HOST_RATIO * own[1][0]:
        return None  # none, or two of its kind that tie: the name cannot decide between them
    ok = own[0][0] <= HOST_SPREAD and own[0][0] <= NAME_TIE * float(np.min(spread))
    return own[0][1] if ok else None


# Joints with more rotations than this (a ball: a hip, a shoulder, a lumbar joint) open no unposed chain below a
# segment: over their ranges the markers below sweep a volume, where a marker of the segment itself sits too (BTKData's
# ADemo1: the sacral wand's markers had been judged past the lumbar and shoulder, by the forearm's marker)
UNPOSED_DOFS = 2


def _chains(model: Model) -> dict[str, list[str]]:
    """Joint name -> the segments below it reached through joints of at most UNPOSED_DOFS rotations (it included)."""
    kids: dict[str, list] = {sg.name: [] for sg in model.segments}
    for j in model.joints:
        kids[j.parent].append(j)

    def down(joint) -> list[str]:
        return [joint.child] + [d for k in kids[joint.child] if len(k.dofs) <= UNPOSED_DOFS for d in down(k)]

    return {j.name: down(j) for j in model.joints}


def unposed_below(model: Model, trials: Sequence[Trial]) -> dict[str, list[str]]:
    """Segment -> the segments below it, across a hinge or two-axis joint (and others below that, UNPOSED_DOFS), that
    carry model markers but that no marker the `trials` show poses (none on them or below them): a forearm whose
    markers the trials spell otherwise."""
    from ..model.resolve import descendants

    shown = {lab for t in trials for lab in t.labels} & set(model.marker_names)
    below = descendants(model)
    chains = _chains(model)
    marked = {s.name: list(s.markers) for s in model.segments}
    out: dict[str, list[str]] = {}
    for j in model.joints:
        if 0 < len(j.dofs) <= UNPOSED_DOFS and not any(m in shown for d in below[j.child] for m in marked[d]):
            out.setdefault(j.parent, []).extend(d for d in chains[j.name] if marked[d])
    return {s: ds for s, ds in out.items() if ds}


@dataclass(frozen=True)
class PastJoint:
    """A new label placed on `placed` that sits where the base model's `by`, a marker of `segment` below it across
    joints no marker the trials show moves, can reach: there it turned with `placed` on the model's poses, so no
    test could tell the two apart, and it is left out."""

    label: str
    placed: str
    by: str
    segment: str
    distance: float  # m: from where `by` comes nearest over those joints' ranges
    own: float  # m: from the nearest base-model marker of `placed`
    near: tuple[str, ...] = ()  # `by` and the markers below that come within NEAR_TIE as near: which it may be

    def reason(self) -> str:
        tie = f" (or {', '.join(m for m in self.near if m != self.by)}, as near)" if len(self.near) > 1 else ""
        return (f"it sits {1e3 * self.distance:.0f} mm from where the base model's {self.by}{tie} on {self.segment} "
                f"comes over the joints below {self.placed} (the nearest marker of {self.placed}: "
                f"{1e3 * self.own:.0f} mm), "
                f"and no marker the trials show moves those joints, so it turned with {self.placed} and no test "
                "tells the two apart: name it as the model's marker it is (--markers map.toml)")


NEAR_TIE = 0.010  # m: markers below that come this much nearer at most tie with the nearest (a wrist's two markers)
REACH_POSES = 512  # random poses of the joints below a segment, over their ranges, where its unposed markers may be
# ... up to this turn from the base model's pose: further, a flexed elbow folds the forearm's markers back onto the
# upper arm's distal half, where a marker of the humerus would then seem to sit past the elbow
REACH_TURN = np.pi / 2


def _reach(model: Model, segment: str, below: Sequence[str], rng: np.random.Generator
           ) -> list[tuple[np.ndarray, list[str], np.ndarray]]:
    """For each joint from `segment` down to segments of `below` (under it, unposed; a markerless talus between): the
    joint's centre in `segment`'s frame, the base model's markers below it, and their places in `segment`'s frame
    over REACH_POSES random poses of the joints down to them, within their limits and REACH_TURN
    ((poses, markers, 3), m)."""
    import pinocchio as pin

    chains = _chains(model)
    data = model.pin.createData()
    frame = model.pin.getFrameId(segment)
    out = []
    for joint in (j for j in model.joints if j.parent == segment and any(d in below for d in chains[j.name])):
        chain = chains[joint.name]
        dofs = [model.dof_index(d) for j in model.joints if j.child in chain for d in j.dofs]
        names = [m for sg in chain for m in model.segments[model.segment_index(sg)].markers]
        lo = np.array([model.dofs[i].lower for i in dofs])
        hi = np.array([model.dofs[i].upper for i in dofs])
        lo, hi = np.maximum(lo, -REACH_TURN), np.minimum(hi, REACH_TURN)
        fids = [model.pin.getFrameId(m) for m in names]
        at = np.empty((REACH_POSES, len(names), 3))
        for k in range(REACH_POSES):
            angles = np.zeros(model.n_dofs)
            angles[dofs] = 0.0 if k == 0 else rng.uniform(lo, hi)
            pin.framesForwardKinematics(model.pin, data, model.pin_configuration(np.zeros(3), [0, 0, 0, 1], angles))
            own = data.oMf[frame]
            at[k] = [own.actInv(data.oMf[f]).translation for f in fids]
        out.append((np.asarray(joint.centre, dtype=float), names, at))
    return out


def _about(axis: np.ndarray, points: np.ndarray) -> np.ndarray:
    """`points` (..., 3) as (along `axis`, distance from it): what stays when the segment turns about it."""
    u = axis / np.linalg.norm(axis)
    a = points @ u
    return np.stack([a, np.linalg.norm(points - a[..., None] * u, axis=-1)], axis=-1)


# A model marker whose direction from a joint's centre is nearer the joint's axis than across it lies along it: the
# joint's turn carries it little (in human.urdf a radius's wrist markers about its pronation axis, 3-11 deg; a
# forearm's, a hand's and a heel's markers about the elbow, wrist and ankle axes: 77-85 deg), so a label sitting by it
# is no reason to leave out (OpenCap's and AddBiomechanics' wrist markers on ulnae whose radius no known marker poses)
AXIAL = np.radians(45.0)


def _joints_between(model: Model, top: str, bottom: str) -> list:
    """The joints from segment `top` down to segment `bottom` (below it), top first."""
    joint_of = {j.child: j for j in model.joints}
    out = []
    while bottom != top and bottom in joint_of:
        out.append(joint_of[bottom])
        bottom = joint_of[bottom].parent
    return out[::-1]


def _along_axes(model: Model, marker: str, joints: Sequence) -> bool:
    """Whether the base model's `marker` lies along every axis of `joints` (above it), within AXIAL of each seen from
    its centre, in the neutral pose: the base model's geometry, not the label's place on poses a segment with few
    markers turns (OpenCap's wrist labels on an ulna posed by one marker: 19-33 deg from its pronation axis)."""
    import pinocchio as pin

    data = model.pin.createData()
    pin.framesForwardKinematics(model.pin, data, model.pin_configuration(np.zeros(3), [0, 0, 0, 1],
                                                                         np.zeros(model.n_dofs)))
    at = data.oMf[model.pin.getFrameId(marker)].translation
    axes = model.parameters().axis
    for j in joints:
        for d in j.dofs:
            joint = data.oMi[model.pin.getJointId(d)]
            v, axis = at - joint.translation, joint.rotation @ axes[model.dof_index(d)]
            if abs(v @ axis) < np.cos(AXIAL) * np.linalg.norm(v) * np.linalg.norm(axis):
                return False
    return True


def past_joints(model: Model, trials: Sequence[Trial], placed: dict[str, str],
                frames: int = HOST_FRAMES, cache: BasePoses | None = None) -> dict[str, PastJoint]:
    """Of `placed` (new label -> segment, by any test), those whose median place on their segment, on about `frames`
    frames of `trials` (the moving ones) posed by the base model's known markers, is nearer where a base-model marker
    of a segment below it that no shown marker poses (unposed_below) can come, over the joints' ranges, than to any
    of its own segment's.  Where no known marker moves an elbow, a wrist marker keeps its distances to the humerus's
    markers and its place on the humerus as well as they do (pig_walk's forearm and hand labels renamed: all put on
    the humeri, 9-19 mm RMS, which then carried the shoulder centres 91 and 117 mm from the scaled base model's);
    the base model's markers say it rides past the elbow, unless the marker it sits by lies along the axes of every
    joint down to it (AXIAL: a wrist marker on the ulna, above the radius's pronation).  A segment that shows fewer
    than three markers is compared about the line to the joint below (along it and off it): its turn about that line
    is what the unposed segment's markers would have fixed (pig_walk's humerus posed by its arm and elbow markers
    alone had put a forearm marker 87 mm off the line, where the base model's has it 5 mm).  `cache`: the
    association's BasePoses."""
    below = unposed_below(model, trials)
    on = {lab: seg for lab, seg in placed.items() if seg in below}
    if not on:
        return {}
    fits = _posed(model, pick_frames(trials, frames), list(on), cache=cache)
    if not fits:
        return {}
    segments = sorted(set(on.values()))
    rng = np.random.default_rng(0)
    reach = {sg: _reach(model, sg, below[sg], rng) for sg in segments}
    shown = {lab for t in trials for lab in t.labels}
    offsets = model.parameters().marker  # each model marker's place on its segment (the base model's, as posed)
    out = {}
    for lab, P in local_places(model, fits, list(on), segments).items():
        sg = on[lab]
        mid = np.median(P[:, segments.index(sg)], axis=0)
        mine = model.segments[model.segment_index(sg)].markers
        few = sum(m in shown for m in mine) < 3
        own_at = np.array([offsets[model.marker_index(m)] for m in mine]).reshape(-1, 3)
        for centre, names, at in reach[sg]:
            if few:
                d = np.linalg.norm(_about(centre, at) - _about(centre, mid), axis=2).min(axis=0)
                own = np.linalg.norm(_about(centre, own_at) - _about(centre, mid), axis=1)
            else:
                d = np.linalg.norm(at - mid, axis=2).min(axis=0)  # (markers,) nearest over the poses
                own = np.linalg.norm(own_at - mid, axis=1)
            k = int(np.argmin(d))
            near_own = float(own.min()) if len(own) else np.inf
            by = names[k]
            host = model.markers[model.marker_index(by)].segment
            if (d[k] < near_own and (lab not in out or d[k] < out[lab].distance)
                    and not _along_axes(model, by, _joints_between(model, sg, host))):
                near = tuple(names[i] for i in np.argsort(d) if d[i] <= d[k] + NEAR_TIE)
                out[lab] = PastJoint(lab, sg, by, host, float(d[k]), near_own, near)
    return out


# A cluster of new labels rigid with each other (CLUSTER_MIN or more: a rigid body's pose needs three) and with no
# segment's known markers, placed like a segment whose model markers the trials never show (a head band whose labels
# the model spells otherwise: AddBiomechanics' initial_off_treadmill, LHEAD, RHEAD, FHEAD and THEAD against
# human.urdf's LFHD, RFHD, LBHD and RBHD), rides on that segment: it then has markers, and its joint is fitted, not
# locked.  Placed like it: the cluster's centroid keeps the distances to the shown markers of the nearest segment above
# (three or more: a trunk's) that the segment's model markers' centroid has in the base model's neutral pose, at the
# subject's size there, to CLUSTER_REACH RMS (median over frames), and at most CLUSTER_RATIO of the next candidate's.
# Distances, not a pose: the trunk's rigid fit to the neutral model turns a head 150-250 mm away by its markers' skin
# and the model's shoulders (measured on the treadmill: its head band 185-205 mm from the head's markers so, 116 by
# distances; a simulated band 27 mm, Hamner's temples 175 mm from the nearest candidate, an ulna).
CLUSTER_MIN = 3
CLUSTER_REACH = 0.15  # m RMS: a head band above a head's forehead and back markers, the neck turned 10-20 deg
CLUSTER_RATIO = 0.5
# Candidates at most this many moving joints below their references: across one (a head on its neck) the distances
# stay near the neutral pose's; a hand hangs by the hip in the neutral pose and goes anywhere (Pose2Sim's augmented
# left hip and thigh markers, rigid in a balancing trial, had been put on hand_l, 29 mm RMS from a hanging hand's).
CLUSTER_JOINTS = 1


@dataclass(frozen=True)
class ClusterHost:
    """A cluster of mutually rigid new labels and the unseen segment placed most like it: `segment` (None: none near
    enough), how far its distances to the references differ from the segment's (m RMS, median over frames) and the
    next segment's."""

    labels: tuple[str, ...]
    segment: str | None
    best: str
    distance: float
    runner_up: str
    runner_up_distance: float
    places: tuple[np.ndarray, ...]  # each label's median place in best's frame on the poses (m, the base model's)

    def reason(self, label: str) -> str:
        """Why `label` (one of `labels`) was placed there, or left out."""
        others = ", ".join(lab for lab in self.labels if lab != label)
        where = (f"placed as the base model's markers of {self.best} (which the trials do not show) are: their "
                 f"distances to the markers above differ by {1e3 * self.distance:.0f} mm RMS"
                 + (f" ({self.runner_up}, the next: {1e3 * self.runner_up_distance:.0f} mm)"
                    if np.isfinite(self.runner_up_distance) else ""))
        if self.segment:
            return f"rigid with {others}, and {where}"
        return (f"rigid with {others}, none of them on a segment; {where}: a host is under "
                f"{1e3 * CLUSTER_REACH:.0f} mm and half the next")


def cluster_hosts(model: Model, trials: Sequence[Trial], labels: Sequence[str], threshold: float,
                  frames: int = HOST_FRAMES) -> dict[str, ClusterHost]:
    """Each of `labels` (new labels no other test placed) in a cluster of CLUSTER_MIN or more that keep their
    distances to each other within the rigidity `threshold` (m², calibrate.seed.association's, over every frame of
    `trials`, the moving ones) -> its ClusterHost, judged on about `frames` frames.  Candidates: the segments that
    carry model markers, none of which the trials show, and a segment above them that shows three or more known
    markers (the references)."""
    from ..seed.geometry import kabsch_batch
    from ..seed.rigidity import distance_variance

    known = set(model.marker_names)
    shown = {lab for t in trials for lab in t.labels if lab in known}
    parent = {j.child: j.parent for j in model.joints}
    moving = {j.child: bool(j.dofs) for j in model.joints}
    labels = [lab for lab in labels if all(lab in t.labels for t in trials)]
    candidates = []  # (segment, the shown markers of the nearest segment above with three or more)
    for sg in model.segments:
        if not sg.markers or any(m in shown for m in sg.markers):
            continue
        above, turns = parent.get(sg.name), int(moving.get(sg.name, False))
        while above is not None and turns <= CLUSTER_JOINTS:
            refs = [m for m in model.segments[model.segment_index(above)].markers if m in shown]
            if len(refs) >= 3:
                candidates.append((sg, refs))
                break
            turns += int(moving.get(above, False))
            above = parent.get(above)
    if not candidates or len(labels) < CLUSTER_MIN:
        return {}
    X = np.concatenate([t.select(labels).markers for t in trials])
    groups = [g for g in _rigid_clusters(distance_variance(X), threshold) if len(g) >= CLUSTER_MIN]
    if not groups:
        return {}
    picked = pick_frames(trials, frames)
    Y = np.concatenate([t.select(labels).markers for t in picked])  # (F, labels, 3)
    far = np.full((len(groups), len(candidates)), np.inf)
    places: list[list[np.ndarray]] = [[np.empty((0, 3))] * len(candidates) for _ in groups]
    data, neutral = _neutral(model)

    for c, (sg, refs) in enumerate(candidates):
        local = neutral(refs)  # (R, 3) the references in the neutral pose
        world = np.concatenate([t.select(refs).markers for t in picked])  # (F, R, 3)
        have = np.all(np.isfinite(world), axis=2)
        turn, _ = kabsch_batch(local, np.where(have[..., None], world, 0.0), have.astype(float))
        own = data.oMf[model.pin.getFrameId(sg.name)]
        centre = neutral(sg.markers).mean(axis=0)
        modelled = np.linalg.norm(local - centre, axis=1)  # (R,) the candidate's distances to the references
        # the subject's size there: its references' distances to each other against the base model's
        pairs = [(a, b) for a in range(len(refs)) for b in range(a + 1, len(refs))]
        size = np.nanmedian([np.nanmedian(np.linalg.norm(world[:, a] - world[:, b], axis=1))
                             / np.linalg.norm(local[a] - local[b]) for a, b in pairs])
        for g, members in enumerate(groups):
            mid = Y[:, list(members)].mean(axis=1)  # (F, 3) the cluster's centroid
            seen = np.linalg.norm(world - mid[:, None], axis=2)  # (F, R)
            miss = np.sqrt(np.nanmean((seen - size * modelled) ** 2, axis=1))
            if np.isfinite(miss).sum() < 3:
                continue
            far[g, c] = float(np.nanmedian(miss))
            # Where each label would sit: about the candidate's model markers as about the cluster's centroid, turned
            # back by the references' rigid fit (the labels' places need only not all sit at the joint's centre: the
            # start's poses place them again, calibrate.calibration.pipeline._place_new_markers).
            rel = Y[:, list(members)] - mid[:, None]
            ok = np.all(np.isfinite(rel), axis=(1, 2)) & np.all(np.isfinite(turn), axis=(1, 2))
            if ok.any():
                back = np.median(np.einsum("fji,fmj->fmi", turn[ok], rel[ok]), axis=0) / size  # (members, 3)
                places[g][c] = (centre + back - own.translation) @ own.rotation
    out = {}
    for g, members in enumerate(groups):
        d = far[g]
        if not np.isfinite(d).any():
            continue
        order = np.argsort(d)
        best = int(order[0])
        second = int(order[1]) if len(order) > 1 else best
        ok = d[best] <= CLUSTER_REACH and (len(order) == 1 or d[best] <= CLUSTER_RATIO * d[second])
        names = tuple(labels[k] for k in members)
        at = places[g][best] if len(places[g][best]) == len(members) else np.zeros((len(members), 3))
        host = ClusterHost(names, candidates[best][0].name if ok else None, candidates[best][0].name,
                           float(d[best]), candidates[second][0].name,
                           float(d[second]) if len(order) > 1 else float("inf"), tuple(at))
        out.update({lab: host for lab in names})
    return out


JOINT_FIT = 0.012  # m RMS: a cluster's markers about a joint of a posed segment (the skin over a thigh: 2-6 mm)
JOINT_TURN = np.radians(20.0)  # ... turning through at least this against it (less: any point nearby fits as well)
JOINT_STILL = np.radians(15.0)  # ... and not less than this against any posed segment (it rides with that one:
# BTKData's functional hip trial, a thigh cluster against its femur's wand and knee markers, 11 deg; a simulated walk's
# shank turns 19 deg against the head)
JOINT_RATIO = 0.6  # ... and fitting at most this share of the best fit for another host (gait2392 on Rajagopal2016:
# a shank plate 9.4 mm RMS off the knee's axis, the talus below the subtalar's 17.9)
JOINT_NEAR = 0.10  # m: ... about a centre (or axis) this near the base model's joint, where the posed segment's
# model markers say where that is (a walk's hips end 28-65 mm from the labs')
JOINT_ROUND = 0.1  # a centre fit's smallest over middle eigenvalue from which it is placed in every direction
JOINT_SKIN = 0.010  # m: ... and keeps its distances to the markers its host shows within this SD
JOINT_RIGID = 0.003  # m: the cluster's distances vary by at most this SD (a plate on the skin: gait2392's 1-2 mm)
JOINT_FRAMES = 400  # about this many evenly spaced frames of the moving trials judge it


@dataclass(frozen=True)
class JointHost:
    """A cluster of mutually rigid new labels that turns about a point (or an axis) of a posed segment, `against`,
    and the segment it rides on, a joint away from there and not posed (`segment`; None: another host fits nearly
    as well).  `fit`: the RMS of the markers' distances to the fitted centre (or axis) about their mean (m); `turn`:
    how far the cluster turns against `against` (rad, _turn; NaN fit: under JOINT_STILL, it moves with that posed
    segment); `candidates`: the hosts that fit within JOINT_FIT;
    `runner_up`, `runner_up_fit`: the best-fitting other host and its fit (m; inf: none)."""

    labels: tuple[str, ...]
    segment: str | None
    against: str
    fit: float
    turn: float
    candidates: tuple[str, ...]
    runner_up: str = ""
    runner_up_fit: float = float("inf")
    still: str = ""  # a segment beyond `segment`'s joint whose markers the cluster keeps as rigidly as its own

    def reason(self, label: str) -> str:
        """Why `label` (one of `labels`) was placed there, or left out."""
        others = ", ".join(lab for lab in self.labels if lab != label)
        if not np.isfinite(self.fit):  # it turns with `against` (JOINT_STILL): on its skin, not about a joint of it
            return (f"rigid with {others}, the cluster turns only {np.degrees(self.turn):.0f} deg against "
                    f"{self.against}, whose markers the other tests did not find it rigid enough with: it moves with "
                    "that segment, not about a joint of it")
        about = (f"rigid with {others}, the cluster turns {np.degrees(self.turn):.0f} deg about a joint of "
                 f"{self.against} (its markers {1e3 * self.fit:.1f} mm RMS off a fixed centre or axis there"
                 + (f"; on {self.runner_up}, the next, {1e3 * self.runner_up_fit:.1f}" if self.runner_up else "") + ")")
        if self.segment:
            return f"{about}: on {self.segment}, the segment beyond that joint its own markers do not pose"
        if self.still:
            return (f"{about}, on {self.candidates[0] if len(self.candidates) == 1 else ' or '.join(self.candidates)}"
                    f" or past it: {self.still}'s markers keep their distances to it as rigidly as its own (the joints "
                    "between barely turn in the trials)")
        return f"{about}, but {' or '.join(self.candidates)} could carry it: the next fits nearly as well"


def joint_hosts(model: Model, trials: Sequence[Trial], labels: Sequence[str], placed: dict[str, str],
                frames: int = JOINT_FRAMES, rounds: int = HOST_ROUNDS) -> dict[str, JointHost]:
    """Each of `labels` (new labels no other test placed) in a rigid cluster of CLUSTER_MIN or more (their distances
    over the moving `trials` varying by JOINT_RIGID SD at most) that turns about a joint of a posed segment -> its
    JointHost, judged on about `frames` evenly spaced frames.

    A lab's thigh and shank plates on a model whose thigh and shank markers the walk does not show (gait2392's
    protocol: the knee and ankle markers in the static alone): no known marker poses the femur or tibia, so neither
    the model's poses (kinematic_hosts) nor the distances to known markers (rigidity) place the plates.  Their own
    motion does (seed 002: closed-form centres and axes of rotation): against the pelvis, posed by its markers, the
    thigh plate turns about one point, the hip's centre (gait2392: 2 mm RMS), while a shank plate, carried by the knee
    as well, does not (15-31 mm).  A posed segment is one the trials show three or more markers on (the model's, and
    new labels `placed` there, label -> segment).  Its candidate hosts: the segments a joint from it that carry model
    markers (through those that carry none, a talus), are not posed, lie on the side the labels name, and whose
    markers the trials show keep their distances to the cluster within JOINT_SKIN SD (OpenCap's walk: its left shank
    plate turns 86 deg about femur_l's knee, and tibia_l shows its ankle marker).  The cluster's markers in the posed
    segment's frame are fitted about a fixed axis where one hinge lies between (calibrate.seed.geometry.sphere_fit),
    else about a fixed centre: a talus below its subtalar hinge turns about an axis, while a shank plate, turned by
    the ankle too, misses one by 17 mm.  The best fit within JOINT_FIT over a turn of JOINT_TURN or more places the
    cluster, if it is within JOINT_RATIO of the best fit for another host.  Where three or more of the posed
    segment's model markers place the base model's joints in its frame, the fit's axis (a centre's least-determined
    line; the centre itself where JOINT_ROUND says every direction is placed, _off) must pass within JOINT_NEAR of one
    of those between (Expert2's sacral plate turns about the lumbar, which the torso's neck had stood for).  Not where
    a segment within two joints beyond the host shows markers the cluster keeps its distances to within JOINT_RIGID
    (the joints between barely turn: an arm in a walk), nor where it turns less than JOINT_STILL against a posed
    segment (it moves with that one, on skin that defeated the other tests: BTKData's functional hip trial, its left
    thigh cluster beside the femur's own markers, had gone on an unposed trunk about the left hip).  Up to `rounds`
    rounds: a segment so placed poses the next clusters (a shank plate about the knee, against the thigh plate)."""
    from ..seed.geometry import rigid_fit, similarity_fit, sphere_fit
    from ..seed.rigidity import distance_variance

    labels = [lab for lab in labels if all(lab in t.labels for t in trials)]
    if len(labels) < CLUSTER_MIN:
        return {}
    picked = pick_frames(trials, frames)
    X = np.concatenate([t.select(labels).markers for t in trials])
    D = distance_variance(X)
    tight = [g for g in _rigid_clusters(D, JOINT_RIGID ** 2) if len(g) >= CLUSTER_MIN]
    groups = [tuple(labels[k] for k in g) for g in tight] + _loose_clusters(trials, labels, D, tight)
    if not groups:
        return {}
    known = set(model.marker_names)
    shown = {lab for t in picked for lab in t.labels if lab in known and np.isfinite(t.marker(lab)).all(1).any()}
    on: dict[str, list[str]] = {sg.name: [m for m in sg.markers if m in shown] for sg in model.segments}
    for lab, seg in placed.items():
        if seg in on and all(lab in t.labels for t in picked):
            on[seg].append(lab)
    near: dict[str, list[tuple[str, int, str]]] = {sg.name: [] for sg in model.segments}  # neighbour, DoFs, joint
    for j in model.joints:
        near[j.parent].append((j.child, len(j.dofs), j.name))
        near[j.child].append((j.parent, len(j.dofs), j.name))
    _, neutral = _neutral(model)

    carries = {sg.name: bool(sg.markers) for sg in model.segments}

    def world(names: Sequence[str]) -> np.ndarray:
        return np.concatenate([t.select(list(names)).markers for t in picked])

    def beyond(seg: str) -> list[tuple[str, int, tuple[str, ...]]]:
        """The segments a joint from `seg` that carry model markers, through those that carry none (a talus), each
        with the degrees of freedom between (1: a hinge, fitted about an axis; more: about a centre) and the joints
        between."""
        out, todo, seen = [], [(seg, 0, ())], {seg}
        while todo:
            at, dofs, path = todo.pop()
            for n, d, j in near[at]:
                if n not in seen:
                    seen.add(n)
                    if carries[n]:
                        out.append((n, dofs + d, (*path, j)))
                    else:  # a segment with no model marker (a talus): passed through; at an end (a patella), none
                        todo.append((n, dofs + d, (*path, j)))
        return out

    def joint_centres(seg: str, frame) -> dict[str, np.ndarray] | None:
        """Every joint centre of the base model (its child segment's origin) in `frame` (the posed segment `seg`'s,
        rigid_fit of its shown markers), by a similarity fit of the base model's neutral pose to the model markers
        among them; None where fewer than three non-collinear model markers pose it (new labels have no place in
        the base model)."""
        names = on[seg]
        mine = [k for k, n in enumerate(names) if n in known]
        if len(mine) < 3:
            return None
        src = neutral([names[k] for k in mine])
        if np.linalg.svd(src - src.mean(0), compute_uv=False)[1] < 0.01:
            return None
        scale, R, t = similarity_fit(src, frame.local[mine])
        return {j.name: scale * R @ neutral([j.child])[0] + t for j in model.joints}

    def still_below(host: str, against: str, g: Sequence[str]) -> str | None:
        """A segment within two joints of `host`, away from `against`, whose shown markers the cluster keeps its
        distances to as rigidly as to each other (JOINT_RIGID): the joints between barely turn, and the cluster may
        ride on either side of them (pig_walk's arm in a walk, its upper-arm, forearm and hand markers within
        1-2.5 mm of each other); None where there is none."""
        todo, seen = [(host, 0)], {host, against}
        while todo:
            at, depth = todo.pop()
            for n, _, _ in near[at]:
                if n in seen or depth >= 2:
                    continue
                seen.add(n)
                if on[n] and _keeps(world(on[n]), world(g), JOINT_RIGID):
                    return n
                todo.append((n, depth + 1))
        return None

    out: dict[str, JointHost] = {}
    for _ in range(rounds):
        posed = {seg: rigid_fit(world(names)) for seg, names in on.items() if len(names) >= 3}
        placed_now = False
        for g in groups:
            if g[0] in out and out[g[0]].segment is not None:
                continue
            sides = {named_side(lab) for lab in g}
            side = sides.pop() if len(sides) == 1 else None
            traj = world(g)  # (F, P, 3) the cluster's trajectories over the picked frames
            pairs = []  # (fit, turn, posed segment, candidate host): fitted about an axis across a hinge, else a centre
            turns = {}  # posed segment -> the cluster's turn against it
            for seg, frame in posed.items():
                rel = frame.to_local(traj)  # (F, P, 3) the cluster in the posed segment's frame
                rel = rel[np.all(np.isfinite(rel), axis=(1, 2))]
                if len(rel) < 10:
                    continue
                turn = _turn(rigid_fit(rel).R)
                if not np.isfinite(turn):
                    continue
                turns[seg] = turn
                cands = [(s, d, js) for s, d, js in beyond(seg) if s not in posed and named_side(s) in (None, side)
                         and _keeps(world(on[s]), traj)]
                if not cands:
                    continue
                try:
                    ball, hinge = sphere_fit(rel), sphere_fit(rel, hinge=True)
                except (ValueError, np.linalg.LinAlgError):
                    continue
                centres = joint_centres(seg, frame)
                for s, d, js in cands:
                    fit = hinge if d == 1 else ball
                    # The fitted axis or centre (_off) passes near one of the joints between, where the posed segment's
                    # model markers put the base model's (a sacral plate turns about the lumbar, not the trunk's neck:
                    # Expert2's run had put one on the head at 5.7 mm RMS about the torso).
                    if centres is not None and min(_off(centres[j], fit) for j in js) > JOINT_NEAR:
                        continue
                    pairs.append((fit.rms, turn, seg, s))
            # The best pair, against the best that names another host: a segment a joint away hosts it only where the
            # cluster turns about that joint as the joint turns (a talus below its subtalar hinge, the shank plate
            # turning with the ankle too: 16.8 mm RMS off an axis, 2.3 off a centre), and better than about any other.
            with_ = min(turns, key=turns.get) if turns else ""
            if with_ and turns[with_] < JOINT_STILL:  # it moves with a posed segment, on its skin: not one beyond it
                out.update({lab: JointHost(g, None, with_, float("nan"), turns[with_], ()) for lab in g})
                continue
            good = [x for x in pairs if x[0] <= JOINT_FIT and x[1] >= JOINT_TURN]
            if not good:
                continue  # no joint of a posed segment carries it: not this test's to judge
            fit, turn, seg, host = min(good, key=lambda x: x[0])
            rival = min(((f, h) for f, _, _, h in pairs if h != host), default=(np.inf, ""))
            still = still_below(host, seg, g)
            ok = fit <= JOINT_RATIO * rival[0] and still is None
            found = JointHost(g, host if ok else None, seg, float(fit), float(turn),
                              tuple(sorted({h for *_, h in good})), rival[1], float(rival[0]), still or "")
            out.update({lab: found for lab in g})
            if ok:
                on[host] = list(g)
                placed_now = True
        if not placed_now:
            break
    return out


def _neutral(model: Model):
    """Pinocchio's data at the base model's neutral pose (the root at the origin, every angle 0), and a function giving
    the places there of named frames ((n, 3), m)."""
    import pinocchio as pin

    data = model.pin.createData()
    pin.framesForwardKinematics(model.pin, data, model.pin_configuration(np.zeros(3), [0, 0, 0, 1],
                                                                         np.zeros(model.n_dofs)))

    def at(names: Sequence[str]) -> np.ndarray:
        return np.array([data.oMf[model.pin.getFrameId(n)].translation for n in names]).reshape(-1, 3)

    return data, at


def _off(point: np.ndarray, fit) -> float:
    """How far `point` lies from a sphere fit's axis, the line through its centre along its least-determined direction
    (a hinge's axis; a swing about one axis leaves a centre free along it), or from its centre where every direction
    is determined (hinge_ratio at least JOINT_ROUND: a functional hip trial's star arc) (m)."""
    d = point - fit.centre
    return float(np.linalg.norm(d if fit.hinge_ratio >= JOINT_ROUND else d - (d @ fit.axis) * fit.axis))


def _keeps(a: np.ndarray, b: np.ndarray, within: float = JOINT_SKIN) -> bool:
    """Whether every marker of `a` (F, A, 3) keeps its distance to every marker of `b` (F, B, 3) within `within` SD
    over the frames that show both (True where `a` has none): a segment's own markers and a cluster on it, the skin
    between them moving (OpenCap's shank plate against its ankle marker: 3-5 mm)."""
    if a.shape[1] == 0:
        return True
    d = np.linalg.norm(a[:, :, None] - b[:, None], axis=3)  # (F, A, B)
    with np.errstate(invalid="ignore"):
        sd = np.nanstd(d, axis=0)
    return bool(np.all(np.nan_to_num(sd, nan=np.inf) <= within))


def _turn(R: np.ndarray) -> float:
    """How far rotations R (F, 3, 3) turn: twice the 95th percentile of their angles from their mean orientation
    (rad; a swing of +-30 deg about the mean: 60 deg); NaN where no frame's rotation is defined (markers on a
    line)."""
    R = R[np.all(np.isfinite(R), axis=(1, 2))]
    if not len(R):
        return float("nan")
    U, _, Vt = np.linalg.svd(R.mean(axis=0))
    mean = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    rel = np.einsum("ji,fjk->fik", mean, R)  # mean^T R_f
    ang = np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    return float(2.0 * np.percentile(ang, 95))


# A cluster strapped loosely to the skin wobbles more than a plate (MOtoNMS's UWA fast walk: its right thigh cluster's
# distances vary by 2.9-3.7 mm SD, the left's by 0.9-1.6) and the tight test leaves it out.  Of the labels no tight
# cluster took, those whose distances vary within JOINT_LOOSE SD form a cluster still where every one of them varies
# JOINT_APART times as much against every other label the trials show: on one segment, away from the others (the UWA
# thigh's: 7.7 mm at least, against the sacral and shank markers).  A forearm and a hand cluster across a wrist a walk
# barely turns (2-5 mm) are each a tight cluster first, and stay two.
JOINT_LOOSE = 0.005  # m
JOINT_APART = 2.0


def _loose_clusters(trials: Sequence[Trial], labels: Sequence[str], D: np.ndarray,
                    tight: Sequence[tuple[int, ...]]) -> list[tuple[str, ...]]:
    """The loosely strapped clusters among `labels` no cluster of `tight` (indices into `labels`) took: CLUSTER_MIN or
    more whose distances vary within JOINT_LOOSE SD (D: their distance variances over `trials`, m²), each varying
    JOINT_APART times its cluster's largest SD against every other label of the trials (unlabelled ones aside)."""
    from ..io.labels import UNLABELLED
    from ..seed.rigidity import distance_variance

    taken = {k for g in tight for k in g}
    left = [k for k in range(len(labels)) if k not in taken]
    if len(left) < CLUSTER_MIN:
        return []
    out = []
    # (not the unlabelled trajectories: a piece of one of the cluster's own markers among them keeps to it)
    everyone = sorted({lab for t in trials for lab in t.labels if not UNLABELLED.fullmatch(lab)} | set(labels))
    full = None
    for g in _rigid_clusters(D[np.ix_(left, left)], JOINT_LOOSE ** 2):
        if len(g) < CLUSTER_MIN:
            continue
        names = [labels[left[i]] for i in g]
        inner = float(np.sqrt(max(D[left[i], left[j]] for i in g for j in g)))
        if full is None:  # every label's distances to every other, over the trials (once)
            full = distance_variance(np.concatenate([t.columns(everyone) for t in trials]))
        mine = [everyone.index(n) for n in names]
        others = [k for k in range(len(everyone)) if k not in mine]
        apart = full[np.ix_(mine, others)]
        if others and np.all(np.sqrt(apart[np.isfinite(apart)]) >= JOINT_APART * inner):
            out.append(tuple(names))
    return out


def _rigid_clusters(D: np.ndarray, threshold: float) -> list[tuple[int, ...]]:
    """Groups of labels every pair of which keeps its distance within `threshold` (D: distance variances, m²):
    complete linkage, pairs taken from the steadiest, two groups merged when every pair across them is steady (the
    paper's greedy keeps two pairs of one head band apart, each formed before the pair between them)."""
    groups = [{k} for k in range(len(D))]
    order = sorted((D[i, j], i, j) for i in range(len(D)) for j in range(i + 1, len(D)) if D[i, j] <= threshold)
    for _, i, j in order:
        a = next(g for g in groups if i in g)
        b = next(g for g in groups if j in g)
        if a is not b and all(D[x, y] <= threshold for x in a for y in b):
            a |= b
            groups.remove(b)
    return [tuple(sorted(g)) for g in groups]


# A segment no marker of the model's poses (a lower-limb marker set's torso: pyCGM2's gait2392 with its cgm23 set) is
# no candidate of the hosts' tests: in their poses it turns with its parent, so a label riding on it keeps its place on
# the parent as well, and the parent takes it (pig_walk's C7, T10, CLAV, STRN, RBAK, both shoulders, its head's back
# and upper-arm markers on that pelvis, 12-18 mm RMS; the lumbar locked; the hip angles' frame-to-frame difference
# from Plug-in Gait's own 3.1 / 3.8 deg SD in flexion, against 1.2 / 1.7 with the upper body left out).  Where three or
# more of a segment's new labels sit past such a child's joint (toward the child's mass centre, in the base model's
# neutral pose: BEYOND_NEAR to BEYOND_FAR of the way, their centroid BEYOND_DEPTH), nearer its mass centre than the
# parent's, and keep their distances to each other within BEYOND_RIGID (a trunk's: 1-3 mm over a walk), they
# ride on the child as one body (unless they keep them to the parent's own markers as well); the others past the
# joint go with them where their places spread in the cluster's frame as a host's would (HOST_SPREAD, HOST_RATIO
# against the parent), stay where they spread less on the parent, and are left out otherwise (an upper arm's swing).
BEYOND_MIN = 3
BEYOND_RIGID = 0.003  # m: SD of each pair's distance over the moving trials' frames (JOINT_RIGID)
BEYOND_NEAR = 0.25  # each past the child's joint by this share of its mass centre's distance from it (an iliac
# crest's marker, by the lumbar centre's height, keeps its distances to a trunk's within BEYOND_RIGID in a walk)
BEYOND_DEPTH = 0.5  # ... and their centroid by this share
BEYOND_FAR = 2.0  # ... and none further than this share (a uniform body's length: a hip's marker is no humerus's)


@dataclass(frozen=True)
class BeyondJoint:
    """A new label the hosts' tests placed on `placed` that sits past the joint of `child`, a segment below it that
    no marker the trials show poses, toward the child's mass centre: `segment` is `child` (with the rigid `cluster`
    that poses it) or None (left out: its place spreads `spread` m RMS in the cluster's frame, `own` m on
    `placed`)."""

    label: str
    segment: str | None
    placed: str
    child: str
    cluster: tuple[str, ...]
    place: np.ndarray | None  # its place in the child's frame (m, the base model's neutral pose)
    spread: float = 0.0
    own: float = 0.0

    def reason(self) -> str:
        """Why it rides on the child (or on neither)."""
        beyond = (f"sits past the joint of {self.child} (toward its mass centre), a segment no marker of the "
                  f"model's poses, which turned with {self.placed} in the poses that put it there")
        if self.label in self.cluster:
            others = ", ".join(lab for lab in self.cluster if lab != self.label)
            return (f"{beyond}; rigid with {others} (within {1e3 * BEYOND_RIGID:.0f} mm SD), they ride on "
                    f"{self.child} as one body")
        if self.segment:
            return (f"{beyond}; its place in the frame of {self.child}'s cluster ({', '.join(self.cluster)}) spreads "
                    f"{1e3 * self.spread:.1f} mm RMS (on {self.placed}: {1e3 * self.own:.0f} mm)")
        return (f"{beyond}; its place spreads {1e3 * self.spread:.1f} mm RMS in the frame of {self.child}'s cluster "
                f"({', '.join(self.cluster)}) and {1e3 * self.own:.1f} on {self.placed}: on neither (a host: under "
                f"{1e3 * HOST_SPREAD:.0f} mm and half the other)")


def _mass_centres(model: Model, data) -> dict[str, np.ndarray]:
    """Each segment's mass centre in the world at `data`'s pose (m; its Pinocchio joint's, welded bodies merged)."""
    out = {}
    for sg in model.segments:
        fid = model.pin.getFrameId(sg.name)
        jid = model.pin.frames[fid].parentJoint
        inertia = model.pin.inertias[jid]
        out[sg.name] = (data.oMi[jid].act(inertia.lever) if inertia.mass > 0
                        else data.oMf[fid].translation.copy())
    return out


def beyond_joints(model: Model, trials: Sequence[Trial], placed: dict[str, str],
                  frames: int = HOST_FRAMES, cache: BasePoses | None = None) -> dict[str, BeyondJoint]:
    """Of `placed` (new label -> segment, by the hosts' tests), those beyond the joint of a child segment that no
    shown model marker poses, on it or below it (BEYOND_MIN, BEYOND_RIGID above) -> BeyondJoint,
    judged on the moving `trials` (their median places on about `frames` frames posed by the base model's known
    markers; their distances over every frame).  The joints are taken down the tree, a child given a cluster then
    carrying the next (a head on its neck above a torso that had no marker either); the labels are those put on the
    child's parent or on a segment above it (a head's, on a pelvis, where both joints between turned with it).
    `cache`: the association's BasePoses."""
    from ..model.resolve import descendants
    from ..seed.geometry import kabsch_batch
    from ..seed.rigidity import distance_variance

    shown = {lab for t in trials for lab in t.labels} & set(model.marker_names)
    # (the segments the poses place: new labels placed on a segment pose it in none of them, a head band the
    # cluster test put on Rajagopal2016's torso, by its head markers, included)
    carried = {model.markers[model.marker_index(m)].segment for m in shown}
    below = descendants(model)
    parent_of = {j.child: j.parent for j in model.joints}

    def up(segment: str | None) -> list[str]:
        """The segment and those above it."""
        return [] if segment is None else [segment, *up(parent_of.get(segment))]

    def open_joint(j: Joint) -> bool:
        return bool(j.dofs) and j.parent in carried and not any(sg in carried for sg in below[j.child])

    if not any(sum(sg in up(j.parent) for sg in placed.values()) >= BEYOND_MIN for j in model.joints if open_joint(j)):
        return {}  # (a child opened by a cluster is below one that is open now)
    data, _ = _neutral(model)
    centres = _mass_centres(model, data)
    picked = pick_frames(trials, frames)
    fits = _posed(model, picked, list(placed), cache=cache)
    if not fits:
        return {}
    names = [sg.name for sg in model.segments]
    places = local_places(model, fits, list(placed), names)
    out: dict[str, BeyondJoint] = {}
    for jt in model.joints:  # down the tree
        if not open_joint(jt):
            continue
        child, parent = jt.child, jt.parent
        labs = [lab for lab, sg in placed.items() if sg in up(parent) and lab not in out and lab in places]
        if len(labs) < BEYOND_MIN:
            continue
        P, C = (data.oMf[model.pin.getFrameId(sg)] for sg in (parent, child))
        joint = P.actInv(C.translation)  # the child's joint centre and mass centre in the parent's frame
        reach = P.actInv(centres[child]) - joint
        depth = float(np.linalg.norm(reach))
        if depth < 1e-6:
            continue
        mids = {lab: np.median(places[lab][:, names.index(parent)], axis=0) for lab in labs}
        past = [lab for lab, x in mids.items() if BEYOND_NEAR < (x - joint) @ reach / depth ** 2 <= BEYOND_FAR]
        # the cluster's own labels nearer the child's mass centre than the parent's (a trunk's plate at the chest's
        # midline lies below a hanging arm's shoulder, toward the humerus's mass centre, yet by the torso's)
        mine, theirs = P.actInv(centres[parent]), P.actInv(centres[child])
        by = [lab for lab in past if np.linalg.norm(mids[lab] - theirs) < np.linalg.norm(mids[lab] - mine)]
        if len(by) < BEYOND_MIN:
            continue
        parts = [t.select(by).markers for t in trials if all(lab in t.labels for lab in by)]
        if not parts:
            continue  # no trial shows them together
        groups = [g for g in _rigid_clusters(distance_variance(np.concatenate(parts)), BEYOND_RIGID ** 2)
                  if len(g) >= BEYOND_MIN]
        if not groups:
            continue
        # the largest; of two as large, the one nearer the child's mass centre (a trunk's, not a head band above it)
        cluster = tuple(by[k] for k in min(groups, key=lambda g: (-len(g), float(np.linalg.norm(
            np.mean([mids[by[k]] for k in g], axis=0) - theirs)))))
        shape = np.array([mids[lab] for lab in cluster])
        if (shape.mean(axis=0) - joint) @ reach < BEYOND_DEPTH * depth ** 2:
            continue  # its centroid by the joint: not beyond it
        if np.linalg.svd(shape - shape.mean(axis=0), compute_uv=False)[1] < 0.01:
            continue  # on a line: it would not pose the child about it
        own = [m for m in model.segments[model.segment_index(parent)].markers if m in shown]
        both = [t for t in trials if all(lab in t.labels for lab in (*cluster, *own))]
        if own and both and _keeps(np.concatenate([t.select(list(cluster)).markers for t in both]),
                                   np.concatenate([t.select(own).markers for t in both]), BEYOND_RIGID):
            continue  # as rigid with the parent's own markers as with each other: it rides on the parent
        rel = C.actInv(P)  # the parent's frame -> the child's, in the neutral pose
        for lab in cluster:
            out[lab] = BeyondJoint(lab, child, placed[lab], child, cluster,
                                   np.asarray(rel.act(mids[lab]), dtype=float))
        carried.add(child)
        rest = [lab for lab in past if lab not in cluster]
        if not rest:
            continue
        # The others in the cluster's own frame: its mean shape fitted to each frame that shows it whole
        parts = [t.columns((*cluster, *rest)) for t in picked if all(lab in t.labels for lab in cluster)]
        Y = np.concatenate(parts) if parts else np.empty((0, len(cluster) + len(rest), 3))
        Y = Y[np.all(np.isfinite(Y[:, :len(cluster)]), axis=(1, 2))]
        if len(Y) < 3:
            continue
        ref = np.median(Y[:, :len(cluster)] - Y[:, :len(cluster)].mean(axis=1, keepdims=True), axis=0)
        R, t = kabsch_batch(ref, Y[:, :len(cluster)], np.ones((len(Y), len(cluster))))
        for k, lab in enumerate(rest):
            q = np.einsum("fji,fj->fi", R, Y[:, len(cluster) + k] - t)  # R^T (x - t)
            q = q[np.all(np.isfinite(q), axis=1)]
            if len(q) < 3:
                continue
            spread = float(np.sqrt(np.mean(np.sum((q - np.median(q, axis=0)) ** 2, axis=1))))
            on_host = places[lab][:, names.index(placed[lab])]
            own = float(np.sqrt(np.mean(np.sum((on_host - np.median(on_host, axis=0)) ** 2, axis=1))))
            if own <= spread:
                continue  # it keeps its place where the tests put it better
            ok = spread <= HOST_SPREAD and spread <= HOST_RATIO * own
            out[lab] = BeyondJoint(lab, child if ok else None, placed[lab], child, cluster,
                                   np.asarray(rel.act(mids[lab]), dtype=float) if ok else None, spread, own)
    return out


def trial_exchanges(model: Model, trials: Sequence[Trial], moving: Sequence[int],
                    labels: Sequence[str], still: Sequence[int] = ()) -> list:
    """Cluster labels that trials name otherwise than each other: the new labels `labels` (markers `model` does not
    know) and the model's own placeholder markers (calibrate.problem.priors.placeholder_markers: a lab's OpenSim
    marker set with each cluster at one point, for the marker placer to fill).  Each trial's labels are hosted alone
    (kinematic_hosts on its own frames; the placeholders as new labels, the model posed without them), and on each
    segment the labels every one of the `moving` trials puts there are matched trial against trial by their places
    (calibrate.calibration.moved.exchange_of).  The reference is the moving trial that agrees with the most others
    (the first of a tie); each other moving trial whose labels read otherwise than the reference's is returned
    (moved.ExchangedCluster, its `reference` set), and so is each `still` trial whose placeholders do (a still trial's
    new labels are matched after the start's poses: moved.exchanged_clusters); the model's other own markers are
    matched among the moving trials by _own_exchanges.  Expert1's static1 with walking1 and
    walkingTO1: the two walks name the right thigh plate's r_thigh3 and r_thigh5 otherwise, and pooled, the host
    rule had found each label's place spread 34-70 mm and left out the plates' markers; on the expert's
    generic.osim, whose plates are placeholders, walking1 with DJ1 fitted walking1 to 27.7 mm."""
    from ..problem.priors import placeholder_markers
    from .moved import exchange_of

    # The placeholders under a name the model does not know (so that they neither pose it nor keep their one point).
    held = [model.markers[k].name for k in placeholder_markers(model, model.parameters())]
    tag = {lab: PLACEHOLDER_TAG + lab for lab in held}
    back = {v: k for k, v in tag.items()}
    asked = [*labels, *tag.values()]
    still = [t for t in still if any(lab in trials[t].labels for lab in held)]
    if not moving or len(moving) + len(still) < 2 or not asked:
        return _own_exchanges(model, trials, moving, set(held))
    seen = {t: replace(trials[t], labels=tuple(tag.get(lab, lab) for lab in trials[t].labels))
            for t in [*moving, *still]}
    # One round (the known markers' poses): the places to match need no more, and the rounds tripled the time (Expert1's
    # static1 + walking1 + walkingTO1: 1.32 s, one round 0.50, the same labels read).
    hosted = {t: kinematic_hosts(model, [seen[t]], [lab for lab in asked if lab in seen[t].labels], rounds=1)
              for t in moving}
    # A still trial's labels are rigid with every segment (no best host): each placeholder's place on its own segment.
    segment_of = {tag[mk.name]: mk.segment for mk in model.markers if mk.name in tag}
    fixed = {t: _segment_places(model, seen[t], {lab: segment_of[lab] for lab in tag.values() if lab in seen[t].labels})
             for t in still}
    out = []
    # A label counts on the segment where its place spreads least, within twice HOST_SPREAD: one walk alone poses a
    # thigh less surely than the trials together (walkingTO1's L_thigh1-3: 20-32 mm, the host rule's 20 mm exceeded).
    on = {t: {lab: h.best for lab, h in hs.items() if h.spread <= 2 * HOST_SPREAD} for t, hs in hosted.items()}
    for segment in sorted({s for t in moving for s in on[t].values()}):
        common = [lab for lab in asked if all(on[t].get(lab) == segment for t in moving)]
        if len(common) < 2:
            continue
        places = {t: np.array([hosted[t][lab].place for lab in common]) for t in moving}
        agree = {t: sum(exchange_of(t, segment, common, places[t], places[u]) is None for u in moving if u != t)
                 for t in moving}
        ref = max(moving, key=lambda t: (agree[t], -t))
        found = [exchange_of(t, segment, common, places[t], places[ref]) for t in moving if t != ref]
        for t in still:
            mine = [k for k, lab in enumerate(common) if lab in fixed[t] and segment_of[lab] == segment]
            if len(mine) >= 2:
                found.append(exchange_of(t, segment, [common[k] for k in mine],
                                         np.array([fixed[t][common[k]] for k in mine]), places[ref][mine]))
        out += [replace(x, reference=ref, labels=tuple(back.get(lab, lab) for lab in x.labels),
                        read_as=tuple(back.get(lab, lab) for lab in x.read_as)) for x in found if x is not None]
    return out + _own_exchanges(model, trials, moving, set(held))


def _own_exchanges(model: Model, trials: Sequence[Trial], moving: Sequence[int], skip: set[str]) -> list:
    """The model's own markers (but `skip`: the placeholders, matched as new labels) that moving trials name otherwise
    than each other: each trial's frames (about HOST_FRAMES) posed by the base model; on each segment where two or
    more markers fit one trial worse than another by moved.SUSPECT or more (median), every trial posed again without
    those (from its first poses), its labels' places on the segment read and matched trial against trial as
    trial_exchanges matches new labels (the reference: the trial agreeing with the most others, the first of a
    tie).  Expert1 on the expert's hand_scaled.osim (its plates placed where the static puts them): walking1 + DJ1 had
    fitted walking1 to 27.8 mm."""
    from ..model.kinematics import build_kinematics
    from ..solve.ik import DECISION_TOLERANCE, inverse_kinematics
    from .moved import SUSPECT, exchange_of

    if len(moving) < 2:
        return []
    kin, params = build_kinematics(model), model.parameters()
    picked = {t: pick_frames([trials[t]], HOST_FRAMES)[0] for t in moving}
    fits = {t: inverse_kinematics(kin, picked[t], params, tolerance=DECISION_TOLERANCE) for t in moving}
    # A segment is read where two or more of its markers fit one trial worse than another by SUSPECT or more (median
    # over the frames): a base model not yet scaled misfits every trial alike (the expert's generic.osim: 12 segments
    # over SUSPECT in both of two walks, 3.3 s to pose them all again).
    typical = {}
    for t in moving:
        err = np.linalg.norm(fits[t].residuals, axis=2)
        typical[t] = np.where(np.isfinite(err).sum(axis=0) >= 3,
                              np.median(np.where(np.isfinite(err), err, 0.0), axis=0), np.nan)
    T = np.array([typical[t] for t in moving])
    apart = np.where(np.isnan(T), -np.inf, T).max(axis=0) - np.where(np.isnan(T), np.inf, T).min(axis=0)
    suspects: dict[str, set[str]] = {}
    for k, mk in enumerate(model.markers):
        if mk.name not in skip and apart[k] >= SUSPECT:
            suspects.setdefault(mk.segment, set()).add(mk.name)
    suspects = {seg: names for seg, names in suspects.items() if len(names) >= 2}
    out = []
    for segment, bad_names in suspects.items():
        places = {}
        for t in moving:
            posed = inverse_kinematics(kin, picked[t].select([lab for lab in picked[t].labels if lab not in bad_names]),
                                       params, tolerance=DECISION_TOLERANCE, start=fits[t].motion)
            local = local_places(model, [(picked[t], posed)], sorted(bad_names), [segment])
            places[t] = {lab: np.median(P[:, 0], axis=0) for lab, P in local.items()}
        common = [lab for lab in sorted(bad_names) if all(lab in places[t] for t in moving)]
        if len(common) < 2:
            continue
        at = {t: np.array([places[t][lab] for lab in common]) for t in moving}
        agree = {t: sum(exchange_of(t, segment, common, at[t], at[u]) is None for u in moving if u != t)
                 for t in moving}
        ref = max(moving, key=lambda t: (agree[t], -t))
        out += [replace(x, reference=ref) for t in moving if t != ref
                and (x := exchange_of(t, segment, common, at[t], at[ref])) is not None]
    return out


def _segment_places(model: Model, trial: Trial, segment_of: dict[str, str]) -> dict[str, np.ndarray]:
    """Each label of `segment_of` -> its median place (m) in its segment's frame over about HOST_FRAMES frames of
    `trial`, the model posed by its known markers (as kinematic_hosts poses it); labels seen in too few frames are
    left out."""
    fits = _posed(model, pick_frames([trial], HOST_FRAMES), list(segment_of))
    if not fits:
        return {}
    segments = sorted(set(segment_of.values()))
    local = local_places(model, fits, list(segment_of), segments)
    return {lab: np.median(P[:, segments.index(segment_of[lab])], axis=0) for lab, P in local.items()}
